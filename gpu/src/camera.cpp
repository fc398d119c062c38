#include "octoray/gpu/camera.h"

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <numbers>

#include "octoray/core/error.h"
#include "octoray/dicom/volume_source.h"

namespace octoray::gpu {
namespace {

constexpr double kDegrees = std::numbers::pi / 180.0;

bool finite(Vec3 v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); }

// Orthonormal view frame: forward, right (image +x) and up (image -y).
struct ViewFrame {
  Vec3 forward, right, up;
};

ViewFrame viewFrame(const Camera& c) {
  ViewFrame f;
  f.forward = normalize(c.target - c.eye);
  f.right = normalize(cross(f.forward, c.up));
  f.up = cross(f.right, f.forward);
  return f;
}

Vec3 vec3FromJson(const nlohmann::json& j, const char* field, const std::string& path) {
  const auto it = j.find(field);
  if (it == j.end() || !it->is_array() || it->size() != 3 || !(*it)[0].is_number() ||
      !(*it)[1].is_number() || !(*it)[2].is_number()) {
    throw Error(path, fmt::format("camera: \"{}\" must be an array of three numbers", field));
  }
  return {(*it)[0].get<double>(), (*it)[1].get<double>(), (*it)[2].get<double>()};
}

template <typename T>
T numberFromJson(const nlohmann::json& j, const char* field, const std::string& path) {
  const auto it = j.find(field);
  if (it == j.end() || !it->is_number()) {
    throw Error(path, fmt::format("camera: \"{}\" must be a number", field));
  }
  if constexpr (std::is_integral_v<T>) {
    if (!it->is_number_integer()) {
      throw Error(path, fmt::format("camera: \"{}\" must be an integer", field));
    }
    const int64_t v = it->get<int64_t>();
    if (v < 1 || v > 65536)
      throw Error(path, fmt::format("camera: \"{}\" must be in [1, 65536]", field));
    return static_cast<T>(v);
  } else {
    return it->get<T>();
  }
}

}  // namespace

double Camera::tanHalfFovY() const { return std::tan(0.5 * fovYDegrees * kDegrees); }

Ray Camera::ray(double x, double y) const {
  const ViewFrame f = viewFrame(*this);
  // Image-plane coordinates in [-1, 1] vertically, scaled by the aspect ratio horizontally.
  const double aspect = static_cast<double>(width) / height;
  const double sx = (2.0 * (x + 0.5) / width - 1.0) * aspect;
  const double sy = 1.0 - 2.0 * (y + 0.5) / height;
  if (projection == Projection::Perspective) {
    const double halfHeight = tanHalfFovY();
    return {eye, normalize(f.forward + (sx * halfHeight) * f.right + (sy * halfHeight) * f.up)};
  }
  const double halfHeightMm = 0.5 * orthoHeightMm;
  return {eye + (sx * halfHeightMm) * f.right + (sy * halfHeightMm) * f.up, f.forward};
}

void Camera::validate() const {
  if (!finite(eye) || !finite(target) || !finite(up)) throw Error("", "camera: non-finite vector");
  if (!(length(target - eye) > 0)) throw Error("", "camera: eye and target coincide");
  const Vec3 forward = normalize(target - eye);
  if (!(length(cross(forward, normalize(up))) > 1e-9)) {
    throw Error("", "camera: up is zero or parallel to the view direction");
  }
  if (width < 1 || height < 1 || width > 65536 || height > 65536) {
    throw Error("", fmt::format("camera: image size {}x{} outside [1, 65536]", width, height));
  }
  if (projection == Projection::Perspective && !(fovYDegrees > 0 && fovYDegrees < 180)) {
    throw Error("", fmt::format("camera: field of view {} not in (0, 180) degrees", fovYDegrees));
  }
  if (projection == Projection::Orthographic &&
      !(orthoHeightMm > 0 && std::isfinite(orthoHeightMm))) {
    throw Error("", fmt::format("camera: orthographic height {} must be positive", orthoHeightMm));
  }
}

VolumeDomain VolumeDomain::of(const VolumeInfo& info) { return {info.dims, info.patientFromIndex}; }

Vec3 VolumeDomain::centrePatient() const {
  return patientFromIndex.transformPoint({0.5 * static_cast<double>(dims[0] - 1),
                                          0.5 * static_cast<double>(dims[1] - 1),
                                          0.5 * static_cast<double>(dims[2] - 1)});
}

double VolumeDomain::boundingRadiusMm() const {
  const Vec3 centre = centrePatient();
  double radius = 0;
  for (int corner = 0; corner < 8; ++corner) {
    const Vec3 index{(corner & 1) ? static_cast<double>(dims[0]) - 0.5 : -0.5,
                     (corner & 2) ? static_cast<double>(dims[1]) - 0.5 : -0.5,
                     (corner & 4) ? static_cast<double>(dims[2]) - 0.5 : -0.5};
    radius = std::max(radius, length(patientFromIndex.transformPoint(index) - centre));
  }
  return radius;
}

Camera turnAboutCentre(const Camera& camera, Vec3 centre, double degrees) {
  // Rodrigues' rotation about the unit axis.
  const Vec3 axis = normalize(camera.up);
  const double angle = degrees * 3.14159265358979323846 / 180.0;
  const double c = std::cos(angle), s = std::sin(angle);
  const auto turn = [&](Vec3 v) { return c * v + s * cross(axis, v) + (dot(axis, v) * (1.0 - c)) * axis; };
  Camera turned = camera;
  turned.eye = centre + turn(camera.eye - centre);
  turned.target = centre + turn(camera.target - centre);
  return turned;
}

