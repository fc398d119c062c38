// octoray-render's GPU path (the default) as a user runs it: the timing loop's --json report,
// a non-store input built into a temporary store that is removed afterwards, agreement with
// --reference, and bad input exiting 1 with one message naming the file.

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <set>

#include "file_damage.h"
#include "gl_test_support.h"
#include "octoray/gpu/camera.h"
#include "octoray/gpu/image_io.h"
#include "octoray/gpu/image_metrics.h"
#include "octoray/gpu/working_set.h"
#include "octoray/volume/phantom.h"
#include "octoray/volume/store_builder.h"
#include "octoray/volume/store_reader.h"
#include "run_process.h"
#include "test_paths.h"

namespace octoray::gpu {
namespace {

using test::ProcessResult;
using test::runProcess;
using test::toolPath;

class GpuRenderTool : public GlTest {
 protected:
  void SetUp() override {
    GlTest::SetUp();  // a context here tells whether the tool will find one
    if (!context_) return;
    if (!std::filesystem::exists(toolPath("octoray-render"))) GTEST_SKIP() << "tool not built";
    dir = test::freshTempDir("gpu_tool");
    volume::PhantomOptions phantom;
    phantom.dims = {48, 44, 40};
    phantom.spacingMm = {1.2, 1.3, 1.5};
    nrrd = (dir / "phantom.nhdr").string();
    volume::writePhantomNrrd(phantom, nrrd);
    store = (dir / "phantom.octoray").string();
    volume::BuildOptions options;
    options.brickSize = 16;
    options.border = 2;
    volume::buildStore(*volume::makePhantom(phantom), store, options);
  }
  std::filesystem::path dir;
  std::string nrrd, store;
};

std::set<std::filesystem::path> temporaryStores() {
  std::set<std::filesystem::path> found;
  for (const auto& entry : std::filesystem::directory_iterator(std::filesystem::temp_directory_path())) {
    if (entry.path().filename().string().starts_with("octoray-render-")) found.insert(entry.path());
  }
  return found;
}

TEST_F(GpuRenderTool, TimingLoopReportsEveryFrame) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const std::string render = toolPath("octoray-render").string();
  const ProcessResult r = runProcess({render, store, "-o", (dir / "gpu.png").string(), "--exr",
                                      (dir / "gpu.exr").string(), "--preset", "bone", "--size",
                                      "64x48", "--gpu", "--lod-pixels", "0", "--frames", "4",
                                      "--orbit", "15", "--json"});
  ASSERT_EQ(r.exitCode, 0) << r.err;
  const auto report = nlohmann::json::parse(r.out);
  EXPECT_EQ(report["renderer"], "gpu");
  EXPECT_EQ(report["width"], 64);
  EXPECT_EQ(report["height"], 48);
  ASSERT_EQ(report["frames"].size(), 4u);
  std::vector<double> ms;
  for (const auto& frame : report["frames"]) {
    ms.push_back(frame["ms"].get<double>());
    EXPECT_GT(frame["samplesPerPixel"].get<double>(), 0);
    EXPECT_GT(frame["bricksTouched"].get<int64_t>(), 0);
    EXPECT_LE(frame["bricksTouched"].get<int64_t>(), frame["workingSetBricks"].get<int64_t>());
    EXPECT_GT(frame["poolBytesUsed"].get<int64_t>(), 0);
    EXPECT_LE(frame["poolBytesUsed"].get<int64_t>(), frame["poolBytes"].get<int64_t>());
  }
  EXPECT_EQ(report["firstFrameMs"].get<double>(), ms[0]);
  std::vector<double> steady(ms.begin() + 1, ms.end());
  std::sort(steady.begin(), steady.end());
  EXPECT_EQ(report["medianMs"].get<double>(), steady[1]);
  // Turning frames touch different bricks: frame 1 (15 degrees) uploads nothing new only if
  // the whole volume is resident, which it is here (lod 0, large pool): uploads happen once.
  EXPECT_GT(report["frames"][0]["bricksUploaded"].get<int64_t>(), 0);
  EXPECT_EQ(report["frames"][1]["bricksUploaded"].get<int64_t>(), 0);

