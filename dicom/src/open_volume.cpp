// openVolume(): picks the reader from what a path is. Extensions decide for files; a folder of
// TIFFs only is a TIFF stack; everything else goes to DICOM discovery, which also recognises
// single DICOM files without an extension and DICOMDIRs.

#include <algorithm>
#include <filesystem>

#include <fmt/format.h>

#include "octoray/dicom/dicom_series.h"
#include "octoray/dicom/dicom_volume.h"
#include "octoray/core/error.h"
#include "octoray/core/text.h"
#include "octoray/dicom/formats.h"

namespace octoray {

namespace {

namespace fs = std::filesystem;

std::string lowerCaseName(const fs::path& path) {
  return asciiLower(path.filename().string());
}

bool isTiffName(const std::string& lowerName) {
  return lowerName.ends_with(".tif") || lowerName.ends_with(".tiff");
}

// DICOM discovery of `path`; `folder` is its listing where it is a folder.
std::unique_ptr<VolumeSource> openDicom(const std::string& path, const OpenOptions& options,
                                        const TiffFolder* folder = nullptr) {
  const dicom::DicomScan scan = dicom::scanDicom(path);
  // A folder of TIFF files with something else beside them (notes, a subfolder), no DICOM
  // series and no DICOM file left out: the TIFF stack, which names what it leaves out. A DICOM
  // folder whose files are all damaged keeps its DICOM error, preview TIFFs or not.
  if (scan.series.empty() && folder && !folder->tiffNames.empty() &&
      std::none_of(scan.skipped.begin(), scan.skipped.end(),
                   [](const dicom::SkippedFile& f) { return dicom::isDicomPart10(f.path); })) {
    return openTiffStack(*folder, options.tiffSpacingMm);
  }
  if (scan.series.empty()) {
    if (fs::is_regular_file(path) && !scan.skipped.empty()) {
      throw Error(path, "not a supported volume format (" + scan.skipped.front().reason + ")");
    }
    throw Error(path,
                fmt::format("no DICOM image series found ({} files examined)", scan.filesExamined));
  }
  const std::size_t index = options.series.empty() ? dicom::defaultSeriesIndex(scan, path)
                                                   : dicom::findSeries(scan, options.series, path);
  return dicom::openDicomSeries(scan.series[index], options.stack);
}

}  // namespace

std::unique_ptr<VolumeSource> openVolume(const std::string& path, const OpenOptions& options) {
  if (options.raw) return openRawVolume(path, options.rawOptions);

  std::error_code ec;
  const auto status = fs::status(path, ec);
  if (ec || !fs::exists(status)) throw Error(path, "no such file or folder");
  if (fs::is_directory(status)) {
    // Only TIFF files: a TIFF stack. Anything else beside them: DICOM discovery first.
    const TiffFolder folder = listTiffFolder(path);
    if (!folder.tiffNames.empty() && folder.otherNames.empty()) {
      return openTiffStack(folder, options.tiffSpacingMm);
    }
    return openDicom(path, options, &folder);
  }
  if (!fs::is_regular_file(status)) throw Error(path, "not a regular file or folder");

  const std::string name = lowerCaseName(path);
  if (name.ends_with(".nrrd") || name.ends_with(".nhdr")) return openNrrd(path);
  if (name.ends_with(".mhd") || name.ends_with(".mha")) return openMetaImage(path);
  if (name.ends_with(".nii") || name.ends_with(".nii.gz") || name.ends_with(".hdr") ||
      name.ends_with(".hdr.gz")) {
    return openNifti(path);
  }
  if (isTiffName(name)) return openTiffStack(path, options.tiffSpacingMm);
  if (name.ends_with(".vdb")) return openVdb(path);
  // DICOMDIR, .dcm, or no telling extension: DICOM discovery decides.
  return openDicom(path, options);
}

}  // namespace octoray
