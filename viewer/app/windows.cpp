// Windows and transfer functions: the table's presets, the automatic window/level, the
// defaults for CT and for other values, and what the reader chose (app.h says when each
// applies). The frame loop and onDatasetReady call in here; the controls call the choosers.
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include "app.h"
#include "octoray/core/error.h"
#include "octoray/transfer/defaults.h"
#include "octoray/transfer/transfer_function_io.h"
#include "octoray/volume/value_histogram.h"

namespace octoray::viewer {

namespace fs = std::filesystem;

void App::computeHistogram() {
  const volume::StoreReader* store = dataset_ ? dataset_->store() : nullptr;
  if (!store) return;
  // Read once, here, when the store is ready (volume::storeHistogram says which level).
  volume::ValueHistogram h = volume::storeHistogram(*store, 256);
  if (!h.problem.empty()) messages.push_back(h.problem);
  histogram_ = std::move(h.counts);
  histLo_ = h.lo;
  histHi_ = h.hi;
}

// ---- model operations ----------------------------------------------------------------------

void App::applyWindowLevelPreset(const WindowLevelPreset& p) {
  session.wl = {p.window, p.level};
  session.wlPreset = p.name;
}

void App::applyAutomaticWindowLevel(const std::vector<int>& counts, double lo, double hi) {
  if (wlChosenForDataset_ || counts.empty()) return;
  if (!autoWlChosen_ && !fileWlPresets_.empty()) return;  // the volume's own window stands
  if (autoWlChosen_ || valueUnit_ != "HU") {
    applyWindowLevelPreset(autoWindowLevel(counts, lo, hi));
    wlUnit_ = valueUnit_;
  } else if (wlUnit_ != "HU" && !wlPresets.empty()) {
    applyWindowLevelPreset(wlPresets.front());  // a CT after a window for other values
    wlUnit_ = "HU";
  }
}

void App::applyAutomaticIsoValue() {
  if (isoChosenForDataset_ || histogram_.empty()) return;
  if (valueUnit_ != "HU") {
    session.isoValue = transfer::automaticIsoValue(histogram_, histLo_, histHi_);
    isoUnit_ = "auto";
  } else if (isoUnit_ != "HU") {
    session.isoValue = transfer::kDefaultCtIsoValueHu;  // a CT after an isovalue for other values
    isoUnit_ = "HU";
  }
}

void App::isoValueChosen() {
  isoChosenForDataset_ = true;
  // Before the store is ready the unit may still be judged: "?" until onDatasetReady says.
  isoUnit_ = slicer_ ? valueUnit_ : "?";
}

void App::applyDefaultTransferFunction() {
  if (tfChosenForDataset_ || histogram_.empty()) return;
  const transfer::DefaultMode mode = session.mode == gpu::RaycastMode::Mip   ? transfer::DefaultMode::Mip
                                     : session.mode == gpu::RaycastMode::Iso ? transfer::DefaultMode::Iso
                                                                             : transfer::DefaultMode::Dvr;
  try {
    session.tf = transfer::defaultTransferFunction(mode, valueUnit_ == "HU", histLo_, histHi_).tf;
    session.preset = session.tf.name;
  } catch (const Error& e) {
    messages.push_back(e.what());
  }
}

void App::modeChanged() {
  if (session.preset.starts_with("default-")) applyDefaultTransferFunction();
}

void App::judgeValueUnit(double minimum) {
  const VolumeInfo info = dataset_->info();
  valueUnit_ = holdsHounsfieldUnits(info.unit, info.modality, info.integerValues, minimum) ? "HU" : "";
  integerValues_ = info.integerValues;
}

VoiFunction App::voiFunction() const { return viewer::voiFunction(declaredVoi_, integerValues_); }

double App::minimumWindow() const {
  // 1 on integer values whatever the function (a narrower window is a threshold there, and the
  // labels carry no decimals to show it).
  return integerValues_ ? 1.0 : std::max(1e-6 * (histHi_ - histLo_), std::numeric_limits<double>::min());
}

int App::labelDecimals() const { return integerValues_ ? 0 : valueDecimals(histHi_ - histLo_); }

void App::windowLevelChosen(bool tablePreset) {
  wlChosenForDataset_ = true;
  autoWlChosen_ = false;
  pendingFileWindow_.clear();  // a later choice replaces one still waiting for the headers
  // Before the store is ready the unit may still be judged: "?" until onDatasetReady says.
  wlUnit_ = tablePreset ? "HU" : slicer_ ? valueUnit_ : "?";
}

void App::applyAutoWindowLevel() {
  autoWlChosen_ = true;
  wlChosenForDataset_ = false;
  pendingFileWindow_.clear();
  session.wlPreset = "auto";
  if (!histogram_.empty()) {
    applyWindowLevelPreset(autoWindowLevel(histogram_, histLo_, histHi_));
    wlUnit_ = valueUnit_;
  } else {
    autoWlPreviewFraction_ = 0;  // the preview's histogram gives it at the next frame
  }
}

void App::chooseWindowLevelPreset(const std::string& name) {
  if (name == "auto") {
    applyAutoWindowLevel();
    return;
  }
  if (name == "file" || name.starts_with("file ")) {
    if (!dataset_) throw Error("", fmt::format("window/level \"{}\": no volume is open", name));
    const auto it = std::find_if(fileWlPresets_.begin(), fileWlPresets_.end(),
                                 [&](const auto& p) { return p.name == name; });
    if (it != fileWlPresets_.end()) {
      applyWindowLevelPreset(*it);
      fileWindowChosen();
    } else if (!fileWindowsFinal_) {
      pendingFileWindow_ = name;  // applied once the volume's headers say (lookAtFileWindows)
    } else if (name != "file" && dataset_->state() != Dataset::State::Failed) {
      // "file" where the volume names none changes nothing; a failed volume says why itself.
      throw Error("", fmt::format("window/level \"{}\": the open volume's file names {} window{}", name,
                                  fileWlPresets_.size(), fileWlPresets_.size() == 1 ? "" : "s"));
    }
    return;
  }
  const auto it = std::find_if(wlPresets.begin(), wlPresets.end(), [&](const auto& p) { return p.name == name; });
  if (it == wlPresets.end()) throw Error("", fmt::format("no window/level preset \"{}\"", name));
  applyWindowLevelPreset(*it);
  windowLevelChosen(true);
}

void App::fileWindowChosen() {
  windowLevelChosen();
  pendingFileWindow_.clear();
  wlUnit_ = "file";  // another volume's own window: the next volume gets its own or the default
}

void App::applyWindowLevelKey(int key) {
  if (key == 0) {
    applyAutoWindowLevel();
    return;
  }
  for (const auto& p : wlPresets) {
    if (p.key == key) {
      applyWindowLevelPreset(p);
      windowLevelChosen(true);
      return;
    }
  }
}

void App::selectTfPreset(const std::string& name) {
  try {
    transfer::TransferFunction tf;
    const auto ours = transfer::presetNames();
    if (std::find(ours.begin(), ours.end(), name) != ours.end()) {
      tf = transfer::findPreset(name);
    } else {
      const fs::path slicerXml = fs::path(OCTORAY_SHARED_DIR) / "data/presets/slicer/presets.xml";
      tf = transfer::selectTransferFunction(transfer::loadTransferFunctions(slicerXml), name,
                                            slicerXml.string());
    }
    session.tf = tf;
    session.preset = name;
    tfChosenForDataset_ = true;
  } catch (const Error& e) {
    messages.push_back(e.what());
  }
}

void App::lookAtFileWindows() {
  if (!dataset_ || fileWindowsFinal_) return;
  // A store's windows are known at once; an import's once its headers are read, and final once
  // it is ready: a series arriving from a PACS shows its first file's until every file is in.
  fileWindowsFinal_ = dataset_->state() != Dataset::State::Importing;
  const std::vector<SourceWindow> windows = dataset_->windows();
  // One VOILUTFunction per file (or per frame): its windows share it.
  declaredVoi_ = windows.empty() ? std::string() : windows.front().function;
  std::vector<WindowLevelPreset> presets = fileWindowLevelPresets(windows);
  const auto same = [](const WindowLevelPreset& a, const WindowLevelPreset& b) {
    return a.name == b.name && a.window == b.window && a.level == b.level && a.source == b.source;
  };
  const bool changed = !std::equal(presets.begin(), presets.end(), fileWlPresets_.begin(), fileWlPresets_.end(), same);
  const bool hadWindows = !fileWlPresets_.empty();  // this volume's: the list is cleared per volume
  fileWlPresets_ = std::move(presets);
  const auto named = [&](const std::string& name) {
    return std::find_if(fileWlPresets_.begin(), fileWlPresets_.end(), [&](const auto& p) { return p.name == name; });
  };
  if (!pendingFileWindow_.empty()) {
    const std::string name = pendingFileWindow_;
    if (const auto it = named(name); it != fileWlPresets_.end()) {
      applyWindowLevelPreset(*it);
      fileWindowChosen();
      return;
    }
    if (fileWindowsFinal_) {
      pendingFileWindow_.clear();
      if (name != "file" && dataset_->state() != Dataset::State::Failed) {
        messages.push_back(fmt::format("{}: window/level \"{}\": its file names {} window{}", dataset_->path(), name,
                                       fileWlPresets_.size(), fileWlPresets_.size() == 1 ? "" : "s"));
      }
    }
    // Meanwhile, or instead, the volume's own first window, as without the request.
  }
  if (!changed) return;
  // A volume's own window in use (automatic or chosen) follows what it names now: a series
  // arriving from a PACS named its first file's windows, the import names most slices'.
  if (hadWindows && wlUnit_ == "file" && session.wlPreset.starts_with("file")) {
    if (const auto it = named(session.wlPreset); it != fileWlPresets_.end()) {
      applyWindowLevelPreset(*it);
      return;
    }
  }
  if (fileWlPresets_.empty() || wlChosenForDataset_ || autoWlChosen_) return;
  applyWindowLevelPreset(fileWlPresets_.front());
  wlUnit_ = "file";
}

void App::lookAtPreview(const PreviewVolume& preview) {
  // While a volume is imported or arrives, the slices in so far are looked at again each time
  // their share doubles: their lowest value judges the unit where the source does not say it,
  // and a volume without HU (or "auto") shows with the auto window/level of those slices,
  // until the reader sets a window; the store's histogram gives the last one.
  // The unit is judged while it is not known to be HU; the window while one is due.
  const bool judging = valueUnit_ != "HU";
  const bool windowDue = !wlChosenForDataset_ && (autoWlChosen_ || (wlUnit_ != "HU" && fileWlPresets_.empty()));
  if (judging || windowDue) {
    const double fraction = preview.fraction();
    if (fraction > 0 && fraction >= 2 * autoWlPreviewFraction_) {
      double lo = 0, hi = 0;
      const std::vector<int> counts = preview.histogram(256, lo, hi);
      if (!counts.empty()) {
        if (histogram_.empty()) {  // the range of the values so far, until the store's
          histLo_ = lo;
          histHi_ = hi;
        }
        judgeValueUnit(lo);
        applyAutomaticWindowLevel(counts, lo, hi);
        autoWlPreviewFraction_ = fraction;
      }
    }
  }
}

}  // namespace octoray::viewer
