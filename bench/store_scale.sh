#!/usr/bin/env bash
# Scale benchmark of the octree store build (issue 3): an octoray-phantom volume imported
# from raw (NRRD header + raw int16 data) and the real 140-slice DICOM series, each imported
# RUNS times; prints medians of seconds, Mvoxels/s and peak RSS, and a same-run baseline
# (reading the raw data once with cat, i.e. the I/O floor of the raw import).
#
# Usage: bench/store_scale.sh BUILD_DIR WORK_DIR [SIZE=2048x2048x1024] [RUNS=3]
set -euo pipefail
build=$1 work=$2 size=${3:-2048x2048x1024} runs=${4:-3}
dicom=${DICOM:-$(dirname "$0")/../../shared/data/dicom/dcm_qa_ct/Philips/S21570/S2020}
mkdir -p "$work"
phantom="$work/phantom-$size.nhdr"

echo "date: $(date -u '+%Y-%m-%d %H:%M UTC')"
echo "machine: $(nproc) cores, $(lscpu | sed -n 's/^Model name: *//p'), $(free -g | awk '/Mem:/{print $2}') GiB RAM"
if [[ ! -f $phantom ]]; then
  "$build/bin/octoray-phantom" --size "$size" -o "$phantom"
fi
raw="${phantom%.nhdr}.raw"
echo "input: $phantom ($(du -h "$raw" | cut -f1) of int16)"

median() { sort -g | awk '{a[NR]=$1} END {print (NR%2 ? a[(NR+1)/2] : (a[NR/2]+a[NR/2+1])/2)}'; }
field() { /usr/bin/python3 -c "import json,sys; print(json.load(sys.stdin)['$1'])"; }

run_imports() {  # label input extra-args...
  local label=$1 input=$2; shift 2
  local secs=() rates=() rss=() out="$work/bench.octoray" json
  for ((i = 0; i < runs; i++)); do
    json=$("$build/bin/octoray-import" "$input" -o "$out" --json "$@")
    secs+=("$(field seconds <<<"$json")")
    rates+=("$(field mvoxelsPerSecond <<<"$json")")
    rss+=("$(field peakRssMiB <<<"$json")")
  done
  echo "$label: voxels $(field voxels <<<"$json"), bricks $(field bricks <<<"$json"), $(($(field bytesOnDisk <<<"$json") >> 20)) MiB on disk"
  echo "$label: median $(printf '%s\n' "${secs[@]}" | median) s, $(printf '%s\n' "${rates[@]}" | median) Mvoxels/s, peak RSS $(printf '%s\n' "${rss[@]}" | median) MiB  (runs: ${rates[*]})"
  rm -f "$out"
}

# Baseline in the same run: reading the raw data once (page cache as it is).
start=$(date +%s.%N); cat "$raw" > /dev/null; end=$(date +%s.%N)
voxels=$(( $(stat -c %s "$raw") / 2 ))
echo "baseline cat of the raw data: $(echo "$start $end $voxels" | awk '{printf "%.2f s, %.0f Mvoxels/s", $2-$1, $3/($2-$1)/1e6}')"
run_imports "raw $size" "$phantom"
if [[ -d $dicom ]]; then
  run_imports "DICOM $(basename "$dicom")" "$dicom"
else
  echo "DICOM: $dicom absent, skipped"
fi
