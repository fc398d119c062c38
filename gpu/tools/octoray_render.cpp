// octoray-render: renders a volume (an octree store or anything openVolume reads) to PNG and
// optionally OpenEXR (float RGBA + depth). By default with the GPU raycaster (gpu_renderer.h)
// in a headless GL context over the store's working set; --reference selects the CPU
// reference renderer (the double-precision oracle). Inputs that are not stores are built into
// a temporary store first for the GPU path (border 2, removed afterwards).
//   octoray-render PATH -o OUT.png [--exr OUT.exr] --mode dvr|iso|mip
//     [--preset NAME | --tf FILE [--tf-name NAME]]  [--iso VALUE]  --size WxH
//     (without --preset/--tf: transfer/defaults.h's default for the mode; without --iso:
//     300 HU for CT, Otsu's threshold of the values otherwise)
//     --azimuth DEG --elevation DEG --zoom F | --camera FILE   [--json]
//     [--gpu [--lod-pixels F] [--frames N --orbit DEG] [--pool-mib N] [--gradient-pool]
//      [--cache-mib N] [--upload-mib-per-frame N] [--visibility rays|occlusion|both|none]
//      [--repack-when-settled]
//      [--path orbit:N[,...]|FILE.json [--stats OUT.csv|OUT.json]]
//      [--boundary KC,KS,KE] [--silhouette KC,KS,KE] [--clip I0,J0,K0,I1,J1,K1]
//      [--cut-reference REF.png]]  (the CPU reference over the GPU picture's LOD cut)
//     | --reference [--converge [--converge-max-change D] [--converge-psnr DB]] [--frustum-cut]
//     [--preintegration on|off | --jitter]  (DVR, both renderers)
// --path renders a camera path one frame each, with the working set carried across frames
// and bricks streamed in the background (the interaction benchmark; camera_path.h).

#include <fmt/format.h>
#include <unistd.h>
#include <tbb/global_control.h>
#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <filesystem>
#include <limits>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "cli_checks.h"
#include "cli_support.h"
#include "octoray/core/atomic_file.h"
#include "octoray/core/error.h"
#include "octoray/dicom/formats.h"
#include "octoray/gpu/camera.h"
#include "octoray/gpu/camera_path.h"
#include "octoray/gpu/gl_context.h"
#include "octoray/gpu/gpu_renderer.h"
#include "octoray/gpu/image_io.h"
#include "octoray/gpu/image_metrics.h"
#include "octoray/gpu/reference/reference_renderer.h"
#include "octoray/transfer/defaults.h"
#include "octoray/transfer/transfer_function_io.h"
#include "octoray/volume/store_builder.h"
#include "octoray/volume/store_format.h"
#include "octoray/volume/store_reader.h"
#include "octoray/volume/value_histogram.h"
#include "octoray_render/render_tool.h"

namespace octoray::render_tool {

// "512x384".
std::array<int, 2> parseSize(const std::string& text) {
  return cli::parseImageSize(text, "--size", 1, 1, 16384);
}

// The PNG and the EXR together: both or neither (gpu::writeImageOutputs).
void writeOutputs(const gpu::Image& image, const Arguments& a) {
  gpu::writeImageOutputs(image, {a.output, a.srgb ? gpu::PngEncoding::Srgb : gpu::PngEncoding::Clamp, a.exr});
}

// Whether a volume holds Hounsfield units, and its value range: what choosing a default
// transfer function needs (holdsHounsfieldUnits of volume_source.h: what the source says, or,
// where it says nothing, integer values reaching down to air). A store from its provenance and
// root node; other inputs from their VolumeInfo, their range read in one pass.
struct ValueKind {
  bool hounsfield = false;
  bool guessed = false;  // hounsfield from the values alone
  double lo = std::numeric_limits<double>::quiet_NaN(), hi = lo;
};

ValueKind valueKind(const std::string& path) {
  ValueKind kind;
  if (volume::isStoreFile(path)) {
    const volume::StoreReader store(path);
    kind.hounsfield = volume::storeHoldsHounsfieldUnits(store, &kind.guessed);
    kind.lo = store.node(0).minValue;
    kind.hi = store.node(0).maxValue;
    return kind;
  }
  const auto source = openVolume(path);
  const VolumeInfo& info = source->info();
  kind.lo = std::numeric_limits<double>::infinity();
  kind.hi = -kind.lo;
  const int64_t slab = std::max<int64_t>(1, (int64_t{64} << 20) / 4 / std::max<int64_t>(1, info.sliceSamples()));
  std::vector<float> buffer;
  for (int64_t k = 0; k < info.dims[2]; k += slab) {
    const int64_t n = std::min(slab, info.dims[2] - k);
    buffer.resize(static_cast<std::size_t>(n * info.sliceSamples()));
    source->readSlab(k, n, buffer);
    for (const float v : buffer) {
      if (!std::isfinite(v)) continue;
      kind.lo = std::min(kind.lo, static_cast<double>(v));
      kind.hi = std::max(kind.hi, static_cast<double>(v));
    }
  }
  kind.hounsfield = holdsHounsfieldUnits(info.unit, info.modality, info.integerValues, kind.lo, &kind.guessed);
  return kind;
}

// A store built from a non-store input, for the GPU path and for the histogram of an automatic
// isovalue (otsuIsoValue); removed when done.
class TemporaryStore {
 public:
  explicit TemporaryStore(const std::string& input) {
    std::random_device random;
    path_ = std::filesystem::temp_directory_path() /
            fmt::format("octoray-render-{:08x}.octoray", random());
    auto source = openVolume(input);
    volume::BuildOptions options;
    options.border = 2;  // central differences of +-1 voxel for shading
    volume::buildStore(*source, path_.string(), options);
  }
  ~TemporaryStore() {
    std::error_code ignored;
    std::filesystem::remove(path_, ignored);
  }
  TemporaryStore(const TemporaryStore&) = delete;
  TemporaryStore& operator=(const TemporaryStore&) = delete;
  std::string path() const { return path_.string(); }

