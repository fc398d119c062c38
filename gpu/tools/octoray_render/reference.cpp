// octoray-render --reference: the CPU reference renderer (the double-precision oracle) over the
// whole volume, or over the leaf bricks in view of a store (--frustum-cut), once or driven to
// convergence (--converge: the truth of docs/accuracy.md).

#include <fmt/format.h>
#include <unistd.h>

#include <iostream>

#include "octoray/core/error.h"
#include "octoray/gpu/working_set.h"
#include "octoray/gpu/reference/reference_volume.h"
#include "octoray/volume/store_reader.h"
#include "render_tool.h"

namespace octoray::render_tool {
namespace {

// --frustum-cut: the store's leaf-level nodes in the camera's view (gpu::nodesInFrustum) are
// the only bricks read, so a zoomed view of a store far larger than memory gets its
// full-resolution truth. Sets the camera; refuses a cut that would not fit in memory.
gpu::reference::ReferenceVolume loadFrustumCut(const Arguments& a, gpu::Camera& camera,
                                               nlohmann::json& report) {
  if (!volume::isStoreFile(a.path)) throw Error(a.path, "--frustum-cut needs an octree store");
  const volume::StoreReader store(a.path);
  const volume::OctreeLayout& layout = store.layout();
  const int leafLevel = layout.leafLevel();
  camera = makeCamera(a, {layout.levelDims(leafLevel), store.patientFromIndex()});
  const std::vector<volume::NodeKey> nodes = gpu::nodesInFrustum(store, camera, leafLevel);
  const volume::Index3& n = layout.levelBricks(leafLevel);
  const double gib = static_cast<double>(nodes.size()) * static_cast<double>(layout.storedSamples()) *
                     sizeof(float) / double(1 << 30);
  const double memoryGib = static_cast<double>(sysconf(_SC_PHYS_PAGES)) *
                           static_cast<double>(sysconf(_SC_PAGE_SIZE)) / double(1 << 30);
  if (gib > 0.75 * memoryGib) {
    throw Error(a.path, fmt::format("the {} leaf bricks in view need {:.1f} GiB as float samples, "
                                    "more than 3/4 of this machine's {:.1f} GiB: zoom in (--zoom)",
                                    nodes.size(), gib, memoryGib));
  }
  std::vector<gpu::reference::CutLeafRef> leaves;
  for (const volume::NodeKey& key : nodes) leaves.push_back({key, 0});
  report = {{"leaves", nodes.size()}, {"leafNodes", n[0] * n[1] * n[2]}, {"gib", gib}};
  return gpu::reference::ReferenceVolume::fromCut(store, leaves);
}
}  // namespace

int runReference(const Arguments& a) {
  const transfer::TransferFunction tf = loadTransferFunction(a);
  const RenderOptions options = renderOptions(a);

  auto start = std::chrono::steady_clock::now();
  gpu::Camera camera;
  nlohmann::json frustumCut;
  const auto volume = [&] {
    if (a.frustumCut) return loadFrustumCut(a, camera, frustumCut);
    auto full = gpu::reference::ReferenceVolume::fromPath(a.path);
    camera = makeCamera(a, {full.dims(), full.patientFromIndex()});
    return full;
  }();
  const double loadMs = millisecondsSince(start);

  if (!a.saveCamera.empty()) gpu::saveCamera(camera, a.saveCamera);

  start = std::chrono::steady_clock::now();
  const gpu::reference::ReferenceRenderer renderer(volume);
  gpu::reference::ReferenceRenderer::ConvergedResult converged;
  if (a.converge) {
    gpu::reference::ReferenceRenderer::ConvergenceRule rule;
    rule.maxChange = a.convergeMaxChange;
    rule.minPsnrDb = a.convergePsnr;
    rule.maxHalvings = a.convergeHalvings;
    converged = renderer.renderConverged(camera, tf, options, rule);
  } else {
    converged.result = renderer.render(camera, tf, options);
  }
  const auto& result = converged.result;
  const double renderMs = millisecondsSince(start);

  writeOutputs(result.image, a);

  if (a.json) {
    const nlohmann::json report = {
        {"renderer", "reference"},
        {"mode", a.mode},
        {"transferFunction", tf.name},
        {"dims", volume.dims()},
        {"width", camera.width},
        {"height", camera.height},
        {"timingMs", {{"load", loadMs}, {"render", renderMs}}},
        {"samples", result.stats.samples},
        {"raysHit", result.stats.raysHit},
        {"stepMm", result.stats.stepMm},
        {"preintegration", options.preintegration},
        {"jitter", options.jitter},
        {"camera", gpu::cameraToJson(camera)},
        {"outputs", a.exr.empty() ? nlohmann::json{a.output} : nlohmann::json{a.output, a.exr}}};
    nlohmann::json report2 = report;
    if (a.frustumCut) report2["frustumCut"] = frustumCut;
    if (a.converge) {
      report2["convergence"] = {{"converged", converged.converged},
                                {"stepsMm", converged.stepsMm},
                                {"changeMax", converged.changeMax},
                                {"changePsnrDb", converged.changePsnrDb},
                                {"estimatedMaxError", converged.estimatedMaxError}};
    }
    std::cout << report2.dump(2) << '\n';
  } else if (a.converge) {
    fmt::print("{}: {}x{} {} truth in {:.0f} ms, {} at step {:g} mm (last change {:.2g}, {:.1f} dB)\n",
               a.output, camera.width, camera.height, a.mode, renderMs,
               converged.converged ? "converged" : "NOT converged", result.stats.stepMm,
               converged.changeMax.empty() ? 0.0 : converged.changeMax.back(),
               converged.changePsnrDb.empty() ? 0.0 : converged.changePsnrDb.back());
  } else {
    fmt::print("{}: {}x{} {} in {:.0f} ms ({} samples), volume loaded in {:.0f} ms\n", a.output,
               camera.width, camera.height, a.mode, renderMs, result.stats.samples, loadMs);
  }
  // The picture is written either way (it is the finest step tried); the status says
  // whether it is a truth.
  return a.converge && !converged.converged ? 3 : 0;
}

}  // namespace octoray::render_tool
