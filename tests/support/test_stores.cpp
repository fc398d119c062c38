#include "test_stores.h"

#include "octoray/volume/store_builder.h"
#include "test_paths.h"

namespace octoray::test {

std::filesystem::path buildTestStore(VolumeSource& source, const std::string& name, int brickSize,
                                     int border) {
  const std::filesystem::path path = freshTempDir(name) / (name + ".octoray");
  volume::BuildOptions options;
  options.brickSize = brickSize;
  options.border = border;
  volume::buildStore(source, path.string(), options);
  return path;
}

std::filesystem::path buildPhantomTestStore(const volume::PhantomOptions& options, const std::string& name,
                                            int brickSize, int border) {
  const auto source = volume::makePhantom(options);
  return buildTestStore(*source, name, brickSize, border);
}

}  // namespace octoray::test