 private:
  std::filesystem::path path_;
};

// The isovalue the viewer opens a volume without HU at: Otsu's threshold
// (transfer::automaticIsoValue) of the histogram the viewer reads, volume::storeHistogram of
// its store. An input that is not a store is built into `temporary` first (the store the GPU
// path then renders), so the value is the viewer's here too.
double otsuIsoValue(const std::string& path, std::optional<TemporaryStore>& temporary) {
  if (!volume::isStoreFile(path) && !temporary) temporary.emplace(path);
  const std::string store = temporary ? temporary->path() : path;
  const volume::ValueHistogram h = volume::storeHistogram(volume::StoreReader(store), 256);
  if (!h.problem.empty()) throw Error(path, h.problem);
  return transfer::automaticIsoValue(h.counts, h.lo, h.hi);
}

// Without --preset and --tf: the default of transfer/defaults.h for the mode and the volume.
// For an isosurface without --iso: 300 HU for CT, Otsu's threshold of the values otherwise, as
// the viewer opens it. Notes what it chose in a.notes.
void resolveDefaults(Arguments& a, std::optional<TemporaryStore>& temporary) {
  const bool needTf = a.preset.empty() && a.tfPath.empty();
  const bool needIso = a.mode == "iso" && !a.iso;
  if (!needTf && !needIso) return;
  const ValueKind kind = valueKind(a.path);
  if (needIso && kind.hounsfield) {
    a.iso = transfer::kDefaultCtIsoValueHu;
    a.notes.push_back(fmt::format("no --iso: using {:g} HU (bone)", *a.iso));
  } else if (needIso) {
    if (!(std::isfinite(kind.lo) && std::isfinite(kind.hi))) {
      throw Error(a.path, "--mode iso: the volume has no finite values to choose an isovalue from: give --iso");
    }
    a.iso = otsuIsoValue(a.path, temporary);
    a.notes.push_back(
        fmt::format("no --iso: using {:.9g}, Otsu's threshold of the values {:g}..{:g} "
                    "(not CT)",
                    *a.iso, kind.lo, kind.hi));
  }
  if (needTf) {
    const transfer::DefaultMode mode = a.mode == "iso"   ? transfer::DefaultMode::Iso
                                       : a.mode == "mip" ? transfer::DefaultMode::Mip
                                                         : transfer::DefaultMode::Dvr;
    transfer::DefaultTransferFunction chosen =
        transfer::defaultTransferFunction(mode, kind.hounsfield, kind.lo, kind.hi);
    a.notes.push_back(fmt::format("no --preset or --tf: using {} ({}{})", chosen.description,
                                  kind.guessed
                                      ? fmt::format("values from {:g} look like CT, ", kind.lo)
                                  : kind.hounsfield ? std::string("CT, ")
                                                    : std::string(),
                                  a.mode));
    a.defaultTf = std::move(chosen.tf);
  }
}

transfer::TransferFunction loadTransferFunction(const Arguments& a) {
  if (a.defaultTf) return *a.defaultTf;
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
    if (!a.iso) throw Error("", "--mode iso needs --iso VALUE");
    o.isoValue = *a.iso;
  }
  o.stepMm = a.stepMm;
  o.earlyTermination = a.earlyTermination;
  o.shading = a.shading == "on"    ? RenderOptions::Shading::On
              : a.shading == "off" ? RenderOptions::Shading::Off
                                   : RenderOptions::Shading::FromTransferFunction;
  o.gradientOpacity = !a.noGradientOpacity;
  o.preintegration = a.preintegration == "on";
  o.jitter = a.jitter;
  if (o.preintegration && o.jitter) {
    throw Error("", "--preintegration on and --jitter are alternatives: choose one");
  }
  return o;
}

