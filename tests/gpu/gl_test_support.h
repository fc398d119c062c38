#pragma once
// The GL test fixture: a headless 4.5 core context per test, or a skip with the reason where
// EGL has none (a failure when OCTORAY_REQUIRE_GL is set). Every GL test file uses it, and
// every GL object a test creates must be destroyed while the context is current.

#include <gtest/gtest.h>

#include <cstdlib>
#include <memory>
#include <string>
#include <string_view>

#include "octoray/core/error.h"
#include "octoray/gpu/gl_context.h"

namespace octoray::gpu {

inline bool glRequired() { return std::getenv("OCTORAY_REQUIRE_GL") != nullptr; }

// A headless context, or a skip (a failure with OCTORAY_REQUIRE_GL) where EGL has none.
class GlTest : public ::testing::Test {
 protected:
  void SetUp() override { context_ = headless({}); }

  std::unique_ptr<GlContext> headless(const GlContextOptions& options) {
    try {
      auto context = createHeadlessContext(options);
      return context;
    } catch (const Error& error) {
      if (glRequired()) {
        ADD_FAILURE() << "OCTORAY_REQUIRE_GL is set and " << error.what();
      } else {
        skipReason_ = error.what();
      }
      return nullptr;
    }
  }

  std::unique_ptr<GlContext> context_;
  std::string skipReason_;
};

#define OCTORAY_REQUIRE_CONTEXT(context)                                     \
  do {                                                                       \
    if (HasFailure()) return;                                                \
    if (!(context)) {                                                        \
      GTEST_SKIP() << "skipped: no OpenGL 4.5 core context (" << skipReason_ \
                   << "); set OCTORAY_REQUIRE_GL=1 to make this a failure";  \
    }                                                                        \
  } while (0)

}  // namespace octoray::gpu
