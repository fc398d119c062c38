// Loading and saving: octoray JSON round trip, the Slicer and ParaView importers on small
// files written here, clear errors for malformed input, --tf-name selection, shipped presets.

#include <gtest/gtest.h>

#include <fstream>

#include "octoray/core/error.h"
#include "octoray/transfer/transfer_function_io.h"
#include "test_paths.h"

namespace octoray::transfer {
namespace {

namespace fs = std::filesystem;

fs::path writeFile(const fs::path& dir, const std::string& name, const std::string& text) {
  const fs::path path = dir / name;
  std::ofstream(path, std::ios::binary) << text;
  return path;
}

// The reason of the octoray::Error loading `path` throws (fails the test if none).
std::string loadError(const fs::path& path) {
  try {
    loadTransferFunctions(path);
  } catch (const Error& e) {
    EXPECT_EQ(e.path(), path.string());
    return e.reason();
  }
  ADD_FAILURE() << "no error for " << path;
  return {};
}

TransferFunction sample() {
  TransferFunction tf;
  tf.name = "sample";
  tf.description = "round trip";
  tf.color = {{-1000, 0, 0, 0}, {0.1, 0.1f, 0.7f, 1.0f / 3.0f}, {3000, 1, 1, 1}};
  tf.opacity = {{-1000, 0}, {150.5, 1e-7f}, {150.5, 0.6f}, {3000, 0.9f}};
  tf.gradientOpacity = {{0, 0.25f}, {77.7, 1}};
  tf.material = {false, 0.3f, 0.6f, 0.5f, 40};
  tf.unitDistanceMm = 0.3;
  tf.interpolation = Interpolation::Nearest;
  return tf;
}

void expectSame(const TransferFunction& a, const TransferFunction& b) {
  EXPECT_EQ(a.name, b.name);
  EXPECT_EQ(a.description, b.description);
  ASSERT_EQ(a.color.size(), b.color.size());
  for (std::size_t i = 0; i < a.color.size(); ++i) {
    EXPECT_EQ(a.color[i].value, b.color[i].value);
    EXPECT_EQ(a.color[i].r, b.color[i].r);
    EXPECT_EQ(a.color[i].g, b.color[i].g);
    EXPECT_EQ(a.color[i].b, b.color[i].b);
  }
  ASSERT_EQ(a.opacity.size(), b.opacity.size());
  for (std::size_t i = 0; i < a.opacity.size(); ++i) {
    EXPECT_EQ(a.opacity[i].value, b.opacity[i].value);
    EXPECT_EQ(a.opacity[i].alpha, b.opacity[i].alpha);
  }
  ASSERT_EQ(a.gradientOpacity.size(), b.gradientOpacity.size());
  for (std::size_t i = 0; i < a.gradientOpacity.size(); ++i) {
    EXPECT_EQ(a.gradientOpacity[i].magnitude, b.gradientOpacity[i].magnitude);
    EXPECT_EQ(a.gradientOpacity[i].alpha, b.gradientOpacity[i].alpha);
  }
  EXPECT_EQ(a.material.shade, b.material.shade);
  EXPECT_EQ(a.material.ambient, b.material.ambient);
  EXPECT_EQ(a.material.diffuse, b.material.diffuse);
  EXPECT_EQ(a.material.specular, b.material.specular);
  EXPECT_EQ(a.material.specularPower, b.material.specularPower);
  EXPECT_EQ(a.unitDistanceMm, b.unitDistanceMm);
  EXPECT_EQ(a.interpolation, b.interpolation);
}

TEST(TransferFunctionIo, OctorayJsonRoundTripIsExact) {
  const fs::path dir = test::freshTempDir("tf_round_trip");
  const TransferFunction tf = sample();
  saveTransferFunction(tf, dir / "a.json");
  const auto loaded = loadTransferFunctions(dir / "a.json");
  ASSERT_EQ(loaded.size(), 1u);
  expectSame(tf, loaded[0]);
  EXPECT_FALSE(fs::exists(dir / "a.json.partial"));

  TransferFunction other = sample();
  other.name = "other";
  saveTransferFunctions({tf, other}, dir / "two.json");
  EXPECT_EQ(loadTransferFunctions(dir / "two.json").size(), 2u);
  EXPECT_THROW(saveTransferFunctions({tf, tf}, dir / "dup.json"), Error);
  EXPECT_FALSE(fs::exists(dir / "dup.json"));
}

TEST(TransferFunctionIo, MalformedOctorayJsonNamesTheField) {
  const fs::path dir = test::freshTempDir("tf_malformed");
  const std::string head = R"({"format": "octoray-transfer-function", "version": 1, "transferFunctions": [)";
  auto with = [&](const std::string& body) { return head + body + "]}"; };
  const std::string good = R"({"name": "t", "color": [[0, 1, 1, 1]], "opacity": [[0, 0], [10, 1]]})";
  EXPECT_NO_THROW(loadTransferFunctions(writeFile(dir, "good.json", with(good))));

  struct Case {
    std::string name, text, expected;
  };
  const std::vector<Case> cases = {
      {"unsorted", with(R"({"name": "t", "color": [[0, 1, 1, 1]], "opacity": [[10, 0], [0, 1]]})"),
       "opacity[1]: value 0 is below"},
      {"alpha", with(R"({"name": "t", "color": [[0, 1, 1, 1]], "opacity": [[0, 1.5]]})"),
       "transferFunctions[0].opacity[0]: 1.5 is outside [0, 1]"},
      {"colour", with(R"({"name": "t", "color": [[0, 1, -1, 1]], "opacity": [[0, 1]]})"),
       "transferFunctions[0].color[0]: -1 is outside [0, 1]"},
      {"shape", with(R"({"name": "t", "color": [[0, 1, 1]], "opacity": [[0, 1]]})"),
       "color[0]: expected an array of 4 numbers"},
      {"string", with(R"({"name": "t", "color": [[0, 1, 1, "x"]], "opacity": [[0, 1]]})"),
       "color[0]: expected a number"},
      {"typo", with(R"({"name": "t", "color": [[0, 1, 1, 1]], "opacty": [[0, 1]]})"),
       "unknown key 'opacty'"},
      {"noname", with(R"({"color": [[0, 1, 1, 1]], "opacity": [[0, 1]]})"), ".name: expected"},
      {"empty", with(R"({"name": "t", "color": [[0, 1, 1, 1]], "opacity": []})"),
       "opacity: needs at least one control point"},
      {"unit", with(R"({"name": "t", "color": [[0,1,1,1]], "opacity": [[0,1]], "unitDistanceMm": -1})"),
       "unitDistanceMm: -1 is not a finite positive number"},
      {"twice", with(good + "," + good), "'t' appears twice"},
      {"version", R"({"format": "octoray-transfer-function", "version": 2, "transferFunctions": []})",
       "version: expected 1"},
      {"syntax", head + "{", "not valid JSON"},
      {"nothing", "  \n", "the file is empty"},
      {"garbage", "hello", "not a transfer-function file"},
  };
  for (const Case& c : cases) {
    const std::string reason = loadError(writeFile(dir, c.name + ".json", c.text));
    EXPECT_NE(reason.find(c.expected), std::string::npos) << c.name << ": " << reason;
  }
  EXPECT_NE(loadError(dir / "absent.json").find("not a readable file"), std::string::npos);
}

TEST(TransferFunctionIo, SlicerXmlVpAndVpJson) {
  const fs::path dir = test::freshTempDir("tf_slicer");
  const auto xml = loadTransferFunctions(writeFile(dir, "p.xml", R"(<?xml version="1.0"?>
<MRML>
  <VolumeProperty name="A" scalarOpacity="4 -10 0 20 0.5" gradientOpacity="4 0 0.5 100 1"
    colorTransfer="8 -10 0 0 0 20 1 0.5 0.25" shade="0" ambient="0.3" diffuse="0.6"
    specular="0.5" specularPower="40" interpolation="0"/>
  <VolumeProperty name="B" scalarOpacity="2 0 1" colorTransfer="4 0 1 1 1"/>
</MRML>)"));
  ASSERT_EQ(xml.size(), 2u);
  EXPECT_EQ(xml[0].name, "A");
  ASSERT_EQ(xml[0].opacity.size(), 2u);
  EXPECT_EQ(xml[0].opacity[1].value, 20);
  EXPECT_EQ(xml[0].opacity[1].alpha, 0.5f);
  EXPECT_EQ(xml[0].gradientOpacity[0].alpha, 0.5f);
  EXPECT_EQ(xml[0].color[1].b, 0.25f);
  EXPECT_FALSE(xml[0].material.shade);
  EXPECT_EQ(xml[0].material.specularPower, 40);
  EXPECT_EQ(xml[0].interpolation, Interpolation::Nearest);
  EXPECT_TRUE(xml[1].gradientOpacity.empty());

  const auto vp = loadTransferFunctions(writeFile(dir, "Bones.vp", "1\n1\n0.2\n0.8\n0.1\n20\n"
                                                                   "4 0 0 100 1\n2 0 1\n"
                                                                   "8 0 1 0 0 100 1 1 1\n"));
  ASSERT_EQ(vp.size(), 1u);
  EXPECT_EQ(vp[0].name, "Bones");
  EXPECT_EQ(vp[0].material.ambient, 0.2f);
  EXPECT_EQ(vp[0].color.size(), 2u);

  // A .vp.json following volume-property-schema-v1.0.0.json.
  const auto vpJson = loadTransferFunctions(writeFile(dir, "Lungs.vp.json", R"({
    "@schema": "https://raw.githubusercontent.com/Slicer/Slicer/main/Modules/Loadable/VolumeRendering/Resources/Schema/volume-property-schema-v1.0.0.json#",
    "volumeProperties": [{
      "effectiveRange": [-1000, 500], "interpolationType": "linear",
      "components": [{
        "componentWeight": 1.0, "shade": true,
        "lighting": {"ambient": 0.1, "diffuse": 0.7, "specular": 0.2, "specularPower": 10.0},
        "disableGradientOpacity": false, "scalarOpacityUnitDistance": 0.5,
        "scalarOpacity": {"points": [{"x": -1000, "y": 0, "midpoint": 0.5, "sharpness": 0}, {"x": 500, "y": 0.4}]},
        "gradientOpacity": {"points": [{"x": 0, "y": 1}]},
        "rgbTransferFunction": {"points": [{"x": -1000, "color": [0, 0.5, 1]}, {"x": 500, "color": [1, 1, 1]}]}
      }]
    }]})"));
  ASSERT_EQ(vpJson.size(), 1u);
  EXPECT_EQ(vpJson[0].name, "Lungs");
  EXPECT_EQ(vpJson[0].unitDistanceMm, 0.5);
  EXPECT_EQ(vpJson[0].opacity[1].alpha, 0.4f);
  EXPECT_EQ(vpJson[0].color[0].g, 0.5f);
  EXPECT_EQ(vpJson[0].material.diffuse, 0.7f);
  EXPECT_EQ(vpJson[0].gradientOpacity.size(), 1u);

  // Malformed Slicer input: each names what is wrong.
  EXPECT_NE(loadError(writeFile(dir, "count.xml",
                                R"(<MRML><VolumeProperty name="C" scalarOpacity="6 0 0 1 1" )"
                                R"(colorTransfer="4 0 1 1 1"/></MRML>)"))
                .find("VolumeProperty 0 ('C') scalarOpacity: count says 6 numbers but 4 follow"),
            std::string::npos);
  EXPECT_NE(loadError(writeFile(dir, "nan.xml",
                                R"(<MRML><VolumeProperty name="C" scalarOpacity="2 nan 0" )"
                                R"(colorTransfer="4 0 1 1 1"/></MRML>)"))
                .find("'nan' is not a finite number"),
            std::string::npos);
  EXPECT_NE(loadError(writeFile(dir, "bad.xml", "<MRML><VolumeProperty name=\"x\"></MRML>"))
                .find("not well-formed XML at line 1"),
            std::string::npos);
  EXPECT_NE(loadError(writeFile(dir, "short.vp", "1\n1\n0.2\n")).find("9 non-empty lines"),
            std::string::npos);
}

TEST(TransferFunctionIo, ParaViewColourMaps) {
  const fs::path dir = test::freshTempDir("tf_paraview");
  const auto maps = loadTransferFunctions(writeFile(dir, "maps.json", R"([
    {"Name": "Cool to Warm", "ColorSpace": "Diverging", "RGBPoints": [0, 0.23, 0.3, 0.75, 1, 0.7, 0.015, 0.15]},
    {"Name": "KAAMS", "IndexedColors": [1, 1, 1, 1, 0, 0]},
    {"Name": "Ramp", "RGBPoints": [-1000, 0, 0, 0, 1000, 1, 1, 1], "Points": [-1000, 0, 0.5, 0, 1000, 0.8, 0.5, 0]}
  ])"));
  ASSERT_EQ(maps.size(), 2u);  // the categorical map has no value axis
  EXPECT_EQ(maps[0].name, "Cool to Warm");
  EXPECT_EQ(maps[0].opacity.size(), 2u);  // ParaView's default opacity ramp
  EXPECT_FLOAT_EQ(maps[0].opacityAt(0.5), 0.5f);
  EXPECT_EQ(maps[1].opacity[1].alpha, 0.8f);
  EXPECT_NE(loadError(writeFile(dir, "odd.json", R"([{"Name": "x", "RGBPoints": [0, 1, 1]}])"))
                .find("[0] ('x').RGBPoints: expected a non-empty array of numbers in groups of 4"),
            std::string::npos);
}

TEST(TransferFunctionIo, SelectByName) {
  TransferFunction a = sample(), b = sample();
  a.name = "CT-Bone";
  b.name = "CT-Lung";
  EXPECT_EQ(selectTransferFunction({a}, "").name, "CT-Bone");
  EXPECT_EQ(selectTransferFunction({a, b}, "CT-Lung").name, "CT-Lung");
  EXPECT_EQ(selectTransferFunction({a, b}, "ct-lung").name, "CT-Lung");
  try {
    selectTransferFunction({a, b}, "", "f.xml");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("f.xml: holds 2 transfer functions; choose one with "
                                         "--tf-name (CT-Bone, CT-Lung)"),
              std::string::npos);
  }
  EXPECT_THROW(selectTransferFunction({a, b}, "liver", "f.xml"), Error);
}

TEST(TransferFunctionIo, ShippedPresetsLoadAndAreFound) {
  for (const char* name : {"bone", "soft-tissue", "lung", "ct-angiography", "skin", "muscle"}) {
    const TransferFunction tf = findPreset(name);
    EXPECT_EQ(tf.name, name);
    EXPECT_FALSE(tf.description.empty()) << name;
    EXPECT_TRUE(tf.transparentOver(-1100, -960)) << name << ": air must be transparent";
  }
  EXPECT_FALSE(findPreset("bone").transparentOver(1000, 1000));
  EXPECT_TRUE(findPreset("bone").transparentOver(-1000, 100));  // soft tissue hidden
  EXPECT_FALSE(findPreset("lung").transparentOver(-800, -700));
  EXPECT_FALSE(findPreset("ct-angiography").transparentOver(300, 300));
  EXPECT_EQ(findPreset("Bone").name, "bone");
  EXPECT_GE(presetNames().size(), 6u);
  EXPECT_THROW(findPreset("no-such-preset"), Error);
  EXPECT_THROW(findPreset("../presets/bone"), Error);
}

}  // namespace
}  // namespace octoray::transfer
