// octoray-render --path: one frame per camera of a path, the working set carried across frames
// and bricks streamed in the background (the interaction benchmark), and --cut-reference: the
// CPU reference over the LOD cut a GPU picture was drawn from.

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <iostream>

#include "octoray/gpu/camera_path.h"
#include "octoray/gpu/image_io.h"
#include "octoray/gpu/image_metrics.h"
#include "octoray/gpu/reference/reference_volume.h"
#include "render_tool.h"

namespace octoray::render_tool {

// --cut-reference: the CPU reference over the LOD cut the GPU picture was drawn from (the same
// camera, TF, options and step; ReferenceVolume::fromCut reads only the cut's bricks), written
// as a PNG and compared with the GPU picture. What checks a converged picture of a volume too
// large for the full-resolution reference. With --cut-truth the reference is the cut's own
// truth instead (a fine step, no early termination): the GPU picture's distance from it is what
// its classification and step lose on that cut, apart from what the coarse levels lose.
nlohmann::json cutReference(const Arguments& a, const volume::StoreReader& store,
                            const gpu::GpuRenderer& renderer, const gpu::Camera& camera,
                            const transfer::TransferFunction& tf, const gpu::Image& gpuImage) {
  const auto start = std::chrono::steady_clock::now();
  std::vector<gpu::reference::CutLeafRef> leaves;
  for (const gpu::CutLeaf& leaf : renderer.workingSet().cut()) leaves.push_back({leaf.key, leaf.dataLevelsUp});
  const auto volume = gpu::reference::ReferenceVolume::fromCut(store, leaves);
  const double loadMs = millisecondsSince(start);
  RenderOptions options = renderOptions(a);
  options.stepMm = a.stepMm > 0 ? a.stepMm : renderer.defaultStepMm();
  if (a.cutTruthStepMm > 0) {
    options.stepMm = a.cutTruthStepMm;
    options.earlyTermination = 1.0;
    options.preintegration = a.mode == "dvr";  // as the leaf truth (bench/accuracy.py): exact per step
    options.jitter = false;
  }
  const auto result = gpu::reference::ReferenceRenderer(volume).render(camera, tf, options);
  const double renderMs = millisecondsSince(start) - loadMs;
  // With --exr the float picture too, beside the PNG (NAME.exr), for comparisons past 8 bits.
  const std::filesystem::path cutExr =
      a.exr.empty() ? std::filesystem::path() : std::filesystem::path(a.cutReference).replace_extension(".exr");
  gpu::writeImageOutputs(result.image,
                         {a.cutReference, a.srgb ? gpu::PngEncoding::Srgb : gpu::PngEncoding::Clamp, cutExr});
  const gpu::ImageMetrics m = gpu::compare(result.image, gpuImage);
  int64_t coarsest = 0;
  for (const gpu::CutLeaf& leaf : renderer.workingSet().cut()) {
    coarsest = std::max<int64_t>(coarsest, store.layout().leafLevel() - (leaf.key.level - leaf.dataLevelsUp));
  }
  const nlohmann::json report = {
      {"output", a.cutReference},
      {"exr", cutExr.string()},
      {"leaves", leaves.size()},
      {"coarsestLevelsAboveLeaf", coarsest},
      {"stepMm", options.stepMm},
      {"earlyTermination", options.earlyTermination},
      {"psnrDb", std::isfinite(m.psnrDb) ? nlohmann::json(m.psnrDb) : nlohmann::json("inf")},
      {"ssim", m.ssim},
      {"maxAbsError", m.maxAbsError},
      {"timingMs", {{"load", loadMs}, {"render", renderMs}}}};
  if (!a.json) {
    fmt::print("{}: CPU reference over the same cut ({} leaves, up to {} levels above the leaf "
               "level), {:.1f} dB, SSIM {:.4f}, in {:.0f} ms\n",
               a.cutReference, leaves.size(), coarsest, m.psnrDb, m.ssim, loadMs + renderMs);
  }
  return report;
}

// --path: one renderFrame() per camera, the working set carried across frames and bricks
// streamed in the background; the per-frame records to --stats, the last frame to -o.
int runPath(const Arguments& a, const volume::StoreReader& store, gpu::GpuRenderer& renderer,
            const transfer::TransferFunction& tf,
            gpu::RaycastOptions options, const gpu::VolumeDomain& domain,
            const gpu::GlContext& context, double setupMs) {
  gpu::OrbitParameters start = orbitParameters(a);
  const auto size = parseSize(a.size.empty() ? "512x512" : a.size);
  start.width = size[0];
  start.height = size[1];
  std::vector<gpu::Camera> cameras = gpu::cameraPath(a.cameraPath, domain, start);
  if (!a.size.empty() && a.cameraPath.rfind("orbit:", 0) != 0) {
    for (gpu::Camera& c : cameras) {
      c.width = size[0];
      c.height = size[1];
    }
  }
  if (!a.saveCamera.empty()) gpu::saveCamera(cameras.back(), a.saveCamera);
  // The camera stops at the first frame from which every camera is the same.
  std::size_t stop = cameras.size() - 1;
  while (stop > 0 && gpu::cameraToJson(cameras[stop - 1]) == gpu::cameraToJson(cameras.back())) --stop;

  options.stats = false;
  nlohmann::json frames = nlohmann::json::array();
  std::vector<double> framesMs;
  std::vector<std::string> errors;
  gpu::Frame last;
  std::optional<double> convergedMs;
  std::optional<std::size_t> convergedFrame;
  double sinceStopMs = 0;
  uint64_t bytesRead = 0, maxCacheBytes = 0;
  int64_t repacked = 0;
  double repackMs = 0;
  std::optional<std::size_t> repackedAtFrame;
  for (std::size_t f = 0; f < cameras.size(); ++f) {
    const auto t0 = std::chrono::steady_clock::now();
    last = renderer.renderFrame(cameras[f], tf, options);
    const double ms = millisecondsSince(t0);
    framesMs.push_back(ms);
    frames.push_back(frameRecord(last, ms));
    bytesRead += last.stats.bytesRead;
    if (last.stats.workingSet.repacked > 0) {
      repacked += last.stats.workingSet.repacked;
      repackMs += last.stats.workingSet.repackMs;
      repackedAtFrame = f;
    }
    maxCacheBytes = std::max(maxCacheBytes, last.stats.cacheBytes);
    for (const std::string& e : last.stats.errors) {
      fmt::print(stderr, "octoray-render: {}\n", e);
      errors.push_back(e);
    }
    if (f >= stop) {
      sinceStopMs += ms;
      if (!convergedMs && renderer.workingSet().settled()) {
        convergedMs = sinceStopMs;
        convergedFrame = f;
      }
    }
  }
  writeOutputs(last.image, a);
  if (!a.statsOut.empty()) writeStats(frames, a.statsOut);

  const auto [rss, peak] = residentMib();  // the path's, before the check below
  // The last frame's cut is the one the working set holds until the next update.
  nlohmann::json cutCheck;
  if (!a.cutReference.empty()) cutCheck = cutReference(a, store, renderer, cameras.back(), tf, last.image);
  const double medianMs = percentile(framesMs, 0.5), p95Ms = percentile(framesMs, 0.95);
  if (a.json) {
    const nlohmann::json report = {
        {"renderer", "gpu"},
        {"glRenderer", context.renderer()},
        {"mode", a.mode},
        {"transferFunction", tf.name},
        {"dims", domain.dims},
        {"path", a.cameraPath},
        {"visibility", a.visibility},
        {"visibilityThreshold", a.visibilityThreshold},
        {"uploadMibPerFrame", a.uploadMibPerFrame},
        {"poolMib", a.poolMib},
        {"cacheMib", a.cacheMib},
        {"lodPixels", a.lodPixels},
        {"framesRendered", cameras.size()},
        {"cameraStopsAtFrame", stop},
        {"setupMs", setupMs},
        {"firstImageMs", setupMs + framesMs.front()},
        {"medianMs", medianMs},
        {"p95Ms", p95Ms},
        {"convergedAfterStopMs", convergedMs ? nlohmann::json(*convergedMs) : nlohmann::json(nullptr)},
        {"convergedAtFrame", convergedFrame ? nlohmann::json(*convergedFrame) : nlohmann::json(nullptr)},
        {"bytesRead", bytesRead},
        {"maxCacheBytes", maxCacheBytes},
        {"peakRssMib", peak},
        {"finalWorkingSetBricks", last.stats.workingSetBricks},
        {"repackWhenSettled", a.repackWhenSettled},
        {"bricksRepacked", repacked},
        {"repackMs", repackMs},
        {"lastRepackAtFrame", repackedAtFrame ? nlohmann::json(*repackedAtFrame) : nlohmann::json(nullptr)},
        {"converged", convergedMs.has_value()},
        {"cutReference", cutCheck},
        {"errors", errors},
        {"frames", frames},
        {"outputs", a.exr.empty() ? nlohmann::json{a.output} : nlohmann::json{a.output, a.exr}}};
    std::cout << report.dump(2) << '\n';
  } else {
    fmt::print("{}: {} frames of {} ({}), median {:.0f} ms, p95 {:.0f} ms, first image {:.0f} ms, "
               "converged {} after the camera stopped, {:.1f} MiB read, peak RSS {:.0f} MiB, "
               "{} bricks in the final working set\n",
               a.output, cameras.size(), a.cameraPath, a.visibility, medianMs, p95Ms,
               setupMs + framesMs.front(),
               convergedMs ? fmt::format("{:.0f} ms", *convergedMs) : std::string("not yet"),
               static_cast<double>(bytesRead) / (1 << 20), peak, last.stats.workingSetBricks);
  }
  return errors.empty() ? 0 : 1;
}

}  // namespace octoray::render_tool
