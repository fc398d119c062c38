#!/usr/bin/env bash
# Issue 5's renderer comparison: our GPU raycaster against VTK, the renderer most medical
# viewers use, in one run. Per scene and mode the CPU reference renderer draws the picture
# once (float EXR); then each renderer is timed over FRAMES frames of the same camera (the
# reference's, saved with --save-camera) at 512x512 and its image compared with the reference
# (octoray-compare: PSNR, SSIM, RMSE, max error over premultiplied RGB):
#   octoray GPU, lod 1 px    octoray-render --gpu --lod-pixels 1   (what a user sees)
#   octoray GPU, full res    octoray-render --gpu --lod-pixels 0   (the accuracy row)
#   octoray GPU, sampled MIP octoray-render --gpu --mip sampled    (MIP mode only)
#   VTK GPU                  vtk-peer --mapper gpu  (vtkGPUVolumeRayCastMapper, same GL driver)
#   VTK CPU                  vtk-peer --mapper cpu  (vtkFixedPointVolumeRayCastMapper)
# Scenes: the 140-slice 1 mm Philips head (dcm_qa_ct) and a 512^3 octoray-phantom, both
# imported into stores with border 2. Modes: DVR shaded and unshaded (Slicer's CT-Bone, its
# unit gradient opacity dropped), MIP, isosurface at ISO_HU (VTK CPU has no isosurface mode).
# Rows that cannot run (octoray-render without --gpu, a failed renderer) are listed with a
# note instead of numbers; the rest of the run goes on.
#
# Usage: bench/render_compare.sh BUILD_DIR OUT_DIR [FRAMES=5]
# Environment: SCENES="head phantom"  MODES="dvr-shaded dvr-unshaded mip iso"  ISO_HU=300
#   STEP_MM (sample distance passed to every timed renderer; unset: each one's default)
#   SIZE=512x512  OCTORAY_SHARED (default: ../shared beside the repository)
# Output: OUT_DIR/results.md (table), OUT_DIR/results.jsonl (one object per row), and per
# scene/mode the images, the JSON each tool printed and its stderr.
set -euo pipefail

