#!/usr/bin/env bash
# Issue 10's interaction benchmark: the persistent, streamed working set on a store larger
# than the GPU pool, in one run.
#  1. Camera path: an orbit with zoom (FRAMES frames turning 180 degrees while the zoom runs
#     from 1 to 6, then STILL frames at the last camera) rendered by `octoray-render --path`
#     with the working set carried across frames, for each configuration:
#       rays       --visibility rays  (the default), upload budget 64 MiB per frame
#       none       --visibility none
#       occlusion  --visibility occlusion
#       both       --visibility both
#       rays-nobudget   --visibility rays --upload-mib-per-frame 0 (unlimited)
#       rays-repack     --visibility rays --repack-when-settled (the viewer's setting: the
#                       settled cut copied to the pool's first slots in node order)
#     REPEATS runs each (OTHER_REPEATS for the others): median and p95 frame time, time to first image, time to the
#     converged image after the camera stops, bytes read, peak RSS, final working set, the
#     bricks a repack copied and its time; the per-phase split of the frame (select, upload,
#     raycast, feedback) from the first run.
#  2. Convergence: the last frame of the first `rays` run against the CPU reference rendered
#     over the same LOD cut (--cut-reference: only the cut's bricks are read, so it works where
#     the full-resolution reference, 17 GiB of floats here, cannot), and against a still
#     render of the same camera with feedback off, same LOD (--camera --visibility none), PSNR.
#  3. Visibility: converged working sets of still, zoomed views (ZOOMS) with a pool large
#     enough not to bound them (--pool-mib VIS_POOL_MIB), for an opaque bone TF and the
#     semi-transparent soft-tissue preset: bricks with each feedback and without, the bricks
#     some ray samples (the counting variant), and PSNR against the picture without feedback.
#  4. Real heads (../shared/data): the same at zoom 1 and 2 with the bone preset on the 1 mm
#     Philips head and the tilted stereotaxis head: the fraction of the removable bricks
#     (set without feedback minus the sampled ones) each feedback leaves in the set.
#
# Usage: bench/working_set.sh BUILD_DIR OUT_DIR [REPEATS=3]
# Environment: SCALE=full|small  (full: a 2048x2048x1024 octoray-phantom, 8 GiB of samples,
#   300 + 60 frames at 512x512; small: 256x256x192, 40 + 20 frames at 128x128, seconds)
#   STORE=PATH (reuse a store instead of building the phantom)  POOL_MIB=512  CACHE_MIB=2048
#   VIS_POOL_MIB=4096  ZOOMS="4 6"  CONFIGS="rays none occlusion both rays-nobudget rays-repack"
#   OCTORAY_SHARED (default: ../shared beside the repository; step 4 is skipped without it)
# Output: OUT_DIR/results.md (tables), OUT_DIR/results.jsonl (one object per row), and the
# reports, per-frame statistics (CSV) and images of every run.
set -euo pipefail

if [[ $# -lt 2 || $# -gt 3 ]]; then
  echo "usage: $0 BUILD_DIR OUT_DIR [REPEATS=3]" >&2
  exit 2
fi
build=$(realpath "$1")
out=$(realpath -m "$2")
repeats=${3:-3}
command_line="$0 $*"
repo=$(realpath "$(dirname "$0")/..")
shared=${OCTORAY_SHARED:-$repo/../shared}
scale=${SCALE:-full}
pool=${POOL_MIB:-512}
cache=${CACHE_MIB:-2048}
vis_pool=${VIS_POOL_MIB:-4096}
zooms=${ZOOMS:-4 6}
configs=${CONFIGS:-rays none occlusion both rays-nobudget rays-repack}
bin=$build/bin
py=/usr/bin/python3
case $scale in
  full) dims=2048x2048x1024 size=512x512 frames=300 still=60 ;;
  small) dims=256x256x192 size=128x128 frames=40 still=20 ;;
  *) echo "$0: SCALE must be full or small" >&2; exit 2 ;;
esac
for tool in octoray-phantom octoray-import octoray-render octoray-compare; do
  [[ -x $bin/$tool ]] || { echo "$0: $bin/$tool is missing" >&2; exit 1; }
done
mkdir -p "$out"
# A reused OUT_DIR keeps its stores (built once), never an earlier run's images or reports.
rm -rf "$out/path" "$out/visibility"
results=$out/results.jsonl
: > "$results"

# The store.
store=${STORE:-}
if [[ -z $store ]]; then
  store=$out/phantom-$dims.octoray
  # Kept from an earlier run unless octoray-import is newer (a store format it may not read).
  if [[ ! -f $store || $store -ot $bin/octoray-import ]]; then
    echo "== building a $dims octoray-phantom store"
    "$bin/octoray-phantom" --size "$dims" -o "$out/phantom.nhdr"
    "$bin/octoray-import" "$out/phantom.nhdr" -o "$store" --border 2
    rm -f "$out/phantom.nhdr" "$out/phantom.raw"
  fi
fi
store=$(realpath "$store")

