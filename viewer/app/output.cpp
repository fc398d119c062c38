// What the viewer writes: sessions, the state file, screenshots, movies, EXR, the
// recent-files list and the per-frame statistics.
#include <epoxy/gl.h>
#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <fstream>

#include "app.h"
#include "pacs_panel.h"
#include "octoray/core/error.h"
#include "octoray/gpu/image_io.h"
#include "util.h"

namespace octoray::viewer {
namespace fs = std::filesystem;

// ---- output --------------------------------------------------------------------------------

void App::saveSessionTo(const std::string& path) {
  try {
    saveSession(session, path);
  } catch (const Error& e) {
    messages.push_back(e.what());
  }
}

void App::loadSessionFrom(const std::string& path) {
  try {
    Session loaded = loadSession(path);
    const bool reopen = !dataset_ || loaded.source != dataset_->path();
    session = loaded;
    if (reopen) {
      const Session keep = session;
      open(session.source);
      session = keep;
      sessionLoaded_ = true;  // its camera and crosshair stay
    }
    // Its window and transfer function stay too, whether the volume was open or not.
    windowLevelChosen(false);
    if (session.wlPreset.starts_with("file")) wlUnit_ = "file";  // that volume's own window
    tfChosenForDataset_ = true;
    isoValueChosen();
  } catch (const Error& e) {
    messages.push_back(e.what());
  }
}

nlohmann::json App::stateJson() {
  nlohmann::json j;
  j["session"] = sessionToJson(session);
  j["tool"] = toolName(controller_.tool);
  j["window"] = {fbWidth_, fbHeight_};
  j["messages"] = messages;
  if (pacs_) j["pacs"] = pacs_->state();
  j["converged"] = converged();
  if (dataset_) {
    j["dataset"] = {{"path", dataset_->path()},
                    {"state", dataset_->state() == Dataset::State::Ready     ? "ready"
                              : dataset_->state() == Dataset::State::Failed ? "failed"
                                                                             : "importing"},
                    {"store", dataset_->storePath()},
                    {"reusedCache", dataset_->reusedCache()},
                    {"progress", dataset_->progress()},
                    {"status", dataset_->status()},
                    {"unit", valueUnit_},
                    {"voiFunction", voiFunctionName(voiFunction())},
                    {"previewFraction", previewFraction()}};
    nlohmann::json windows = nlohmann::json::array();
    for (const WindowLevelPreset& p : fileWlPresets_) {
      windows.push_back({{"name", p.name}, {"window", p.window}, {"level", p.level}, {"source", p.source}});
    }
    j["dataset"]["fileWindows"] = windows;
  }
  nlohmann::json views = nlohmann::json::object();
  for (int v = 0; v < kViewCount; ++v) {
    const ViewId id = static_cast<ViewId>(v);
    const Rect r = viewRect(id);
    nlohmann::json view{{"rect", {r.x, r.y, r.w, r.h}}, {"overlayText", overlayText_[static_cast<std::size_t>(v)]}};
    if (isMpr(id) && mpr_[static_cast<std::size_t>(v)]) {
      const MprView& m = *mpr_[static_cast<std::size_t>(v)];
      const MprPlane& p = m.plane();
      auto vec = [](Vec3 a) { return nlohmann::json::array({a.x, a.y, a.z}); };
      view["plane"] = {{"origin", vec(p.origin)}, {"right", vec(p.right)}, {"down", vec(p.down)},
                       {"normal", vec(p.normal)}, {"mmPerPixel", p.mmPerPixel},
                       {"width", p.width}, {"height", p.height}};
      view["level"] = m.slice().level;
      view["coarsestLevelUsed"] = m.slice().coarsestLevelUsed;
      view["complete"] = m.complete();
      view["fromPreview"] = m.fromPreview();
      view["slabSamples"] = m.slice().slabSamples;
      view["labels"] = {{"left", orientationLabel(-1.0 * p.right)}, {"right", orientationLabel(p.right)},
                        {"top", orientationLabel(-1.0 * p.down)}, {"bottom", orientationLabel(p.down)}};
    }
    if (id == ViewId::Volume && view3d_) {
      gpu::Camera c = session.camera;
      c.width = r.w;
      c.height = r.h;
      view["camera"] = gpu::cameraToJson(c);
      view["converged"] = view3d_->converged();
      const gpu::FrameStats& st = view3d_->stats();
      view["workingSet"] = {{"leaves", st.workingSet.leaves}, {"bricks", st.workingSet.bricks},
                            {"proxyLeaves", st.workingSet.proxyLeaves}, {"poolSlotsUsed", st.poolSlotsUsed},
                            {"framesRendered", view3d_->framesRendered()}, {"lastFrameMs", view3d_->lastFrameMs()}};
    }
    views[viewName(id)] = view;
  }
  j["views"] = views;
  nlohmann::json results = nlohmann::json::array();
  for (const Measurement& m : session.measurements) {
    nlohmann::json r{{"kind", measureKindName(m.kind)}};
    if (m.kind == MeasureKind::Distance) r["mm"] = distanceMm(m);
    else if (m.kind == MeasureKind::Angle) r["degrees"] = angleDegrees(m);
    else {
      const RoiStats st = roiStatsOf(m);
      r["samples"] = st.samples;
      r["mean"] = st.mean;
      r["sd"] = st.sd;
      r["min"] = st.min;
      r["max"] = st.max;
      r["areaMm2"] = st.areaMm2;
    }
    results.push_back(r);
  }
  j["measurements"] = results;
  if (grid_) {
    const Vec3 sp{length(grid_->patientFromIndex.column(0)), length(grid_->patientFromIndex.column(1)),
                  length(grid_->patientFromIndex.column(2))};
    j["volume"] = {{"dims", grid_->dims}, {"spacingMm", {sp.x, sp.y, sp.z}}};
  }
  j["timing"] = {{"firstMprMs", firstMprMs_}, {"first3dMs", first3dMs_}};
  return j;
}

void App::dumpState(const std::string& path) {
  std::ofstream out(path);
  out << stateJson().dump(2, ' ', false, nlohmann::json::error_handler_t::replace) << "\n";
  if (!out) messages.push_back(path + ": cannot write the state file");
}

void App::capture() {
  if (!shot_) return;
  std::vector<uint8_t> pixels(static_cast<std::size_t>(fbWidth_ * fbHeight_) * 4);
  glPixelStorei(GL_PACK_ALIGNMENT, 1);
  glReadBuffer(GL_BACK);
  glReadPixels(0, 0, fbWidth_, fbHeight_, GL_RGBA, GL_UNSIGNED_BYTE, pixels.data());
  Rect r{0, 0, fbWidth_, fbHeight_};
  if (shot_->view) r = viewRect(*shot_->view);
  gpu::Image image(r.w, r.h);
  image.hasAlpha = false;
  for (int y = 0; y < r.h; ++y) {
    const int srcY = fbHeight_ - 1 - (r.y + y);
    for (int x = 0; x < r.w; ++x) {
      const uint8_t* p = &pixels[static_cast<std::size_t>((srcY * fbWidth_ + r.x + x) * 4)];
      float* q = image.pixel(x, y);
      q[0] = p[0] / 255.0f;
      q[1] = p[1] / 255.0f;
      q[2] = p[2] / 255.0f;
      q[3] = 1.0f;
    }
  }
  try {
    gpu::writePng(image, shot_->path);
    std::ofstream(shot_->path + ".json") << stateJson().dump(2, ' ', false, nlohmann::json::error_handler_t::replace) << "\n";
  } catch (const Error& e) {
    messages.push_back(e.what());
  }
  shot_.reset();
}

void App::exportMovie(const std::string& folder, int frames, double degrees) {
  if (!view3d_ || !grid_) {
    messages.push_back("movie: no volume open");
    return;
  }
  fs::create_directories(folder);
  const Rect r = viewRect(ViewId::Volume);
  gpu::Camera camera = session.camera;
  camera.width = std::max(8, r.w) & ~1;  // even sizes for H.264
  camera.height = std::max(8, r.h) & ~1;
  const gpu::RaycastOptions o = view3d_->raycastOptions(session);
  for (int i = 0; i < frames; ++i) {
    const gpu::Camera c = gpu::turnAboutCentre(camera, grid_->centre(), degrees * i / frames);
    const gpu::Frame f = view3d_->renderer().render(c, session.tf, o);
    gpu::writePng(f.image, fs::path(folder) / fmt::format("frame_{:04d}.png", i));
  }
  if (std::system("command -v ffmpeg >/dev/null 2>&1") == 0) {
    const std::string cmd = fmt::format(
        "ffmpeg -y -loglevel error -framerate 30 -i '{}/frame_%04d.png' -pix_fmt yuv420p '{}/rotation.mp4'",
        folder, folder);
    if (std::system(cmd.c_str()) != 0) messages.push_back(folder + ": ffmpeg failed to write rotation.mp4");
  }
}

void App::export3dExr(const std::string& path) {
  if (!view3d_) return;
  gpu::Camera c = session.camera;
  const Rect r = viewRect(ViewId::Volume);
  c.width = std::max(8, r.w);
  c.height = std::max(8, r.h);
  const gpu::RaycastOptions o = view3d_->raycastOptions(session);
  gpu::writeExr(view3d_->renderer().render(c, session.tf, o).image, path);
}

void App::loadRecent() {
  std::ifstream in(configDir() / "recent.json");
  if (!in) return;
  const auto j = nlohmann::json::parse(in, nullptr, false);
  if (!j.is_array()) return;
  for (const auto& p : j) {
    if (p.is_string()) recent_.push_back(p.get<std::string>());
  }
}

void App::saveRecent() {
  std::error_code ec;
  fs::create_directories(configDir(), ec);
  std::ofstream out(configDir() / "recent.json");
  out << nlohmann::json(recent_).dump(2) << "\n";
}

void App::writeStats() {
  if (!stats_) return;
  const gpu::FrameStats* s = view3d_ ? &view3d_->stats() : nullptr;
  bool mprComplete = true;
  for (const auto& m : mpr_) mprComplete = mprComplete && m && m->complete();
  std::fprintf(stats_, "%lld,%.3f,%.2f,%.2f,%d,%lld,%d,%d,%lld,%lld,%.1f,%lld,%llu,%.1f\n",
               static_cast<long long>(frameIndex_), secondsSince(openedAt_), frameMs_,
               view3d_ ? view3d_->lastFrameMs() : 0.0, interactionFrames_ > 0 ? 1 : 0,
               static_cast<long long>(view3d_ ? view3d_->framesRendered() : 0),
               view3d_ && view3d_->converged() ? 1 : 0, mprComplete ? 1 : 0,
               static_cast<long long>(s ? s->workingSet.bricks : 0),
               static_cast<long long>(s ? s->poolSlotsUsed : 0),
               s ? static_cast<double>(s->cacheBytes) / (1 << 20) : 0.0,
               static_cast<long long>(s ? s->loaderQueued : 0),
               static_cast<unsigned long long>((view3d_ ? view3d_->bytesRead() : 0) + (slicer_ ? slicer_->stats().bytesRead : 0)),
               residentMib());
  std::fflush(stats_);
}

}  // namespace octoray::viewer