// The orbit the options describe (its image size left at the default).
gpu::OrbitParameters orbitParameters(const Arguments& a) {
  gpu::OrbitParameters orbit;
  orbit.azimuthDegrees = a.azimuth;
  orbit.elevationDegrees = a.elevation;
  orbit.zoom = a.zoom;
  orbit.fovYDegrees = a.fovY;
  orbit.projection = a.projection == "orthographic" ? gpu::Projection::Orthographic
                                                    : gpu::Projection::Perspective;
  return orbit;
}

gpu::Camera makeCamera(const Arguments& a, const gpu::VolumeDomain& domain) {
  gpu::Camera camera;
  if (!a.camera.empty()) {
    camera = gpu::loadCamera(a.camera);
  } else {
    camera = gpu::orbitCamera(domain, orbitParameters(a));
  }
  if (a.camera.empty() || !a.size.empty()) {
    const auto size = parseSize(a.size);
    camera.width = size[0];
    camera.height = size[1];
  }
  return camera;
}

// Frame `frame` of the timing loop: the camera turned frame * orbitDegrees about the volume's
// centre (the orbit's azimuth, or the camera's up axis for a --camera file).
gpu::Camera frameCamera(const Arguments& a, const gpu::VolumeDomain& domain,
                        const gpu::Camera& first, int frame) {
  const double turn = frame * a.orbitDegrees;
  if (turn == 0.0) return first;
  if (a.camera.empty()) {
    Arguments turned = a;
    turned.azimuth = a.azimuth + turn;
    gpu::Camera camera = makeCamera(turned, domain);
    camera.width = first.width;
    camera.height = first.height;
    return camera;
  }
  return gpu::turnAboutCentre(first, domain.centrePatient(), turn);
}

gpu::Enhancement parseEnhancement(const std::string& text, const char* option) {
  gpu::Enhancement e;
  if (text.empty()) return e;
  double kc = 0, ks = 0, ke = 0;
  char extra = 0;
  if (std::sscanf(text.c_str(), "%lf,%lf,%lf%c", &kc, &ks, &ke, &extra) != 3 ||
      !std::isfinite(kc) || !std::isfinite(ks) || !std::isfinite(ke) || ke < 0) {
    throw Error("", fmt::format("{} \"{}\": expected KC,KS,KE (finite, KE >= 0)", option, text));
  }
  e.enabled = true;
  e.kC = kc;
  e.kS = ks;
  e.kE = ke;
  return e;
}

// Resident and peak resident memory of this process (MiB), from /proc/self/status.
std::pair<double, double> residentMib() {
  std::ifstream in("/proc/self/status");
  std::string line;
  double rss = 0, peak = 0;
  while (std::getline(in, line)) {
    if (line.rfind("VmRSS:", 0) == 0) rss = std::atof(line.c_str() + 6) / 1024.0;
    if (line.rfind("VmHWM:", 0) == 0) peak = std::atof(line.c_str() + 6) / 1024.0;
  }
  return {rss, peak};
}

// One frame's figures (the JSON of --json's frames and --stats).
nlohmann::json frameRecord(const gpu::Frame& frame, double ms) {
  const gpu::FrameStats& s = frame.stats;
  const gpu::WorkingSetStats& w = s.workingSet;
  const auto [rss, peak] = residentMib();
  return {{"frame", s.frameIndex},
          {"ms", ms},
          {"selectMs", s.selectMs},
          {"uploadMs", s.uploadMs},
          {"drawMs", s.drawMs},
          {"raysCast", s.raysCast},
          {"feedbackMs", s.feedbackMs},
          {"workingSetBricks", s.workingSetBricks},
          {"visibleLeaves", w.visibleLeaves},
          {"hiddenLeaves", w.hiddenLeaves},
          {"unknownLeaves", w.unknownLeaves},
          {"emptyNodes", s.emptyNodes},
          {"split", w.split},
          {"merged", w.merged},
          {"wantRefine", w.wantRefine},
          {"waitingForData", w.waitingForData},
          {"stoppedByPool", w.stoppedByPool},
          {"stoppedByBudget", w.stoppedByBudget},
          {"requestsIssued", w.requestsIssued},
          {"requestsQueued", w.requestsQueued},
          {"requestsCancelled", w.requestsCancelled},
          {"bricksLoaded", s.loaderLoaded},
          {"bytesRead", s.bytesRead},
          {"bricksUploaded", s.bricksUploaded},
          {"bytesUploaded", w.uploadBytes},
          {"repacked", w.repacked},
          {"repackMs", w.repackMs},
          {"poolSlots", s.poolSlots},
          {"poolSlotsUsed", s.poolSlotsUsed},
          {"poolBytes", s.poolBytes},
          {"poolBytesUsed", s.poolBytesUsed},
          {"poolEvictions", s.poolEvictions},
          {"cacheBytes", s.cacheBytes},
          {"cacheBudgetBytes", s.cacheBudgetBytes},
          {"cacheEvictions", s.cacheEvictions},
          {"loaderQueued", s.loaderQueued},
          {"loaderLoading", s.loaderLoading},
          {"feedbackDelayFrames", s.feedbackDelayFrames},
          {"queriesIssued", s.queriesIssued},
          {"queryTiles", s.queryTiles},
          {"proxyLeaves", w.proxyLeaves},
          {"cutLeaves", w.leaves},
          {"rssMib", rss},
          {"peakRssMib", peak},
          {"errors", s.errors}};
}

