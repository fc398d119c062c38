#!/usr/bin/env bash
# What accuracy costs in time, for octoray's GPU raycaster (octoray-render --gpu): one scene
# (a store), DVR with Slicer's CT-Bone (gradient opacity dropped), shaded; the CPU reference
# at its default step is the picture every row is compared with (octoray-compare).
#   step sweep   --lod-pixels 0, --step 0 (the reference's 0.25 x smallest spacing), 0.25,
#                0.5, 1.0 mm
#   LOD sweep    --lod-pixels 0, 1, 2, 4, 8 at SIZE and at half SIZE (coarser levels where a
#                voxel projects smaller than F pixels)
#   effects      unshaded, shaded, shaded + boundary enhancement, shaded + view-dependent
#                transparency (each a shader variant: a scene pays for what it uses)
# Each row: median ms of FRAMES frames after the first (octoray-render --frames), working-set
# bricks, pool MiB used, samples per pixel, PSNR and SSIM against the reference.
#
# Usage: bench/accuracy_cost.sh BUILD_DIR STORE OUT_DIR [FRAMES=5]
# Environment: SIZE=512x512  OCTORAY_SHARED (default: ../shared beside the repository)
set -euo pipefail

if [[ $# -lt 3 || $# -gt 4 ]]; then
  echo "usage: $0 BUILD_DIR STORE OUT_DIR [FRAMES=5]" >&2
  exit 2
fi
bin=$(realpath "$1")/bin
store=$(realpath "$2")
out=$(realpath -m "$3")
frames=${4:-5}
size=${SIZE:-512x512}
repo=$(realpath "$(dirname "$0")/..")
shared=${OCTORAY_SHARED:-$repo/../shared}
presets=$shared/data/presets/slicer/presets.xml
[[ -f $presets ]] || { echo "$0: $presets is missing (../shared/data)" >&2; exit 1; }
[[ -f $store ]] || { echo "$0: $store is missing" >&2; exit 1; }
mkdir -p "$out"
tf=(--tf "$presets" --tf-name CT-Bone --no-gradient-opacity --azimuth 30 --elevation 15)
half=$((${size%x*} / 2))x$((${size#*x} / 2))
rows=$out/rows.tsv
: > "$rows"

# reference SIZE SHADING: the reference picture for that size and shading (once).
reference() {
  local name=reference-$1-$2
  if [[ ! -f $out/$name.exr ]]; then
    "$bin/octoray-render" "$store" --reference -o "$out/$name.png" --exr "$out/$name.exr" \
      "${tf[@]}" --size "$1" --shading "$2" > /dev/null
  fi
  echo "$out/$name.exr"
}

# run GROUP LABEL SIZE SHADING ARGS...: one timed row.
run() {
  local group=$1 label=$2 sz=$3 shading=$4
  shift 4
  local name
  name=$(echo "$group-$label-$sz" | tr -c 'A-Za-z0-9.-' '_')
  local ref
  ref=$(reference "$sz" "$shading")
  echo "[$(date +%H:%M:%S)] $group $label $sz" >&2
  "$bin/octoray-render" "$store" -o "$out/$name.png" --exr "$out/$name.exr" "${tf[@]}" \
    --size "$sz" --shading "$shading" --frames "$frames" --orbit 0 --json "$@" > "$out/$name.json"
  "$bin/octoray-compare" "$ref" "$out/$name.exr" --json > "$out/$name.cmp.json"
  printf '%s\t%s\t%s\t%s\t%s\n' "$group" "$label" "$sz" "$out/$name.json" "$out/$name.cmp.json" >> "$rows"
}

for step in 0 0.25 0.5 1.0; do
  run step "step $([[ $step == 0 ]] && echo default || echo "$step mm")" "$size" on --lod-pixels 0 --step "$step"
done
for sz in "$size" "$half"; do
  for lod in 0 1 2 4 8; do run lod "lod $lod px" "$sz" on --lod-pixels "$lod"; done
done
run effects "unshaded" "$size" off --lod-pixels 1
run effects "shaded" "$size" on --lod-pixels 1
run effects "shaded + boundary 0,1,0.5" "$size" on --lod-pixels 1 --boundary 0,1,0.5
run effects "shaded + silhouette 0.2,1,1" "$size" on --lod-pixels 1 --silhouette 0.2,1,1

/usr/bin/python3 - "$rows" "$store" "$0 $*" <<'PY'
import json, statistics, sys
rows, store, command = sys.argv[1:4]
print(f"Store: `{store}`  \nCommand: `{command}`\n")
print("| group | setting | image | median ms | first ms | step mm | bricks | pool MiB used | samples/pixel | PSNR dB | SSIM |")
print("|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")
for line in open(rows):
    group, label, size, run_path, cmp_path = line.rstrip("\n").split("\t")
    run, cmp = json.load(open(run_path)), json.load(open(cmp_path))
    frames = run["frames"]
    med = lambda k: statistics.median(f[k] for f in frames)
    psnr = cmp.get("psnrDb")
    print(f"| {group} | {label} | {size} | {run['medianMs']:.0f} | {run['firstFrameMs']:.0f} | "
          f"{run['stepMm']:.3f} | {med('workingSetBricks'):.0f} | {med('poolBytesUsed') / 2**20:.1f} | "
          f"{med('samplesPerPixel'):.1f} | {'∞' if psnr is None else format(psnr, '.2f')} | {cmp['ssim']:.4f} |")
PY