if [[ $# -lt 2 || $# -gt 3 ]]; then
  echo "usage: $0 BUILD_DIR OUT_DIR [FRAMES=5]" >&2
  exit 2
fi
build=$(realpath "$1")
out=$(realpath -m "$2")
frames=${3:-5}
command_line="$0 $*"
repo=$(realpath "$(dirname "$0")/..")
shared=${OCTORAY_SHARED:-$repo/../shared}
scenes=${SCENES:-head phantom}
modes=${MODES:-dvr-shaded dvr-unshaded mip iso}
iso_hu=${ISO_HU:-300}
size=${SIZE:-512x512}
step=${STEP_MM:-}
presets=$shared/data/presets/slicer/presets.xml
head_dicom=$shared/data/dicom/dcm_qa_ct/Philips/S21570/S2020  # STD BRAIN 1MM, 140 slices
py=/usr/bin/python3
bin=$build/bin

for tool in octoray-import octoray-phantom octoray-render octoray-compare vtk-peer; do
  if [[ ! -x $bin/$tool ]]; then
    echo "$0: $bin/$tool is missing (build it: cmake --build $1 --target $tool)" >&2
    exit 1
  fi
done
[[ -f $presets ]] || { echo "$0: $presets is missing (../shared/data)" >&2; exit 1; }
mkdir -p "$out"
manifest=$out/manifest.tsv
: > "$manifest"

# vtk-peer needs an X display for its GL context; give it a virtual one when there is none.
vtk_prefix=()
if [[ -z ${DISPLAY:-} ]]; then
  command -v xvfb-run > /dev/null || { echo "$0: no DISPLAY and no xvfb-run" >&2; exit 1; }
  vtk_prefix=(xvfb-run -a -s "-screen 0 1024x768x24 -noreset")
fi

has_gpu=0
if "$bin/octoray-render" --help 2>/dev/null | grep -q -- '--gpu'; then has_gpu=1; fi
step_args=()
[[ -n $step ]] && step_args=(--step "$step")
tf_args=(--tf "$presets" --tf-name CT-Bone)

log() { echo "[$(date +%H:%M:%S)] $*" >&2; }

# row SCENE MODE SHADING RENDERER RUN_JSON CMP_JSON NOTE COMMAND...: one line of the manifest.
row() {
  local scene=$1 mode=$2 shading=$3 renderer=$4 run_json=$5 cmp_json=$6 note=$7
  shift 7
  printf '%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\n' "$scene" "$mode" "$shading" "$renderer" \
    "$run_json" "$cmp_json" "$note" "$*" >> "$manifest"
}

# timed DIR NAME COMMAND...: runs COMMAND with stdout to DIR/NAME.json and stderr to
# DIR/NAME.err; on failure prints the error's last line and returns non-zero.
timed() {
  local dir=$1 name=$2
  shift 2
  if "$@" > "$dir/$name.json" 2> "$dir/$name.err"; then return 0; fi
  log "  $name failed: $(tail -n 1 "$dir/$name.err")"
  return 1
}

# compare DIR NAME: octoray-compare of DIR/NAME.exr against DIR/reference.exr.
compare() {
  "$bin/octoray-compare" "$1/reference.exr" "$1/$2.exr" --json > "$1/$2.cmp.json" \
    2> "$1/$2.cmp.err" || { log "  compare $2 failed: $(tail -n 1 "$1/$2.cmp.err")"; return 1; }
}

# prepare_scene NAME: prints the path of the scene's store, building it when absent.
prepare_scene() {
  local store=$out/$1.store
  if [[ -f $store ]]; then echo "$store"; return; fi
  case $1 in
    head)
      [[ -d $head_dicom ]] || { echo "$0: $head_dicom is missing" >&2; return 1; }
      log "import $head_dicom -> $store"
      "$bin/octoray-import" "$head_dicom" -o "$store" --border 2 >&2 ;;
    phantom)
      log "octoray-phantom 512^3 -> $store"
      "$bin/octoray-phantom" --size 512x512x512 -o "$out/phantom-512.nhdr" >&2
      "$bin/octoray-import" "$out/phantom-512.nhdr" -o "$store" --border 2 >&2
      rm -f "$out/phantom-512.nhdr" "$out/phantom-512.raw" ;;
    *) echo "$0: unknown scene $1 (head, phantom)" >&2; return 1 ;;
  esac
  echo "$store"
}

mode_args() {  # MODE: the mode flags shared by every renderer
  case $1 in
    dvr-shaded) echo "--mode dvr --shading on --no-gradient-opacity" ;;
    dvr-unshaded) echo "--mode dvr --shading off --no-gradient-opacity" ;;
    mip) echo "--mode mip" ;;
    iso) echo "--mode iso --iso $iso_hu --shading on" ;;
    *) echo "$0: unknown mode $1" >&2; return 1 ;;
  esac
}
shading_of() { case $1 in dvr-shaded | iso) echo on ;; dvr-unshaded) echo off ;; *) echo "-" ;; esac; }

for mode in $modes; do mode_args "$mode" > /dev/null || exit 2; done