// --stats: the per-frame records as CSV (one header row) or JSON.
void writeStats(const nlohmann::json& frames, const std::string& path) {
  std::ofstream out(path);
  if (!out) throw Error(path, "cannot write the statistics file");
  if (path.size() >= 4 && path.compare(path.size() - 4, 4, ".csv") == 0) {
    std::vector<std::string> keys;
    for (const auto& [key, value] : frames.front().items()) {
      if (key != "errors") keys.push_back(key);
    }
    for (std::size_t i = 0; i < keys.size(); ++i) out << (i ? "," : "") << keys[i];
    out << '\n';
    for (const nlohmann::json& f : frames) {
      for (std::size_t i = 0; i < keys.size(); ++i) out << (i ? "," : "") << f[keys[i]].dump();
      out << '\n';
    }
  } else {
    out << frames.dump(1) << '\n';
  }
  if (!out) throw Error(path, "writing the statistics failed");
}

double percentile(std::vector<double> values, double p) {
  if (values.empty()) return 0;
  std::sort(values.begin(), values.end());
  const double rank = p * static_cast<double>(values.size() - 1);
  const auto lo = static_cast<std::size_t>(std::floor(rank));
  const std::size_t hi = std::min(lo + 1, values.size() - 1);
  return values[lo] + (rank - static_cast<double>(lo)) * (values[hi] - values[lo]);
}

