// vtk-peer: renders a volume with VTK, "the renderer most medical viewers use", so that issue
// 5's benchmark compares our GPU raycaster with VTK's vtkGPUVolumeRayCastMapper (on the same GL
// driver) and vtkFixedPointVolumeRayCastMapper (VTK's CPU raycaster) in the same run, with the
// same volume, transfer function, camera and image size as octoray-render.
//   vtk-peer PATH --mapper gpu|cpu -o OUT.png [--exr OUT.exr] --mode dvr|iso|mip
//     --preset NAME | --tf FILE [--tf-name NAME]  [--iso HU]  --size WxH
//     --azimuth DEG --elevation DEG --zoom F | --camera FILE   [--frames N --orbit DEG] [--json]
// Under X without a display: xvfb-run -a -s "-screen 0 1024x768x24" vtk-peer ...
//
// How our scene maps onto VTK (bench/README.md says more):
//   - geometry: vtkImageData with origin 0 and spacing = the lengths of patientFromIndex's
//     columns, and a vtkVolume user matrix = patientFromIndex x diag(1 / spacing), so that the
//     product is exactly patientFromIndex (rotation, shear and all) while VTK's sample distance
//     and scalar opacity unit distance, which VTK measures in dataset units, are millimetres.
//     VTK's domain spans the voxel centres [0, dim - 1]; ours spans [-0.5, dim - 0.5].
//   - transfer function: colour and opacity points as they are (linear, clamped ends), the
//     opacity unit distance, gradient opacity unless dropped, the material's Phong terms;
//     VTK's renderer default light is a white headlight of intensity 1, as in our reference.
//   - image: RGBA read back from an 8-bit framebuffer cleared to transparent black, so RGB is
//     the colour over black (premultiplied) as in our images; rows flipped to row 0 = top.

#include <fmt/format.h>
#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <vtkCamera.h>
#include <vtkColorTransferFunction.h>
#include <vtkContourValues.h>
#include <vtkFixedPointVolumeRayCastMapper.h>
#include <vtkFloatArray.h>
#include <vtkGPUVolumeRayCastMapper.h>
#include <vtkImageData.h>
#include <vtkMatrix4x4.h>
#include <vtkNew.h>
#include <vtkPiecewiseFunction.h>
#include <vtkPointData.h>
#include <vtkRenderWindow.h>
#include <vtkRenderer.h>
#include <vtkShortArray.h>
#include <vtkSmartPointer.h>
#include <vtkUnsignedCharArray.h>
#include <vtkVolume.h>
#include <vtkVolumeProperty.h>
#include <vtkWindowToImageFilter.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <limits>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "cli_checks.h"
#include "cli_support.h"
#include "octoray/core/error.h"
#include "octoray/dicom/formats.h"
#include "octoray/gpu/camera.h"
#include "octoray/gpu/image_io.h"
#include "octoray/gpu/reference/reference_volume.h"
#include "octoray/transfer/transfer_function_io.h"
#include "octoray/volume/store_format.h"
#include "octoray/volume/store_reader.h"

namespace {

using namespace octoray;

struct Arguments {
  std::string path, mapper = "gpu", output, exr, mode = "dvr", preset, tfPath, tfName;
  std::string size = "512x512", camera, projection = "perspective", shading = "auto";
  std::optional<double> iso;
  double azimuth = 0, elevation = 0, zoom = 1, fovY = 30, stepMm = 0, orbitDegrees = 0;
  double imageSampleDistance = 1.0;  // CPU mapper: rays every this many pixels, interpolated
  int frames = 1;
  bool json = false, noGradientOpacity = false, offScreen = true;
};

double millisecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
      .count();
}

// The full-resolution volume exactly as octoray-render's reference path loads it.
transfer::TransferFunction loadTransferFunction(const Arguments& a) {
  if (!a.tfPath.empty()) {
    return transfer::selectTransferFunction(transfer::loadTransferFunctions(a.tfPath), a.tfName,
                                            a.tfPath);
  }
  return transfer::findPreset(a.preset);
}

