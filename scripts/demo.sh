#!/usr/bin/env bash
# The main job on a built-in default: write a small synthetic CT exam (a tilted axial series
# with a localiser beside it), list and inspect it with octoray-import, export it to NIfTI,
# build its octree store and validate the store; then a synthetic head phantom is built into a
# store and rendered to BUILD_DIR/octoray-demo.png. Usage: scripts/demo.sh [BUILD_DIR]
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
echo
# A synthetic head CT through the whole chain, rendered by the CPU reference renderer.
"$build/bin/octoray-phantom" --size 160x160x160 -o "$out/head.nhdr"
"$build/bin/octoray-import" "$out/head.nhdr" -o "$out/head.octoray"
"$build/bin/octoray-render" "$out/head.octoray" -o "$build/octoray-demo.png" --preset bone \
  --size 384x384 --azimuth 30 --elevation 15
echo "picture: $build/octoray-demo.png"
