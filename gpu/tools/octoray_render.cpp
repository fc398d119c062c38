// octoray-render: renders a volume (an octree store or anything openVolume reads) to PNG and
// optionally OpenEXR (float RGBA + depth). Today the CPU reference renderer is the only
// renderer, so --reference is accepted and implied; the GPU raycaster joins later (issue 5),
// when --reference will select the oracle instead of the default GPU path.
//   octoray-render PATH -o OUT.png [--exr OUT.exr] --mode dvr|iso|mip
//     --preset NAME | --tf FILE [--tf-name NAME]  [--iso HU]  --size WxH
//     --azimuth DEG --elevation DEG --zoom F | --camera FILE   [--json]

#include <fmt/format.h>
#include <tbb/global_control.h>
#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <array>
#include <chrono>
#include <cmath>
#include <fstream>
#include <iostream>
#include <optional>
#include <string>

#include "cli_support.h"
#include "octoray/dicom/error.h"
#include "octoray/dicom/formats.h"
#include "octoray/gpu/camera.h"
#include "octoray/gpu/image_io.h"
#include "octoray/gpu/reference/reference_renderer.h"
#include "octoray/transfer/transfer_function_io.h"
#include "octoray/volume/store_format.h"
#include "octoray/volume/store_reader.h"

namespace {

using namespace octoray;
using gpu::reference::RenderMode;
using gpu::reference::RenderOptions;

struct Arguments {
  std::string path, output, exr, mode = "dvr", preset, tfPath, tfName, size = "512x512";
  std::string camera, saveCamera, projection = "perspective", shading = "auto";
  std::optional<double> iso;
  double azimuth = 0, elevation = 0, zoom = 1, fovY = 30, stepMm = 0, earlyTermination = 0.99;
  bool reference = false, json = false, srgb = false, noGradientOpacity = false;
  int threads = 0;
};

double millisecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
      .count();
}

// "512x384": two positive integers.
std::array<int, 2> parseSize(const std::string& text) {
  int w = 0, h = 0;
  char x = 0, extra = 0;
  if (std::sscanf(text.c_str(), "%d%c%d%c", &w, &x, &h, &extra) != 3 || x != 'x' || w < 1 ||
      h < 1 || w > 16384 || h > 16384) {
    throw Error("", fmt::format("--size \"{}\": expected WxH with sides in [1, 16384]", text));
  }
  return {w, h};
}

bool isStore(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  char magic[sizeof(volume::kStoreMagic)] = {};
  in.read(magic, sizeof(magic));
  return in.gcount() == sizeof(magic) &&
         std::equal(magic, magic + sizeof(magic), volume::kStoreMagic);
}

gpu::reference::ReferenceVolume loadVolume(const std::string& path) {
  if (isStore(path)) {
    const volume::StoreReader store(path);
    return gpu::reference::ReferenceVolume::fromStore(store);
  }
  const auto source = openVolume(path);
  return gpu::reference::ReferenceVolume::fromSource(*source);
}

transfer::TransferFunction loadTransferFunction(const Arguments& a) {
  if (!a.tfPath.empty()) {
    return transfer::selectTransferFunction(transfer::loadTransferFunctions(a.tfPath), a.tfName,
                                            a.tfPath);
  }
  return transfer::findPreset(a.preset);
}

RenderOptions renderOptions(const Arguments& a) {
  RenderOptions o;
  o.mode = a.mode == "iso" ? RenderMode::Iso : a.mode == "mip" ? RenderMode::Mip : RenderMode::Dvr;
  if (o.mode == RenderMode::Iso) {
    if (!a.iso) throw Error("", "--mode iso needs --iso HU");
    o.isoValue = *a.iso;
  }
  o.stepMm = a.stepMm;
  o.earlyTermination = a.earlyTermination;
  o.shading = a.shading == "on"    ? RenderOptions::Shading::On
              : a.shading == "off" ? RenderOptions::Shading::Off
                                   : RenderOptions::Shading::FromTransferFunction;
  o.gradientOpacity = !a.noGradientOpacity;
  return o;
}

