#pragma once
// The viewing session: everything a reader sets while looking at one volume, apart from the
// views that draw it and the panels that edit it (f3d's application/library seam). Input
// handlers (controller.h) turn mouse and key events, real or replayed, into changes of this
// model; the views (3D, MPR, overlays) read it each frame; the session JSON saves exactly this
// struct (docs/session-json.md).
//
// Geometry is patient space (DICOM LPS, mm). The three MPR planes share one orientation
// `mprRotation` (identity: axial, coronal and sagittal) and pass through `crosshair`.

#include <array>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json_fwd.hpp>

#include "octoray/core/geometry.h"
#include "octoray/gpu/camera.h"
#include "octoray/gpu/working_set.h"
#include "octoray/transfer/defaults.h"
#include "octoray/transfer/transfer_function.h"

namespace octoray::viewer {

// The four views, in the four-up order (axial top left, 3D top right, coronal bottom left,
// sagittal bottom right is the layout's business; this is their identity).
enum class ViewId { Axial = 0, Coronal = 1, Sagittal = 2, Volume = 3 };
inline constexpr int kViewCount = 4;
inline bool isMpr(ViewId v) { return v != ViewId::Volume; }
const char* viewName(ViewId v);                // "axial", "coronal", "sagittal", "3d"
ViewId parseViewName(const std::string& name);  // throws octoray::Error

enum class Layout { FourUp, OneUp, OnePlusThree };
const char* layoutName(Layout l);               // "four-up", "one-up", "1+3"
Layout parseLayoutName(const std::string& name);

enum class SlabMode { None, Mip, MinIp, Mean };
const char* slabModeName(SlabMode m);  // "none", "mip", "minip", "mean"
SlabMode parseSlabMode(const std::string& name);

const char* modeName(gpu::RaycastMode m);  // "dvr", "iso", "mip"
gpu::RaycastMode parseModeName(const std::string& name);

struct WindowLevel {
  double window = 400;  // HU, > 0
  double level = 40;    // HU
};

// Per MPR view: zoom 1 fits the volume's extent in the view; pan moves the view centre (mm,
// along the view's screen right and down directions).
struct MprViewState {
  double zoom = 1;
  double panRightMm = 0, panDownMm = 0;
};

enum class MeasureKind { Distance, Angle, Ellipse, Rectangle };
const char* measureKindName(MeasureKind k);  // "distance", "angle", "ellipse", "rectangle"
MeasureKind parseMeasureKind(const std::string& name);

// A measurement made in an MPR view. Points are patient positions: distance 2 (ends), angle 3
// (first arm, vertex, second arm), ellipse/rectangle 2 (opposite corners of the bounding box
// in the view's plane, whose screen axes `right` and `down` are kept with it).
struct Measurement {
  MeasureKind kind = MeasureKind::Distance;
  ViewId view = ViewId::Axial;
  std::vector<Vec3> points;
  Vec3 right{1, 0, 0}, down{0, 1, 0};
};

// The 3D view's crop box, in the volume's index space (voxel centres at integers; the whole
// domain is [-0.5, dim - 0.5] per axis). Edited with handles in the MPR views.
struct ClipBox {
  bool enabled = false;
  Vec3 lo{-0.5, -0.5, -0.5}, hi{0.5, 0.5, 0.5};
};

struct Session {
  std::string source;  // what was opened (a store, a DICOM folder, a volume file)
  Layout layout = Layout::FourUp;
  ViewId mainView = ViewId::Volume;  // the big view of one-up and 1+3
  // 3D
  gpu::Camera camera;                  // width/height follow the 3D view's size on screen
  std::string preset = "bone";         // name of the preset `tf` started from
  transfer::TransferFunction tf;       // as edited
  gpu::RaycastMode mode = gpu::RaycastMode::Dvr;
  double isoValue = transfer::kDefaultCtIsoValueHu;  // in the volume's unit (App opens others at theirs)
  double lodPixels = 1.0;              // working-set refinement target (pixels per voxel)
  double stepFactor = 1.0;             // x the renderer's default step
  double earlyTermination = 0.99;
  bool shading = true;                 // DVR: Phong shading when the TF asks for it
  bool preintegration = false;         // DVR still frames: pre-integrated classification (sharp TFs)
  bool interactiveQuality = true;      // half resolution, coarser LOD, image-adaptive rays while moving
  ClipBox clip;
  // MPR
  WindowLevel wl;
  std::string wlPreset = "brain";
  Vec3 crosshair;                      // patient mm: where the three planes meet
  Mat4 mprRotation;                    // rotation of the three planes (oblique MPR)
  SlabMode slab = SlabMode::None;
  double slabMm = 10;                  // slab thickness when slab != None
  std::array<MprViewState, 3> mprViews;
  std::vector<Measurement> measurements;
  // Overlays
  bool overlays = true;                // orientation letters, slice position, W/L, scale bar
  bool patientInfo = false;            // patient name/ID/date corners (off by default)
};

// The JSON of docs/session-json.md ("format": "octoray-session", "version": 1).
nlohmann::json sessionToJson(const Session& session);
// Throws octoray::Error naming `path` and the field at fault; every field is checked.
Session sessionFromJson(const nlohmann::json& json, const std::string& path = {});
void saveSession(const Session& session, const std::filesystem::path& path);  // temp + rename
Session loadSession(const std::filesystem::path& path);

}  // namespace octoray::viewer