for scene in $scenes; do
  store=$(prepare_scene "$scene")
  camera=$out/$scene.camera.json
  for mode in $modes; do
    dir=$out/$scene/$mode
    mkdir -p "$dir"
    read -r -a margs <<< "$(mode_args "$mode")"
    shading=$(shading_of "$mode")
    log "$scene $mode"

    # The reference, once; its camera (default orbit, SIZE) is every renderer's camera.
    cmd=("$bin/octoray-render" "$store" --reference -o "$dir/reference.png" --exr
         "$dir/reference.exr" "${tf_args[@]}" "${margs[@]}" --json)
    if [[ -f $camera ]]; then cmd+=(--camera "$camera"); else cmd+=(--size "$size" --save-camera "$camera"); fi
    if ! timed "$dir" reference "${cmd[@]}"; then
      row "$scene" "$mode" "$shading" "CPU reference" - - "reference failed" "${cmd[@]}"
      continue
    fi
    row "$scene" "$mode" "$shading" "CPU reference" "$dir/reference.json" - "" "${cmd[@]}"

    # Ours: octoray-render --gpu (lod 1 px timed; lod 0 px for accuracy).
    for lod in 1 0; do
      name=octoray-gpu-lod$lod
      label="octoray GPU, $([[ $lod == 1 ]] && echo "lod 1 px" || echo "full res")"
      cmd=("$bin/octoray-render" "$store" --gpu --lod-pixels "$lod" --frames "$frames" --orbit 0
           --camera "$camera" -o "$dir/$name.png" --exr "$dir/$name.exr" "${tf_args[@]}"
           "${margs[@]}" "${step_args[@]}" --json)
      if [[ $has_gpu == 0 ]]; then
        row "$scene" "$mode" "$shading" "$label" - - "octoray-render has no --gpu yet" "${cmd[@]}"
      elif timed "$dir" "$name" "${cmd[@]}" && compare "$dir" "$name"; then
        row "$scene" "$mode" "$shading" "$label" "$dir/$name.json" "$dir/$name.cmp.json" "" "${cmd[@]}"
      else
        row "$scene" "$mode" "$shading" "$label" - - "failed (see $name.err, $name.cmp.err)" "${cmd[@]}"
      fi
    done

    # MIP also as other raycasters do it: the maximum at the step's samples (--mip sampled).
    if [[ $mode == mip && $has_gpu == 1 ]]; then
      name=octoray-gpu-mip-sampled
      label="octoray GPU, sampled MIP"
      cmd=("$bin/octoray-render" "$store" --gpu --lod-pixels 1 --mip sampled --frames "$frames"
           --orbit 0 --camera "$camera" -o "$dir/$name.png" --exr "$dir/$name.exr" "${tf_args[@]}"
           "${margs[@]}" "${step_args[@]}" --json)
      if timed "$dir" "$name" "${cmd[@]}" && compare "$dir" "$name"; then
        row "$scene" "$mode" "$shading" "$label" "$dir/$name.json" "$dir/$name.cmp.json" "" "${cmd[@]}"
      else
        row "$scene" "$mode" "$shading" "$label" - - "failed (see $name.err, $name.cmp.err)" "${cmd[@]}"
      fi
    fi

    # VTK's two mappers with the same volume, TF, camera and step.
    for mapper in gpu cpu; do
      name=vtk-$mapper
      label="VTK $([[ $mapper == gpu ]] && echo GPU || echo CPU)"
      cmd=("$bin/vtk-peer" "$store" --mapper "$mapper" --frames "$frames" --orbit 0 --camera
           "$camera" -o "$dir/$name.png" --exr "$dir/$name.exr" "${tf_args[@]}" "${margs[@]}"
           "${step_args[@]}" --json)
      if [[ $mapper == cpu && $mode == iso ]]; then
        row "$scene" "$mode" "$shading" "$label" - - \
          "vtkFixedPointVolumeRayCastMapper has no isosurface mode" "${cmd[@]}"
      elif timed "$dir" "$name" "${vtk_prefix[@]}" "${cmd[@]}" && compare "$dir" "$name"; then
        row "$scene" "$mode" "$shading" "$label" "$dir/$name.json" "$dir/$name.cmp.json" "" "${cmd[@]}"
      else
        row "$scene" "$mode" "$shading" "$label" - - "failed (see $name.err, $name.cmp.err)" "${cmd[@]}"
      fi
    done
  done
done

# The table: one JSON object per row, then Markdown with the machine and the command.
"$py" - "$manifest" "$out" "$command_line" "$frames" "${step:-}" <<'PY'
import json, statistics, subprocess, sys, datetime, platform

manifest, out, command_line, frames, step = sys.argv[1:6]

def load(path):
    if path == "-":
        return {}
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError):
        return {}

def frame_median(run, key):
    values = [f[key] for f in run.get("frames", []) if isinstance(f, dict) and key in f]
    return statistics.median(values) if values else None

