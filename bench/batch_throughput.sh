#!/usr/bin/env bash
# Batch import throughput: `octoray-batch run --jobs 1` (the baseline) against `--jobs 2`
# (and more where given) on one archive, timed in the same run, REPEATS times each, medians
# reported; and `--jobs 1` confined to one CPU (taskset), which shows how far one worker
# already uses the second core. The archive: every series of ../shared's Philips set plus SYNTHETIC series written by
# octoray-sample-series (SIZE each, every third tilted with uneven gaps).
#
#   bench/batch_throughput.sh BUILD WORK [REPEATS=3] [SYNTHETIC=18] [SIZE=256x256x120] [JOBS="1 2"]
#
# Prints a Markdown table (docs/benchmarks/batch.md) and leaves the archive in WORK.
set -euo pipefail

build=$(realpath "$1")
work=$2
repeats=${3:-3}
synthetic=${4:-18}
size=${5:-256x256x120}
jobs_list=${6:-"1cpu 1 2"}
here=$(cd "$(dirname "$0")/.." && pwd)
shared=${OCTORAY_SHARED:-$here/../shared}
bin=$build/bin
py=/usr/bin/python3

mkdir -p "$work"
work=$(realpath "$work")
archive=$work/archive
if [[ ! -d $archive ]]; then
  mkdir -p "$archive"
  cp -r "$shared/data/dicom/dcm_qa_ct/Philips" "$archive/philips"
  for ((i = 0; i < synthetic; i++)); do
    extra=()
    if ((i % 3 == 2)); then extra=(--tilt 12 --variable-gaps --with-localizer); fi
    "$bin/octoray-sample-series" "$archive/synthetic-$i" --seed $((100 + i)) --size "$size" \
      --patient-id "BENCH-$((i % 5))" "${extra[@]}" >/dev/null
  done
fi
plan=$work/plan.json
"$bin/octoray-batch" plan "$archive" -o "$plan" --json >"$work/plan-summary.json"
items=$($py -c "import json,sys; print(json.load(open(sys.argv[1]))['items'])" "$work/plan-summary.json")
mvox=$($py -c "import json,sys; print(round(json.load(open(sys.argv[1]))['totalVoxels']/1e6,1))" "$work/plan-summary.json")

declare -A times peaks
for ((r = 0; r < repeats; r++)); do
  for j in $jobs_list; do
    rm -rf "$work/stores" "$work/plan.manifest"
    sync
    if [[ $j == 1cpu ]]; then
      taskset -c 0 "$bin/octoray-batch" run "$plan" --jobs 1 --json >"$work/run-$j-$r.json"
    else
      "$bin/octoray-batch" run "$plan" --jobs "$j" --json >"$work/run-$j-$r.json"
    fi
    "$bin/octoray-batch" status "$plan" --json >"$work/status-$j-$r.json"
    times[$j]+="$($py -c "import json,sys; print(json.load(open(sys.argv[1]))['seconds'])" "$work/run-$j-$r.json") "
    peaks[$j]+="$($py -c "
import json,sys
recs=[json.loads(l) for f in __import__('glob').glob(sys.argv[1]+'/*.jsonl') for l in open(f)]
print(max(r['peakRssMiB'] for r in recs))" "$work/plan.manifest") "
  done
done
"$bin/octoray-batch" validate "$plan" >/dev/null

echo "Archive: $items items, $mvox Mvoxels ($(du -sh "$archive" | cut -f1) of DICOM); $repeats runs per setting, stores and manifest removed before each run."
echo
echo "| setting | median s | runs (s) | Mvoxels/s | speed-up vs --jobs 1 | largest worker peak RSS MiB |"
echo "|---|---|---|---|---|---|"
read -r base <<<"$($py -c "
import statistics,sys
print(round(statistics.median(float(x) for x in sys.argv[1].split()),2))" "${times[1]}")"
for j in $jobs_list; do
  read -r med all <<<"$($py -c "
import statistics,sys
v=[float(x) for x in sys.argv[1].split()]
print(round(statistics.median(v),2), '/'.join(f'{x:.2f}' for x in v))" "${times[$j]}")"
  label="--jobs $j"
  [[ $j == 1cpu ]] && label="--jobs 1 on one CPU (taskset -c 0)"
  peak=$($py -c "import sys; print(round(max(float(x) for x in sys.argv[1].split())))" "${peaks[$j]}")
  echo "| $label | $med | $all | $($py -c "print(round($mvox/$med,1))") | $($py -c "print(round($base/$med,2))")× | $peak |"
done
