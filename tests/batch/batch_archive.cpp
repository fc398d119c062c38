#include "batch_archive.h"

#include <gtest/gtest.h>

#include <fstream>
#include <sstream>

#include "run_process.h"
#include "test_paths.h"

namespace octoray::test {

namespace fs = std::filesystem;

ToolRun runTool(const std::string& tool, const std::vector<std::string>& args) {
  std::vector<std::string> argv = {toolPath(tool).string()};
  argv.insert(argv.end(), args.begin(), args.end());
  const ProcessResult r = runProcess(argv);
  return {r.exitCode, r.out, r.err};
}

nlohmann::json ToolRun::json() const {
  const auto j = nlohmann::json::parse(out, nullptr, false);
  EXPECT_FALSE(j.is_discarded()) << "not JSON: " << out << "\nstderr: " << err;
  return j;
}

std::string readText(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

BatchArchive makeBatchArchive(const fs::path& root) {
  BatchArchive a;
  a.root = root;
  fs::create_directories(root);
  fs::copy(philipsDir(), root / "philips", fs::copy_options::recursive);
  struct Synthetic {
    const char* folder;
    std::vector<std::string> args;
  };
  const std::vector<Synthetic> synthetic = {
      {"patient-a/ct1", {"--seed", "21", "--size", "96x80x48", "--patient-name", "DOE^JANE", "--patient-id", "PAT-A-001"}},
      {"patient-a/ct2", {"--seed", "22", "--size", "64x64x30", "--patient-name", "DOE^JANE", "--patient-id", "PAT-A-001"}},
      {"patient-b/tilted", {"--seed", "23", "--tilt", "15", "--variable-gaps", "--with-localizer",
                            "--patient-name", "ROE^RICHARD", "--patient-id", "PAT-B-002"}},
  };
  for (const auto& s : synthetic) {
    std::vector<std::string> args = s.args;
    args.insert(args.begin(), (root / s.folder).string());
    const ToolRun r = runTool("octoray-sample-series", args);
    EXPECT_EQ(r.exitCode, 0) << r.err;
  }
  fs::create_directories(root / "volumes");
  const ToolRun nifti =
      runTool("octoray-import", {"--export", (root / "volumes/ct1.nii.gz").string(), (root / "patient-a/ct1").string()});
  EXPECT_EQ(nifti.exitCode, 0) << nifti.err;
  fs::create_directories(root / "broken");
  std::ofstream(root / "broken/junk.dcm") << "not a DICOM file at all";
  {
    // The first 3000 bytes of a real slice: a header cut short.
    std::ifstream in(root / "philips/S21570/S2010/I10", std::ios::binary);
    std::string head(3000, '\0');
    in.read(head.data(), 3000);
    std::ofstream(root / "broken/cut.dcm", std::ios::binary) << head;
  }
  std::ofstream(root / "broken/bad.nrrd", std::ios::binary) << "NRRD0004\ntype: int16";
  return a;
}

}  // namespace octoray::test