# An opaque bone TF: transparent below 150 HU, opaque from 300 HU.
opaque=$out/opaque-bone.json
cat > "$opaque" <<'EOF'
{"format": "octoray-transfer-function", "version": 1, "transferFunctions": [{
  "name": "opaque-bone", "unitDistanceMm": 1.0, "interpolation": "linear",
  "color": [[-3024, 0, 0, 0], [150, 0.73, 0.25, 0.3], [400, 0.9, 0.82, 0.56], [1000, 1, 0.97, 0.9]],
  "opacity": [[-3024, 0], [150, 0], [300, 1], [3071, 1]],
  "gradientOpacity": [],
  "material": {"shade": true, "ambient": 0.15, "diffuse": 0.85, "specular": 0.3, "specularPower": 20}}]}
EOF

# 1. Camera paths.
path="orbit:$frames,degrees:180,zoom-from:1,zoom-to:6,still:$still"
for config in $configs; do
  visibility=${config%-nobudget}
  visibility=${visibility%-repack}
  budget=64
  [[ $config == *-nobudget ]] && budget=0
  repack=()
  [[ $config == *-repack ]] && repack=(--repack-when-settled)
  runs=$repeats
  [[ $config == rays || $config == none ]] || runs=${OTHER_REPEATS:-$repeats}
  for ((r = 1; r <= runs; ++r)); do
    dir=$out/path/$config/run$r
    mkdir -p "$dir"
    echo "== path $config, run $r"
    cut_reference=()
    [[ $config == rays && $r == 1 ]] && cut_reference=(--cut-reference "$dir/cut-reference.png")
    "$bin/octoray-render" "$store" -o "$dir/last.png" --preset bone --size "$size" --path "$path" \
      --visibility "$visibility" --upload-mib-per-frame "$budget" --pool-mib "$pool" \
      --cache-mib "$cache" --stats "$dir/frames.csv" --save-camera "$dir/camera.json" --json "${cut_reference[@]}" "${repack[@]}" \
      > "$dir/report.json" 2> "$dir/stderr.txt"
    if [[ $config == rays && $r == 1 ]]; then
      # 2. Convergence: the still render of the last camera, feedback off, same LOD.
      "$bin/octoray-render" "$store" -o "$dir/still.png" --preset bone --camera "$dir/camera.json" \
        --visibility none --pool-mib "$vis_pool" --cache-mib "$cache" > /dev/null
      "$bin/octoray-compare" "$dir/still.png" "$dir/last.png" --json > "$dir/compare.json"
    fi
  done
done

# 3. Visibility on still, zoomed views (converged sets, pool large enough).
visibility_views() {  # name store tf-args zooms
  local name=$1 source=$2 zs=$3
  shift 3
  for zoom in $zs; do
    local dir=$out/visibility/$name/zoom$zoom
    mkdir -p "$dir"
    echo "== visibility $name zoom $zoom"
    for visibility in none rays occlusion both; do
      "$bin/octoray-render" "$source" -o "$dir/$visibility.png" "$@" --size "$size" \
        --azimuth 30 --elevation 10 --zoom "$zoom" --visibility "$visibility" \
        --pool-mib "$vis_pool" --cache-mib "$cache" --json > "$dir/$visibility.json"
      "$bin/octoray-compare" "$dir/none.png" "$dir/$visibility.png" --json > "$dir/$visibility-compare.json"
    done
  done
}
visibility_views phantom-opaque-bone "$store" "$zooms" --tf "$opaque"
visibility_views phantom-soft-tissue "$store" "$zooms" --preset soft-tissue