  const ProcessResult ref = runProcess({render, store, "-o", (dir / "ref.png").string(), "--exr",
                                        (dir / "ref.exr").string(), "--preset", "bone", "--size",
                                        "64x48", "--reference"});
  ASSERT_EQ(ref.exitCode, 0) << ref.err;
  const ImageMetrics m = compare(readImage(dir / "ref.exr"), readImage(dir / "gpu.exr"));
  EXPECT_GE(m.psnrDb, 40.0);
  EXPECT_EQ(m.nonFiniteB, 0);
}

// A pool too small for the finest level the view asks for: the picture is coarser, and the
// tool says so (stderr and --json), instead of a silently coarser picture.
TEST_F(GpuRenderTool, PoolTooSmallForTheLevelOfDetailIsWarned) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  volume::PhantomOptions phantom;
  phantom.dims = {160, 160, 128};  // 800 leaves of 16^3 (+ borders): 13 MiB, a 1 MiB pool holds ~50
  const std::string big = (dir / "big.octoray").string();
  volume::BuildOptions options;
  options.brickSize = 16;
  options.border = 2;
  volume::buildStore(*volume::makePhantom(phantom), big, options);
  const std::string render = toolPath("octoray-render").string();
  const std::vector<std::string> common = {"--preset", "bone", "--size", "96x96", "--gpu", "--lod-pixels", "0", "--json"};
  std::vector<std::string> small = {render, big, "-o", (dir / "small-pool.png").string(), "--pool-mib", "1"};
  small.insert(small.end(), common.begin(), common.end());
  const ProcessResult r = runProcess(small);
  ASSERT_EQ(r.exitCode, 0) << r.err;
  EXPECT_NE(r.err.find("--pool-mib 1"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("coarser than --lod-pixels 0"), std::string::npos) << r.err;
  const auto report = nlohmann::json::parse(r.out);
  ASSERT_EQ(report["warnings"].size(), 1u);
  EXPECT_GT(report["frames"][0]["stoppedByPool"].get<int64_t>(), 0);

  std::vector<std::string> large = {render, big, "-o", (dir / "large-pool.png").string(), "--pool-mib", "64"};
  large.insert(large.end(), common.begin(), common.end());
  const ProcessResult enough = runProcess(large);
  ASSERT_EQ(enough.exitCode, 0) << enough.err;
  EXPECT_EQ(enough.err.find("warning"), std::string::npos) << enough.err;
  EXPECT_TRUE(nlohmann::json::parse(enough.out)["warnings"].empty());
}

TEST_F(GpuRenderTool, NonStoreInputUsesATemporaryStoreThatIsRemoved) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const std::string render = toolPath("octoray-render").string();
  const auto before = temporaryStores();
  const ProcessResult r = runProcess({render, nrrd, "-o", (dir / "n.exr.png").string(), "--exr",
                                      (dir / "n.exr").string(), "--preset", "bone", "--size",
                                      "40x40", "--lod-pixels", "0"});
  ASSERT_EQ(r.exitCode, 0) << r.err;
  EXPECT_EQ(temporaryStores(), before) << "the temporary store was left behind";
  const ProcessResult s = runProcess({render, store, "-o", (dir / "s.png").string(), "--exr",
                                      (dir / "s.exr").string(), "--preset", "bone", "--size",
                                      "40x40", "--lod-pixels", "0"});
  ASSERT_EQ(s.exitCode, 0) << s.err;
  const ImageMetrics m = compare(readImage(dir / "s.exr"), readImage(dir / "n.exr"));
  EXPECT_GE(m.psnrDb, 60.0) << "the NRRD and its store should render alike";
}