// Per index axis, the length in mm of one index step (the column norms of the affine).
std::array<double, 3> spacingMm(const Mat4& patientFromIndex) {
  return {length(patientFromIndex.column(0)), length(patientFromIndex.column(1)),
          length(patientFromIndex.column(2))};
}

// The volume as VTK point data: int16 when every value is an integer in range (CT in HU,
// lossless, half the memory), float otherwise. Voxel (i, j, k) is VTK point (i, j, k).
vtkSmartPointer<vtkImageData> toVtkImage(const gpu::reference::ReferenceVolume& volume) {
  const auto& dims = volume.dims();
  const std::vector<float>& values = volume.values();
  const bool fitsShort = std::all_of(values.begin(), values.end(), [](float v) {
    return v >= -32768.0f && v <= 32767.0f && std::nearbyint(v) == v;
  });
  auto image = vtkSmartPointer<vtkImageData>::New();
  image->SetDimensions(static_cast<int>(dims[0]), static_cast<int>(dims[1]),
                       static_cast<int>(dims[2]));
  const auto spacing = spacingMm(volume.patientFromIndex());
  image->SetSpacing(spacing[0], spacing[1], spacing[2]);
  image->SetOrigin(0, 0, 0);
  const auto count = static_cast<vtkIdType>(values.size());
  vtkSmartPointer<vtkDataArray> scalars;
  if (fitsShort) {
    auto shorts = vtkSmartPointer<vtkShortArray>::New();
    shorts->SetNumberOfTuples(count);
    short* out = shorts->GetPointer(0);
    std::transform(values.begin(), values.end(), out,
                   [](float v) { return static_cast<short>(v); });
    scalars = shorts;
  } else {
    auto floats = vtkSmartPointer<vtkFloatArray>::New();
    floats->SetNumberOfTuples(count);
    std::copy(values.begin(), values.end(), floats->GetPointer(0));
    scalars = floats;
  }
  scalars->SetName("values");
  image->GetPointData()->SetScalars(scalars);
  return image;
}

// patientFromIndex x diag(1 / spacing): maps VTK's dataset space (index x spacing) to patient.
vtkSmartPointer<vtkMatrix4x4> patientFromDataset(const Mat4& patientFromIndex) {
  const auto spacing = spacingMm(patientFromIndex);
  auto matrix = vtkSmartPointer<vtkMatrix4x4>::New();
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) {
      const double scale = c < 3 ? 1.0 / spacing[static_cast<std::size_t>(c)] : 1.0;
      matrix->SetElement(r, c, patientFromIndex.m[static_cast<std::size_t>(r)]
                                                 [static_cast<std::size_t>(c)] * scale);
    }
  }
  return matrix;
}

bool shadingOn(const Arguments& a, const transfer::TransferFunction& tf) {
  if (a.shading == "on") return true;
  if (a.shading == "off") return false;
  return tf.material.shade;
}

