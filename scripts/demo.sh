#!/usr/bin/env bash
# The main job on a built-in default: write a small synthetic CT exam (a tilted axial series
# with a localiser beside it), list and inspect it with octoray-import, export it to NIfTI,
# build its octree store and validate the store; then a synthetic head phantom is built into a
# store (kept as BUILD_DIR/octoray-demo-head.octoray) and rendered to BUILD_DIR/octoray-demo.png.
# Last, where a display exists ($DISPLAY or $WAYLAND_DISPLAY), the viewer opens on that store;
# where none does, the headless demo above is the whole job (and it says so).
# Usage: scripts/demo.sh [BUILD_DIR]
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
# A synthetic head CT through the whole chain: rendered by the GPU raycaster (headless GL;
# llvmpipe where there is no GPU), then by the CPU reference renderer, and the two compared.
"$build/bin/octoray-phantom" --size 160x160x160 -o "$out/head.nhdr"
"$build/bin/octoray-import" "$out/head.nhdr" -o "$build/octoray-demo-head.octoray" --border 2
view=(--preset bone --size 384x384 --azimuth 30 --elevation 15)
"$build/bin/octoray-render" "$build/octoray-demo-head.octoray" -o "$build/octoray-demo.png" --exr "$out/gpu.exr" \
  "${view[@]}" --frames 5 --orbit 10
"$build/bin/octoray-render" "$build/octoray-demo-head.octoray" --reference -o "$out/reference.png" \
  --exr "$out/reference.exr" "${view[@]}"
"$build/bin/octoray-compare" "$out/reference.exr" "$out/gpu.exr"
echo "picture: $build/octoray-demo.png"
if [ -n "${DISPLAY:-}${WAYLAND_DISPLAY:-}" ] && [ -x "$build/bin/octoray-view" ]; then
  echo "opening the viewer on the demo head: $build/bin/octoray-view $build/octoray-demo-head.octoray"
  "$build/bin/octoray-view" "$build/octoray-demo-head.octoray" --wl bone
else
  echo "no display: the viewer is not opened; the headless demo above is the main job."
  echo "With a display: $build/bin/octoray-view $build/octoray-demo-head.octoray"
fi