int runGpu(const Arguments& a, std::optional<TemporaryStore>& temporary) {
  const transfer::TransferFunction tf = loadTransferFunction(a);
  // The options both renderers share, parsed once (renderOptions), then the GPU's own.
  const RenderOptions shared = renderOptions(a);
  gpu::RaycastOptions options = gpu::raycastOptions(shared);
  options.boundary = parseEnhancement(a.boundary, "--boundary");
  if (!a.clip.empty()) {
    double v[6];
    char extra = 0;
    if (std::sscanf(a.clip.c_str(), "%lf,%lf,%lf,%lf,%lf,%lf%c", &v[0], &v[1], &v[2], &v[3], &v[4], &v[5], &extra) != 6) {
      throw Error("", fmt::format("--clip \"{}\": expected I0,J0,K0,I1,J1,K1 (index space)", a.clip));
    }
    options.clip.enabled = true;
    options.clip.lo = {v[0], v[1], v[2]};
    options.clip.hi = {v[3], v[4], v[5]};
  }
  options.silhouette = parseEnhancement(a.silhouette, "--silhouette");
  if (!(a.lodPixels >= 0 && std::isfinite(a.lodPixels))) {
    throw Error("", fmt::format("--lod-pixels {}: must be >= 0", a.lodPixels));
  }
  options.lodPixels = a.lodPixels;
  options.cellSkipping = !a.noCellSkipping;
  if (a.imageAdaptive == "on") {
    options.imageAdaptive = gpu::kImageAdaptiveDefaultThreshold;
  } else if (a.imageAdaptive != "off") {
    char* end = nullptr;
    options.imageAdaptive = std::strtod(a.imageAdaptive.c_str(), &end);
    if (end == a.imageAdaptive.c_str() || *end != '\0' || !(options.imageAdaptive > 0) ||
        !std::isfinite(options.imageAdaptive)) {
      throw Error("", fmt::format("--image-adaptive \"{}\": expected off, on or a positive error bound",
                                  a.imageAdaptive));
    }
  }
  options.imageAdaptiveLevels = a.imageAdaptiveLevels;
  options.mip = a.mip == "sampled" ? gpu::RaycastOptions::MipMethod::Sampled
                                   : gpu::RaycastOptions::MipMethod::Exact;

  auto start = std::chrono::steady_clock::now();
  if (!volume::isStoreFile(a.path) && !temporary) temporary.emplace(a.path);
  const volume::StoreReader store(temporary ? temporary->path() : a.path);
  const double loadMs = millisecondsSince(start);

  const gpu::VolumeDomain domain{store.layout().levelDims(store.layout().leafLevel()),
                                 store.patientFromIndex()};
  const gpu::Camera camera = makeCamera(a, domain);
  if (!a.saveCamera.empty()) gpu::saveCamera(camera, a.saveCamera);

  start = std::chrono::steady_clock::now();
  const auto context = gpu::createHeadlessContext();
  gpu::RendererConfig config;
  config.poolBytes = a.poolMib << 20;
  config.gradientPool = a.gradientPool;
  config.cacheBytes = a.cacheMib << 20;
  config.uploadBytesPerFrame = a.uploadMibPerFrame << 20;
  config.visibility = gpu::parseVisibility(a.visibility);
  config.visibilityThreshold = a.visibilityThreshold;
  config.repackWhenSettled = a.repackWhenSettled;
  gpu::GpuRenderer renderer(store, config);
  const double setupMs = millisecondsSince(start);
  if (!a.cameraPath.empty()) return runPath(a, store, renderer, tf, options, domain, *context, loadMs + setupMs);

  // The timing loop: each frame's ms is the whole render() call (working-set selection,
  // uploads, index, the raycasting pass finished, read-back). With --json each frame is then
  // rendered again, untimed, by the counting variant for the per-pixel statistics.
  std::vector<double> framesMs;
  nlohmann::json frames = nlohmann::json::array();
  gpu::Frame first;  // frame 0: its view is the image written
  for (int f = 0; f < a.frames; ++f) {
    const gpu::Camera view = frameCamera(a, domain, camera, f);
    options.stats = false;
    start = std::chrono::steady_clock::now();
    gpu::Frame frame = renderer.render(view, tf, options);
    const double ms = millisecondsSince(start);
    framesMs.push_back(ms);
    nlohmann::json record = frameRecord(frame, ms);
    if (a.json) {
      options.stats = true;
      const gpu::Frame counted = renderer.render(view, tf, options);
      record["samplesPerPixel"] = counted.stats.samplesPerPixel;
      record["contributingSamplesPerPixel"] = counted.stats.contributingPerPixel;
      record["leavesPerPixel"] = counted.stats.leavesPerPixel;
      record["bricksTouched"] = counted.stats.bricksTouched;
      record["pixelsCovered"] = counted.stats.pixelsCovered;
      record["samplesTaken"] = counted.stats.samplesTaken;
      record["raysFraction"] = static_cast<double>(counted.stats.raysCast) / (static_cast<double>(view.width) * view.height);
    }
    frames.push_back(std::move(record));
    if (f == 0) first = std::move(frame);
  }
  const double medianMs = cli::medianOfSteadyFrames(framesMs);
  nlohmann::json adaptiveError;
  if (a.json && options.imageAdaptive > 0) {
    // The error image-adaptive sampling makes: frame 0's view again, adaptive and with every
    // pixel cast, after the timed frames (a full frame sees every brick and would change the
    // working set the timed adaptive frames run on).
    const gpu::Camera view = frameCamera(a, domain, camera, 0);
    options.stats = false;
    const gpu::Frame adaptive = renderer.render(view, tf, options);
    gpu::RaycastOptions full = options;
    full.imageAdaptive = 0;
    const gpu::Frame exact = renderer.render(view, tf, full);
    const gpu::ImageMetrics m = gpu::compare(exact.image, adaptive.image);
    adaptiveError = {{"psnrDb", std::isfinite(m.psnrDb) ? nlohmann::json(m.psnrDb) : nlohmann::json("inf")},
                     {"maxAbsError", m.maxAbsError},
                     {"raysFraction", static_cast<double>(adaptive.stats.raysCast) /
                                          (static_cast<double>(view.width) * view.height)}};
  }

  writeOutputs(first.image, a);
  nlohmann::json cutCheck;
  if (!a.cutReference.empty()) {
    // Frame 0's view converged again: later frames (--frames, --json's counting pass) may
    // have moved the working set to another cut.
    options.stats = false;
    const gpu::Frame again = renderer.render(camera, tf, options);
    cutCheck = cutReference(a, store, renderer, camera, tf, again.image);
  }

  // A pool too small for the cut the view asks for draws some places coarser than
  // --lod-pixels: said, never silent.
  std::vector<std::string> warnings;
  if (const gpu::WorkingSetStats& w = first.stats.workingSet; w.stoppedByPool > 0) {
    warnings.push_back(fmt::format(
        "the GPU brick pool (--pool-mib {}: {} bricks) is full: {} place(s) of the picture are drawn "
        "coarser than --lod-pixels {} asks; raise --pool-mib",
        a.poolMib, first.stats.poolSlots, w.stoppedByPool, a.lodPixels));
  }
  for (const auto& w : warnings) fmt::print(stderr, "octoray-render: warning: {}\n", w);

  if (a.json) {
    options.stats = false;  // the timed variant's defines, not the counting one's
    const std::vector<std::string> defines = renderer.variantDefines(tf, options, camera.projection);
    const nlohmann::json report = {
        {"renderer", "gpu"},
        {"glRenderer", context->renderer()},
        {"glVersion", context->version()},
        {"mode", a.mode},
        {"transferFunction", tf.name},
        {"dims", domain.dims},
        {"width", camera.width},
        {"height", camera.height},
        {"lodPixels", a.lodPixels},
        {"stepMm", a.stepMm > 0 ? a.stepMm : renderer.defaultStepMm()},
        {"variant", defines},
        {"timingMs", {{"load", loadMs}, {"setup", setupMs}}},
        {"firstFrameMs", framesMs.front()},
        {"medianMs", medianMs},
        {"medianOf", cli::steadyFramesDescription(framesMs.size())},
        {"frames", frames},
        {"imageAdaptiveError", adaptiveError},
        {"cutReference", cutCheck},
        {"warnings", warnings},
        {"camera", gpu::cameraToJson(camera)},
        {"outputs", a.exr.empty() ? nlohmann::json{a.output} : nlohmann::json{a.output, a.exr}}};
    std::cout << report.dump(2) << '\n';
  } else {
    fmt::print("{}: {}x{} {} on {} in {:.0f} ms median ({} frames, first {:.0f} ms), "
               "{} bricks in the working set\n",
               a.output, camera.width, camera.height, a.mode, context->renderer(), medianMs,
               a.frames, framesMs.front(), first.stats.workingSetBricks);
  }
  return 0;
}