Camera orbitCamera(const VolumeDomain& domain, const OrbitParameters& orbit) {
  if (!(orbit.zoom > 0 && std::isfinite(orbit.zoom))) {
    throw Error("", fmt::format("zoom {} must be positive and finite", orbit.zoom));
  }
  if (!std::isfinite(orbit.azimuthDegrees) || !std::isfinite(orbit.elevationDegrees)) {
    throw Error("", "azimuth and elevation must be finite");
  }
  // Checked here, before the eye distance divides by it (--fov 0 said "non-finite vector").
  if (orbit.projection == Projection::Perspective && !(orbit.fovYDegrees > 0 && orbit.fovYDegrees < 180)) {
    throw Error("", fmt::format("field of view {} degrees (--fov) must be in (0, 180)", orbit.fovYDegrees));
  }
  const double az = orbit.azimuthDegrees * kDegrees;
  const double el = orbit.elevationDegrees * kDegrees;
  // Unit vector from the centre to the eye, and its derivative in elevation as the up vector
  // (well defined at the poles, +Z at elevation 0).
  const Vec3 toEye{std::cos(el) * std::sin(az), -std::cos(el) * std::cos(az), std::sin(el)};
  const Vec3 up{-std::sin(el) * std::sin(az), std::sin(el) * std::cos(az), std::cos(el)};
  const double radius = std::max(domain.boundingRadiusMm(), 1e-9);

  Camera c;
  c.projection = orbit.projection;
  c.width = orbit.width;
  c.height = orbit.height;
  c.target = domain.centrePatient();
  c.up = up;
  if (orbit.projection == Projection::Perspective) {
    const double half = 0.5 * orbit.fovYDegrees * kDegrees;
    // The sphere's tangent cone fills the field of view; zoom narrows the field of view.
    c.eye = c.target + (radius / std::sin(half)) * toEye;
    c.fovYDegrees = 2.0 * std::atan(std::tan(half) / orbit.zoom) / kDegrees;
  } else {
    c.eye = c.target + (2.0 * radius) * toEye;
    c.orthoHeightMm = 2.0 * radius / orbit.zoom;
    c.fovYDegrees = orbit.fovYDegrees;
  }
  // A zoom far from 1 widens the field of view to 180 degrees or narrows it to 0 (the
  // orthographic height to infinity or 0): said of the zoom, not of a field of view not given.
  const bool framed = orbit.projection == Projection::Perspective
                          ? c.fovYDegrees > 0 && c.fovYDegrees < 180
                          : c.orthoHeightMm > 0 && std::isfinite(c.orthoHeightMm);
  if (!framed) {
    throw Error("", fmt::format("zoom {:g} is too {} to frame the volume", orbit.zoom,
                                orbit.zoom < 1 ? "small" : "large"));
  }
  c.validate();
  return c;
}

nlohmann::json cameraToJson(const Camera& c) {
  return {{"projection", c.projection == Projection::Perspective ? "perspective" : "orthographic"},
          {"eye", {c.eye.x, c.eye.y, c.eye.z}},
          {"target", {c.target.x, c.target.y, c.target.z}},
          {"up", {c.up.x, c.up.y, c.up.z}},
          {"fovYDegrees", c.fovYDegrees},
          {"orthoHeightMm", c.orthoHeightMm},
          {"width", c.width},
          {"height", c.height}};
}

Camera cameraFromJson(const nlohmann::json& j, const std::string& path) {
  if (!j.is_object()) throw Error(path, "camera: expected a JSON object");
  Camera c;
  const auto projection = j.find("projection");
  if (projection == j.end() || !projection->is_string()) {
    throw Error(path, "camera: \"projection\" must be \"perspective\" or \"orthographic\"");
  }
  if (*projection == "perspective") {
    c.projection = Projection::Perspective;
  } else if (*projection == "orthographic") {
    c.projection = Projection::Orthographic;
  } else {
    throw Error(path, "camera: \"projection\" must be \"perspective\" or \"orthographic\"");
  }
  c.eye = vec3FromJson(j, "eye", path);
  c.target = vec3FromJson(j, "target", path);
  c.up = vec3FromJson(j, "up", path);
  c.fovYDegrees = numberFromJson<double>(j, "fovYDegrees", path);
  c.orthoHeightMm = numberFromJson<double>(j, "orthoHeightMm", path);
  c.width = numberFromJson<int>(j, "width", path);
  c.height = numberFromJson<int>(j, "height", path);
  try {
    c.validate();
  } catch (const Error& e) {
    throw Error(path, e.reason());
  }
  return c;
}

void saveCamera(const Camera& camera, const std::filesystem::path& path) {
  const std::filesystem::path temporary = path.string() + ".tmp";
  {
    std::ofstream out(temporary);
    out << cameraToJson(camera).dump(2) << '\n';
    if (!out) throw Error(path.string(), "cannot write the camera file");
  }
  std::error_code ec;
  std::filesystem::rename(temporary, path, ec);
  if (ec) throw Error(path.string(), "cannot write the camera file: " + ec.message());
}

Camera loadCamera(const std::filesystem::path& path) {
  std::ifstream in(path);
  if (!in) throw Error(path.string(), "cannot open the camera file");
  nlohmann::json j;
  try {
    in >> j;
  } catch (const nlohmann::json::exception& e) {
    throw Error(path.string(), fmt::format("camera: not valid JSON ({})", e.what()));
  }
  return cameraFromJson(j, path.string());
}

}  // namespace octoray::gpu