vtkSmartPointer<vtkVolumeProperty> volumeProperty(const Arguments& a,
                                                  const transfer::TransferFunction& tf) {
  auto color = vtkSmartPointer<vtkColorTransferFunction>::New();
  color->SetAllowDuplicateScalars(1);  // a step (two points at one value) stays a step
  for (const auto& p : tf.color) color->AddRGBPoint(p.value, p.r, p.g, p.b);
  color->ClampingOn();

  auto opacity = vtkSmartPointer<vtkPiecewiseFunction>::New();
  opacity->SetAllowDuplicateScalars(1);
  if (a.mode == "iso") {
    // Our isosurface is opaque at the first crossing; VTK takes the opacity TF at the isovalue.
    opacity->AddPoint(tf.opacity.front().value, 1.0);
    opacity->AddPoint(tf.opacity.back().value, 1.0);
  } else {
    for (const auto& p : tf.opacity) opacity->AddPoint(p.value, p.alpha);
  }
  opacity->ClampingOn();

  auto property = vtkSmartPointer<vtkVolumeProperty>::New();
  property->SetColor(color);
  property->SetScalarOpacity(opacity);
  property->SetScalarOpacityUnitDistance(tf.unitDistanceMm);
  property->SetInterpolationType(tf.interpolation == transfer::Interpolation::Nearest
                                     ? VTK_NEAREST_INTERPOLATION
                                     : VTK_LINEAR_INTERPOLATION);
  if (!a.noGradientOpacity && !tf.gradientOpacity.empty() && a.mode == "dvr") {
    auto gradient = vtkSmartPointer<vtkPiecewiseFunction>::New();
    for (const auto& p : tf.gradientOpacity) gradient->AddPoint(p.magnitude, p.alpha);
    property->SetGradientOpacity(gradient);
  } else {
    // Never call GetGradientOpacity(): it would create a default (unit) function.
    property->DisableGradientOpacityOn();
  }
  property->SetShade(a.mode != "mip" && shadingOn(a, tf) ? 1 : 0);
  property->SetAmbient(tf.material.ambient);
  property->SetDiffuse(tf.material.diffuse);
  property->SetSpecular(tf.material.specular);
  property->SetSpecularPower(tf.material.specularPower);
  if (a.mode == "iso") property->GetIsoSurfaceValues()->SetValue(0, *a.iso);
  return property;
}

int blendMode(const std::string& mode) {
  if (mode == "mip") return vtkVolumeMapper::MAXIMUM_INTENSITY_BLEND;
  if (mode == "iso") return vtkVolumeMapper::ISOSURFACE_BLEND;
  return vtkVolumeMapper::COMPOSITE_BLEND;
}

// A mapper with every automatic quality reduction off: the sample distance is `stepMm`
// everywhere and the CPU mapper casts one ray per pixel.
vtkSmartPointer<vtkVolumeMapper> makeMapper(const Arguments& a, double stepMm) {
  if (a.mapper == "gpu") {
    auto mapper = vtkSmartPointer<vtkGPUVolumeRayCastMapper>::New();
    mapper->AutoAdjustSampleDistancesOff();
    mapper->LockSampleDistanceToInputSpacingOff();
    mapper->UseJitteringOff();
    mapper->SetSampleDistance(static_cast<float>(stepMm));
    mapper->SetBlendMode(blendMode(a.mode));
    return mapper;
  }
  if (a.mode == "iso") {
    throw Error("", "--mode iso: vtkFixedPointVolumeRayCastMapper has no isosurface blend mode "
                    "(use --mapper gpu)");
  }
  auto mapper = vtkSmartPointer<vtkFixedPointVolumeRayCastMapper>::New();
  mapper->AutoAdjustSampleDistancesOff();
  mapper->LockSampleDistanceToInputSpacingOff();
  mapper->SetSampleDistance(static_cast<float>(stepMm));
  mapper->SetInteractiveSampleDistance(static_cast<float>(stepMm));
  const auto isd = static_cast<float>(a.imageSampleDistance);
  mapper->SetImageSampleDistance(isd);
  mapper->SetMinimumImageSampleDistance(isd);
  mapper->SetMaximumImageSampleDistance(isd);
  mapper->SetBlendMode(blendMode(a.mode));
  return mapper;
}

void applyCamera(const gpu::Camera& camera, vtkCamera* vtk) {
  vtk->SetPosition(camera.eye.x, camera.eye.y, camera.eye.z);
  vtk->SetFocalPoint(camera.target.x, camera.target.y, camera.target.z);
  vtk->SetViewUp(camera.up.x, camera.up.y, camera.up.z);
  vtk->OrthogonalizeViewUp();
  if (camera.projection == gpu::Projection::Orthographic) {
    vtk->ParallelProjectionOn();
    vtk->SetParallelScale(camera.orthoHeightMm / 2.0);
  } else {
    vtk->ParallelProjectionOff();
    vtk->UseHorizontalViewAngleOff();
    vtk->SetViewAngle(camera.fovYDegrees);
  }
}