// Outputs are checked before the (possibly long) rendering: their folders must be writable,
// and none may be one of the files read.
void checkOutputFolders(const Arguments& a) {
  for (const std::string& out : {a.output, a.exr, a.cutReference}) {
    if (out.empty()) continue;
    const std::filesystem::path folder = std::filesystem::absolute(out).parent_path();
    std::error_code ec;
    if (!std::filesystem::is_directory(folder, ec)) throw Error(out, "its folder does not exist");
    if (::access(folder.c_str(), W_OK) != 0) throw Error(out, "its folder is not writable");
    checkOutputIsNotAnInput(out, {a.path, a.tfPath, a.camera, a.cameraPath});
  }
}

int run(Arguments a) {
  checkOutputFolders(a);
  // An input that is not a store, built into a temporary one where the defaults need its
  // histogram (kept for the GPU path, which renders it) or by the GPU path.
  std::optional<TemporaryStore> temporary;
  resolveDefaults(a, temporary);
  std::optional<tbb::global_control> threadLimit;
  if (a.threads > 0) {
    threadLimit.emplace(tbb::global_control::max_allowed_parallelism,
                        static_cast<std::size_t>(a.threads));
  }
  const int status = a.reference ? runReference(a) : runGpu(a, temporary);
  for (const std::string& note : a.notes) fmt::print(stderr, "octoray-render: {}\n", note);
  return status;
}

}  // namespace octoray::render_tool

using octoray::render_tool::Arguments;