int run(const Arguments& a) {
  std::optional<tbb::global_control> threadLimit;
  if (a.threads > 0) {
    threadLimit.emplace(tbb::global_control::max_allowed_parallelism,
                        static_cast<std::size_t>(a.threads));
  }
  const transfer::TransferFunction tf = loadTransferFunction(a);
  const RenderOptions options = renderOptions(a);

  auto start = std::chrono::steady_clock::now();
  const auto volume = loadVolume(a.path);
  const double loadMs = millisecondsSince(start);

  gpu::Camera camera;
  if (!a.camera.empty()) {
    camera = gpu::loadCamera(a.camera);
  } else {
    gpu::OrbitParameters orbit;
    orbit.azimuthDegrees = a.azimuth;
    orbit.elevationDegrees = a.elevation;
    orbit.zoom = a.zoom;
    orbit.fovYDegrees = a.fovY;
    orbit.projection = a.projection == "orthographic" ? gpu::Projection::Orthographic
                                                      : gpu::Projection::Perspective;
    camera = gpu::orbitCamera({volume.dims(), volume.patientFromIndex()}, orbit);
  }
  if (a.camera.empty() || !a.size.empty()) {
    const auto size = parseSize(a.size);
    camera.width = size[0];
    camera.height = size[1];
  }
  if (!a.saveCamera.empty()) gpu::saveCamera(camera, a.saveCamera);

  start = std::chrono::steady_clock::now();
  const gpu::reference::ReferenceRenderer renderer(volume);
  const auto result = renderer.render(camera, tf, options);
  const double renderMs = millisecondsSince(start);

  gpu::writePng(result.image, a.output, a.srgb ? gpu::PngEncoding::Srgb : gpu::PngEncoding::Clamp);
  if (!a.exr.empty()) gpu::writeExr(result.image, a.exr);

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
        {"camera", gpu::cameraToJson(camera)},
        {"outputs", a.exr.empty() ? nlohmann::json{a.output} : nlohmann::json{a.output, a.exr}}};
    std::cout << report.dump(2) << '\n';
  } else {
    fmt::print("{}: {}x{} {} in {:.0f} ms ({} samples), volume loaded in {:.0f} ms\n", a.output,
               camera.width, camera.height, a.mode, renderMs, result.stats.samples, loadMs);
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "Renders a CT volume with the CPU reference renderer (the GPU renderer joins later)."};
  Arguments a;
  app.add_option("path", a.path, "octree store, DICOM folder or volume file")->required();
  app.add_option("-o,--output", a.output, "PNG to write (colour over black, 8-bit)")->required();
  app.add_option("--exr", a.exr, "also write float RGBA + Z (depth, mm) as OpenEXR");
  app.add_option("--mode", a.mode, "dvr, iso or mip")
      ->check(CLI::IsMember({"dvr", "iso", "mip"}))
      ->capture_default_str();
  auto* preset = app.add_option("--preset", a.preset, "shipped preset by name (bone, lung, ...)");
  auto* tfFile =
      app.add_option("--tf", a.tfPath, "transfer function file (octoray JSON, Slicer, ParaView)");
  preset->excludes(tfFile);
  app.add_option("--tf-name", a.tfName, "which function of a --tf file holding several")
      ->needs(tfFile);
  app.add_option("--iso", a.iso, "isovalue (HU) for --mode iso");
  auto* size = app.add_option("--size", a.size, "image WxH")->capture_default_str();
  app.add_option("--azimuth", a.azimuth,
                 "degrees; 0 = from anterior, 90 = from the patient's left");
  app.add_option("--elevation", a.elevation, "degrees; positive = from superior");
  app.add_option("--zoom", a.zoom, "1 frames the volume's bounding sphere")->capture_default_str();
  app.add_option("--projection", a.projection, "perspective or orthographic")
      ->check(CLI::IsMember({"perspective", "orthographic"}))
      ->capture_default_str();
  app.add_option("--fov", a.fovY, "vertical field of view in degrees (perspective)")
      ->capture_default_str();
  app.add_option("--camera", a.camera, "camera JSON (eye, target, up, ...) instead of the orbit");
  app.add_option("--save-camera", a.saveCamera, "write the camera used as JSON");
  app.add_option("--step", a.stepMm, "step in mm (default 0.25 x the smallest spacing)");
  app.add_option("--early-termination", a.earlyTermination,
                 "opacity at which a ray stops; 1 = never")
      ->capture_default_str();
  app.add_option("--shading", a.shading, "auto (the preset's material), on or off")
      ->check(CLI::IsMember({"auto", "on", "off"}))
      ->capture_default_str();
  app.add_flag("--no-gradient-opacity", a.noGradientOpacity, "ignore the TF's gradient opacity");
  app.add_flag("--srgb", a.srgb,
               "sRGB-encode the PNG (default: clamp, as VTK and Slicer show TF colours)");
  app.add_flag("--reference", a.reference, "use the CPU reference renderer (today the only one)");
  app.add_option("--threads", a.threads, "worker threads (0: all cores)")
      ->check(CLI::NonNegativeNumber);
  app.add_flag("--json", a.json, "print timing (ms), image size, samples and the camera as JSON");
  try {
    app.parse(argc, argv);
    if (a.preset.empty() && a.tfPath.empty()) {
      throw CLI::ValidationError("--preset or --tf", "one of them is required");
    }
    if (!a.camera.empty() && size->count() == 0) a.size.clear();
  } catch (const CLI::Success& e) {
    return app.exit(e);
  } catch (const CLI::Error& e) {
    fmt::print(stderr, "octoray-render: {}\nRun with --help for more information.\n", e.what());
    return 2;
  }
  return cli::runTool("octoray-render", [&] { return run(a); });
}