TEST_F(GpuRenderTool, BadInputExitsOneNamingTheFile) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const std::string render = toolPath("octoray-render").string();
  const std::string out = (dir / "x.png").string();
  const ProcessResult missing =
      runProcess({render, (dir / "none.nrrd").string(), "-o", out, "--preset", "bone"});
  EXPECT_EQ(missing.exitCode, 1);
  EXPECT_NE(missing.err.find("none.nrrd"), std::string::npos) << missing.err;
  std::ofstream(dir / "bad.octoray") << "OCTORAY\x1a" << std::string(40, 'x');
  const ProcessResult bad =
      runProcess({render, (dir / "bad.octoray").string(), "-o", out, "--preset", "bone"});
  EXPECT_EQ(bad.exitCode, 1);
  EXPECT_NE(bad.err.find("bad.octoray"), std::string::npos) << bad.err;
  const ProcessResult noGradients =
      runProcess({render, store, "-o", out, "--preset", "bone", "--gradient-pool"});
  EXPECT_EQ(noGradients.exitCode, 1);
  EXPECT_NE(noGradients.err.find("--gradients"), std::string::npos) << noGradients.err;
  EXPECT_EQ(runProcess({render, store, "-o", out, "--preset", "bone", "--lod-pixels", "-1"}).exitCode, 1);
  EXPECT_EQ(runProcess({render, store, "-o", out, "--preset", "bone", "--boundary", "1,2"}).exitCode, 1);
  // A step too small for single-precision stepping: refused naming the store, not a black picture.
  const ProcessResult tinyStep = runProcess({render, store, "-o", out, "--preset", "bone", "--step", "1e-9"});
  EXPECT_EQ(tinyStep.exitCode, 1);
  EXPECT_NE(tinyStep.err.find("step 1e-09 mm is too small for the GPU raycaster"), std::string::npos) << tinyStep.err;
  EXPECT_NE(tinyStep.err.find(store), std::string::npos) << tinyStep.err;
  EXPECT_FALSE(std::filesystem::exists(out)) << "no output after a failure";
}

// A brick the view needs fails its checksum: one message naming the store and the node, exit
// 1, no picture.
TEST_F(GpuRenderTool, CorruptedBrickFailsTheRenderNamingTheStore) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const std::filesystem::path corrupt = dir / "corrupt.octoray";
  std::filesystem::copy_file(store, corrupt);
  int64_t victim = -1;
  {
    const volume::StoreReader reader(store);
    const int leaf = reader.layout().leafLevel();
    float best = -1e30f;
    for (int64_t id = 0; id < static_cast<int64_t>(reader.nodes().size()); ++id) {
      const volume::NodeRecord& node = reader.node(id);
      if (reader.layout().nodeKey(id).level != leaf || node.payloadBytes == 0) continue;
      if (node.maxValue > best) {  // bone: visible with the bone preset, so in the working set
        best = node.maxValue;
        victim = id;
      }
    }
    ASSERT_GE(victim, 0);
    const volume::NodeRecord& node = reader.node(victim);
    test::flipByte(corrupt, static_cast<std::streamoff>(node.payloadOffset + node.payloadBytes / 2));
    if (HasFatalFailure()) return;
  }
  const std::string out = (dir / "corrupt.png").string();
  const ProcessResult r = runProcess({toolPath("octoray-render").string(), corrupt.string(), "-o",
                                      out, "--preset", "bone", "--size", "48x48", "--lod-pixels", "0"});
  EXPECT_EQ(r.exitCode, 1) << r.err;
  EXPECT_NE(r.err.find("corrupt.octoray"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("checksum"), std::string::npos) << r.err;
  EXPECT_FALSE(std::filesystem::exists(out));
}


// --cut-reference: the CPU reference over the cut of the path's last (converged) frame; what
// the tool reports is what the files hold.
TEST_F(GpuRenderTool, CutReferenceChecksTheConvergedPictureOfAPath) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const std::string render = toolPath("octoray-render").string();
  const std::string out = (dir / "path.png").string(), ref = (dir / "cut.png").string();
  const ProcessResult r = runProcess({render, store, "-o", out, "--preset", "bone", "--size", "64x64",
                                      "--lod-pixels", "2", "--path", "orbit:4,degrees:40,still:16",
                                      "--cut-reference", ref, "--json"});
  ASSERT_EQ(r.exitCode, 0) << r.err;
  const auto report = nlohmann::json::parse(r.out);
  ASSERT_TRUE(report["converged"].get<bool>());
  const auto& c = report["cutReference"];
  EXPECT_EQ(c["output"], ref);
  EXPECT_GT(c["leaves"].get<int>(), 0);
  EXPECT_GE(c["coarsestLevelsAboveLeaf"].get<int>(), 1) << "LOD 2 at 64x64 draws coarse levels";
  const ImageMetrics m = compare(readImage(ref), readImage(out));
  EXPECT_GE(m.psnrDb, 40.0);
  EXPECT_NEAR(c["psnrDb"].get<double>(), m.psnrDb, 1.0) << "the report is about these pictures";
  // What the reference does not model is refused before anything is rendered.
  const std::string mipOut = (dir / "mip.png").string();
  const ProcessResult mip = runProcess({render, store, "-o", mipOut, "--mode", "mip", "--cut-reference", ref});
  EXPECT_EQ(mip.exitCode, 2) << mip.err;
  EXPECT_NE(mip.err.find("--cut-reference"), std::string::npos) << mip.err;
  EXPECT_FALSE(std::filesystem::exists(mipOut));
}