// The camera of frame `frame`: the orbit flags with the azimuth advanced by frame x orbit
// degrees, or a --camera turned by as much about its up vector through the volume's centre.
gpu::Camera frameCamera(const Arguments& a, const gpu::VolumeDomain& domain,
                        const gpu::Camera& first, int frame) {
  const double turn = frame * a.orbitDegrees;
  if (turn == 0.0) return first;
  if (a.camera.empty()) {
    gpu::OrbitParameters orbit;
    orbit.azimuthDegrees = a.azimuth + turn;
    orbit.elevationDegrees = a.elevation;
    orbit.zoom = a.zoom;
    orbit.fovYDegrees = a.fovY;
    orbit.projection = first.projection;
    orbit.width = first.width;
    orbit.height = first.height;
    return gpu::orbitCamera(domain, orbit);
  }
  return gpu::turnAboutCentre(first, domain.centrePatient(), turn);
}

// The window's RGBA as our Image: float in [0, 1], row 0 = top (VTK's row 0 is the bottom).
gpu::Image readBack(vtkRenderWindow* window, int width, int height) {
  vtkNew<vtkWindowToImageFilter> grab;
  grab->SetInput(window);
  grab->SetInputBufferTypeToRGBA();
  grab->ReadFrontBufferOff();
  grab->Update();
  vtkImageData* pixels = grab->GetOutput();
  int dims[3] = {0, 0, 0};
  pixels->GetDimensions(dims);
  auto* data = vtkUnsignedCharArray::SafeDownCast(pixels->GetPointData()->GetScalars());
  if (dims[0] != width || dims[1] != height || data == nullptr ||
      data->GetNumberOfComponents() != 4) {
    throw Error("", fmt::format("VTK read back a {}x{} image, not {}x{} RGBA", dims[0], dims[1],
                                width, height));
  }
  gpu::Image image(width, height);
  const unsigned char* rgba = data->GetPointer(0);
  for (int y = 0; y < height; ++y) {
    const unsigned char* row = rgba + static_cast<std::size_t>(height - 1 - y) * width * 4;
    float* out = image.pixel(0, y);
    for (int i = 0; i < width * 4; ++i) out[i] = static_cast<float>(row[i]) / 255.0f;
  }
  return image;
}

// "OpenGL renderer string: llvmpipe (...)" from VTK's capability report.
std::string glRenderer(vtkRenderWindow* window) {
  const char* report = window->ReportCapabilities();
  std::istringstream lines(report != nullptr ? report : "");
  const std::string key = "OpenGL renderer string:";
  for (std::string line; std::getline(lines, line);) {
    const auto at = line.find(key);
    if (at == std::string::npos) continue;
    std::string value = line.substr(at + key.size());
    value.erase(0, value.find_first_not_of(" \t"));
    return value;
  }
  return "unknown";
}

