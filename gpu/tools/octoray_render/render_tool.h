#pragma once
// octoray-render's parts, shared by its files: the parsed command line and the helpers the
// GPU timing loop, the camera path and the CPU reference all use.
//   octoray_render.cpp   the command line, defaults, the GPU timing loop (runGpu)
//   reference.cpp        --reference: the CPU reference, converged or not, whole or in view
//   path.cpp             --path: a camera path with the working set streamed; --cut-reference

#include <nlohmann/json.hpp>

#include <array>
#include <chrono>
#include <cstddef>
#include <optional>
#include <string>
#include <vector>

#include "octoray/core/elapsed.h"
#include "octoray/gpu/camera.h"
#include "octoray/gpu/gl_context.h"
#include "octoray/gpu/gpu_renderer.h"
#include "octoray/gpu/reference/reference_renderer.h"
#include "octoray/transfer/transfer_function.h"
#include "octoray/volume/store_reader.h"

namespace octoray::render_tool {

using gpu::reference::RenderMode;
using gpu::reference::RenderOptions;

struct Arguments {
  std::string path, output, exr, mode = "dvr", preset, tfPath, tfName, size = "512x512";
  std::string camera, saveCamera, projection = "perspective", shading = "auto";
  std::optional<double> iso;
  double azimuth = 0, elevation = 0, zoom = 1, fovY = 30, stepMm = 0, earlyTermination = 0.99;
  bool reference = false, gpu = false, json = false, srgb = false, noGradientOpacity = false;
  bool gradientPool = false, noCellSkipping = false, jitter = false, converge = false;
  bool repackWhenSettled = false;  // GPU: RendererConfig::repackWhenSettled, as the viewer runs
  std::string preintegration = "off", imageAdaptive = "off";
  int imageAdaptiveLevels = 2;
  double convergeMaxChange = 1.0 / 1024, convergePsnr = 70;
  int convergeHalvings = 6;
  std::string mip = "exact";
  double lodPixels = 1.0, orbitDegrees = 0;
  int frames = 1, threads = 0;
  std::size_t poolMib = 1024, cacheMib = 2048, uploadMibPerFrame = 64;
  std::string visibility = "rays", cameraPath, statsOut;
  int visibilityThreshold = 4;
  std::string boundary, silhouette, clip;
  std::string cutReference;  // PNG: the CPU reference over the GPU picture's LOD cut
  double cutTruthStepMm = 0;  // > 0: that reference as the cut's truth (this step, no early termination)
  bool frustumCut = false;   // reference: only the leaf bricks in view
  // Set by resolveDefaults() when neither --preset nor --tf was given.
  std::optional<transfer::TransferFunction> defaultTf;
  // What the defaults chose, said on stderr once the render succeeded (a failure says only
  // what failed).
  std::vector<std::string> notes;
};

// "512x384": two positive integers; throws octoray::Error otherwise.
std::array<int, 2> parseSize(const std::string& text);
// The PNG and the EXR together: both or neither (gpu::writeImageOutputs).
void writeOutputs(const gpu::Image& image, const Arguments& a);
transfer::TransferFunction loadTransferFunction(const Arguments& a);
gpu::reference::RenderOptions renderOptions(const Arguments& a);
// The orbit the options describe (its image size left at the default).
gpu::OrbitParameters orbitParameters(const Arguments& a);
gpu::Camera makeCamera(const Arguments& a, const gpu::VolumeDomain& domain);
// Resident and peak resident memory of this process (MiB), from /proc/self/status.
std::pair<double, double> residentMib();
// One frame's figures (the JSON of --json's frames and --stats).
nlohmann::json frameRecord(const gpu::Frame& frame, double ms);
// --stats: the per-frame records as CSV (one header row) or JSON.
void writeStats(const nlohmann::json& frames, const std::string& path);
double percentile(std::vector<double> values, double p);

// reference.cpp
int runReference(const Arguments& a);

// path.cpp
nlohmann::json cutReference(const Arguments& a, const volume::StoreReader& store,
                            const gpu::GpuRenderer& renderer, const gpu::Camera& camera,
                            const transfer::TransferFunction& tf, const gpu::Image& gpuImage);
int runPath(const Arguments& a, const volume::StoreReader& store, gpu::GpuRenderer& renderer,
            const transfer::TransferFunction& tf, gpu::RaycastOptions options,
            const gpu::VolumeDomain& domain, const gpu::GlContext& context, double setupMs);

}  // namespace octoray::render_tool