// --cut-truth: the reference over the cut at a fine step and without early termination, the
// cut's own truth. At a coarse step the GPU picture agrees with the same-step reference (one
// discretisation) better than with this truth, the truth has converged (halving its step
// changes little), and the report and the EXR say what was rendered.
TEST_F(GpuRenderTool, CutTruthIsTheCutsConvergedPicture) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const std::string render = toolPath("octoray-render").string();
  const std::string gpuExr = (dir / "gpu.exr").string();
  const std::vector<std::string> common{render, store, "-o", (dir / "gpu.png").string(), "--exr", gpuExr,
                                        "--preset", "bone", "--size", "64x64", "--azimuth", "30",
                                        "--elevation", "15", "--lod-pixels", "2", "--step", "2.4", "--json"};
  auto run = [&](const std::string& name, std::vector<std::string> extra) {
    std::vector<std::string> args = common;
    args.insert(args.end(), {"--cut-reference", (dir / (name + ".png")).string()});
    args.insert(args.end(), extra.begin(), extra.end());
    const ProcessResult r = runProcess(args);
    EXPECT_EQ(r.exitCode, 0) << r.err;
    return r.exitCode == 0 ? nlohmann::json::parse(r.out)["cutReference"] : nlohmann::json();
  };
  const auto sameStep = run("same", {});
  const auto truth = run("truth", {"--cut-truth", "0.15"});
  const auto finer = run("finer", {"--cut-truth", "0.075"});
  if (HasFailure()) return;
  EXPECT_DOUBLE_EQ(sameStep["stepMm"].get<double>(), 2.4);
  EXPECT_DOUBLE_EQ(sameStep["earlyTermination"].get<double>(), 0.99);
  EXPECT_DOUBLE_EQ(truth["stepMm"].get<double>(), 0.15);
  EXPECT_DOUBLE_EQ(truth["earlyTermination"].get<double>(), 1.0);
  EXPECT_GE(truth["coarsestLevelsAboveLeaf"].get<int>(), 1) << "LOD 2 at 64x64 draws coarse levels";
  ASSERT_EQ(truth["exr"], (dir / "truth.exr").string());
  const Image gpu = readImage(gpuExr), truthImage = readImage(truth["exr"].get<std::string>());
  const ImageMetrics toTruth = compare(gpu, truthImage);
  EXPECT_NEAR(truth["psnrDb"].get<double>(), toTruth.psnrDb, 0.01) << "the report is about these pictures";
  EXPECT_GT(compare(truthImage, Image(gpu.width, gpu.height)).maxAbsError, 0.1) << "the truth shows the volume";
  const double toSameStep = compare(gpu, readImage((dir / "same.exr").string())).psnrDb;
  EXPECT_GT(toSameStep, toTruth.psnrDb + 10) << "a 2-voxel step is further from the truth than from its own reference";
  EXPECT_GT(compare(truthImage, readImage((dir / "finer.exr").string())).psnrDb, 50.0) << "converged";
  // It qualifies --cut-reference, and only that.
  const std::string out = (dir / "refused.png").string();
  EXPECT_EQ(runProcess({render, store, "-o", out, "--cut-truth", "0.1"}).exitCode, 2);
  EXPECT_EQ(runProcess({render, store, "-o", out, "--reference", "--cut-truth", "0.1"}).exitCode, 2);
  EXPECT_FALSE(std::filesystem::exists(out));
}

