// The transfer-function editor: opacity control points over the volume's HU histogram (drag
// to move, click on empty space to add, right-click to delete), the colour of each point
// below the curve (click a swatch to edit its colour), and the gradient-opacity table.
// Edits change session.tf, which the 3D view re-renders from at once (interactive quality
// while a point is dragged).
#include <imgui.h>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>

#include "app.h"

namespace octoray::viewer {

namespace {

// Whether the editor changed a transfer function's points (an edit makes it the reader's).
bool samePoints(const transfer::TransferFunction& a, const transfer::TransferFunction& b) {
  return std::equal(a.opacity.begin(), a.opacity.end(), b.opacity.begin(), b.opacity.end(),
                    [](const auto& x, const auto& y) { return x.value == y.value && x.alpha == y.alpha; }) &&
         std::equal(a.color.begin(), a.color.end(), b.color.begin(), b.color.end(),
                    [](const auto& x, const auto& y) {
                      return x.value == y.value && x.r == y.r && x.g == y.g && x.b == y.b;
                    }) &&
         std::equal(a.gradientOpacity.begin(), a.gradientOpacity.end(), b.gradientOpacity.begin(),
                    b.gradientOpacity.end(),
                    [](const auto& x, const auto& y) { return x.magnitude == y.magnitude && x.alpha == y.alpha; });
}

}  // namespace

void App::drawTfEditor() {
  transfer::TransferFunction& tf = session.tf;
  if (!ImGui::TreeNodeEx("Transfer function", ImGuiTreeNodeFlags_DefaultOpen)) return;
  const transfer::TransferFunction before = tf;
  const ImVec2 size(ImGui::GetContentRegionAvail().x, 140);
  const ImVec2 p0 = ImGui::GetCursorScreenPos();
  const ImVec2 p1(p0.x + size.x, p0.y + size.y);
  ImGui::InvisibleButton("tf-canvas", size, ImGuiButtonFlags_MouseButtonLeft | ImGuiButtonFlags_MouseButtonRight);
  ImDrawList* dl = ImGui::GetWindowDrawList();
  dl->AddRectFilled(p0, p1, IM_COL32(20, 20, 24, 255));
  // The value axis: the histogram's range (the store's minimum to maximum), in the volume's unit.
  const double lo = histLo_, hi = histHi_;
  const std::string unit = unitSuffix(valueUnit_);
  const std::string gradientLabel =
      (valueUnit_.empty() ? std::string("per mm") : valueUnit_ + "/mm") + ", alpha";
  auto xOf = [&](double v) { return p0.x + static_cast<float>((v - lo) / (hi - lo)) * size.x; };
  auto vOf = [&](float x) { return lo + (x - p0.x) / size.x * (hi - lo); };
  auto yOf = [&](float a) { return p1.y - a * size.y; };
  if (!histogram_.empty()) {
    int peak = 1;
    for (std::size_t i = 1; i + 1 < histogram_.size(); ++i) peak = std::max(peak, histogram_[i]);  // ends are air/clamp
    const float bw = size.x / static_cast<float>(histogram_.size());
    for (std::size_t i = 0; i < histogram_.size(); ++i) {
      const float h = std::min(1.0f, std::log1p(static_cast<float>(histogram_[i])) / std::log1p(static_cast<float>(peak)));
      dl->AddRectFilled(ImVec2(p0.x + i * bw, p1.y - h * size.y), ImVec2(p0.x + (i + 1) * bw, p1.y), IM_COL32(70, 70, 78, 255));
    }
  }
  // Colour band under the curve.
  for (int i = 0; i < 64; ++i) {
    const double v = lo + (hi - lo) * (i + 0.5) / 64;
    const auto c = tf.evaluate(v);
    const float a = tf.opacityAt(v);
    dl->AddRectFilled(ImVec2(p0.x + size.x * i / 64, yOf(std::min(1.0f, a))), ImVec2(p0.x + size.x * (i + 1) / 64, p1.y),
                      ImGui::ColorConvertFloat4ToU32(ImVec4(c[0] / std::max(1e-6f, c[3]), c[1] / std::max(1e-6f, c[3]),
                                                            c[2] / std::max(1e-6f, c[3]), 0.35f)));
  }
  // The opacity curve and its points.
  static int dragging = -1;
  const ImVec2 mouse = ImGui::GetIO().MousePos;
  int hovered = -1;
  for (std::size_t i = 0; i < tf.opacity.size(); ++i) {
    const ImVec2 q(xOf(tf.opacity[i].value), yOf(tf.opacity[i].alpha));
    if (i + 1 < tf.opacity.size()) {
      dl->AddLine(q, ImVec2(xOf(tf.opacity[i + 1].value), yOf(tf.opacity[i + 1].alpha)), IM_COL32(240, 240, 240, 255), 1.5f);
    }
    if (std::abs(mouse.x - q.x) < 6 && std::abs(mouse.y - q.y) < 6) hovered = static_cast<int>(i);
  }
  for (std::size_t i = 0; i < tf.opacity.size(); ++i) {
    const ImVec2 q(xOf(tf.opacity[i].value), yOf(tf.opacity[i].alpha));
    dl->AddCircleFilled(q, 4.5f, static_cast<int>(i) == hovered || static_cast<int>(i) == dragging ? IM_COL32(255, 200, 60, 255)
                                                                                                   : IM_COL32(255, 255, 255, 255));
  }
  if (ImGui::IsItemActive() && ImGui::IsMouseClicked(ImGuiMouseButton_Left)) {
    if (hovered >= 0) {
      dragging = hovered;
    } else {
      const double v = vOf(mouse.x);
      const float a = std::clamp((p1.y - mouse.y) / size.y, 0.0f, 1.0f);
      tf.opacity.push_back({v, a});
      std::sort(tf.opacity.begin(), tf.opacity.end(), [](auto& x, auto& y) { return x.value < y.value; });
      markInteraction();
    }
  }
  if (dragging >= 0 && ImGui::IsMouseDown(ImGuiMouseButton_Left) && dragging < static_cast<int>(tf.opacity.size())) {
    const std::size_t i = static_cast<std::size_t>(dragging);
    const double vmin = i > 0 ? tf.opacity[i - 1].value : lo - 1e6;
    const double vmax = i + 1 < tf.opacity.size() ? tf.opacity[i + 1].value : hi + 1e6;
    tf.opacity[i].value = std::clamp(vOf(mouse.x), vmin, vmax);
    tf.opacity[i].alpha = std::clamp((p1.y - mouse.y) / size.y, 0.0f, 1.0f);
    markInteraction();
  } else {
    dragging = -1;
  }
  if (hovered >= 0 && ImGui::IsItemHovered() && ImGui::IsMouseClicked(ImGuiMouseButton_Right) && tf.opacity.size() > 1) {
    tf.opacity.erase(tf.opacity.begin() + hovered);
  }
  if (hovered >= 0) {
    ImGui::SetTooltip("%.*f%s, opacity %.3f", labelDecimals(), tf.opacity[static_cast<std::size_t>(hovered)].value, unit.c_str(),
                      tf.opacity[static_cast<std::size_t>(hovered)].alpha);
  }
  dl->AddRect(p0, p1, IM_COL32(90, 90, 100, 255));
  ImGui::TextDisabled("%.*f%s", labelDecimals(), lo, unit.c_str());
  ImGui::SameLine(ImGui::GetContentRegionAvail().x - 60);
  ImGui::TextDisabled("%.*f%s", labelDecimals(), hi, unit.c_str());

  // Colour points: swatches, each editable.
  ImGui::TextUnformatted("colour points");
  for (std::size_t i = 0; i < tf.color.size(); ++i) {
    ImGui::PushID(static_cast<int>(i));
    float c[3] = {tf.color[i].r, tf.color[i].g, tf.color[i].b};
    if (ImGui::ColorEdit3("##c", c, ImGuiColorEditFlags_NoInputs)) {
      tf.color[i].r = c[0];
      tf.color[i].g = c[1];
      tf.color[i].b = c[2];
      markInteraction();
    }
    if (ImGui::IsItemHovered()) ImGui::SetTooltip("%.*f%s", labelDecimals(), tf.color[i].value, unit.c_str());
    if ((i + 1) % 10 != 0) ImGui::SameLine();
    ImGui::PopID();
  }
  ImGui::NewLine();
  // Gradient opacity: |gradient| (unit/mm) -> multiplier.
  if (ImGui::TreeNode("gradient opacity")) {
    int remove = -1;
    for (std::size_t i = 0; i < tf.gradientOpacity.size(); ++i) {
      ImGui::PushID(static_cast<int>(i));
      float g[2] = {static_cast<float>(tf.gradientOpacity[i].magnitude), tf.gradientOpacity[i].alpha};
      ImGui::SetNextItemWidth(180);
      if (ImGui::InputFloat2(gradientLabel.c_str(), g, "%.2f")) {
        const double lowest = i > 0 ? tf.gradientOpacity[i - 1].magnitude : 0.0;
        tf.gradientOpacity[i].magnitude = std::max(static_cast<double>(g[0]), lowest);
        tf.gradientOpacity[i].alpha = std::clamp(g[1], 0.0f, 1.0f);
      }
      ImGui::SameLine();
      if (ImGui::SmallButton("x")) remove = static_cast<int>(i);
      ImGui::PopID();
    }
    if (remove >= 0) tf.gradientOpacity.erase(tf.gradientOpacity.begin() + remove);
    if (ImGui::SmallButton("add point")) {
      const double m = tf.gradientOpacity.empty() ? 0.0 : tf.gradientOpacity.back().magnitude + 10;
      tf.gradientOpacity.push_back({m, 1.0f});
    }
    ImGui::TreePop();
  }
  ImGui::TreePop();
  if (!samePoints(before, tf)) tfChosenForDataset_ = true;
}

}  // namespace octoray::viewer
