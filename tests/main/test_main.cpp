// The main() of every test binary: GoogleTest's, and then waiting for TBB's worker threads to
// end before the process exits (log4cplus's pool, which OpenVDB brings, is joined by an exit
// handler of the same cli_support.cpp). Left to themselves they are torn down by static
// destructors while LeakSanitizer's exit-time check is stopping every thread, and on a loaded
// machine LSan's tracer then crashes now and then ("Tracer caught signal 11") after every test
// passed.

#include <gtest/gtest.h>

#include "cli_support.h"

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  const octoray::cli::WorkerThreadsJoinedAtExit joined;
  return RUN_ALL_TESTS();
}
