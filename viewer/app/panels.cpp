// The ImGui panels that edit the session: menu bar, the side panel (data, layout, window/level
// table, 3D rendering, MPR slab and planes, measurements), the status bar, the help window,
// the file dialog and the message banner. They change the same model the input handlers do.
#include <imgui.h>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <filesystem>

#include "app.h"
#include "octoray/core/error.h"

namespace octoray::viewer {
namespace fs = std::filesystem;


void App::drawPanels() {
  // Menu bar.
  if (ImGui::BeginMainMenuBar()) {
    if (ImGui::BeginMenu("File")) {
      if (ImGui::MenuItem("Open\u2026", "Ctrl+O")) showFileDialog = true;
      if (ImGui::MenuItem("PACS\u2026")) showPacs = true;
      if (ImGui::BeginMenu("Open recent", !recent_.empty())) {
        for (const auto& r : recent_) {
          if (ImGui::MenuItem(r.c_str())) open(r);
        }
        ImGui::EndMenu();
      }
      ImGui::Separator();
      if (ImGui::MenuItem("Save session", nullptr, false, dataset_ != nullptr)) saveSessionTo("octoray-session.json");
      if (ImGui::MenuItem("Load session")) loadSessionFrom("octoray-session.json");
      if (ImGui::MenuItem("Screenshot (layout)")) shot_ = PendingShot{"octoray-screenshot.png", std::nullopt, false};
      if (ImGui::MenuItem("Screenshot (3D view)")) shot_ = PendingShot{"octoray-3d.png", ViewId::Volume, false};
      if (ImGui::MenuItem("3D view as EXR", nullptr, false, view3d_ != nullptr)) export3dExr("octoray-3d.exr");
      if (ImGui::MenuItem("Rotation movie", nullptr, false, view3d_ != nullptr)) exportMovie("octoray-movie", 72, 360);
      ImGui::Separator();
      if (ImGui::MenuItem("Quit")) quit_ = true;
      ImGui::EndMenu();
    }
    if (ImGui::BeginMenu("View")) {
      if (ImGui::MenuItem("Four-up", nullptr, session.layout == Layout::FourUp)) setLayout(Layout::FourUp);
      if (ImGui::MenuItem("1 + 3", nullptr, session.layout == Layout::OnePlusThree)) setLayout(Layout::OnePlusThree);
      if (ImGui::MenuItem("One-up", nullptr, session.layout == Layout::OneUp)) setLayout(Layout::OneUp);
      ImGui::Separator();
      ImGui::MenuItem("Overlays", "O", &session.overlays);
      ImGui::MenuItem("Patient information", nullptr, &session.patientInfo);
      ImGui::MenuItem("Side panel", nullptr, &showPanel);
      ImGui::EndMenu();
    }
    if (ImGui::BeginMenu("Help")) {
      if (ImGui::MenuItem("Mouse and keyboard", "F1")) showHelp = true;
      ImGui::EndMenu();
    }
    if (dataset_) {
      const VolumeInfo info = dataset_->info();
      ImGui::SameLine(ImGui::GetWindowWidth() * 0.5f);
      ImGui::TextDisabled("%s", fs::path(dataset_->path()).filename().string().c_str());
    }
    ImGui::EndMainMenuBar();
  }

  // Messages: errors in the window, each naming its file.
  if (!messages.empty()) {
    ImGui::SetNextWindowPos(ImVec2(static_cast<float>(viewArea_.x + 12), static_cast<float>(viewArea_.y + 12)));
    ImGui::SetNextWindowSizeConstraints(ImVec2(200, 0), ImVec2(static_cast<float>(std::max(240, viewArea_.w - 24)), 400));
    ImGui::PushStyleColor(ImGuiCol_WindowBg, ImVec4(0.45f, 0.08f, 0.08f, 0.95f));
    ImGui::Begin("##messages", nullptr, ImGuiWindowFlags_NoTitleBar | ImGuiWindowFlags_AlwaysAutoResize |
                                            ImGuiWindowFlags_NoMove | ImGuiWindowFlags_NoSavedSettings);
    for (const auto& m : messages) ImGui::TextWrapped("%s", m.c_str());
    if (ImGui::Button("Dismiss")) messages.clear();
    ImGui::End();
    ImGui::PopStyleColor();
  }

  if (!showPanel) return;
  const float menuH = ImGui::GetFrameHeight();
  const float statusH = ImGui::GetFrameHeight() + 6;
  ImGui::SetNextWindowPos(ImVec2(static_cast<float>(fbWidth_ - 340), menuH));
  ImGui::SetNextWindowSize(ImVec2(340, static_cast<float>(fbHeight_) - menuH - statusH));
  ImGui::Begin("##panel", nullptr, ImGuiWindowFlags_NoTitleBar | ImGuiWindowFlags_NoMove |
                                       ImGuiWindowFlags_NoResize | ImGuiWindowFlags_NoSavedSettings);
  ImGui::PushItemWidth(-110);

  if (ImGui::CollapsingHeader("Data", ImGuiTreeNodeFlags_DefaultOpen)) {
    if (!dataset_) {
      ImGui::TextWrapped("No volume open. File \u25b8 Open, drop a file or folder on the window, or start octoray-view PATH.");
    } else {
      const VolumeInfo info = dataset_->info();
      ImGui::TextWrapped("%s", info.description.empty() ? dataset_->path().c_str() : info.description.c_str());
      if (grid_) {
        const Vec3 sp{length(grid_->patientFromIndex.column(0)), length(grid_->patientFromIndex.column(1)),
                      length(grid_->patientFromIndex.column(2))};
        ImGui::Text("%lld x %lld x %lld, %.3g x %.3g x %.3g mm", static_cast<long long>(grid_->dims[0]),
                    static_cast<long long>(grid_->dims[1]), static_cast<long long>(grid_->dims[2]), sp.x, sp.y, sp.z);
        // What the values are: Hounsfield units, or numbers without a unit (MR, files without
        // units), which no CT window or preset fits.
        const std::string values = valueUnit_.empty() ? "values without a unit" : "values in " + valueUnit_;
        ImGui::TextDisabled("%s%s", info.modality.empty() ? "" : (info.modality + ": ").c_str(), values.c_str());
      }
      if (dataset_->state() == Dataset::State::Importing) {
        ImGui::ProgressBar(static_cast<float>(dataset_->progress()), ImVec2(-1, 0), dataset_->status().c_str());
      } else if (dataset_->reusedCache()) {
        ImGui::TextDisabled("store reused from the cache");
      }
      // What the reader decided or repaired, and files left out of the volume, by name.
      const std::vector<std::string> warnings = dataset_->warnings();
      if (!warnings.empty()) {
        ImGui::PushStyleColor(ImGuiCol_Text, ImVec4(1.0f, 0.78f, 0.3f, 1.0f));
        const bool open = ImGui::TreeNode("warnings", "%zu warning%s", warnings.size(), warnings.size() == 1 ? "" : "s");
        ImGui::PopStyleColor();
        if (open) {
          for (const auto& w : warnings) ImGui::TextWrapped("%s", w.c_str());
          ImGui::TreePop();
        }
      }
    }
  }

  if (ImGui::CollapsingHeader("Layout", ImGuiTreeNodeFlags_DefaultOpen)) {
    int layout = static_cast<int>(session.layout);
    ImGui::RadioButton("four-up", &layout, 0);
    ImGui::SameLine();
    ImGui::RadioButton("1+3", &layout, 2);
    ImGui::SameLine();
    ImGui::RadioButton("one-up", &layout, 1);
    session.layout = static_cast<Layout>(layout);
    const char* views[] = {"axial", "coronal", "sagittal", "3D"};
    int main = static_cast<int>(session.mainView);
    if (ImGui::Combo("main view", &main, views, 4)) session.mainView = static_cast<ViewId>(main);
  }

  if (ImGui::CollapsingHeader("Window / level", ImGuiTreeNodeFlags_DefaultOpen)) {
    double w = session.wl.window, l = session.wl.level;
    // The labels name the volume's unit; the widgets' IDs stay the same ("###").
    const std::string unit = valueUnit_.empty() ? "" : " (" + valueUnit_ + ")";
    // Steps of about a hundredth and a tenth of the range (10 and 100 for CT).
    const std::string valueFormat = fmt::format("%.{}f", labelDecimals());
    const double step = valueStep(histHi_ - histLo_);
    if (ImGui::InputDouble(("window" + unit + "###window").c_str(), &w, step, 10 * step, valueFormat.c_str())) {
      session.wl.window = std::max(minimumWindow(), w);
      session.wlPreset.clear();
      windowLevelChosen();
    }
    if (ImGui::InputDouble(("level" + unit + "###level").c_str(), &l, step, 10 * step, valueFormat.c_str())) {
      session.wl.level = l;
      session.wlPreset.clear();
      windowLevelChosen();
    }
    // A VOI function other than LINEAR says so: the file's SIGMOID or LINEAR_EXACT (applied to
    // every window on this volume), or LINEAR_EXACT for values that are not integers.
    if (voiFunction() != VoiFunction::Linear) {
      ImGui::TextDisabled("%s", fmt::format("grey: {}{}", voiFunctionName(voiFunction()),
                                            declaredVoi_.empty() ? " (values not integers)" : " (the file's VOILUTFunction)")
                                    .c_str());
    }
    // The windows the volume's file names (its default first), above the table's CT presets.
    if (!fileWlPresets_.empty() &&
        ImGui::BeginTable("file-wl", 3, ImGuiTableFlags_BordersInnerH | ImGuiTableFlags_SizingStretchProp)) {
      ImGui::TableSetupColumn("from the file");
      ImGui::TableSetupColumn("W");
      ImGui::TableSetupColumn("L");
      ImGui::TableHeadersRow();
      for (std::size_t i = 0; i < fileWlPresets_.size(); ++i) {
        const WindowLevelPreset p = fileWlPresets_[i];
        ImGui::PushID(static_cast<int>(i));
        ImGui::TableNextRow();
        ImGui::TableNextColumn();
        const std::string::size_type colon = p.source.find(": ");
        const std::string label = colon == std::string::npos ? p.name : p.name + "  " + p.source.substr(colon + 2);
        if (ImGui::Selectable(label.c_str(), session.wlPreset == p.name)) {
          applyWindowLevelPreset(p);
          fileWindowChosen();
        }
        if (ImGui::IsItemHovered()) ImGui::SetTooltip("%s", p.source.c_str());
        ImGui::TableNextColumn();
        ImGui::Text("%.*f", labelDecimals(), p.window);
        ImGui::TableNextColumn();
        ImGui::Text("%.*f", labelDecimals(), p.level);
        ImGui::PopID();
      }
      ImGui::EndTable();
    }
    if (ImGui::BeginTable("wl", 4, ImGuiTableFlags_BordersInnerH | ImGuiTableFlags_SizingStretchProp)) {
      ImGui::TableSetupColumn("key");
      ImGui::TableSetupColumn("preset");
      ImGui::TableSetupColumn("W");
      ImGui::TableSetupColumn("L");
      ImGui::TableHeadersRow();
      for (std::size_t i = 0; i < wlPresets.size(); ++i) {
        auto& p = wlPresets[i];
        ImGui::PushID(static_cast<int>(i));
        ImGui::TableNextRow();
        ImGui::TableNextColumn();
        ImGui::Text("%d", p.key);
        ImGui::TableNextColumn();
        if (ImGui::Selectable(p.name.c_str(), session.wlPreset == p.name)) {
          applyWindowLevelPreset(p);
          windowLevelChosen(true);
        }
        if (ImGui::IsItemHovered() && !p.source.empty()) ImGui::SetTooltip("%s", p.source.c_str());
        ImGui::TableNextColumn();
        ImGui::SetNextItemWidth(-1);
        ImGui::InputDouble("##w", &p.window, 0, 0, "%.0f");
        ImGui::TableNextColumn();
        ImGui::SetNextItemWidth(-1);
        ImGui::InputDouble("##l", &p.level, 0, 0, "%.0f");
        ImGui::PopID();
      }
      ImGui::EndTable();
    }
    if (ImGui::Button("Save table")) {
      try {
        saveWindowLevelPresets(wlPresets, defaultWindowLevelPresetsPath());
      } catch (const std::exception& e) {
        messages.push_back(e.what());
      }
    }
  }

  if (ImGui::CollapsingHeader("3D view", ImGuiTreeNodeFlags_DefaultOpen)) {
    int mode = static_cast<int>(session.mode);
    ImGui::RadioButton("DVR", &mode, 0);
    ImGui::SameLine();
    ImGui::RadioButton("isosurface", &mode, 1);
    ImGui::SameLine();
    ImGui::RadioButton("MIP", &mode, 2);
    if (mode != static_cast<int>(session.mode)) {
      session.mode = static_cast<gpu::RaycastMode>(mode);
      modeChanged();
    }
    if (ImGui::BeginCombo("preset", session.preset.c_str())) {
      for (const auto& name : tfPresetNames) {
        if (ImGui::Selectable(name.c_str(), name == session.preset)) selectTfPreset(name);
      }
      ImGui::EndCombo();
    }
    float iso = static_cast<float>(session.isoValue);
    const std::string isoLabel = valueUnit_.empty() ? "isovalue###iso" : "isovalue (" + valueUnit_ + ")###iso";
    const std::string isoFormat = fmt::format("%.{}f", valueDecimals(histHi_ - histLo_));
    if (ImGui::SliderFloat(isoLabel.c_str(), &iso, static_cast<float>(histLo_), static_cast<float>(histHi_), isoFormat.c_str())) {
      session.isoValue = iso;
      isoValueChosen();
      markInteraction();
    }
    float lod = static_cast<float>(session.lodPixels);
    if (ImGui::SliderFloat("LOD pixels", &lod, 0.5f, 8.0f, "%.2f")) {
      session.lodPixels = lod;
      markInteraction();
    }
    float step = static_cast<float>(session.stepFactor);
    if (ImGui::SliderFloat("step factor", &step, 0.25f, 4.0f, "%.2f")) {
      session.stepFactor = step;
      markInteraction();
    }
    float term = static_cast<float>(session.earlyTermination);
    if (ImGui::SliderFloat("termination", &term, 0.80f, 1.0f, "%.3f")) {
      session.earlyTermination = std::clamp(term, 0.01f, 1.0f);
      markInteraction();
    }
    ImGui::Checkbox("shading", &session.shading);
    ImGui::SameLine();
    ImGui::Checkbox("pre-integrated", &session.preintegration);
    if (ImGui::IsItemHovered()) {
      ImGui::SetTooltip("DVR: classify each step exactly instead of at its sample. Removes the grain\n"
                        "of sharp transfer functions (CT-AAA, angiography); still frames take about\n"
                        "twice as long. Interactive frames stay post-classified.");
    }
    ImGui::Checkbox("interactive quality", &session.interactiveQuality);
    for (const char* v : {"A", "P", "L", "R", "S", "I"}) {
      if (ImGui::Button(v, ImVec2(36, 0))) standardView(v[0]);
      ImGui::SameLine();
    }
    if (ImGui::Button("reset")) resetCamera();
    ImGui::Checkbox("clip box", &session.clip.enabled);
    if (session.clip.enabled && grid_) {
      ImGui::SameLine();
      if (ImGui::SmallButton("whole volume")) resetClip();
      const char* axes[] = {"i (columns)", "j (rows)", "k (slices)"};
      double* lo[] = {&session.clip.lo.x, &session.clip.lo.y, &session.clip.lo.z};
      double* hi[] = {&session.clip.hi.x, &session.clip.hi.y, &session.clip.hi.z};
      for (int a = 0; a < 3; ++a) {
        float range[2] = {static_cast<float>(*lo[a]), static_cast<float>(*hi[a])};
        const float top = static_cast<float>(grid_->dims[static_cast<std::size_t>(a)]) - 0.5f;
        if (ImGui::DragFloatRange2(axes[a], &range[0], &range[1], 1.0f, -0.5f, top, "%.0f", "%.0f")) {
          *lo[a] = std::clamp(static_cast<double>(range[0]), -0.5, static_cast<double>(top) - 1);
          *hi[a] = std::clamp(static_cast<double>(range[1]), *lo[a] + 1, static_cast<double>(top));
          markInteraction();
        }
      }
    }
    drawTfEditor();
  }

  if (ImGui::CollapsingHeader("MPR", ImGuiTreeNodeFlags_DefaultOpen)) {
    const char* slabs[] = {"none", "MIP", "MinIP", "mean"};
    int slab = static_cast<int>(session.slab);
    if (ImGui::Combo("slab", &slab, slabs, 4)) session.slab = static_cast<SlabMode>(slab);
    float mm = static_cast<float>(session.slabMm);
    if (ImGui::SliderFloat("thickness (mm)", &mm, 0.5f, 100.0f, "%.1f", ImGuiSliderFlags_Logarithmic)) {
      session.slabMm = std::max(0.1f, mm);
    }
    ImGui::Text("crosshair %.1f, %.1f, %.1f mm", session.crosshair.x, session.crosshair.y, session.crosshair.z);
    if (ImGui::Button("reset planes")) session.mprRotation = Mat4::identity();
    ImGui::SameLine();
    if (ImGui::Button("reset zoom")) resetMprViews();
  }

  if (ImGui::CollapsingHeader("Measurements", ImGuiTreeNodeFlags_DefaultOpen)) {
    const char* tools[] = {"window/level (w)", "crosshair (x)", "distance (l)", "angle (a)", "ellipse (e)", "rectangle (b)"};
    int tool = static_cast<int>(controller_.tool);
    if (ImGui::Combo("tool", &tool, tools, 6)) controller_.tool = static_cast<Tool>(tool);
    int remove = -1;
    for (std::size_t i = 0; i < session.measurements.size(); ++i) {
      const Measurement& m = session.measurements[i];
      ImGui::PushID(static_cast<int>(i));
      if (ImGui::SmallButton("x")) remove = static_cast<int>(i);
      ImGui::SameLine();
      std::string text;
      if (m.kind == MeasureKind::Ellipse || m.kind == MeasureKind::Rectangle) {
        const RoiStats st = roiStatsOf(m);
        text = describe(m, &st, valueUnit_, labelDecimals());
      } else {
        text = describe(m);
      }
      ImGui::TextWrapped("%s %s: %s", viewName(m.view), measureKindName(m.kind), text.c_str());
      ImGui::PopID();
    }
    if (remove >= 0) session.measurements.erase(session.measurements.begin() + remove);
  }
  ImGui::PopItemWidth();
  ImGui::End();
}

void App::drawStatusBar() {
  const float h = ImGui::GetFrameHeight() + 6;
  ImGui::SetNextWindowPos(ImVec2(0, static_cast<float>(fbHeight_) - h));
  ImGui::SetNextWindowSize(ImVec2(static_cast<float>(fbWidth_), h));
  ImGui::PushStyleVar(ImGuiStyleVar_WindowPadding, ImVec2(8, 3));
  ImGui::Begin("##status", nullptr, ImGuiWindowFlags_NoTitleBar | ImGuiWindowFlags_NoMove | ImGuiWindowFlags_NoResize |
                                        ImGuiWindowFlags_NoSavedSettings | ImGuiWindowFlags_NoScrollbar);
  // Compact, so the whole line fits a 1280-pixel window.
  std::string line = fmt::format("{:.0f} fps", fps_);
  if (view3d_) {
    const gpu::FrameStats& s = view3d_->stats();
    const uint64_t read = view3d_->bytesRead() + (slicer_ ? slicer_->stats().bytesRead : 0);
    const std::size_t queued = static_cast<std::size_t>(s.loaderQueued) + (slicer_ ? slicer_->stats().queued : 0);
    line += fmt::format("  \u2502  3D {:.0f} ms  \u2502  working set {} bricks  \u2502  pool {}/{} ({}/{} MiB)"
                        "  \u2502  cache {}/{} MiB  \u2502  queue {}  \u2502  read {} MiB",
                        view3d_->lastFrameMs(), s.workingSet.bricks, s.poolSlotsUsed, s.poolSlots,
                        s.poolBytesUsed >> 20, s.poolBytes >> 20, s.cacheBytes >> 20, s.cacheBudgetBytes >> 20,
                        queued, read >> 20);
  }
  if (grid_) {
    const Vec3 sp{length(grid_->patientFromIndex.column(0)), length(grid_->patientFromIndex.column(1)),
                  length(grid_->patientFromIndex.column(2))};
    line += fmt::format("  \u2502  {}\u00d7{}\u00d7{}, {:.3g}\u00d7{:.3g}\u00d7{:.3g} mm", grid_->dims[0], grid_->dims[1],
                        grid_->dims[2], sp.x, sp.y, sp.z);
  }
  line += fmt::format("  \u2502  {}", toolName(controller_.tool));
  ImGui::TextUnformatted(line.c_str());
  ImGui::End();
  ImGui::PopStyleVar();
}

void App::drawHelp() {
  ImGui::SetNextWindowSize(ImVec2(620, 560), ImGuiCond_FirstUseEver);
  ImGui::SetNextWindowPos(ImVec2(static_cast<float>(viewArea_.x + 40), static_cast<float>(viewArea_.y + 40)), ImGuiCond_FirstUseEver);
  ImGui::Begin("Mouse and keyboard", &showHelp, ImGuiWindowFlags_NoSavedSettings);
  static const char* rows[][2] = {
      {"MPR views", ""},
      {"left-drag", "current tool; window/level by default: right = wider window, up = higher level (window/200 per pixel)"},
      {"Shift + left-click/drag", "move the crosshair (the other views follow)"},
      {"Ctrl + left-drag", "rotate the other planes about this view's normal (oblique MPR)"},
      {"middle-drag", "pan"},
      {"right-drag / Ctrl + wheel", "zoom"},
      {"wheel, Up/Down, Left/Right", "previous/next slice"},
      {"PageUp / PageDown", "10 slices"},
      {"r", "reset zoom and pan"},
      {"3D view", ""},
      {"left-drag", "rotate (trackball)"},
      {"middle-drag", "pan"},
      {"right-drag / wheel", "zoom"},
      {"r", "reset the camera"},
      {"Shift + A P L R S I", "anterior, posterior, left, right, superior, inferior view"},
      {"Everywhere", ""},
      {"1 - 9", "window/level presets (table in the side panel)"},
      {"0", "auto window/level: 0.1st to 99.9th percentile of the volume's values"},
      {"w x l a e b", "tools: window/level, crosshair, distance, angle, ellipse, rectangle"},
      {"Delete", "remove the last measurement"},
      {"double-click / f", "maximise a view, and back"},
      {"o", "overlays on/off"},
      {"Ctrl + O", "open a file or folder (or drop it on the window)"},
      {"F1", "this window"},
      {"Esc", "cancel a measurement, close this window"},
  };
  if (ImGui::BeginTable("help", 2, ImGuiTableFlags_RowBg | ImGuiTableFlags_SizingStretchProp)) {
    for (const auto& r : rows) {
      ImGui::TableNextRow();
      ImGui::TableNextColumn();
      if (r[1][0] == '\0') {
        ImGui::TextColored(ImVec4(0.55f, 0.75f, 1.0f, 1.0f), "%s", r[0]);
      } else {
        ImGui::TextUnformatted(r[0]);
        ImGui::TableNextColumn();
        ImGui::TextWrapped("%s", r[1]);
      }
    }
    ImGui::EndTable();
  }
  ImGui::End();
}

void App::drawFileDialog() {
  ImGui::SetNextWindowSize(ImVec2(640, 460), ImGuiCond_FirstUseEver);
  ImGui::SetNextWindowPos(ImVec2(static_cast<float>(viewArea_.x + 60), static_cast<float>(viewArea_.y + 40)), ImGuiCond_FirstUseEver);
  ImGui::Begin("Open", &showFileDialog, ImGuiWindowFlags_NoSavedSettings);
  static char buffer[4096];
  static std::string shownDir;
  if (shownDir != fileDialogPath_) {  // a new folder: its path in the box
    std::snprintf(buffer, sizeof(buffer), "%s", fileDialogPath_.c_str());
    shownDir = fileDialogPath_;
  }
  ImGui::SetNextItemWidth(-150);
  if (ImGui::InputText("##path", buffer, sizeof(buffer), ImGuiInputTextFlags_EnterReturnsTrue)) fileDialogPath_ = buffer;
  ImGui::SameLine();
  if (ImGui::Button("Open this")) {
    open(buffer);
    showFileDialog = false;
  }
  ImGui::SameLine();
  if (ImGui::Button("Up")) fileDialogPath_ = fs::path(fileDialogPath_).parent_path().string();
  ImGui::TextDisabled("A store (.octoray), a DICOM folder/DICOMDIR/file, NRRD, MHD, NIfTI or TIFF");
  ImGui::BeginChild("entries", ImVec2(0, 0), true);
  std::error_code ec;
  std::vector<fs::directory_entry> entries;
  for (const auto& e : fs::directory_iterator(fileDialogPath_, fs::directory_options::skip_permission_denied, ec)) {
    if (e.path().filename().string().starts_with(".")) continue;
    entries.push_back(e);
  }
  std::sort(entries.begin(), entries.end(), [](const auto& a, const auto& b) {
    if (a.is_directory() != b.is_directory()) return a.is_directory();
    return a.path().filename() < b.path().filename();
  });
  for (const auto& e : entries) {
    const std::string name = e.path().filename().string() + (e.is_directory() ? "/" : "");
    if (ImGui::Selectable(name.c_str(), false, ImGuiSelectableFlags_AllowDoubleClick)) {
      if (ImGui::IsMouseDoubleClicked(0)) {
        if (e.is_directory()) fileDialogPath_ = e.path().string();
        else {
          open(e.path().string());
          showFileDialog = false;
        }
      } else {
        std::snprintf(buffer, sizeof(buffer), "%s", e.path().string().c_str());
      }
    }
  }
  if (ec) ImGui::TextColored(ImVec4(1, 0.4f, 0.4f, 1), "%s: %s", fileDialogPath_.c_str(), ec.message().c_str());
  ImGui::EndChild();
  ImGui::End();
}

}  // namespace octoray::viewer
