// octoray-tf run as a user would: list, convert with and without --tf-name, and one clear
// message with exit status 1 for bad input.

#include <gtest/gtest.h>

#include <algorithm>
#include <fstream>

#include "octoray/transfer/transfer_function_io.h"
#include "run_process.h"
#include "test_paths.h"

namespace octoray::transfer {
namespace {

namespace fs = std::filesystem;

const std::string kTwoPresets = R"(<MRML>
  <VolumeProperty name="First" scalarOpacity="4 0 0 10 1" colorTransfer="4 0 1 1 1"/>
  <VolumeProperty name="Second" scalarOpacity="2 0 0.5" colorTransfer="4 0 1 0 0"/>
</MRML>)";

TEST(OctorayTf, ListAndConvert) {
  const fs::path dir = test::freshTempDir("tf_tool");
  const fs::path input = dir / "presets.xml";
  std::ofstream(input) << kTwoPresets;
  const std::string tool = test::toolPath("octoray-tf").string();

  const test::ProcessResult list = test::runProcess({tool, "list", input.string()});
  EXPECT_EQ(list.exitCode, 0) << list.err;
  EXPECT_EQ(list.out, "First\nSecond\n");

  const fs::path output = dir / "second.json";
  const test::ProcessResult convert = test::runProcess(
      {tool, "convert", input.string(), "--tf-name", "second", "-o", output.string()});
  EXPECT_EQ(convert.exitCode, 0) << convert.err;
  const auto converted = loadTransferFunctions(output);
  ASSERT_EQ(converted.size(), 1u);
  EXPECT_EQ(converted[0].name, "Second");
  EXPECT_EQ(converted[0].opacity[0].alpha, 0.5f);

  const test::ProcessResult ambiguous =
      test::runProcess({tool, "convert", input.string(), "-o", (dir / "x.json").string()});
  EXPECT_EQ(ambiguous.exitCode, 1);
  EXPECT_NE(ambiguous.err.find(input.string() + ": holds 2 transfer functions"), std::string::npos)
      << ambiguous.err;
  EXPECT_FALSE(fs::exists(dir / "x.json"));

  const fs::path all = dir / "all.json";
  EXPECT_EQ(test::runProcess({tool, "convert", input.string(), "--all", "-o", all.string()}).exitCode, 0);
  EXPECT_EQ(loadTransferFunctions(all).size(), 2u);

  // Converting a file onto itself would replace the presets with one function: refused.
  const test::ProcessResult self =
      test::runProcess({tool, "convert", input.string(), "--tf-name", "First", "-o", input.string()});
  EXPECT_EQ(self.exitCode, 1);
  EXPECT_NE(self.err.find(input.string() + ": the output is the same file as the input"),
            std::string::npos)
      << self.err;
  std::ifstream in(input);
  EXPECT_EQ(std::string(std::istreambuf_iterator<char>(in), {}), kTwoPresets);
}

TEST(OctorayTf, BadInputIsOneMessageAndExit1) {
  const fs::path dir = test::freshTempDir("tf_tool_bad");
  const fs::path input = dir / "broken.json";
  std::ofstream(input) << R"([{"Name": "x", "RGBPoints": [0, 1, 1, 1, -5, 2, 0, 0]}])";
  const test::ProcessResult result =
      test::runProcess({test::toolPath("octoray-tf").string(), "list", input.string()});
  EXPECT_EQ(result.exitCode, 1);
  EXPECT_EQ(result.out, "");
  EXPECT_NE(result.err.find(input.string() + ": "), std::string::npos) << result.err;
  EXPECT_EQ(std::count(result.err.begin(), result.err.end(), '\n'), 1) << result.err;
}

// A number too large for a double is named with the file, like every other JSON mistake.
TEST(OctorayTf, NumberOverflowNamesTheFile) {
  const fs::path dir = test::freshTempDir("tf_tool_overflow");
  const fs::path input = dir / "overflow.json";
  std::ofstream(input) << R"({"format": "octoray-transfer-function", "version": 1, "name": "x",
                             "opacity": [[1e999, 0]]})";
  const test::ProcessResult result =
      test::runProcess({test::toolPath("octoray-tf").string(), "list", input.string()});
  EXPECT_EQ(result.exitCode, 1);
  EXPECT_NE(result.err.find(input.string() + ": "), std::string::npos) << result.err;
  EXPECT_NE(result.err.find("1e999"), std::string::npos) << result.err;
}

}  // namespace
}  // namespace octoray::transfer
