#!/usr/bin/env bash
# The viewer's interaction benchmark (issue 11): octoray-view under Xvfb at 1280x800 (four-up,
# the 3D view 469x375), a scripted 80-step rotation drag in the 3D view, a 20-notch slice
# scroll and a 40-step drag back, then the still picture's convergence; per frame the frame
# time, the 3D render time, the working set and the RSS (octoray-view --stats). Each store is
# run REPEATS times with interactive quality on (half resolution and twice the LOD target
# while the camera moves) and, as the baseline in the same run, off (full quality while
# dragging). Medians over the frames of all repeats; the first 3D image and the first MPR
# slices after the store was opened (ms) are medians over the repeats.
#   bench/viewer.sh BUILD_DIR OUT_DIR STORE [STORE...]      (REPEATS=3)
set -euo pipefail
build=$(cd "$1" && pwd)
out=$2
shift 2
repeats=${REPEATS:-3}
mkdir -p "$out"
cat > "$out/drag.json" <<'JSON'
{"format": "octoray-view-script", "version": 1, "events": [
 {"type": "drag", "button": "left", "wait": 0, "from": {"view": "3d", "fraction": [0.3, 0.5]},
  "to": {"view": "3d", "fraction": [0.8, 0.4]}, "steps": 80},
 {"type": "wheel", "at": {"view": "axial", "fraction": [0.5, 0.5]}, "dy": 20},
 {"type": "drag", "button": "left", "from": {"view": "3d", "fraction": [0.8, 0.4]},
  "to": {"view": "3d", "fraction": [0.3, 0.5]}, "steps": 40},
 {"type": "wait-converged", "timeout": 600},
 {"type": "dump-state", "path": "STATE"},
 {"type": "quit"}]}
JSON
for store in "$@"; do
  name=$(basename "$store" .octoray)
  for quality in on off; do
    for r in $(seq 1 "$repeats"); do
      run=$out/$name-$quality-$r
      sed "s|STATE|$run.state.json|" "$out/drag.json" > "$run.script.json"
      if [ "$quality" = off ]; then
        # The same script with interactive quality switched off first.
        python3 - "$run.script.json" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
s["events"].insert(0, {"type": "action", "name": "interactive-quality", "value": False, "wait": 0})
s["events"][1]["wait"] = 1
json.dump(s, open(sys.argv[1], "w"))
PY
      fi
      OCTORAY_CONFIG=$out/config xvfb-run -a -s "-screen 0 1280x800x24 -noreset" "$build/bin/octoray-view" "$store" \
        --script "$run.script.json" --exit --stats "$run.csv" --cache-dir "$out/cache" 2> "$run.log"
    done
  done
done
/usr/bin/python3 - "$out" "$@" <<'PY'
import csv, datetime, glob, json, os, platform, statistics, sys
out, stores = sys.argv[1], sys.argv[2:]
print(f"date {datetime.date.today()}, {platform.node()}, {os.cpu_count()} cores")
print("| store | interactive quality | frames while dragging | frame ms median | p95 | max | 3D ms median | first 3D image ms | first MPR ms | converged s | peak RSS MiB |")
print("|---|---|---|---|---|---|---|---|---|---|---|")
for store in stores:
    name = os.path.basename(store).removesuffix(".octoray")
    for quality in ("on", "off"):
        frames, render, first3d, firstmpr, converged, rss = [], [], [], [], [], []
        for f in sorted(glob.glob(f"{out}/{name}-{quality}-*.csv")):
            rows = list(csv.DictReader(open(f)))
            state = json.load(open(f.removesuffix(".csv") + ".state.json"))
            first3d.append(state["timing"]["first3dMs"])
            firstmpr.append(state["timing"]["firstMprMs"])
            converged.append(float(rows[-1]["seconds"]))
            rss.append(max(float(r["rss_mib"]) for r in rows))
            # Frames that drew the 3D view while the camera moved (the drags).
            for a, b in zip(rows, rows[1:]):
                if b["interactive"] == "1" and int(b["rendered3d"]) > int(a["rendered3d"]):
                    frames.append(float(b["frame_ms"]))
                    render.append(float(b["view3d_ms"]))
        frames.sort()
        print(f"| {name} | {quality} | {len(frames)} | {statistics.median(frames):.1f} | {frames[int(0.95 * (len(frames) - 1))]:.1f} | "
              f"{frames[-1]:.1f} | {statistics.median(render):.1f} | {statistics.median(first3d):.0f} | "
              f"{statistics.median(firstmpr):.0f} | {statistics.median(converged):.1f} | {max(rss):.0f} |")
PY
