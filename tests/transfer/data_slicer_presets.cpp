// The real 3D Slicer presets in ../shared/data/presets/slicer: all 31 load with the point
// counts the file states (counted here independently by string search), CT-Bone matches the
// file's numbers, and the older .vp file loads.

#include <gtest/gtest.h>

#include <fstream>
#include <regex>
#include <sstream>

#include "octoray/transfer/transfer_function_io.h"
#include "test_paths.h"

namespace octoray::transfer {
namespace {

namespace fs = std::filesystem;

fs::path slicerDir() { return test::sharedDir() / "data" / "presets" / "slicer"; }

// The leading count of attribute `key` in `element` ("12 -3024 0 ..." -> 12).
int leadingCount(const std::string& element, const std::string& key) {
  const std::regex pattern(" " + key + "=\"(\\d+) ");
  std::smatch match;
  if (!std::regex_search(element, match, pattern)) return -1;
  return std::stoi(match[1]);
}

TEST(SlicerPresets, All31LoadWithTheFilesPointCounts) {
  const fs::path path = slicerDir() / "presets.xml";
  OCTORAY_REQUIRE_PATH(path);
  std::ifstream file(path);
  std::stringstream text;
  text << file.rdbuf();
  const std::string xml = text.str();
  std::vector<std::string> elements;
  for (std::size_t at = xml.find("<VolumeProperty "); at != std::string::npos;
       at = xml.find("<VolumeProperty ", at + 1)) {
    elements.push_back(xml.substr(at, xml.find("/>", at) - at));
  }
  ASSERT_EQ(elements.size(), 31u);

  const std::vector<TransferFunction> tfs = loadTransferFunctions(path);
  ASSERT_EQ(tfs.size(), 31u);
  for (std::size_t i = 0; i < tfs.size(); ++i) {
    SCOPED_TRACE(tfs[i].name);
    EXPECT_NE(elements[i].find("name=\"" + tfs[i].name + "\""), std::string::npos);
    EXPECT_EQ(static_cast<int>(tfs[i].opacity.size()) * 2, leadingCount(elements[i], "scalarOpacity"));
    EXPECT_EQ(static_cast<int>(tfs[i].gradientOpacity.size()) * 2,
              leadingCount(elements[i], "gradientOpacity"));
    EXPECT_EQ(static_cast<int>(tfs[i].color.size()) * 4, leadingCount(elements[i], "colorTransfer"));
    const bool shade = elements[i].find(" shade=\"1\"") != std::string::npos;
    EXPECT_EQ(tfs[i].material.shade, shade);
  }
}

TEST(SlicerPresets, CtBoneMatchesTheFile) {
  const fs::path path = slicerDir() / "presets.xml";
  OCTORAY_REQUIRE_PATH(path);
  const TransferFunction bone = selectTransferFunction(loadTransferFunctions(path), "CT-Bone");
  // scalarOpacity="8 -3024 0 -16.4458 0 641.385 0.715686 3071 0.705882"
  ASSERT_EQ(bone.opacity.size(), 4u);
  EXPECT_EQ(bone.opacity[1].value, -16.4458);
  EXPECT_EQ(bone.opacity[2].value, 641.385);
  EXPECT_EQ(bone.opacity[2].alpha, 0.715686f);
  EXPECT_EQ(bone.opacity[3].alpha, 0.705882f);
  // colorTransfer="16 -3024 0 0 0 -16.4458 0.729412 0.254902 0.301961 641.385 0.905882 ..."
  ASSERT_EQ(bone.color.size(), 4u);
  EXPECT_EQ(bone.color[1].r, 0.729412f);
  EXPECT_EQ(bone.color[1].g, 0.254902f);
  EXPECT_EQ(bone.color[1].b, 0.301961f);
  EXPECT_EQ(bone.color[3].value, 3071);
  // gradientOpacity="4 0 1 255 1", specularPower="10" specular="0.2" ambient="0.1" diffuse="0.9"
  ASSERT_EQ(bone.gradientOpacity.size(), 2u);
  EXPECT_EQ(bone.gradientOpacity[1].magnitude, 255);
  EXPECT_EQ(bone.material.specularPower, 10.0f);
  EXPECT_EQ(bone.material.specular, 0.2f);
  EXPECT_EQ(bone.material.ambient, 0.1f);
  EXPECT_EQ(bone.material.diffuse, 0.9f);
  EXPECT_TRUE(bone.material.shade);
  EXPECT_EQ(bone.interpolation, Interpolation::Linear);
  // Everything below -16.4458 HU (air, lung, fat) is exactly transparent.
  EXPECT_TRUE(bone.transparentOver(-3024, -16.4458));
  EXPECT_FALSE(bone.transparentOver(-3024, -16.4));
}

TEST(SlicerPresets, OlderVpFileLoads) {
  const fs::path path = slicerDir() / "VolumeProperty.vp";
  OCTORAY_REQUIRE_PATH(path);
  const std::vector<TransferFunction> tfs = loadTransferFunctions(path);
  ASSERT_EQ(tfs.size(), 1u);
  const TransferFunction& tf = tfs[0];
  EXPECT_EQ(tf.name, "VolumeProperty");
  EXPECT_EQ(tf.interpolation, Interpolation::Linear);
  EXPECT_TRUE(tf.material.shade);
  EXPECT_EQ(tf.material.ambient, 0.42f);
  EXPECT_EQ(tf.material.diffuse, 0.44f);
  EXPECT_EQ(tf.material.specular, 0.46f);
  EXPECT_EQ(tf.material.specularPower, 38.5f);
  EXPECT_EQ(tf.opacity.size(), 4u);
  EXPECT_EQ(tf.gradientOpacity.size(), 2u);
  ASSERT_EQ(tf.color.size(), 7u);
  EXPECT_EQ(tf.color[2].value, 35.5882339477539);
}

TEST(SlicerPresets, AllConvertToOctorayJsonAndBack) {
  const fs::path path = slicerDir() / "presets.xml";
  OCTORAY_REQUIRE_PATH(path);
  const std::vector<TransferFunction> tfs = loadTransferFunctions(path);
  const fs::path out = test::freshTempDir("tf_slicer_convert") / "all.json";
  saveTransferFunctions(tfs, out);
  const std::vector<TransferFunction> back = loadTransferFunctions(out);
  ASSERT_EQ(back.size(), tfs.size());
  for (std::size_t i = 0; i < tfs.size(); ++i) {
    EXPECT_EQ(back[i].name, tfs[i].name);
    for (double v = -3100; v < 3100; v += 37.3) {
      EXPECT_EQ(back[i].evaluate(v), tfs[i].evaluate(v)) << tfs[i].name << " at " << v;
    }
  }
}

}  // namespace
}  // namespace octoray::transfer