# 4. Real heads.
if [[ -d $shared/data/dicom/dcm_qa_ct/Philips ]]; then
  for head in S21570/S2020 S21610/S2010; do
    name=head-${head//\//-}
    if [[ ! -f $out/$name.octoray || $out/$name.octoray -ot $bin/octoray-import ]]; then
      "$bin/octoray-import" "$shared/data/dicom/dcm_qa_ct/Philips/$head" -o "$out/$name.octoray" --border 2 > /dev/null
    fi
    visibility_views "$name" "$out/$name.octoray" "1 2" --preset bone
  done
else
  echo "$0: $shared/data is absent: the real heads are skipped" >&2
fi

# Tables.
"$py" - "$out" "$results" "$repeats" "$command_line" "$store" "$path" "$size" "$pool" "$cache" "$vis_pool" <<'PY'
import csv, glob, json, os, platform, statistics, subprocess, sys, datetime
out, results, repeats, command, store, path, size, pool, cache, vis_pool = sys.argv[1:11]
def med(values):
    values = [v for v in values if v is not None]
    return statistics.median(values) if values else None
def fmt(v, digits=0):
    return "—" if v is None else f"{v:.{digits}f}"
def db(v):  # octoray-compare reports identical images as an infinite PSNR (null in JSON)
    return "identical" if v is None or v == float("inf") else f"{v:.1f}"
lines = [f"Run {datetime.date.today()} on {platform.node()} ({os.cpu_count()} cores), "
         f"`{command}`; store `{os.path.basename(store)}`, path `{path}` at {size}, "
         f"--pool-mib {pool} --cache-mib {cache}; medians of the runs counted in each row.", ""]
lines += ["| config (runs) | median ms | p95 ms | first image ms | converged after stop ms | MiB read | peak RSS MiB | final bricks | select / upload / raycast / feedback ms (median frame) | repack: bricks, ms |",
          "|---|---|---|---|---|---|---|---|---|---|"]
with open(results, "a") as jl:
    for config_dir in sorted(glob.glob(f"{out}/path/*")):
        config = os.path.basename(config_dir)
        reports = [json.load(open(f)) for f in sorted(glob.glob(f"{config_dir}/run*/report.json"))]
        if not reports:
            continue
        row = {k: med([r[k] for r in reports]) for k in ["medianMs", "p95Ms", "firstImageMs", "convergedAfterStopMs", "bytesRead", "peakRssMib", "finalWorkingSetBricks", "bricksRepacked", "repackMs"]}
        frames = list(csv.DictReader(open(f"{config_dir}/run1/frames.csv")))
        phases = [med([float(f[k]) for f in frames]) for k in ["selectMs", "uploadMs", "drawMs", "feedbackMs"]]
        jl.write(json.dumps({"part": "path", "config": config, **row, "phases": phases}) + "\n")
        lines.append(f"| {config} ({len(reports)}) | {fmt(row['medianMs'])} | {fmt(row['p95Ms'])} | {fmt(row['firstImageMs'])} | "
                     f"{fmt(row['convergedAfterStopMs'])} | {fmt(row['bytesRead'] / 2**20, 1)} | {fmt(row['peakRssMib'])} | "
                     f"{fmt(row['finalWorkingSetBricks'])} | {' / '.join(fmt(p, 1) for p in phases)} | "
                     f"{fmt(row['bricksRepacked']) + ', ' + fmt(row['repackMs'], 1) if row['bricksRepacked'] else '—'} |")
    for compare in sorted(glob.glob(f"{out}/path/rays/run1/compare.json")):
        c = json.load(open(compare))
        lines += ["", f"Converged `rays` path frame against the still render of its camera with feedback off: PSNR {db(c['psnrDb'])} dB, SSIM {c['ssim']:.4f}."]
        jl.write(json.dumps({"part": "convergence", **c}) + "\n")
    for report in sorted(glob.glob(f"{out}/path/rays/run1/report.json")):
        r = json.load(open(report))
        c = r.get("cutReference") or {}
        if c:
            lines += [f"The same frame against the CPU reference over its LOD cut ({c['leaves']} leaves, up to {c['coarsestLevelsAboveLeaf']} levels above the leaf level; converged: {r['converged']}): "
                      f"PSNR {db(c['psnrDb'])} dB, SSIM {c['ssim']:.4f}, max |error| {c['maxAbsError']:.3f}; the reference took {c['timingMs']['load'] / 1000:.1f} s to read the cut and {c['timingMs']['render'] / 1000:.1f} s to render."]
            jl.write(json.dumps({"part": "cut-reference", **c}) + "\n")
    lines += ["", "| view | zoom | without feedback | sampled by rays | rays | occlusion | both | PSNR rays / occlusion / both dB | left of the removable: rays / occlusion / both |",
              "|---|---|---|---|---|---|---|---|---|"]
    for view_dir in sorted(glob.glob(f"{out}/visibility/*/zoom*")):
        name, zoom = view_dir.split("/")[-2], view_dir.split("/")[-1][4:]
        rep = {v: json.load(open(f"{view_dir}/{v}.json")) for v in ["none", "rays", "occlusion", "both"]}
        bricks = {v: rep[v]["frames"][0]["workingSetBricks"] for v in rep}
        sampled = rep["none"]["frames"][0]["bricksTouched"]
        psnr = {v: json.load(open(f"{view_dir}/{v}-compare.json"))["psnrDb"] for v in ["rays", "occlusion", "both"]}
        removable = max(1, bricks["none"] - sampled)
        left = {v: (bricks[v] - sampled) / removable for v in ["rays", "occlusion", "both"]}
        jl.write(json.dumps({"part": "visibility", "view": name, "zoom": zoom, "bricks": bricks, "sampled": sampled, "psnr": psnr, "leftOfRemovable": left}) + "\n")
        smaller = {v: 100 * (1 - bricks[v] / bricks["none"]) for v in ["rays", "occlusion", "both"]}
        lines.append(f"| {name} | {zoom} | {bricks['none']} | {sampled} | {bricks['rays']} (−{smaller['rays']:.0f} %) | "
                     f"{bricks['occlusion']} (−{smaller['occlusion']:.0f} %) | {bricks['both']} (−{smaller['both']:.0f} %) | "
                     f"{' / '.join(db(psnr[v]) for v in ['rays', 'occlusion', 'both'])} | "
                     f"{' / '.join(f'{100 * left[v]:.0f} %' for v in ['rays', 'occlusion', 'both'])} |")
open(f"{out}/results.md", "w").write("\n".join(lines) + "\n")
print("\n".join(lines))
PY