int run(const Arguments& a) {
  if (a.mode == "iso" && !a.iso) throw Error("", "--mode iso needs --iso HU");
  const transfer::TransferFunction tf = loadTransferFunction(a);

  // Load as octoray-render does, then hand VTK its own copy (the float volume is freed).
  auto start = std::chrono::steady_clock::now();
  gpu::VolumeDomain domain;
  vtkSmartPointer<vtkImageData> image;
  {
    const auto volume = gpu::reference::ReferenceVolume::fromPath(a.path);
    domain = gpu::VolumeDomain{volume.dims(), volume.patientFromIndex()};
    image = toVtkImage(volume);
  }
  const double loadSeconds = millisecondsSince(start) / 1000.0;
  const auto spacing = spacingMm(domain.patientFromIndex);
  // Default: half the smallest spacing, the sampling of 3D Slicer's default quality.
  const double stepMm =
      a.stepMm > 0 ? a.stepMm : 0.5 * *std::min_element(spacing.begin(), spacing.end());

  gpu::Camera camera;
  if (!a.camera.empty()) {
    camera = gpu::loadCamera(a.camera);
  } else {
    gpu::OrbitParameters orbit;
    orbit.azimuthDegrees = a.azimuth;
    orbit.elevationDegrees = a.elevation;
    orbit.zoom = a.zoom;
    orbit.fovYDegrees = a.fovY;
    orbit.projection = a.projection == "orthographic" ? gpu::Projection::Orthographic
                                                      : gpu::Projection::Perspective;
    camera = gpu::orbitCamera(domain, orbit);
  }
  if (a.camera.empty() || !a.size.empty()) {
    const auto size = cli::parseImageSize(a.size, "--size", 1, 1, 16384);  // as octoray-render
    camera.width = size[0];
    camera.height = size[1];
  }
  camera.validate();

  auto mapper = makeMapper(a, stepMm);
  mapper->SetInputData(image);
  vtkNew<vtkVolume> actor;
  actor->SetMapper(mapper);
  actor->SetProperty(volumeProperty(a, tf));
  actor->SetUserMatrix(patientFromDataset(domain.patientFromIndex));

  vtkNew<vtkRenderer> renderer;
  renderer->SetBackground(0, 0, 0);
  renderer->SetBackgroundAlpha(0.0);
  renderer->AddVolume(actor);
  vtkNew<vtkRenderWindow> window;
  window->SetOffScreenRendering(a.offScreen ? 1 : 0);
  window->SetMultiSamples(0);
  window->AlphaBitPlanesOn();
  window->SetSize(camera.width, camera.height);
  window->AddRenderer(renderer);

  // Each frame: Render() then WaitForCompletion() (glFinish), so GL work queued by the
  // frame is inside its time.
  std::vector<double> framesMs;
  for (int frame = 0; frame < a.frames; ++frame) {
    applyCamera(frameCamera(a, domain, camera, frame), renderer->GetActiveCamera());
    renderer->ResetCameraClippingRange();
    start = std::chrono::steady_clock::now();
    window->Render();
    window->WaitForCompletion();
    framesMs.push_back(millisecondsSince(start));
  }

  // The image is frame 0's view, rendered again (untimed) and read back.
  applyCamera(camera, renderer->GetActiveCamera());
  renderer->ResetCameraClippingRange();
  const gpu::Image result = readBack(window, camera.width, camera.height);
  gpu::writePng(result, a.output);
  if (!a.exr.empty()) gpu::writeExr(result, a.exr);

  const std::string mapperName =
      a.mapper == "gpu" ? "vtkGPUVolumeRayCastMapper" : "vtkFixedPointVolumeRayCastMapper";
  const double medianMs = cli::medianOfSteadyFrames(framesMs);
  if (a.json) {
    const nlohmann::json report = {
        {"renderer", "vtk"},
        {"mapper", mapperName},
        {"glRenderer", glRenderer(window)},
        {"vtkVersion", VTK_VERSION},
        {"mode", a.mode},
        {"shading", a.mode != "mip" && shadingOn(a, tf)},
        {"gradientOpacity", !a.noGradientOpacity && !tf.gradientOpacity.empty() && a.mode == "dvr"},
        {"transferFunction", tf.name},
        {"dims", domain.dims},
        {"scalarType", image->GetScalarTypeAsString()},
        {"stepMm", stepMm},
        {"imageSampleDistance", a.imageSampleDistance},
        {"width", camera.width},
        {"height", camera.height},
        {"framesMs", framesMs},
        {"firstFrameMs", framesMs.front()},
        {"medianMs", medianMs},
        {"medianOf", cli::steadyFramesDescription(framesMs.size())},
        {"loadSeconds", loadSeconds},
        {"camera", gpu::cameraToJson(camera)},
        {"outputs", a.exr.empty() ? nlohmann::json{a.output} : nlohmann::json{a.output, a.exr}}};
    std::cout << report.dump(2) << '\n';
  } else {
    fmt::print("{}: {}x{} {} with {} in {:.0f} ms median ({} frames, first {:.0f} ms), "
               "volume loaded in {:.2f} s\n",
               a.output, camera.width, camera.height, a.mode, mapperName, medianMs, a.frames,
               framesMs.front(), loadSeconds);
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "Renders a CT volume with VTK's vtkGPUVolumeRayCastMapper or "
      "vtkFixedPointVolumeRayCastMapper, with octoray-render's volume, transfer function and "
      "camera conventions, and times the frames."};
  Arguments a;
  app.add_option("path", a.path, "octree store, DICOM folder or volume file")->required();
  app.add_option("--mapper", a.mapper, "gpu (vtkGPUVolumeRayCastMapper) or cpu "
                                       "(vtkFixedPointVolumeRayCastMapper)")
      ->check(CLI::IsMember({"gpu", "cpu"}))
      ->capture_default_str();
  app.add_option("-o,--output", a.output, "PNG to write (colour over black, 8-bit)")->required();
  app.add_option("--exr", a.exr, "also write RGBA (premultiplied, from the 8-bit framebuffer) "
                                 "as OpenEXR");
  app.add_option("--mode", a.mode, "dvr, iso (gpu mapper only) or mip")
      ->check(CLI::IsMember({"dvr", "iso", "mip"}))
      ->capture_default_str();
  auto* preset = app.add_option("--preset", a.preset, "shipped preset by name (bone, lung, ...)");
  auto* tfFile =
      app.add_option("--tf", a.tfPath, "transfer function file (octoray JSON, Slicer, ParaView)");
  preset->excludes(tfFile);
  app.add_option("--tf-name", a.tfName, "which function of a --tf file holding several")
      ->needs(tfFile);
  app.add_option("--iso", a.iso, "isovalue (HU) for --mode iso");
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
  app.add_option("--image-sample-distance", a.imageSampleDistance,
                 "cpu mapper: distance between rays in pixels (VTK interpolates between them)")
      ->check(CLI::Range(0.5, 8.0))
      ->capture_default_str();
  app.add_option("--step", a.stepMm, "sample distance in mm (default: half the smallest spacing)")
      ->check(octoray::cli::kNonNegative);
  app.add_option("--shading", a.shading, "auto (the preset's material), on or off")
      ->check(CLI::IsMember({"auto", "on", "off"}))
      ->capture_default_str();
  app.add_flag("--no-gradient-opacity", a.noGradientOpacity, "ignore the TF's gradient opacity");
  app.add_option("--frames", a.frames, "frames to render and time")
      ->check(CLI::Range(1, 100000))
      ->capture_default_str();
  app.add_option("--orbit", a.orbitDegrees, "azimuth turn in degrees between frames")
      ->capture_default_str();
  app.add_flag("!--on-screen", a.offScreen,
               "render into a visible window instead of VTK's off-screen buffer");
  app.add_flag("--json", a.json, "print the mapper, GL renderer, frame times (ms) as JSON");
  try {
    app.parse(argc, argv);
    if (a.preset.empty() && a.tfPath.empty()) {
      throw CLI::ValidationError("--preset or --tf", "one of them is required");
    }
    if (!a.camera.empty() && size->count() == 0) a.size.clear();
  } catch (const CLI::Success& e) {
    return app.exit(e);
  } catch (const CLI::Error& e) {
    fmt::print(stderr, "vtk-peer: {}\nRun with --help for more information.\n", e.what());
    return 2;
  }
  return cli::runTool("vtk-peer", [&] { return run(a); });
}
