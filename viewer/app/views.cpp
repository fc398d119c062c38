// The 3D view and the MPR views: what each draws from the session, as textures the window
// shows 1:1 (nearest filtering) so a screenshot of a view is exactly its picture.
#include <epoxy/gl.h>
#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <cmath>

#include "app.h"
#include "octoray/core/error.h"
#include "octoray/transfer/transfer_function_io.h"

namespace octoray::viewer {
namespace {

double msSince(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t).count();
}

void uploadRgba8(unsigned& texture, int& tw, int& th, int w, int h, const std::vector<uint8_t>& rgba,
                 bool linear) {
  if (texture == 0) glGenTextures(1, &texture);
  glBindTexture(GL_TEXTURE_2D, texture);
  glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
  glPixelStorei(GL_UNPACK_ROW_LENGTH, 0);
  if (tw != w || th != h) {
    glTexImage2D(GL_TEXTURE_2D, 0, GL_RGBA8, w, h, 0, GL_RGBA, GL_UNSIGNED_BYTE, rgba.data());
    tw = w;
    th = h;
  } else {
    glTexSubImage2D(GL_TEXTURE_2D, 0, 0, 0, w, h, GL_RGBA, GL_UNSIGNED_BYTE, rgba.data());
  }
  const GLint filter = linear ? GL_LINEAR : GL_NEAREST;
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, filter);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, filter);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
  glBindTexture(GL_TEXTURE_2D, 0);
}

// The raycaster's premultiplied colour over black, clamped and rounded as octoray-render's
// PNG writer does (image_io.h, PngEncoding::Clamp).
uint8_t displayByte(float c) {
  return static_cast<uint8_t>(std::lround(std::clamp(c, 0.0f, 1.0f) * 255.0f));
}

}  // namespace

gpu::RaycastOptions::ClipBox clipOptions(const ClipBox& c) {
  gpu::RaycastOptions::ClipBox out;
  out.enabled = c.enabled;
  out.lo = {c.lo.x, c.lo.y, c.lo.z};
  out.hi = {c.hi.x, c.hi.y, c.hi.z};
  return out;
}

gpu::RaycastOptions View3d::raycastOptions(const Session& s) const {
  gpu::RaycastOptions o;
  o.mode = s.mode;
  o.isoValue = s.isoValue;
  o.lodPixels = s.lodPixels;
  o.stepMm = s.stepFactor == 1.0 ? 0.0 : s.stepFactor * renderer_->defaultStepMm();
  o.earlyTermination = s.earlyTermination;
  o.shading = s.shading ? gpu::RaycastOptions::Shading::FromTransferFunction
                        : gpu::RaycastOptions::Shading::Off;
  o.preintegration = s.preintegration && s.mode == gpu::RaycastMode::Dvr;
  o.clip = clipOptions(s.clip);
  return o;
}

// ---- View3d --------------------------------------------------------------------------------

View3d::View3d(const volume::StoreReader& store, const gpu::RendererConfig& config)
    : renderer_(std::make_unique<gpu::GpuRenderer>(store, config)) {}

View3d::~View3d() {
  if (texture_) glDeleteTextures(1, &texture_);
}

std::vector<std::string> View3d::takeErrors() { return std::exchange(errors_, {}); }