rows, gl_renderers = [], {}
with open(manifest) as f:
    for line in f:
        scene, mode, shading, renderer, run_path, cmp_path, note, command = \
            line.rstrip("\n").split("\t")
        run, cmp = load(run_path), load(cmp_path)
        row = {"scene": scene, "mode": mode, "shading": shading, "renderer": renderer,
               "medianMs": run.get("medianMs"), "firstFrameMs": run.get("firstFrameMs"),
               "samplesPerPixel": frame_median(run, "samplesPerPixel"),
               "contributingSamplesPerPixel": frame_median(run, "contributingSamplesPerPixel"),
               "psnrDb": cmp.get("psnrDb"), "ssim": cmp.get("ssim"), "rmse": cmp.get("rmse"),
               "maxAbsError": cmp.get("maxAbsError"), "stepMm": run.get("stepMm"),
               "note": note, "command": command}
        if renderer == "CPU reference" and run:
            # One frame; "samples" counts every interpolant evaluation (gradients included).
            ms = run.get("timingMs", {}).get("render")
            row["medianMs"] = row["firstFrameMs"] = ms
            pixels = run.get("width", 0) * run.get("height", 0)
            if pixels and "samples" in run:
                row["samplesPerPixel"] = run["samples"] / pixels
        if run.get("frames") and row["medianMs"] is None:
            times = [f["ms"] for f in run["frames"] if isinstance(f, dict) and "ms" in f]
            row["medianMs"] = statistics.median(times) if times else None
            row["firstFrameMs"] = times[0] if times else None
        for key in ("glRenderer", "renderer_gl", "glRendererString"):
            if isinstance(run.get(key), str):
                gl_renderers[renderer] = run[key]
        if run and cmp_path != "-" and not cmp:
            row["note"] = (note + "; " if note else "") + "no comparison"
        rows.append(row)

with open(f"{out}/results.jsonl", "w") as f:
    for row in rows:
        f.write(json.dumps(row) + "\n")

def num(value, fmt):
    return "–" if value is None else format(value, fmt)

def psnr(row):
    if row["renderer"] == "CPU reference":
        return "(reference)"
    if row["psnrDb"] is None and row["ssim"] is not None:
        return "∞"
    return num(row["psnrDb"], ".2f")

def run(*args):
    try:
        return subprocess.run(args, capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"

cpu = next((l.split(":", 1)[1].strip() for l in run("lscpu").splitlines()
            if l.startswith("Model name:")), "unknown")
lines = [
    "# Renderer comparison (issue 5): octoray GPU, VTK GPU and VTK CPU against the CPU reference",
    "",
    f"- Date: {datetime.datetime.now(datetime.timezone.utc).strftime('%Y-%m-%d %H:%M UTC')}",
    f"- `uname -a`: `{run('uname', '-a')}`",
    f"- CPU: {cpu}, {run('nproc')} cores",
    "- GL_RENDERER: " + ("; ".join(f"{k}: `{v}`" for k, v in sorted(gl_renderers.items()))
                         or "unknown (no GL renderer ran)"),
    f"- Command: `{command_line}`",
    f"- Frames per timed renderer: {frames} (median; VTK's median leaves out the first frame, "
    "which uploads the volume and compiles shaders); sample distance: "
    + (f"{step} mm for every timed renderer" if step else "each renderer's default "
       "(VTK: half the smallest spacing)"),
    "- Transfer function: Slicer's CT-Bone (presets.xml), gradient opacity dropped; "
    "errors over premultiplied RGB against the reference EXR (VTK images come from an 8-bit "
    "framebuffer).",
    "",
    "| scene | mode | shading | renderer | median ms/frame | first-frame ms | samples/pixel "
    "taken | contributing samples/pixel | PSNR dB | SSIM vs reference | note |",
    "|---|---|---|---|---:|---:|---:|---:|---:|---:|---|",
]
for r in rows:
    lines.append(
        f"| {r['scene']} | {r['mode']} | {r['shading']} | {r['renderer']} | "
        f"{num(r['medianMs'], '.0f')} | {num(r['firstFrameMs'], '.0f')} | "
        f"{num(r['samplesPerPixel'], '.1f')} | {num(r['contributingSamplesPerPixel'], '.1f')} | "
        f"{psnr(r)} | {num(r['ssim'], '.4f')} | {r['note']} |")
lines += ["", "The reference's samples/pixel counts every interpolant evaluation (gradients, "
          "isosurface refinement, MIP candidates), not only classified samples.", ""]
with open(f"{out}/results.md", "w") as f:
    f.write("\n".join(lines))
print("\n".join(lines))
PY
