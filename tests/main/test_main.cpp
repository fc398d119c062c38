// The main() of every test binary: GoogleTest's, with the temporary folders of a run whose
// tests all passed removed (test_paths.h), and then waiting for TBB's worker threads to
// end before the process exits (log4cplus's pool, which OpenVDB brings, is joined by an exit
// handler of the same cli_support.cpp). Left to themselves they are torn down by static
// destructors while LeakSanitizer's exit-time check is stopping every thread. (The tracer
// crashes "Tracer caught signal 11" seen after passing tests had another cause, a misread
// dynamic TLS block: scripts/test.sh sets intercept_tls_get_addr=0 for it.)

#include <gtest/gtest.h>

#include "cli_support.h"
#include "test_paths.h"

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  octoray::test::removeTempDirsOfPassedRuns();
  const octoray::cli::WorkerThreadsJoinedAtExit joined;
  return RUN_ALL_TESTS();
}