int main(int argc, char** argv) {
  CLI::App app{
      "Renders a CT volume with the GPU raycaster (default) or the CPU reference renderer."};
  app.footer(
      "Examples:\n"
      "  octoray-render head.octoray -o head.png             # DVR, bone preset, 512x512\n"
      "  octoray-render head.octoray --mode iso -o bone.png  # bone surface at 300 HU\n"
      "  octoray-render head.octoray --mode mip --azimuth 90 --size 1024x1024 -o mip.png\n"
      "  octoray-render head.octoray --preset lung --reference --converge -o truth.png\n");
  Arguments a;
  app.add_option("path", a.path, "octree store, DICOM folder or volume file")->required();
  app.add_option("-o,--output", a.output, "PNG to write (colour over black, 8-bit)")->required();
  app.add_option("--exr", a.exr, "also write float RGBA + Z (depth, mm) as OpenEXR");
  app.add_option("--mode", a.mode, "dvr, iso or mip")
      ->check(CLI::IsMember({"dvr", "iso", "mip"}))
      ->capture_default_str();
  auto* preset = app.add_option("--preset", a.preset, "shipped preset by name (bone, lung, ...); default: bone for CT DVR, a bone-coloured "
                                "surface for iso, a grey ramp for MIP");
  auto* tfFile =
      app.add_option("--tf", a.tfPath, "transfer function file (octoray JSON, Slicer, ParaView)");
  preset->excludes(tfFile);
  app.add_option("--tf-name", a.tfName, "which function of a --tf file holding several")
      ->needs(tfFile);
  app.add_option("--iso", a.iso, "isovalue for --mode iso, in the volume's unit (default: 300 HU for CT, Otsu's threshold of the values otherwise)");
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
  auto* referenceFlag =
      app.add_flag("--reference", a.reference, "use the CPU reference renderer (the oracle)");
  auto* gpuFlag = app.add_flag("--gpu", a.gpu, "use the GPU raycaster (the default)");
  gpuFlag->excludes(referenceFlag);
  app.add_option("--lod-pixels", a.lodPixels,
                 "GPU: refine while a node's voxels project to more than F pixels; 0: finest "
                 "level everywhere")
      ->capture_default_str();
  app.add_option("--frames", a.frames, "GPU: frames to render (the timing loop)")
      ->check(CLI::Range(1, 100000))
      ->capture_default_str();
  app.add_option("--orbit", a.orbitDegrees, "GPU: degrees the camera turns each frame")
      ->capture_default_str();
  app.add_option("--pool-mib", a.poolMib, "GPU: brick pool budget in MiB")
      ->check(CLI::Range(1, 1 << 20))
      ->capture_default_str();
  app.add_option("--cache-mib", a.cacheMib, "GPU: CPU brick cache budget in MiB")
      ->check(CLI::Range(1, 1 << 22))
      ->capture_default_str();
  app.add_option("--upload-mib-per-frame", a.uploadMibPerFrame,
                 "GPU, --path: texture upload budget per frame in MiB; 0: unlimited")
      ->check(CLI::Range(0, 1 << 20))
      ->capture_default_str();
  app.add_option("--visibility", a.visibility,
                 "GPU: feedback that prunes the working set: rays (which leaves rays reach and "
                 "want finer), occlusion (queries on the leaves' boxes against the depth of "
                 "the rays' last samples, screen-space tiling), both, or none")
      ->check(CLI::IsMember({"rays", "occlusion", "both", "none"}))
      ->capture_default_str();
  app.add_option("--visibility-threshold", a.visibilityThreshold,
                 "GPU: rays (pixels) a leaf needs to count as seen")
      ->check(CLI::Range(1, 1 << 20))
      ->capture_default_str();
  app.add_option("--path", a.cameraPath,
                 "GPU: camera path, one frame each, streaming: orbit:N[,degrees:D]"
                 "[,zoom-from:Z1,zoom-to:Z2][,still:S] or a JSON list of cameras");
  app.add_option("--stats", a.statsOut, "GPU, --path: per-frame statistics to OUT.csv or OUT.json");
  app.add_flag("--gradient-pool", a.gradientPool,
               "GPU: shade from the store's precomputed gradients (import with --gradients)");
  app.add_option("--boundary", a.boundary, "GPU: boundary enhancement KC,KS,KE");
  app.add_option("--clip", a.clip, "GPU: clip box I0,J0,K0,I1,J1,K1 in index space (voxel centres at integers)");
  app.add_option("--mip", a.mip,
                 "GPU, --mode mip: exact (the interpolant's maximum along the ray, as the "
                 "reference) or sampled (its maximum at the step's samples; faster)")
      ->check(CLI::IsMember({"exact", "sampled"}))
      ->capture_default_str();
  app.add_option("--preintegration", a.preintegration,
                 "DVR: on = classify each step as a segment through the pre-integrated TF "
                 "(removes coarse-step rings), off = at its sample")
      ->check(CLI::IsMember({"on", "off"}))
      ->capture_default_str();
  app.add_flag("--jitter", a.jitter,
               "DVR: each sample at a hashed per-pixel fraction of its step (deterministic)");
  app.add_option("--image-adaptive", a.imageAdaptive,
                 "GPU: adaptive sampling in the image plane: off (every pixel), on (error bound "
                 "0.005, within 1 dB of off on CT DVR) or an error bound (largest channel "
                 "difference between coarse rays)")
      ->capture_default_str();
  app.add_option("--image-adaptive-levels", a.imageAdaptiveLevels,
                 "GPU: pyramid levels above the image (coarsest rays every 2^N pixels)")
      ->check(CLI::Range(1, 4))
      ->capture_default_str();
  app.add_flag("--converge", a.converge,
               "reference: the converged truth (the step halved until the picture stops "
               "changing; exit 3 if it does not); --step is the first step");
  app.add_option("--converge-max-change", a.convergeMaxChange,
                 "reference --converge: largest change of any channel to stop at")
      ->capture_default_str();
  app.add_option("--converge-psnr", a.convergePsnr,
                 "reference --converge: PSNR (dB) of the last change to stop at")
      ->capture_default_str();
  app.add_option("--converge-halvings", a.convergeHalvings,
                 "reference --converge: most halvings")
      ->check(CLI::Range(1, 12))
      ->capture_default_str();
  app.add_flag("--no-cell-skipping", a.noCellSkipping,
               "GPU: sample transparent 8^3 cells of bricks too, and in exact MIP evaluate cells that "
               "cannot raise the maximum (same picture; to measure)");
  app.add_option("--silhouette", a.silhouette,
                 "GPU: view-dependent transparency KC,KS,KE");
  app.add_option("--threads", a.threads, "worker threads (0: all cores)")
      ->check(octoray::cli::kNonNegative);
  app.add_flag("--frustum-cut", a.frustumCut,
               "reference, store: read only the leaf bricks in the camera's view (the truth of a "
               "zoomed view of a store too large for memory; the same picture)");
  app.add_flag("--repack-when-settled", a.repackWhenSettled,
               "GPU: once the working set settles, move its bricks to the pool's first slots in node "
               "order, as the viewer does (the same view is then the same picture whatever the history)");
  app.add_option("--cut-reference", a.cutReference,
                 "GPU: also render the CPU reference over the LOD cut of the GPU picture (the last "
                 "frame of --path) to this PNG (and with --exr to the same name .exr) and report their "
                 "agreement (DVR and iso)");
  app.add_option("--cut-truth", a.cutTruthStepMm,
                 "with --cut-reference: render it as the cut's own truth, at this step in mm and "
                 "without early termination, so the GPU picture's error on its cut (classification, "
                 "step) is told apart from what the cut's coarse levels lose")
      ->check(octoray::cli::kPositive);
  app.add_flag("--json", a.json, "print timing (ms), image size, samples and the camera as JSON");
  try {
    app.parse(argc, argv);
    if (!a.camera.empty() && size->count() == 0) a.size.clear();
    if (!a.cameraPath.empty() && (app.count("--frames") > 0 || app.count("--orbit") > 0)) {
      throw CLI::ValidationError("--path", "replaces --frames and --orbit");
    }
    if (!a.statsOut.empty() && a.cameraPath.empty()) {
      throw CLI::ValidationError("--stats", "needs --path");
    }
    if (!a.reference) {
      for (const char* referenceOnly : {"--converge", "--converge-max-change", "--converge-psnr",
                                        "--converge-halvings", "--frustum-cut"}) {
        if (app.count(referenceOnly) > 0) {
          throw CLI::ValidationError(referenceOnly, "applies to --reference");
        }
      }
    }
    if (a.cutTruthStepMm > 0 && a.cutReference.empty()) {
      throw CLI::ValidationError("--cut-truth", "needs --cut-reference");
    }
    if (!a.cutReference.empty()) {
      // What the reference does not model, or models differently.
      for (const char* gpuOnly : {"--gradient-pool", "--boundary", "--silhouette", "--clip",
                                  "--image-adaptive", "--mip"}) {
        if (app.count(gpuOnly) > 0) {
          throw CLI::ValidationError("--cut-reference", fmt::format("cannot check {}", gpuOnly));
        }
      }
      if (a.mode == "mip") throw CLI::ValidationError("--cut-reference", "checks DVR and iso, not MIP");
    }
    if (a.reference) {
      for (const char* gpuOnly : {"--cut-reference", "--lod-pixels", "--frames", "--orbit", "--pool-mib",
                                  "--gradient-pool", "--boundary", "--silhouette", "--clip",
                                  "--no-cell-skipping", "--mip", "--cache-mib",
                                  "--upload-mib-per-frame", "--visibility",
                                  "--visibility-threshold", "--path", "--stats",
                                  "--image-adaptive", "--image-adaptive-levels",
                                  "--repack-when-settled", "--cut-truth"}) {
        if (app.count(gpuOnly) > 0) {
          throw CLI::ValidationError(gpuOnly, "applies to the GPU renderer, not --reference");
        }
      }
    }
  } catch (const CLI::Success& e) {
    return app.exit(e);
  } catch (const CLI::Error& e) {
    fmt::print(stderr, "octoray-render: {}\nRun with --help for more information.\n", e.what());
    return 2;
  }
  return octoray::cli::runTool("octoray-render", [&] { return run(a); });
}
