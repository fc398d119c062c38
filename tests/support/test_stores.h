#pragma once
// Stores the tests build from in-memory volumes: one helper so that every suite builds its
// stores with the same options and puts them in its own fresh folder under the build tree.

#include <filesystem>
#include <string>

#include "octoray/dicom/volume_source.h"
#include "octoray/volume/phantom.h"

namespace octoray::test {

// The store of `source` in a fresh temporary folder named after `name` (freshTempDir), with
// `brickSize`-voxel bricks and a `border`-voxel replicated border (2: the central differences
// of gradients need it).
std::filesystem::path buildTestStore(VolumeSource& source, const std::string& name, int brickSize,
                                     int border = 2);

// The same for octoray-phantom's volume with `options` (dims, spacing, seed).
std::filesystem::path buildPhantomTestStore(const volume::PhantomOptions& options, const std::string& name,
                                            int brickSize, int border = 2);

}  // namespace octoray::test
