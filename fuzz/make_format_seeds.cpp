// Writes the seed corpora of the format fuzz targets: real files, each prefixed with the byte
// that selects its format in the target.
//   make_format_seeds OUT_DIR [SHARED_DIR [SOURCE_DIR]]
// OUT_DIR/volume-headers: a small phantom as NRRD (attached), NIfTI (.nii) and MetaImage (.mha),
//   a detached NRRD and MetaImage header naming data.raw;
// OUT_DIR/transfer-functions: every built-in preset as octoray JSON, and 3D Slicer's presets.xml,
//   VolumeProperty.vp and a .vp.json where SHARED_DIR/data/presets/slicer holds them;
// OUT_DIR/dicomdir: the Philips DICOMDIR of SHARED_DIR/data/dicom/dcm_qa_ct, when present;
// OUT_DIR/raw-options: the four raw-volume options of octoray-import, one per line;
// OUT_DIR/json-documents: a camera, a viewer script, and from SOURCE_DIR the window/level
//   preset table and the session example of docs/session-json.md.

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>
#include <string>

#include "octoray/dicom/formats.h"
#include "octoray/dicom/nifti_export.h"
#include "octoray/transfer/transfer_function_io.h"
#include "octoray/volume/phantom.h"

namespace fs = std::filesystem;

namespace {

std::string readAll(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

void seed(const fs::path& dir, const std::string& name, char selector, const std::string& bytes) {
  fs::create_directories(dir);
  std::ofstream(dir / name, std::ios::binary) << selector << bytes;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::cerr << "usage: make_format_seeds OUT_DIR [SHARED_DIR]\n";
    return 2;
  }
  const fs::path out = argv[1];
  const fs::path work = out / "work";
  fs::create_directories(work);

  // Volume headers (selector: 0 .nrrd, 1 .nhdr, 2 .mha, 3 .mhd, 4 .nii).
  octoray::volume::PhantomOptions phantom;
  phantom.dims = {12, 10, 8};
  phantom.spacingMm = {0.8, 0.9, 1.5};
  octoray::volume::writePhantomNrrd(phantom, (work / "p.nhdr").string());
  const fs::path headers = out / "volume-headers";
  std::string raw;
  for (const auto& e : fs::directory_iterator(work)) {
    if (e.path().extension() == ".raw") raw = readAll(e.path());
  }
  std::string nhdr = readAll(work / "p.nhdr");
  const auto dataLine = nhdr.find("data file:");
  if (dataLine != std::string::npos) nhdr = nhdr.substr(0, dataLine) + "data file: data.raw\n";
  seed(headers, "detached.nhdr", 1, nhdr);
  std::string attached = nhdr.substr(0, nhdr.find("data file:")) + "\n" + raw;
  seed(headers, "attached.nrrd", 0, attached);
  const std::string mhd =
      "ObjectType = Image\nNDims = 3\nDimSize = 12 10 8\nElementSpacing = 0.8 0.9 1.5\n"
      "ElementType = MET_SHORT\nBinaryData = True\nBinaryDataByteOrderMSB = False\n";
  seed(headers, "detached.mhd", 3, mhd + "ElementDataFile = data.raw\n");
  seed(headers, "local.mha", 2, mhd + "ElementDataFile = LOCAL\n" + raw);
  {
    auto source = octoray::openVolume((work / "p.nhdr").string());
    octoray::exportNifti(*source, (work / "p.nii").string());
    seed(headers, "phantom.nii", 4, readAll(work / "p.nii"));
  }

  // Transfer functions (selector: 0 .json, 1 .xml, 2 .vp, 3 .vp.json).
  const fs::path tfs = out / "transfer-functions";
  for (const auto& name : octoray::transfer::presetNames()) {
    seed(tfs, name + ".json", 0, octoray::transfer::transferFunctionToJsonText(octoray::transfer::findPreset(name)));
  }
  if (argc > 2) {
    const fs::path shared = argv[2];
    const fs::path slicer = shared / "data/presets/slicer";
    if (fs::exists(slicer / "presets.xml")) seed(tfs, "presets.xml", 1, readAll(slicer / "presets.xml"));
    if (fs::exists(slicer / "VolumeProperty.vp")) seed(tfs, "VolumeProperty.vp", 2, readAll(slicer / "VolumeProperty.vp"));
    const fs::path dicomdir = shared / "data/dicom/dcm_qa_ct/Philips/DICOMDIR";
    if (fs::exists(dicomdir)) {
      fs::create_directories(out / "dicomdir");
      std::ofstream(out / "dicomdir/philips", std::ios::binary) << readAll(dicomdir);
    }
  }
  seed(tfs, "minimal.vp.json", 3,
       R"({"@schema": "x", "volumeProperties": [{"effectiveRange": [-1000, 3000], "isosurface": false,
           "scalarOpacity": [[-1000, 0], [3000, 1]], "rgbTransferFunction": [[-1000, 0, 0, 0], [3000, 1, 1, 1]]}]})");
  fs::create_directories(out / "dicomdir");
  std::ofstream(out / "dicomdir/empty", std::ios::binary) << std::string(132, '\0');

  // Raw-volume options, one per line: dims, type, spacing, header bytes.
  const fs::path rawOptions = out / "raw-options";
  fs::create_directories(rawOptions);
  std::ofstream(rawOptions / "int16") << "16x16x8\nint16\n0.5,0.5,1\n0\n";
  std::ofstream(rawOptions / "float32") << "8x8x8\nfloat32\n1,1,2\n2048\n";
  std::ofstream(rawOptions / "uint8") << "64x64x1\nuint8\n\n\n";

  // JSON documents (selector: 0 camera, 1 session, 2 script, 3 window/level presets).
  const fs::path documents = out / "json-documents";
  seed(documents, "camera.json", 0,
       R"({"projection": "perspective", "eye": [0, -400, 0], "target": [0, 0, 0], "up": [0, 0, 1],
           "fovYDegrees": 30, "orthoHeightMm": 200, "width": 512, "height": 512})");
  seed(documents, "script.json", 2,
       R"({"format": "octoray-view-script", "version": 1, "events": [
           {"type": "key", "key": "1"},
           {"type": "drag", "button": "left", "from": {"view": "axial", "pixel": [200, 200]},
            "to": {"view": "axial", "pixel": [300, 150]}, "steps": 5},
           {"type": "wait-converged"}, {"type": "screenshot", "path": "after.png"}, {"type": "quit"}]})");
  if (argc > 3) {
    // The source tree's own documents: the preset table and the session examples of the docs.
    const fs::path source = argv[3];
    if (fs::exists(source / "viewer/presets/window-level.json")) {
      seed(documents, "window-level.json", 3, readAll(source / "viewer/presets/window-level.json"));
    }
    const std::string doc = readAll(source / "docs/session-json.md");
    const auto start = doc.find("```json\n");
    if (start != std::string::npos) {
      const auto end = doc.find("```", start + 8);
      seed(documents, "session.json", 1, doc.substr(start + 8, end - start - 8));
    }
  }
  fs::remove_all(work);
  std::cout << "seeds written to " << out << "\n";
  return 0;
}
