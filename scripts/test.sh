#!/usr/bin/env bash
# Builds and runs the whole test suite under AddressSanitizer + UndefinedBehaviorSanitizer
# (optimised, with debug info: every test runs, and any memory error or undefined behaviour
# fails it), the loader and working-set tests under ThreadSanitizer, then fuzzes the store
# reader for 60 s. Installs missing Debian packages first.
# The Release build of README's first command runs the same code without instrumentation.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh

jobs=$(nproc)
echo "== AddressSanitizer + UndefinedBehaviorSanitizer build and tests"
cmake -S . -B build-asan -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DOCTORAY_SANITIZE=ON \
  -DOCTORAY_BUILD_BENCHMARKS=OFF
cmake --build build-asan -j "$jobs"
export ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1
if ! ctest --test-dir build-asan --output-on-failure -j "$jobs" --timeout 900; then
  # LeakSanitizer's own tracer (the thread that stops the others for the exit-time leak check)
  # now and then segfaults in GL programs after every check passed: "Tracer caught signal 11",
  # a sanitizer runtime fault (google/sanitizers#1353), not a leak and not our code. Only when
  # every failure shows it are the failed tests run once more; any other failure fails here.
  failed=$(wc -l < build-asan/Testing/Temporary/LastTestsFailed.log)
  tracer=$(grep -c "LeakSanitizer does not work under ptrace" build-asan/Testing/Temporary/LastTest.log || true)
  if ((tracer >= failed)); then
    echo "== LeakSanitizer's tracer crashed in ${failed} test(s) after their checks; rerunning them once"
    ctest --test-dir build-asan --output-on-failure --rerun-failed --timeout 900
  else
    exit 1
  fi
fi
unset ASAN_OPTIONS UBSAN_OPTIONS
echo "== ThreadSanitizer: the brick loader, the caches and the working set"
# A separate build: the loader's threads, the cache they fill and the working set that polls,
# requests, cancels and shuts them down mid-load, with every data race an error.
cmake -S . -B build-tsan -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DOCTORAY_TSAN=ON \
  -DOCTORAY_BUILD_BENCHMARKS=OFF
cmake --build build-tsan -j "$jobs" --target volume_unit_tests gpu_gl_tests
# On one CPU (taskset): Debian's libtbb is not instrumented, so TSan cannot see its task
# synchronisation and reports TBB's own hand-offs as races; on one CPU TBB starts no workers.
# The loader's std::threads still interleave, and TSan's happens-before analysis does not
# depend on timing.
export TSAN_OPTIONS="halt_on_error=1 second_deadlock_stack=1 suppressions=$PWD/scripts/tsan.supp"
taskset -c 0 build-tsan/bin/volume_unit_tests --gtest_filter='BrickLoader*:BrickCache*'
OCTORAY_REQUIRE_GL=1 taskset -c 0 build-tsan/bin/gpu_gl_tests --gtest_filter='WorkingSetTest.*'
unset TSAN_OPTIONS
echo "== libFuzzer: store reader (60 s, ASan + UBSan)"
CC=clang CXX=clang++ cmake -S . -B build-fuzz -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DOCTORAY_FUZZ=ON -DOCTORAY_BUILD_TESTS=OFF -DOCTORAY_BUILD_BENCHMARKS=OFF
cmake --build build-fuzz -j "$jobs" --target fuzz_store_reader
fuzz_dir=build-fuzz/fuzz-store-reader
rm -rf "$fuzz_dir" && mkdir -p "$fuzz_dir/corpus" "$fuzz_dir/artifacts"
build-fuzz/bin/make_store_seeds "$fuzz_dir/seeds"
# New inputs go to corpus/; a crash, leak, timeout or OOM input to artifacts/ and fails the run.
if ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  build-fuzz/bin/fuzz_store_reader "$fuzz_dir/corpus" "$fuzz_dir/seeds" \
    -max_total_time=60 -timeout=10 -rss_limit_mb=2048 -print_final_stats=1 \
    -artifact_prefix="$fuzz_dir/artifacts/" >"$fuzz_dir/fuzz.log" 2>&1; then
  echo "fuzz_store_reader: no crash in 60 s ($(grep -o 'stat::number_of_executed_units: *[0-9]*' \
    "$fuzz_dir/fuzz.log" | grep -o '[0-9]*$') executions; log $fuzz_dir/fuzz.log)"
else
  tail -n 60 "$fuzz_dir/fuzz.log"
  echo "fuzz_store_reader: FAILED, reproducer in $fuzz_dir/artifacts/ (log $fuzz_dir/fuzz.log)" >&2
  exit 1
fi
