// The main() of every test binary: GoogleTest's, and then waiting for TBB's worker threads to
// end before the process exits. Left to themselves they are torn down by TBB's static
// destructors while LeakSanitizer's exit-time check is stopping every thread, and on a loaded
// machine LSan's tracer then crashes now and then ("Tracer caught signal 11") after every test
// passed.

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <cstdio>
#include <new>

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  tbb::task_scheduler_handle scheduler{tbb::attach{}};
  const int result = RUN_ALL_TESTS();
  if (!tbb::finalize(scheduler, std::nothrow)) {
    std::fprintf(stderr, "test_main: TBB's worker threads could not be waited for\n");
  }
  return result;
}