void View3d::update(const Session& s, int width, int height, bool interacting) {
  if (width < 8 || height < 8) return;
  // What the picture shows (camera, TF, mode, quality) apart from interactive quality; a
  // change while the user is interacting renders at interactive quality until it settles.
  const std::string content = fmt::format(
      "{}|{}|{}|{}|{}|{}|{}|{}|{}|{}|{}|{}|{},{},{},{},{},{}", gpu::cameraToJson(s.camera).dump(),
      transfer::transferFunctionToJsonText(s.tf), modeName(s.mode), s.isoValue, s.lodPixels,
      s.stepFactor, s.earlyTermination, s.shading, s.preintegration, width, height, s.clip.enabled, s.clip.lo.x,
      s.clip.lo.y, s.clip.lo.z, s.clip.hi.x, s.clip.hi.y, s.clip.hi.z);
  if (content != lastContent_) {
    lastContent_ = content;
    changedFrames_ = 3;
  } else if (changedFrames_ > 0 && !interacting) {
    --changedFrames_;
  }
  const bool interactive = interacting && s.interactiveQuality && changedFrames_ > 0;
  gpu::Camera camera = s.camera;
  camera.width = interactive ? std::max(8, width / 2) : width;
  camera.height = interactive ? std::max(8, height / 2) : height;
  gpu::RaycastOptions o = raycastOptions(s);
  if (interactive) {
    // Interactive quality: half resolution, coarser levels, and rays only where the picture
    // has detail (image-plane adaptive sampling at its interactive bound); post-classified,
    // since pre-integration costs about twice the time (docs/accuracy.md).
    o.lodPixels = std::max(2.0, 2.0 * s.lodPixels);
    o.imageAdaptive = gpu::kImageAdaptiveInteractiveThreshold;
    o.preintegration = false;
  }
  const std::string key = fmt::format("{}|{}", content, interactive);
  if (key != lastKey_) {
    converged_ = false;
    lastKey_ = key;
  }
  if (converged_) return;
  const auto start = std::chrono::steady_clock::now();
  gpu::Frame frame = renderer_->renderFrame(camera, s.tf, o);
  lastFrameMs_ = msSince(start);
  ++frames_;
  stats_ = frame.stats;
  bytesRead_ += frame.stats.bytesRead;
  for (auto& e : frame.stats.errors) errors_.push_back(e);
  const auto& ws = renderer_->workingSet();
  converged_ = !interactive && ws.settled() && frame.stats.workingSet.uploaded == 0 &&
               frame.stats.workingSet.fetched == 0;
  lastInteractive_ = interactive;
  const gpu::Image& img = frame.image;
  std::vector<uint8_t> rgba(img.pixelCount() * 4);
  for (std::size_t i = 0; i < img.pixelCount(); ++i) {
    rgba[4 * i + 0] = displayByte(img.rgba[4 * i + 0]);
    rgba[4 * i + 1] = displayByte(img.rgba[4 * i + 1]);
    rgba[4 * i + 2] = displayByte(img.rgba[4 * i + 2]);
    rgba[4 * i + 3] = 255;
  }
  uploadRgba8(texture_, texWidth_, texHeight_, img.width, img.height, rgba, interactive);
  lastImage_ = std::move(frame.image);
}

// ---- MprView -------------------------------------------------------------------------------

MprView::MprView(ViewId id) : id_(id) {}

MprView::~MprView() {
  if (texture_) glDeleteTextures(1, &texture_);
}

double MprView::valueAt(int x, int y) const {
  if (!hasSlice_ || x < 0 || y < 0 || x >= slice_.width || y >= slice_.height) {
    return std::numeric_limits<double>::quiet_NaN();
  }
  return slice_.hu[static_cast<std::size_t>(y * slice_.width + x)];
}

void MprView::update(const Session& s, const Grid& grid, int width, int height, StoreSlicer* slicer,
                     const PreviewVolume* preview, bool bricksArrived, VoiFunction voi) {
  if (width < 8 || height < 8) return;
  plane_ = mprPlane(id_, s, grid, width, height);
  SliceRequest req;
  req.plane = plane_;
  req.slab = s.slab;
  req.slabMm = s.slab == SlabMode::None ? 0.0 : s.slabMm;
  req.level = slicer ? slicer->targetLevel(plane_.mmPerPixel) : 0;
  const std::string key =
      fmt::format("{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}", plane_.origin.x, plane_.origin.y,
                  plane_.origin.z, plane_.right.x, plane_.right.y, plane_.right.z, plane_.down.x,
                  plane_.down.y, plane_.down.z, plane_.mmPerPixel, width, height,
                  slabModeName(req.slab), req.slabMm, slicer ? 1 : 0);
  const bool source = slicer != nullptr || preview != nullptr;
  const bool redo = source && (key != sliceKey_ || !hasSlice_ ||
                               (!slice_.complete() && (bricksArrived || (preview && !slicer))));
  if (redo) {
    const auto start = std::chrono::steady_clock::now();
    slice_ = slicer ? slicer->slice(req) : preview->slice(req);
    lastSliceMs_ = msSince(start);
    fromPreview_ = slicer == nullptr;
    hasSlice_ = true;
    sliceKey_ = key;
    mappedWl_ = {-1, 0};
  }
  if (!hasSlice_) return;
  if (mappedWl_.window != s.wl.window || mappedWl_.level != s.wl.level || mappedVoi_ != voi) {
    std::vector<uint8_t> rgba(static_cast<std::size_t>(slice_.width * slice_.height) * 4);
    for (std::size_t i = 0; i < slice_.hu.size(); ++i) {
      const uint8_t g = windowGrey(slice_.hu[i], s.wl, voi);
      rgba[4 * i + 0] = rgba[4 * i + 1] = rgba[4 * i + 2] = g;
      rgba[4 * i + 3] = 255;
    }
    uploadRgba8(texture_, texWidth_, texHeight_, slice_.width, slice_.height, rgba, false);
    mappedWl_ = s.wl;
    mappedVoi_ = voi;
  }
}

}  // namespace octoray::viewer
