#pragma once
// Cameras in patient space (DICOM LPS, mm). A camera is an eye, a target and an up vector
// with a perspective field of view or an orthographic view height, and the image size; every
// renderer turns a pixel into a ray through the same rule (Camera::ray).
//
// Orbit conventions (orbitCamera), fixed so that the same numbers give the same view in every
// tool and test:
//   - the orbit centre is the centre of the volume's domain in patient space;
//   - azimuth 0, elevation 0 looks from the patient's anterior (-Y in LPS) towards posterior,
//     superior (+Z) up, so the patient's left (+X) appears on the image's right (the usual
//     "anterior view");
//   - positive azimuth moves the eye towards the patient's left: azimuth 90 looks from the
//     left (+X) towards the right, azimuth 180 from posterior;
//   - positive elevation moves the eye towards superior (+Z): elevation 90 looks down from
//     above the head, the image's up then pointing to posterior (+Y) at azimuth 0;
//   - zoom 1 frames the bounding sphere of the domain exactly (the sphere touches the top and
//     bottom of the image); zoom 2 halves the visible height.
// Pixel (x, y) has its centre at (x + 0.5, y + 0.5); y = 0 is the top row.

#include <filesystem>
#include <string>

#include <nlohmann/json_fwd.hpp>

#include "octoray/core/geometry.h"

namespace octoray {
struct VolumeInfo;
}

namespace octoray::gpu {

enum class Projection { Perspective, Orthographic };

struct Ray {
  Vec3 origin;     // patient space, mm
  Vec3 direction;  // patient space, unit length
};

struct Camera {
  Projection projection = Projection::Perspective;
  Vec3 eye{0, -500, 0};
  Vec3 target{0, 0, 0};
  Vec3 up{0, 0, 1};              // need not be orthogonal to the view direction, not parallel
  double fovYDegrees = 30.0;     // perspective: full vertical field of view, in (0, 180)
  double orthoHeightMm = 300.0;  // orthographic: visible height in mm
  int width = 512;
  int height = 512;

  // The ray through the centre of pixel (x, y); x, y may be fractional. Perspective rays start
  // at the eye; orthographic rays start on the plane through the eye facing the target.
  Ray ray(double x, double y) const;
  // tan(fovYDegrees / 2): the half-height of the perspective image at unit distance.
  double tanHalfFovY() const;
  // Throws octoray::Error when the camera cannot form rays (eye == target, up parallel to the
  // view direction, non-finite values, bad field of view or size).
  void validate() const;
};

// The box the renderers draw: voxel centres at integer indices, each voxel owning the cube of
// half-width 0.5 around its centre, so the domain is [-0.5, dim - 0.5] per index axis.
struct VolumeDomain {
  std::array<int64_t, 3> dims{1, 1, 1};
  Mat4 patientFromIndex;

  static VolumeDomain of(const VolumeInfo& info);
  Vec3 centrePatient() const;
  // Radius of the smallest sphere about centrePatient() holding the domain's 8 corners.
  double boundingRadiusMm() const;
};

struct OrbitParameters {
  double azimuthDegrees = 0;
  double elevationDegrees = 0;
  double zoom = 1;
  Projection projection = Projection::Perspective;
  double fovYDegrees = 30.0;
  int width = 512;
  int height = 512;
};

// A camera orbiting the domain's centre (conventions above). Throws octoray::Error on a
// non-positive or non-finite zoom or a bad size.
Camera orbitCamera(const VolumeDomain& domain, const OrbitParameters& orbit);

// `camera` turned by `degrees` about the line through `centre` along its up vector (eye and
// target move; the up vector stays): the timing loops' --orbit for cameras from a file.
Camera turnAboutCentre(const Camera& camera, Vec3 centre, double degrees);

// Camera JSON: {"projection": "perspective"|"orthographic", "eye": [x,y,z], "target": [...],
// "up": [...], "fovYDegrees": f, "orthoHeightMm": h, "width": w, "height": h}; every field
// required on load. Throws octoray::Error naming `path` and the field at fault.
nlohmann::json cameraToJson(const Camera& camera);
Camera cameraFromJson(const nlohmann::json& json, const std::string& path = {});
void saveCamera(const Camera& camera, const std::filesystem::path& path);
Camera loadCamera(const std::filesystem::path& path);

}  // namespace octoray::gpu