// The leaf-level nodes in a zoomed view (gpu::nodesInFrustum) hold every point a ray of the
// camera reaches, and not the whole store: rays through pixel centres, corners included,
// marched through the volume, meet no node outside the list.
TEST_F(GpuRenderTool, NodesInFrustumHoldEveryPointOfEveryRay) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const volume::StoreReader reader(store);
  const volume::OctreeLayout& layout = reader.layout();
  const int leafLevel = layout.leafLevel();
  const volume::Index3& dims = layout.levelDims(leafLevel);
  for (const Projection projection : {Projection::Perspective, Projection::Orthographic}) {
    OrbitParameters orbit;
    orbit.azimuthDegrees = 30;
    orbit.elevationDegrees = 15;
    orbit.zoom = 3;
    orbit.projection = projection;
    orbit.width = orbit.height = 33;
    const Camera camera = orbitCamera({dims, reader.patientFromIndex()}, orbit);
    const std::vector<volume::NodeKey> nodes = nodesInFrustum(reader, camera, leafLevel);
    std::set<int64_t> inView;
    for (const volume::NodeKey& key : nodes) {
      EXPECT_EQ(key.level, leafLevel);
      inView.insert(layout.nodeId(key));
    }
    const volume::Index3& n = layout.levelBricks(leafLevel);
    EXPECT_LT(inView.size(), static_cast<std::size_t>(n[0] * n[1] * n[2])) << "zoom 3 sees part of the store";
    const Mat4 indexFromPatient = reader.patientFromIndex().inverseAffine();
    int64_t inside = 0;
    for (int y = 0; y < camera.height; ++y) {
      for (int x = 0; x < camera.width; ++x) {
        const Ray ray = camera.ray(x, y);
        for (double t = 0; t < 600; t += 0.25) {
          const Vec3 p = indexFromPatient.transformPoint(ray.origin + t * ray.direction);
          const double q[3] = {p.x, p.y, p.z};
          volume::NodeKey key{leafLevel, {}};
          bool outside = false;
          for (int a = 0; a < 3; ++a) {
            outside = outside || q[a] < -0.5 || q[a] > static_cast<double>(dims[a]) - 0.5;
            key.brick[a] = std::clamp<int64_t>(static_cast<int64_t>(std::floor(q[a] + 0.5)), 0, dims[a] - 1) /
                           layout.brickSize();
          }
          if (outside) continue;
          ++inside;
          ASSERT_TRUE(inView.count(layout.nodeId(key))) << "pixel " << x << "," << y << " t " << t
                                                        << " reaches brick " << key.brick[0] << " "
                                                        << key.brick[1] << " " << key.brick[2];
        }
      }
    }
    EXPECT_GT(inside, 1000) << "the rays cross the volume";
  }
}

// --reference --frustum-cut reads only the leaf bricks in view and draws the same picture as
// the full volume, in every mode; a view that would not fit in memory is refused by name.
TEST_F(GpuRenderTool, FrustumCutReferenceIsTheFullVolumesPicture) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const std::string render = toolPath("octoray-render").string();
  for (const std::vector<std::string>& mode : {std::vector<std::string>{"--mode", "dvr", "--preset", "bone"},
                                               {"--mode", "iso", "--iso", "300"},
                                               {"--mode", "mip"}}) {
    std::vector<std::string> common{render, store, "--reference", "--size", "48x40", "--zoom", "4",
                                    "--azimuth", "30", "--elevation", "15", "--json"};
    common.insert(common.end(), mode.begin(), mode.end());
    std::vector<std::string> full = common, cut = common;
    full.insert(full.end(), {"-o", (dir / "full.png").string(), "--exr", (dir / "full.exr").string()});
    cut.insert(cut.end(), {"-o", (dir / "cut.png").string(), "--exr", (dir / "cut.exr").string(), "--frustum-cut"});
    const ProcessResult a = runProcess(full), b = runProcess(cut);
    ASSERT_EQ(a.exitCode, 0) << a.err;
    ASSERT_EQ(b.exitCode, 0) << b.err;
    const auto report = nlohmann::json::parse(b.out)["frustumCut"];
    EXPECT_GT(report["leaves"].get<int>(), 0);
    EXPECT_LT(report["leaves"].get<int>(), report["leafNodes"].get<int>()) << mode[1];
    const Image fullImage = readImage((dir / "full.exr").string()), cutImage = readImage((dir / "cut.exr").string());
    const ImageMetrics m = compare(fullImage, cutImage);
    EXPECT_EQ(m.maxAbsError, 0.0) << mode[1] << ": " << m.psnrDb << " dB";
    EXPECT_GT(compare(fullImage, Image(fullImage.width, fullImage.height)).maxAbsError, 0.1)
        << mode[1] << ": the picture shows the volume";
  }
  // Only stores have bricks to choose from.
  const ProcessResult notStore = runProcess({render, nrrd, "--reference", "--frustum-cut", "-o",
                                             (dir / "nrrd.png").string()});
  EXPECT_EQ(notStore.exitCode, 1);
  EXPECT_NE(notStore.err.find("--frustum-cut needs an octree store"), std::string::npos) << notStore.err;
  EXPECT_NE(notStore.err.find(nrrd), std::string::npos) << notStore.err;
  const ProcessResult gpuFlag = runProcess({render, store, "--frustum-cut", "-o", (dir / "g.png").string()});
  EXPECT_EQ(gpuFlag.exitCode, 2) << gpuFlag.err;
}

