// Drawing the views and their overlays: each view's texture 1:1 at its rectangle, then on top
// (when the session's overlays are on) orientation letters at the edges, the view's name and
// slice position, slab, window/level, a scale bar, the other planes' lines, the HU probe, and
// the measurements. Patient corners only when asked (and never in a screenshot unless asked).
#include <imgui.h>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>

#include "app.h"

namespace octoray::viewer {
namespace {

// Slicer's view colours: red axial, green coronal, yellow sagittal; the 3D view's is blue.
ImU32 viewColour(ViewId v, int alpha = 255) {
  switch (v) {
    case ViewId::Axial: return IM_COL32(230, 80, 70, alpha);
    case ViewId::Coronal: return IM_COL32(90, 200, 90, alpha);
    case ViewId::Sagittal: return IM_COL32(235, 205, 70, alpha);
    case ViewId::Volume: return IM_COL32(90, 150, 235, alpha);
  }
  return IM_COL32_WHITE;
}

const char* viewTitle(ViewId v) {
  switch (v) {
    case ViewId::Axial: return "Axial";
    case ViewId::Coronal: return "Coronal";
    case ViewId::Sagittal: return "Sagittal";
    case ViewId::Volume: return "3D";
  }
  return "";
}

// Text with a dark outline so it stays legible on any image.
void outlinedText(ImDrawList* dl, ImFont* font, float size, ImVec2 p, ImU32 colour, const std::string& text) {
  const ImU32 shadow = IM_COL32(0, 0, 0, 220);
  for (int dx = -1; dx <= 1; ++dx) {
    for (int dy = -1; dy <= 1; ++dy) {
      if (dx || dy) dl->AddText(font, size, ImVec2(p.x + dx, p.y + dy), shadow, text.c_str());
    }
  }
  dl->AddText(font, size, p, colour, text.c_str());
}

ImVec2 textSize(ImFont* font, float size, const std::string& text) {
  return font->CalcTextSizeA(size, 10000.0f, 0.0f, text.c_str());
}

// A nice scale-bar length (1, 2, 5 x 10^n mm) close to `target` mm.
double niceLength(double target) {
  const double p = std::pow(10.0, std::floor(std::log10(std::max(1e-6, target))));
  for (double m : {5.0, 2.0, 1.0}) {
    if (m * p <= target) return m * p;
  }
  return p;
}

std::string positionText(Vec3 normal, double position) {
  // The slice position along the view's normal, named by the direction it points to (Slicer's
  // "S: 12.5mm"), from the patient-space origin.
  const std::string letter = orientationLabel(normal).substr(0, 1);
  return fmt::format("{} {:.1f} mm", letter, position);
}

}  // namespace

void App::drawViews() {
  ImDrawList* dl = ImGui::GetBackgroundDrawList();
  ImFont* font = overlayFont_ ? overlayFont_ : ImGui::GetFont();
  const float fs = font->FontSize;
  const ImU32 text = IM_COL32(235, 235, 225, 255);
  const ImU32 dim = IM_COL32(175, 180, 185, 255);
  dl->AddRectFilled(ImVec2(static_cast<float>(viewArea_.x), static_cast<float>(viewArea_.y)),
                    ImVec2(static_cast<float>(viewArea_.x + viewArea_.w), static_cast<float>(viewArea_.y + viewArea_.h)),
                    IM_COL32(45, 45, 50, 255));
  const ImVec2 mouse = ImGui::GetIO().MousePos;
  for (int v = 0; v < kViewCount; ++v) {
    // Each text drawn over the view is also kept for the state a script dumps (overlayText_).
    auto& drawn = overlayText_[static_cast<std::size_t>(v)];
    drawn.clear();
    const auto put = [&](float size, ImVec2 at, ImU32 colour, const std::string& t) {
      drawn.push_back(t);
      outlinedText(dl, font, size, at, colour, t);
    };
    const ViewId id = static_cast<ViewId>(v);
    const Rect r = viewRect(id);
    if (r.w < 8 || r.h < 8) continue;
    const ImVec2 a(static_cast<float>(r.x), static_cast<float>(r.y));
    const ImVec2 b(static_cast<float>(r.x + r.w), static_cast<float>(r.y + r.h));
    dl->AddRectFilled(a, b, IM_COL32(0, 0, 0, 255));
    dl->PushClipRect(a, b, true);
    const bool overlays = session.overlays;

    if (id == ViewId::Volume) {
      if (view3d_ && view3d_->texture()) {
        dl->AddImage(reinterpret_cast<ImTextureID>(static_cast<intptr_t>(view3d_->texture())), a, b);
      }
      if (overlays) {
        put(fs, ImVec2(a.x + 8, a.y + 6), viewColour(id), viewTitle(id));
        std::string line = fmt::format("{}  {}", modeName(session.mode), session.preset);
        if (session.mode == gpu::RaycastMode::Iso) line = fmt::format("iso {:.{}f}{}", session.isoValue, valueDecimals(histHi_ - histLo_), unitSuffix(valueUnit_));
        std::transform(line.begin(), line.begin() + 3, line.begin(), ::toupper);
        put(fs, ImVec2(a.x + 8, a.y + 8 + fs), text, line);
        if (view3d_) {
          // Interactive frames are post-classified whatever the box says (views.cpp).
          const bool pre = session.preintegration && session.mode == gpu::RaycastMode::Dvr;
          const std::string q = view3d_->converged() ? (pre ? "full quality, pre-integrated" : "full quality")
                                : (controller_.dragging3d() || interactionFrames_ > 0) ? "interactive (half resolution)"
                                                                                         : "refining\u2026";
          put(fs * 0.9f, ImVec2(a.x + 8, b.y - fs - 6), dim, q);
          // The screen's right and up as patient directions.
          const gpu::Camera& c = session.camera;
          const Vec3 forward = normalize(c.target - c.eye);
          const Vec3 right = normalize(cross(forward, c.up));
          const Vec3 up = normalize(cross(right, forward));
          const std::string rl = orientationLabel(right), ll = orientationLabel(-1.0 * right);
          const std::string ul = orientationLabel(up), dl2 = orientationLabel(-1.0 * up);
          put(fs, ImVec2(b.x - textSize(font, fs, rl).x - 6, a.y + r.h * 0.5f - fs * 0.5f), dim, rl);
          put(fs, ImVec2(a.x + 6, a.y + r.h * 0.5f - fs * 0.5f), dim, ll);
          put(fs, ImVec2(a.x + r.w * 0.5f - textSize(font, fs, ul).x * 0.5f, a.y + 6), dim, ul);
          put(fs, ImVec2(a.x + r.w * 0.5f - textSize(font, fs, dl2).x * 0.5f, b.y - fs - 6), dim, dl2);
        }
      }
      if (!view3d_) {
        std::string msg;
        if (!dataset_) msg = "Open a CT volume: File \u25b8 Open (Ctrl+O), drop a file or folder here,\nor start octoray-view PATH";
        else if (dataset_->state() == Dataset::State::Importing)
          msg = fmt::format("Importing \u2014 {} ({:.0f}%)\nthe 3D view appears when the store is built", dataset_->status(),
                            100 * dataset_->progress());
        else if (dataset_->state() == Dataset::State::Failed) msg = "Nothing to show: see the message above";
        else msg = "The 3D view could not start: see the message above";
        const ImVec2 ts = textSize(font, fs, msg);
        put(fs, ImVec2(a.x + (r.w - ts.x) * 0.5f, a.y + (r.h - ts.y) * 0.5f), text, msg);
        if (dataset_ && dataset_->state() == Dataset::State::Importing) {
          const float w = std::min(300.0f, r.w - 40.0f), y = a.y + (r.h + ts.y) * 0.5f + 12;
          const float x0 = a.x + (r.w - w) * 0.5f;
          dl->AddRect(ImVec2(x0, y), ImVec2(x0 + w, y + 10), dim);
          dl->AddRectFilled(ImVec2(x0 + 2, y + 2), ImVec2(x0 + 2 + (w - 4) * static_cast<float>(dataset_->progress()), y + 8),
                            viewColour(ViewId::Volume));
        }
      }
      dl->PopClipRect();
      continue;
    }

    // MPR view.
    const MprView* mv = mpr_[static_cast<std::size_t>(v)].get();
    if (mv && mv->texture()) {
      dl->AddImage(reinterpret_cast<ImTextureID>(static_cast<intptr_t>(mv->texture())), a, b);
    }
    if (mv && grid_) {
      const MprPlane& p = mv->plane();
      auto toScreen = [&](Vec3 q) {
        const auto px = p.pixelOf(q);
        return ImVec2(a.x + static_cast<float>(px[0]), a.y + static_cast<float>(px[1]));
      };
      if (overlays) {
        // The other planes' intersections with this one, through the crosshair.
        const ImVec2 c = toScreen(session.crosshair);
        for (int o = 0; o < 3; ++o) {
          if (o == v) continue;
          Vec3 rr, dd, nn;
          viewAxes(static_cast<ViewId>(o), session.mprRotation, rr, dd, nn);
          const Vec3 dir = cross(p.normal, nn);
          if (length(dir) < 1e-6) continue;
          const Vec3 d = normalize(dir);
          const float ux = static_cast<float>(dot(d, p.right)), uy = static_cast<float>(dot(d, p.down));
          const float len = static_cast<float>(r.w + r.h);
          // A gap around the crosshair so the anatomy under it stays visible.
          const float gap = 12.0f;
          dl->AddLine(ImVec2(c.x - ux * len, c.y - uy * len), ImVec2(c.x - ux * gap, c.y - uy * gap), viewColour(static_cast<ViewId>(o), 170), 1.0f);
          dl->AddLine(ImVec2(c.x + ux * gap, c.y + uy * gap), ImVec2(c.x + ux * len, c.y + uy * len), viewColour(static_cast<ViewId>(o), 170), 1.0f);
        }
        // Orientation letters at the middle of each edge.
        const std::string right = orientationLabel(p.right), left = orientationLabel(-1.0 * p.right);
        const std::string bottom = orientationLabel(p.down), top = orientationLabel(-1.0 * p.down);
        const float big = fs * 1.15f;
        put(big, ImVec2(b.x - textSize(font, big, right).x - 8, a.y + r.h * 0.5f - big * 0.5f), text, right);
        put(big, ImVec2(a.x + 8, a.y + r.h * 0.5f - big * 0.5f), text, left);
        put(big, ImVec2(a.x + r.w * 0.5f - textSize(font, big, top).x * 0.5f, a.y + 6), text, top);
        put(big, ImVec2(a.x + r.w * 0.5f - textSize(font, big, bottom).x * 0.5f, b.y - big - 6), text, bottom);
        // Name, slice position, slab.
        put(fs, ImVec2(a.x + 8, a.y + 6), viewColour(id), viewTitle(id));
        put(fs, ImVec2(a.x + 8, a.y + 8 + fs), text,
                     positionText(p.normal, dot(session.crosshair, p.normal)));
        if (session.slab != SlabMode::None) {
          std::string slab = fmt::format("{} slab {:.1f} mm", slabModeName(session.slab), session.slabMm);
          std::transform(slab.begin(), slab.begin() + 5, slab.begin(), ::toupper);
          put(fs, ImVec2(a.x + 8, a.y + 10 + 2 * fs), text, slab);
        }
        // Window/level (bottom left), the level of detail while loading.
        const int decimals = labelDecimals();
        std::string wl = fmt::format("W {:.{}f}  L {:.{}f}", session.wl.window, decimals, session.wl.level, decimals);
        if (!session.wlPreset.empty()) wl += "  " + session.wlPreset;
        put(fs, ImVec2(a.x + 8, b.y - fs - 6), text, wl);
        if (!mv->complete()) {
          const std::string loading = mv->fromPreview() ? "import preview" : "loading finer data\u2026";
          put(fs * 0.9f, ImVec2(a.x + 8, b.y - 2 * fs - 8), dim, loading);
        }
        // Scale bar (bottom right): about a fifth of the view's width.
        const double mm = niceLength(0.2 * r.w * p.mmPerPixel);
        const float px = static_cast<float>(mm / p.mmPerPixel);
        const float y = b.y - 12, x1 = b.x - 16, x0 = x1 - px;
        dl->AddLine(ImVec2(x0, y), ImVec2(x1, y), text, 2.0f);
        dl->AddLine(ImVec2(x0, y - 5), ImVec2(x0, y + 1), text, 2.0f);
        dl->AddLine(ImVec2(x1, y - 5), ImVec2(x1, y + 1), text, 2.0f);
        const std::string label = fmt::format("{:g} mm", mm);
        put(fs * 0.9f, ImVec2(x1 - textSize(font, fs * 0.9f, label).x, y - fs - 6), text, label);
        // HU and position under the cursor.
        if (r.contains(mouse.x, mouse.y) && !shot_) {
          const int mx = static_cast<int>(mouse.x) - r.x, my = static_cast<int>(mouse.y) - r.y;
          const Vec3 q = p.at(mx + 0.5, my + 0.5);
          const double hu = mv->valueAt(mx, my);
          const std::string probe = std::isnan(hu)
                                        ? fmt::format("({:.1f}, {:.1f}, {:.1f}) mm LPS", q.x, q.y, q.z)
                                        : fmt::format("{:.{}f}{}   ({:.1f}, {:.1f}, {:.1f}) mm LPS", hu, decimals,
                                                      unitSuffix(valueUnit_), q.x, q.y, q.z);
          put(fs * 0.9f, ImVec2(b.x - textSize(font, fs * 0.9f, probe).x - 8, a.y + 6), dim, probe);
        }
      }
      if (session.clip.enabled) {
        // The crop box's cross-section, with a handle at the middle of each side.
        const auto section = clipSection(p);
        std::vector<ImVec2> pts;
        for (const Vec3& q : section) pts.push_back(toScreen(q));
        const ImU32 cc = IM_COL32(255, 150, 40, 230);
        if (pts.size() >= 3) {
          dl->AddPolyline(pts.data(), static_cast<int>(pts.size()), cc, ImDrawFlags_Closed, 1.5f);
          for (std::size_t i = 0; i < pts.size(); ++i) {
            const ImVec2 m((pts[i].x + pts[(i + 1) % pts.size()].x) * 0.5f, (pts[i].y + pts[(i + 1) % pts.size()].y) * 0.5f);
            dl->AddRectFilled(ImVec2(m.x - 3.5f, m.y - 3.5f), ImVec2(m.x + 3.5f, m.y + 3.5f), cc);
          }
        }
      }
      if (session.patientInfo && !hidePatientInfo_ && dataset_) {
        // Off by default; never in a screenshot unless the screenshot asks for it.
        const VolumeInfo info = dataset_->info();
        const dicom::PatientIdentity person = dataset_->patient();
        // DICOM dates (YYYYMMDD) as YYYY-MM-DD; absent values left out.
        auto date = [](const std::string& d) {
          return d.size() == 8 ? d.substr(0, 4) + "-" + d.substr(4, 2) + "-" + d.substr(6, 2) : d;
        };
        std::string who;
        if (person.name.empty() && person.id.empty()) {
          who = fmt::format("(the store keeps no patient identity)\n{}  {}", info.description, info.modality);
        } else {
          who = person.name + "\nID " + person.id;
          if (!person.birthDate.empty()) who += "  born " + date(person.birthDate);
          who += "\nstudy " + date(person.studyDate) + "  " + person.studyDescription;
          who += "\n" + info.description + "  " + info.modality;
        }
        // Never recorded: the state a script dumps carries no patient identity.
        outlinedText(dl, font, fs * 0.9f, ImVec2(b.x - textSize(font, fs * 0.9f, who).x - 8, a.y + 8 + fs), dim, who);
      }
      // Measurements of this view (and the one being drawn).
      const ImU32 mc = IM_COL32(120, 230, 255, 255);
      auto drawMeasurement = [&](const Measurement& m, bool finished) {
        if (m.view != id) return;
        // Only where the measurement lies in (or near) the shown plane.
        if (std::abs(dot(m.points[0] - p.origin, p.normal)) > std::max(0.5, 0.5 * grid_->sliceStepMm(p.normal))) return;
        std::vector<ImVec2> pts;
        for (const Vec3& q : m.points) pts.push_back(toScreen(q));
        std::string label;
        if (m.kind == MeasureKind::Distance && pts.size() == 2) {
          dl->AddLine(pts[0], pts[1], mc, 1.5f);
          for (auto& q : pts) dl->AddCircle(q, 3.0f, mc);
          label = describe(m);
        } else if (m.kind == MeasureKind::Angle) {
          for (std::size_t i = 0; i + 1 < pts.size(); ++i) dl->AddLine(pts[i], pts[i + 1], mc, 1.5f);
          for (auto& q : pts) dl->AddCircle(q, 3.0f, mc);
          if (pts.size() == 3) label = describe(m);
        } else if (pts.size() == 2) {
          const Vec3 d = m.points[1] - m.points[0];
          const double du = dot(d, m.right), dv = dot(d, m.down);
          const Vec3 c0 = m.points[0], c1 = m.points[0] + du * m.right, c2 = m.points[1], c3 = m.points[0] + dv * m.down;
          if (m.kind == MeasureKind::Rectangle) {
            dl->AddQuad(toScreen(c0), toScreen(c1), toScreen(c2), toScreen(c3), mc, 1.5f);
          } else {
            const Vec3 centre = m.points[0] + 0.5 * d;
            std::vector<ImVec2> ring;
            for (int i = 0; i < 64; ++i) {
              const double t = 2 * 3.14159265358979 * i / 64;
              ring.push_back(toScreen(centre + (0.5 * du * std::cos(t)) * m.right + (0.5 * dv * std::sin(t)) * m.down));
            }
            dl->AddPolyline(ring.data(), static_cast<int>(ring.size()), mc, ImDrawFlags_Closed, 1.5f);
          }
          if (finished) {
            const RoiStats st = roiStatsOf(m);
            label = st.samples == 0 ? describe(m, &st, valueUnit_, labelDecimals())
                                    : fmt::format("mean {:.{}f} SD {:.{}f}{}\nmin {:.{}f} max {:.{}f}\n{:.1f} mm\u00b2",
                                                  st.mean, labelDecimals() + 1, st.sd, labelDecimals() + 1,
                                                  unitSuffix(valueUnit_), st.min, labelDecimals(), st.max,
                                                  labelDecimals(), st.areaMm2);
          }
        }
        if (!label.empty()) {
          // Beside the last point, kept inside the view.
          const ImVec2 size = textSize(font, fs * 0.9f, label);
          float lx = pts.back().x + 8, ly = pts.back().y + 4;
          if (lx + size.x > b.x - 4) lx = std::max(a.x + 4, pts.back().x - 8 - size.x);
          if (ly + size.y > b.y - 4) ly = std::max(a.y + 4, pts.back().y - 4 - size.y);
          put(fs * 0.9f, ImVec2(lx, ly), mc, label);
        }
      };
      for (const Measurement& m : session.measurements) drawMeasurement(m, true);
      if (controller_.pending()) drawMeasurement(*controller_.pending(), false);
    } else if (!mv || !mv->texture()) {
      const std::string msg = dataset_ ? "" : "No volume";
      const ImVec2 ts = textSize(font, fs, msg);
      put(fs, ImVec2(a.x + (r.w - ts.x) * 0.5f, a.y + (r.h - ts.y) * 0.5f), dim, msg);
    }
    dl->PopClipRect();
  }
}

}  // namespace octoray::viewer
