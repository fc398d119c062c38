#!/usr/bin/env bash
# Builds and runs the whole test suite under AddressSanitizer + UndefinedBehaviorSanitizer
# (optimised, with debug info: every test runs, and any memory error or undefined behaviour
# fails it; the test programs' own code, not what they exercise, is built without UBSan, as
# tests/CMakeLists.txt says), the loader and working-set tests under ThreadSanitizer, then fuzzes the store
# reader for 60 s and the volume-header, raw-option, transfer-function, DICOMDIR and
# JSON-document (camera, session, script, presets) parsers for 20-25 s each, two fuzzers at a
# time. Installs missing Debian packages first.
# The Release build of README's first command runs the same code without instrumentation.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh

jobs=$(nproc)
# Each stage's header says when it began (seconds since the script started), to see what CI
# time goes to.
section() { echo "== [${SECONDS} s] $*"; }
# The sanitizer and fuzzing builds keep line tables only (-g1): reports still name function,
# file and line, and a compile takes 0.69x the time of full debug info (octoray_render.cpp
# under ASan: 99 s with -g, 69 s with -g1, 2026-12-04). The ASan build, which runs every test,
# optimises the libraries at -O2 and the test programs and tools' front ends at -O1
# (CMakeLists.txt's octoray_front_end); the ThreadSanitizer build, a dozen threaded tests, and
# the fuzzing build are at -O1 throughout, as OSS-Fuzz builds its fuzzers (its default CFLAGS:
# -O1 -fno-omit-frame-pointer -gline-tables-only).
line_tables=(-DCMAKE_C_FLAGS_RELWITHDEBINFO="-O2 -g1 -DNDEBUG" -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O2 -g1 -DNDEBUG")
o1_line_tables=(-DCMAKE_C_FLAGS_RELWITHDEBINFO="-O1 -g1 -DNDEBUG" -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O1 -g1 -DNDEBUG")
# All three are unity builds (CMake joins each target's sources, 8 at a time, into one
# translation unit): the headers every file includes (fmt, nlohmann-json, GDCM, OpenVDB, gtest)
# are parsed once per batch instead of once per file. The README's Release build compiles file
# by file, so a name that two files of one target both define in their anonymous namespaces
# fails here first.
unity=(-DCMAKE_UNITY_BUILD=ON)
section "AddressSanitizer + UndefinedBehaviorSanitizer build and tests"
cmake -S . -B build-asan -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo "${line_tables[@]}" "${unity[@]}" -DOCTORAY_SANITIZE=ON \
  -DOCTORAY_BUILD_BENCHMARKS=OFF
cmake --build build-asan -j "$jobs"
# intercept_tls_get_addr=0: LeakSanitizer's exit-time tracer ("Tracer caught signal 11" after
# every check passed, no leak reported) read outside a dynamic TLS block. GCC 12's libasan (as
# clang 14's runtime) takes a block 16 bytes past a page boundary for glibc 2.19's, and reads
# the two words before it as that block's start and size; since glibc 2.25 there is no such
# header, and a malloc'd block lands there by chance, so it came and went with the address
# layout (google/sanitizers#1322). Without the interceptor LSan does not scan the dynamic TLS of
# dlopen'd libraries (Mesa's driver) as roots; no test needs it to.
export ASAN_OPTIONS=detect_leaks=1:abort_on_error=1:intercept_tls_get_addr=0
export UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1
ctest --test-dir build-asan --output-on-failure -j "$jobs" --timeout 900
unset ASAN_OPTIONS UBSAN_OPTIONS
section "ThreadSanitizer: the brick loader, the caches and the working set"
# A separate build: the loader's threads, the cache they fill and the working set that polls,
# requests, cancels and shuts them down mid-load, with every data race an error.
cmake -S . -B build-tsan -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo "${o1_line_tables[@]}" "${unity[@]}" -DOCTORAY_TSAN=ON \
  -DOCTORAY_BUILD_BENCHMARKS=OFF
cmake --build build-tsan -j "$jobs" --target volume_unit_tests gpu_gl_tests
# On one CPU (taskset): Debian's libtbb is not instrumented, so TSan cannot see its task
# synchronisation and reports TBB's own hand-offs as races; on one CPU TBB starts no workers.
# The loader's std::threads still interleave, and TSan's happens-before analysis does not
# depend on timing. The real-head relative-bar test is an accuracy check with no threads of
# its own beyond the others', and two DICOM imports: it runs in the ASan stage only.
export TSAN_OPTIONS="halt_on_error=1 second_deadlock_stack=1 suppressions=$PWD/scripts/tsan.supp"
taskset -c 0 build-tsan/bin/volume_unit_tests --gtest_filter='BrickLoader*:BrickCache*'
OCTORAY_REQUIRE_GL=1 taskset -c 0 build-tsan/bin/gpu_gl_tests --gtest_filter='WorkingSetTest.*:-WorkingSetTest.RealHeadsMeetTheRelativeBar'
unset TSAN_OPTIONS
section "libFuzzer: store reader 60 s; volume headers, raw options, transfer functions, DICOMDIR, JSON documents 20-25 s each (ASan + UBSan)"
CC=clang CXX=clang++ cmake -S . -B build-fuzz -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo "${o1_line_tables[@]}" "${unity[@]}" \
  -DOCTORAY_FUZZ=ON -DOCTORAY_BUILD_TESTS=OFF -DOCTORAY_BUILD_BENCHMARKS=OFF
fuzz_targets=(fuzz_store_reader fuzz_volume_headers fuzz_raw_options fuzz_transfer_functions fuzz_dicomdir
              fuzz_json_documents)
cmake --build build-fuzz -j "$jobs" --target "${fuzz_targets[@]}"
rm -rf build-fuzz/seeds && build-fuzz/bin/make_store_seeds build-fuzz/seeds/store-reader
shared_dir=$(cd .. && pwd)/shared
build-fuzz/bin/make_format_seeds build-fuzz/seeds "$shared_dir" "$PWD"
# fuzz TARGET SEEDS SECONDS: the kept crashers of fuzz/regressions/TARGET first (each must now
# pass), then SECONDS of fuzzing from SEEDS; new inputs go to corpus/, a crash, leak, timeout or
# OOM input to artifacts/ and fails the run. The targets' scratch files go to tmp/ (TMPDIR), so
# a target killed mid-run leaves them in the build tree, removed by the next run, not in /tmp.
fuzz() {
  local target=$1 seeds=$2 seconds=$3 dir=build-fuzz/$1
  rm -rf "$dir" && mkdir -p "$dir/corpus" "$dir/artifacts" "$dir/tmp"
  local options=(-timeout=10 -rss_limit_mb=2048 -artifact_prefix="$dir/artifacts/")
  export ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1
  local scratch=$PWD/$dir/tmp
  if [[ -d fuzz/regressions/$target ]] && compgen -G "fuzz/regressions/$target/*" >/dev/null; then
    if ! TMPDIR=$scratch "build-fuzz/bin/$target" "${options[@]}" fuzz/regressions/"$target"/* >"$dir/regressions.log" 2>&1; then
      tail -n 40 "$dir/regressions.log"
      echo "$target: a kept crasher (fuzz/regressions/$target) fails again" >&2
      exit 1
    fi
  fi
  if TMPDIR=$scratch "build-fuzz/bin/$target" "$dir/corpus" "$seeds" -max_total_time="$seconds" -print_final_stats=1 \
      "${options[@]}" >"$dir/fuzz.log" 2>&1; then
    echo "$target: no crash in $seconds s ($(grep -o 'stat::number_of_executed_units: *[0-9]*' \
      "$dir/fuzz.log" | grep -o '[0-9]*$') executions; log $dir/fuzz.log)"
  else
    tail -n 60 "$dir/fuzz.log"
    echo "$target: FAILED, reproducer in $dir/artifacts/ (keep it in fuzz/regressions/$target once fixed)" >&2
    exit 1
  fi
  unset ASAN_OPTIONS UBSAN_OPTIONS
}
# Each fuzzer runs on one core: with two or more, two lanes run side by side (85 and 95 s of
# fuzzing instead of 180 s one after the other), and a lane that fails fails the script.
lane_a() {
  fuzz fuzz_store_reader build-fuzz/seeds/store-reader 60
  fuzz fuzz_dicomdir build-fuzz/seeds/dicomdir 25
}
lane_b() {
  fuzz fuzz_volume_headers build-fuzz/seeds/volume-headers 25
  fuzz fuzz_raw_options build-fuzz/seeds/raw-options 20
  fuzz fuzz_transfer_functions build-fuzz/seeds/transfer-functions 25
  fuzz fuzz_json_documents build-fuzz/seeds/json-documents 25
}
if (( jobs >= 2 )); then
  lane_a & pid_a=$!
  lane_b & pid_b=$!
  status=0
  wait "$pid_a" || status=1
  wait "$pid_b" || status=1
  (( status == 0 )) || exit 1
else
  lane_a
  lane_b
fi
section "done"