// --path: one frame per camera with the working set carried across frames, per-frame figures
// to CSV and JSON, the camera stopping and the picture converging, a camera-list file, and
// bad paths refused with a message.
TEST_F(GpuRenderTool, CameraPathStreamsAndReportsEveryFrame) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const std::string render = toolPath("octoray-render").string();
  const std::string csv = (dir / "path.csv").string(), last = (dir / "last.json").string();
  const ProcessResult r = runProcess({render, store, "-o", (dir / "path.png").string(), "--preset",
                                      "bone", "--size", "64x64", "--lod-pixels", "0", "--path",
                                      "orbit:6,degrees:60,zoom-from:1,zoom-to:2,still:12", "--stats",
                                      csv, "--upload-mib-per-frame", "1", "--save-camera", last, "--json"});
  ASSERT_EQ(r.exitCode, 0) << r.err;
  const auto report = nlohmann::json::parse(r.out);
  EXPECT_EQ(report["framesRendered"], 18);
  EXPECT_EQ(report["cameraStopsAtFrame"], 5);
  EXPECT_EQ(report["visibility"], "rays");
  ASSERT_FALSE(report["convergedAfterStopMs"].is_null()) << "12 still frames converge this small store";
  EXPECT_GT(report["bytesRead"].get<int64_t>(), 0);
  EXPECT_GT(report["p95Ms"].get<double>(), 0);
  EXPECT_GE(report["p95Ms"].get<double>(), report["medianMs"].get<double>());
  EXPECT_GT(report["peakRssMib"].get<double>(), 0);
  ASSERT_EQ(report["frames"].size(), 18u);
  int64_t loaded = 0;
  for (const auto& f : report["frames"]) {
    loaded += f["bricksLoaded"].get<int64_t>();
    EXPECT_LE(f["cacheBytes"].get<int64_t>(), f["cacheBudgetBytes"].get<int64_t>());
    EXPECT_LE(f["poolSlotsUsed"].get<int64_t>(), f["poolSlots"].get<int64_t>());
    EXPECT_EQ(f["feedbackDelayFrames"], 1);
  }
  EXPECT_GT(loaded, 0) << "bricks arrive through the loader";
  // The CSV: a header and one row per frame, the same figures.
  std::ifstream in(csv);
  std::string header, line;
  ASSERT_TRUE(std::getline(in, header));
  EXPECT_NE(header.find("selectMs"), std::string::npos);
  EXPECT_NE(header.find("bytesRead"), std::string::npos);
  int rows = 0;
  while (std::getline(in, line)) ++rows;
  EXPECT_EQ(rows, 18);
  // The converged last frame equals a still render of the saved camera.
  const ProcessResult still = runProcess({render, store, "-o", (dir / "still.png").string(), "--preset",
                                          "bone", "--lod-pixels", "0", "--camera", last,
                                          "--visibility", "none"});
  ASSERT_EQ(still.exitCode, 0) << still.err;
  const ImageMetrics m = compare(readImage((dir / "still.png").string()), readImage((dir / "path.png").string()));
  EXPECT_GE(m.psnrDb, 40.0);
  // A camera list.
  {
    std::ofstream list(dir / "cameras.json");
    list << "{\"cameras\": [" << std::ifstream(last).rdbuf() << ", " << std::ifstream(last).rdbuf() << "]}";
  }
  const ProcessResult fromFile = runProcess({render, store, "-o", (dir / "list.png").string(), "--preset",
                                             "bone", "--path", (dir / "cameras.json").string(), "--json"});
  ASSERT_EQ(fromFile.exitCode, 0) << fromFile.err;
  EXPECT_EQ(nlohmann::json::parse(fromFile.out)["framesRendered"], 2);
  // Bad paths: a message naming the problem, no picture.
  for (const std::string& bad : {std::string("orbit:0"), std::string("orbit:5,spin:3"),
                                 (dir / "missing.json").string()}) {
    const std::string out = (dir / "bad.png").string();
    const ProcessResult b = runProcess({render, store, "-o", out, "--preset", "bone", "--path", bad});
    EXPECT_EQ(b.exitCode, 1) << bad;
    EXPECT_NE(b.err.find("path"), std::string::npos) << b.err;
    EXPECT_FALSE(std::filesystem::exists(out)) << bad;
  }
}

