#pragma once
// Camera paths: the interaction benchmark's input (octoray-render --path) and the test
// harness's random walks. A path is a list of cameras rendered one frame each with the working
// set carried across frames.
//
//   orbit:N[,degrees:D][,zoom-from:Z1,zoom-to:Z2][,still:S]
//       N frames turning D degrees in all (default 360) about the volume's centre, starting
//       from `start`; the zoom runs geometrically from Z1 to Z2 (default: start's zoom
//       throughout); then S frames at the last camera (the camera has stopped).
//   FILE.json
//       {"cameras": [camera, ...]} or [camera, ...] with the camera JSON of camera.h.

#include <string>
#include <vector>

#include "octoray/gpu/camera.h"

namespace octoray::gpu {

// Throws octoray::Error naming the spec or file and what is wrong.
std::vector<Camera> cameraPath(const std::string& spec, const VolumeDomain& domain,
                               const OrbitParameters& start);

}  // namespace octoray::gpu
