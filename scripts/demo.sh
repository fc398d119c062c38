#!/usr/bin/env bash
# The main job on a built-in default: write a small synthetic CT exam (a tilted axial series
# with a localiser beside it), list and inspect it with octoray-import, export it to NIfTI,
# build its octree store and validate the store. Usage: scripts/demo.sh [BUILD_DIR]
set -euo pipefail
build=${1:-build}
out=$(mktemp -d "${TMPDIR:-/tmp}/octoray-demo.XXXXXX")
trap 'rm -rf "$out"' EXIT

"$build/bin/octoray-sample-series" "$out/exam" --size 128x128x48 --tilt 12 --with-localizer
echo
"$build/bin/octoray-import" --list "$out/exam"
echo
"$build/bin/octoray-import" --inspect "$out/exam"
echo
"$build/bin/octoray-import" --export "$out/exam.nii.gz" "$out/exam"
echo
"$build/bin/octoray-import" "$out/exam" -o "$out/exam.octoray"
echo
"$build/bin/octoray-validate" "$out/exam.octoray"