// --repack-when-settled (the viewer's setting): once the camera stops and the working set
// settles, one frame copies the cut's bricks (and the root) to the pool's first slots and
// reports what it copied and the time; later frames find them in place and copy nothing.
// Without the flag no frame repacks.
TEST_F(GpuRenderTool, RepackWhenSettledReportsTheCopyOnce) {
  OCTORAY_REQUIRE_CONTEXT(context_);
  const std::string render = toolPath("octoray-render").string();
  const auto run = [&](bool repack) {
    std::vector<std::string> args{render, store, "-o", (dir / "repack.png").string(), "--preset", "bone",
                                  "--size", "64x64", "--lod-pixels", "0", "--path",
                                  "orbit:6,degrees:90,zoom-from:1,zoom-to:2,still:16", "--json"};
    if (repack) args.push_back("--repack-when-settled");
    const ProcessResult r = runProcess(args);
    EXPECT_EQ(r.exitCode, 0) << r.err;
    return nlohmann::json::parse(r.out);
  };
  const auto plain = run(false);
  EXPECT_FALSE(plain["repackWhenSettled"].get<bool>());
  EXPECT_EQ(plain["bricksRepacked"], 0);
  EXPECT_TRUE(plain["lastRepackAtFrame"].is_null());
  for (const auto& f : plain["frames"]) EXPECT_EQ(f["repacked"], 0);

  const auto repacked = run(true);
  ASSERT_TRUE(repacked["converged"].get<bool>()) << "16 still frames converge this small store";
  EXPECT_TRUE(repacked["repackWhenSettled"].get<bool>());
  const int64_t bricks = repacked["finalWorkingSetBricks"].get<int64_t>();
  ASSERT_GT(bricks, 1);
  int repackFrames = 0;
  for (const auto& f : repacked["frames"]) {
    const int64_t n = f["repacked"].get<int64_t>();
    if (n == 0) {
      EXPECT_EQ(f["repackMs"].get<double>(), 0.0);
      continue;
    }
    ++repackFrames;
    // The cut's bricks and the root, which is resident for good even where no seen leaf
    // draws from it; counted in the frame's uploads too.
    EXPECT_GE(n, bricks);
    EXPECT_LE(n, bricks + 1);
    EXPECT_GE(f["bricksUploaded"].get<int64_t>(), n);
    EXPECT_GT(f["repackMs"].get<double>(), 0.0);
    EXPECT_LE(f["repackMs"].get<double>(), f["uploadMs"].get<double>());
    EXPECT_GE(f["frame"].get<int64_t>(), repacked["cameraStopsAtFrame"].get<int64_t>())
        << "a moving camera never settles";
  }
  EXPECT_EQ(repackFrames, 1) << "a repacked cut stays in place while the view holds still";
  EXPECT_EQ(repacked["lastRepackAtFrame"], repacked["convergedAtFrame"]);
  EXPECT_GT(repacked["repackMs"].get<double>(), 0.0);
}

}  // namespace
}  // namespace octoray::gpu
