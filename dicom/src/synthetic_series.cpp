#include "octoray/dicom/synthetic_series.h"

#include <gdcmDataElement.h>
#include <gdcmDataSet.h>
#include <gdcmFile.h>
#include <gdcmImage.h>
#include <gdcmImageChangeTransferSyntax.h>
#include <gdcmItem.h>
#include <gdcmPhotometricInterpretation.h>
#include <gdcmPixelFormat.h>
#include <gdcmSequenceOfItems.h>
#include <gdcmTransferSyntax.h>
#include <gdcmWriter.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <numbers>
#include <system_error>

#include <fmt/format.h>

#include "octoray/core/error.h"

namespace octoray::dicom {
namespace {

constexpr const char* kCtImageStorage = "1.2.840.10008.5.1.4.1.1.2";
constexpr const char* kEnhancedCtImageStorage = "1.2.840.10008.5.1.4.1.1.2.1";
constexpr const char* kSecondaryCaptureStorage = "1.2.840.10008.5.1.4.1.1.7";

// ---- Deterministic UIDs ---------------------------------------------------------------------

uint64_t splitMix64(uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

uint64_t hashString(const std::string& s) {
  uint64_t h = 0xCBF29CE484222325ull;  // FNV-1a
  for (unsigned char ch : s) h = (h ^ ch) * 0x100000001B3ull;
  return h;
}

// A "2.25." UID (PS3.5 §B.2: the decimal form of a UUID) made from the seed and a purpose,
// so the same spec always yields the same UIDs without a registered organisation root.
std::string deterministicUid(uint64_t seed, const std::string& purpose, uint64_t index = 0) {
  const uint64_t base = splitMix64(seed ^ splitMix64(hashString(purpose) + index));
  uint64_t hi = splitMix64(base);
  uint64_t lo = splitMix64(base + 1);
  hi = (hi & ~0xF000ull) | 0x8000ull;                        // UUID version 8 (custom)
  lo = (lo & 0x3FFFFFFFFFFFFFFFull) | 0x8000000000000000ull;  // RFC 4122 variant
  std::array<uint32_t, 4> limbs{static_cast<uint32_t>(hi >> 32), static_cast<uint32_t>(hi),
                                static_cast<uint32_t>(lo >> 32), static_cast<uint32_t>(lo)};
  std::string digits;
  while (std::any_of(limbs.begin(), limbs.end(), [](uint32_t v) { return v != 0; })) {
    uint64_t remainder = 0;
    for (uint32_t& limb : limbs) {
      const uint64_t value = (remainder << 32) | limb;
      limb = static_cast<uint32_t>(value / 10);
      remainder = value % 10;
    }
    digits.push_back(static_cast<char>('0' + remainder));
  }
  std::reverse(digits.begin(), digits.end());
  return "2.25." + (digits.empty() ? std::string("0") : digits);
}

// ---- Decimal strings exactly as written ---------------------------------------------------

// A DS value of at most 16 characters; tiny magnitudes are written as 0.
std::string decimalString(double v) {
  if (std::abs(v) < 1e-9) v = 0;
  return fmt::format("{:.10g}", v);
}
double writtenDecimal(double v) { return std::strtod(decimalString(v).c_str(), nullptr); }
Vec3 writtenVec(Vec3 v) { return {writtenDecimal(v.x), writtenDecimal(v.y), writtenDecimal(v.z)}; }
std::string vecString(Vec3 v) {
  return decimalString(v.x) + "\\" + decimalString(v.y) + "\\" + decimalString(v.z);
}

// ---- Data set helpers ----------------------------------------------------------------------

// Puts a string element, padded to even length as PS3.5 §6.2 requires (NUL for UI).
void putString(gdcm::DataSet& ds, uint16_t group, uint16_t element, gdcm::VR vr,
               std::string value) {
  if (value.size() % 2 != 0) value.push_back(vr == gdcm::VR::UI ? '\0' : ' ');
  gdcm::DataElement de(gdcm::Tag(group, element));
  de.SetVR(vr);
  de.SetByteValue(value.data(), static_cast<uint32_t>(value.size()));
  ds.Replace(de);
}

// Binary elements hold host (little-endian) order in memory; gdcm::Writer swaps them for
// Explicit VR Big Endian.
void putUShort(gdcm::DataSet& ds, uint16_t group, uint16_t element, uint16_t value,
               gdcm::VR vr = gdcm::VR::US) {
  gdcm::DataElement de(gdcm::Tag(group, element));
  de.SetVR(vr);
  de.SetByteValue(reinterpret_cast<const char*>(&value), 2);
  ds.Replace(de);
}

void putSequence(gdcm::DataSet& ds, uint16_t group, uint16_t element,
                 const std::vector<gdcm::DataSet>& items) {
  gdcm::SmartPointer<gdcm::SequenceOfItems> sequence = new gdcm::SequenceOfItems();
  sequence->SetLengthToUndefined();
  for (const gdcm::DataSet& nested : items) {
    gdcm::Item item;
    item.SetVLToUndefined();
    item.SetNestedDataSet(nested);
    sequence->AddItem(item);
  }
  gdcm::DataElement de(gdcm::Tag(group, element));
  de.SetVR(gdcm::VR::SQ);
  de.SetValue(*sequence);
  de.SetVLToUndefined();
  ds.Replace(de);
}

gdcm::TransferSyntax::TSType gdcmSyntax(SyntheticTransferSyntax syntax) {
  switch (syntax) {
    case SyntheticTransferSyntax::ExplicitVRLittleEndian:
      return gdcm::TransferSyntax::ExplicitVRLittleEndian;
    case SyntheticTransferSyntax::ImplicitVRLittleEndian:
      return gdcm::TransferSyntax::ImplicitVRLittleEndian;
    case SyntheticTransferSyntax::ExplicitVRBigEndian:
      return gdcm::TransferSyntax::ExplicitVRBigEndian;
    case SyntheticTransferSyntax::RLELossless:
      return gdcm::TransferSyntax::RLELossless;
    case SyntheticTransferSyntax::JPEGLossless:
      return gdcm::TransferSyntax::JPEGLosslessProcess14_1;
    case SyntheticTransferSyntax::JPEGLSLossless:
      return gdcm::TransferSyntax::JPEGLSLossless;
    case SyntheticTransferSyntax::JPEG2000Lossless:
      return gdcm::TransferSyntax::JPEG2000Lossless;
  }
  return gdcm::TransferSyntax::ExplicitVRLittleEndian;
}

bool isNativeSyntax(SyntheticTransferSyntax syntax) {
  return syntax == SyntheticTransferSyntax::ExplicitVRLittleEndian ||
         syntax == SyntheticTransferSyntax::ImplicitVRLittleEndian ||
         syntax == SyntheticTransferSyntax::ExplicitVRBigEndian;
}

// ---- Pixel data -----------------------------------------------------------------------------

// The pixel module of one object: what the pixel bytes mean.
struct PixelLayout {
  int rows = 0;
  int columns = 0;
  int frames = 1;
  int bitsAllocated = 16;
  int bitsStored = 16;
  bool pixelSigned = false;
  bool monochrome1 = false;
};

void putPixelModule(gdcm::DataSet& ds, const PixelLayout& layout) {
  putUShort(ds, 0x0028, 0x0002, 1);
  putString(ds, 0x0028, 0x0004, gdcm::VR::CS, layout.monochrome1 ? "MONOCHROME1" : "MONOCHROME2");
  putUShort(ds, 0x0028, 0x0010, static_cast<uint16_t>(layout.rows));
  putUShort(ds, 0x0028, 0x0011, static_cast<uint16_t>(layout.columns));
  putUShort(ds, 0x0028, 0x0100, static_cast<uint16_t>(layout.bitsAllocated));
  putUShort(ds, 0x0028, 0x0101, static_cast<uint16_t>(layout.bitsStored));
  putUShort(ds, 0x0028, 0x0102, static_cast<uint16_t>(layout.bitsStored - 1));
  putUShort(ds, 0x0028, 0x0103, layout.pixelSigned ? 1 : 0);
}

// Native pixel bytes (little-endian words) encoded into `syntax` by GDCM's codecs.
gdcm::DataElement encodePixelData(std::vector<char> bytes, const PixelLayout& layout,
                                  SyntheticTransferSyntax syntax, const std::string& path) {
  gdcm::DataElement native(gdcm::Tag(0x7fe0, 0x0010));
  native.SetVR(layout.bitsAllocated == 8 ? gdcm::VR::OB : gdcm::VR::OW);
  native.SetByteValue(bytes.data(), static_cast<uint32_t>(bytes.size()));
  if (isNativeSyntax(syntax)) return native;

  // The filter keeps a reference-counted pointer to its input: it must live on the heap.
  gdcm::SmartPointer<gdcm::Image> image = new gdcm::Image;
  image->SetNumberOfDimensions(layout.frames > 1 ? 3 : 2);
  image->SetDimension(0, static_cast<unsigned int>(layout.columns));
  image->SetDimension(1, static_cast<unsigned int>(layout.rows));
  if (layout.frames > 1) image->SetDimension(2, static_cast<unsigned int>(layout.frames));
  const gdcm::PixelFormat format(1, static_cast<unsigned short>(layout.bitsAllocated),
                                 static_cast<unsigned short>(layout.bitsStored),
                                 static_cast<unsigned short>(layout.bitsStored - 1),
                                 layout.pixelSigned ? 1 : 0);
  image->SetPixelFormat(format);
  image->SetPhotometricInterpretation(layout.monochrome1 ? gdcm::PhotometricInterpretation::MONOCHROME1
                                                        : gdcm::PhotometricInterpretation::MONOCHROME2);
  image->SetTransferSyntax(gdcm::TransferSyntax::ExplicitVRLittleEndian);
  image->SetDataElement(native);

  gdcm::ImageChangeTransferSyntax change;
  change.SetTransferSyntax(gdcmSyntax(syntax));
  change.SetInput(*image);
  if (!change.Change()) {
    throw Error(path, fmt::format("GDCM could not encode the pixel data as {}",
                                  transferSyntaxUid(syntax)));
  }
  // A lossless codec must not have changed what the pixels mean.
  const gdcm::Pixmap& out = change.GetOutput();
  if (!(out.GetPixelFormat() == format) ||
      out.GetPhotometricInterpretation() != image->GetPhotometricInterpretation()) {
    throw Error(path, fmt::format("GDCM changed the pixel format while encoding {}",
                                  transferSyntaxUid(syntax)));
  }
  gdcm::DataElement encoded = out.GetDataElement();
  encoded.SetTag(gdcm::Tag(0x7fe0, 0x0010));
  return encoded;
}

void writeDataSet(const std::filesystem::path& path, const gdcm::DataSet& ds,
                  SyntheticTransferSyntax syntax) {
  gdcm::Writer writer;
  writer.SetFileName(path.string().c_str());
  writer.GetFile().GetHeader().SetDataSetTransferSyntax(gdcmSyntax(syntax));
  writer.GetFile().SetDataSet(ds);
  if (!writer.Write()) throw Error(path.string(), "GDCM could not write the file");
}

// ---- The series geometry ------------------------------------------------------------------

struct SeriesGeometry {
  Vec3 rowDirection, columnDirection, normal;
  double rowSpacingMm = 0, columnSpacingMm = 0;
  double slope = 1, intercept = 0;
  int storedMin = 0, storedMax = 0;
};

// Validates `spec` and derives the geometry exactly as it will be written.
SeriesGeometry resolveGeometry(const SyntheticSeriesSpec& spec, const std::string& where) {
  auto fail = [&](const std::string& reason) { throw Error(where, "synthetic series: " + reason); };
  if (spec.rows < 1 || spec.columns < 1 || spec.rows > 4096 || spec.columns > 4096) {
    fail(fmt::format("{} x {} pixels: rows and columns must be 1..4096", spec.rows, spec.columns));
  }
  if (!(spec.rowSpacingMm > 0) || !(spec.columnSpacingMm > 0) ||
      !std::isfinite(spec.rowSpacingMm) || !std::isfinite(spec.columnSpacingMm)) {
    fail("pixel spacing must be positive");
  }
  if (spec.sliceDistancesMm.empty() && (spec.sliceCount < 1 || !(spec.sliceSpacingMm > 0))) {
    fail("need at least one slice and a positive slice spacing");
  }
  if (spec.bitsStored < 8 || spec.bitsStored > 16) fail("BitsStored must be 8..16");
  if (spec.bitsStored == 16 ? spec.highBitsPattern != 0
                            : spec.highBitsPattern >> (16 - spec.bitsStored) != 0) {
    fail(fmt::format("high-bits pattern {:#x} does not fit above BitsStored {}",
                     spec.highBitsPattern, spec.bitsStored));
  }
  // JPEG-family codecs encode BitsStored bits only: garbage above them would not survive.
  if (spec.highBitsPattern != 0 && !isNativeSyntax(spec.transferSyntax) &&
      spec.transferSyntax != SyntheticTransferSyntax::RLELossless) {
    fail("bits above HighBit can only be written uncompressed or RLE");
  }
  if (spec.rescaleSlope == 0 || !std::isfinite(spec.rescaleSlope)) fail("RescaleSlope is 0");
  if (!(std::abs(spec.tiltDegrees) < 60)) fail("gantry tilt must be within +-60 degrees");

  SeriesGeometry g;
  const Vec3 rowDir = normalize(spec.rowDirection);
  const Vec3 colDir = spec.columnDirection - dot(spec.columnDirection, rowDir) * rowDir;
  if (length(rowDir) < 0.5 || length(colDir) < 1e-6) {
    fail("row and column directions must be non-zero and not parallel");
  }
  g.rowDirection = writtenVec(rowDir);
  g.columnDirection = writtenVec(normalize(colDir));
  g.normal = normalize(cross(g.rowDirection, g.columnDirection));
  g.rowSpacingMm = writtenDecimal(spec.rowSpacingMm);
  g.columnSpacingMm = writtenDecimal(spec.columnSpacingMm);
  g.slope = writtenDecimal(spec.rescaleSlope);
  g.intercept = writtenDecimal(spec.rescaleIntercept);
  const bool isSigned = spec.storage == SyntheticStorage::Int16;
  g.storedMin = isSigned ? -(1 << (spec.bitsStored - 1)) : 0;
  g.storedMax = isSigned ? (1 << (spec.bitsStored - 1)) - 1 : (1 << spec.bitsStored) - 1;
  if (spec.pixelPaddingValue &&
      (*spec.pixelPaddingValue < g.storedMin || *spec.pixelPaddingValue > g.storedMax)) {
    fail(fmt::format("PixelPaddingValue {} is outside the stored range {}..{}",
                     *spec.pixelPaddingValue, g.storedMin, g.storedMax));
  }
  return g;
}

Vec3 slicePosition(const SyntheticSeriesSpec& spec, const SeriesGeometry& g, double distanceMm) {
  const double tiltShiftMm = std::tan(spec.tiltDegrees * std::numbers::pi / 180) * distanceMm;
  const Vec3 toFirstPixel = (-0.5 * (spec.columns - 1) * g.columnSpacingMm) * g.rowDirection +
                            (-0.5 * (spec.rows - 1) * g.rowSpacingMm) * g.columnDirection;
  return writtenVec(spec.centreMm + distanceMm * g.normal + tiltShiftMm * g.columnDirection +
                    toFirstPixel);
}

int storedValue(double hu, const SeriesGeometry& g, Vec3 p, const std::string& where) {
  const double stored = std::round((hu - g.intercept) / g.slope);
  if (!(stored >= g.storedMin && stored <= g.storedMax)) {
    throw Error(where, fmt::format("synthetic series: value {:.1f} HU at ({:.2f}, {:.2f}, {:.2f}) "
                                   "mm does not fit the stored range {}..{} (change the rescale "
                                   "or the extent)", hu, p.x, p.y, p.z, g.storedMin, g.storedMax));
  }
  return static_cast<int>(stored);
}

// Encodes one frame's stored values as 16-bit words with the spec's bits above HighBit.
void appendFrame(std::vector<char>& bytes, const SyntheticSeriesSpec& spec,
                 const SeriesGeometry& g, Vec3 firstPixelMm, Vec3 rowDir, Vec3 colDir,
                 double rowSpacingMm, double columnSpacingMm, bool withPadding,
                 const std::string& where) {
  const uint32_t mask = (1u << spec.bitsStored) - 1;
  const uint32_t high = spec.bitsStored < 16 ? uint32_t{spec.highBitsPattern} << spec.bitsStored : 0;
  for (int r = 0; r < spec.rows; ++r) {
    for (int c = 0; c < spec.columns; ++c) {
      int stored = 0;
      if (withPadding && spec.pixelPaddingValue && syntheticIsPadding(spec, c, r)) {
        stored = *spec.pixelPaddingValue;
      } else {
        const Vec3 p = firstPixelMm + (c * columnSpacingMm) * rowDir + (r * rowSpacingMm) * colDir;
        stored = storedValue(syntheticHu(p, spec.pattern), g, p, where);
      }
      const auto word = static_cast<uint16_t>((static_cast<uint32_t>(stored) & mask) | high);
      bytes.push_back(static_cast<char>(word & 0xFF));  // little-endian: GDCM's native order
      bytes.push_back(static_cast<char>(word >> 8));
    }
  }
}

// Patient, study, series and equipment attributes shared by every object of the exam.
void putCommon(gdcm::DataSet& ds, const SyntheticSeriesSpec& spec, const SyntheticSeries& out,
               const std::string& sopClass, const std::string& sopInstance) {
  putString(ds, 0x0008, 0x0005, gdcm::VR::CS, "ISO_IR 100");
  putString(ds, 0x0008, 0x0016, gdcm::VR::UI, sopClass);
  putString(ds, 0x0008, 0x0018, gdcm::VR::UI, sopInstance);
  putString(ds, 0x0008, 0x0020, gdcm::VR::DA, "20240101");
  putString(ds, 0x0008, 0x0030, gdcm::VR::TM, "120000");
  putString(ds, 0x0008, 0x0050, gdcm::VR::SH, fmt::format("SYN{}", spec.seed % 1000000));
  putString(ds, 0x0008, 0x0070, gdcm::VR::LO, "octoray");
  putString(ds, 0x0010, 0x0010, gdcm::VR::PN, spec.patientName);
  putString(ds, 0x0010, 0x0020, gdcm::VR::LO,
            spec.patientId.empty() ? fmt::format("SYN{}", spec.seed % 1000000) : spec.patientId);
  putString(ds, 0x0020, 0x000D, gdcm::VR::UI, out.studyUid);
  putString(ds, 0x0020, 0x0010, gdcm::VR::SH, "1");
}

void putRescale(gdcm::DataSet& ds, const SeriesGeometry& g) {
  putString(ds, 0x0028, 0x1050, gdcm::VR::DS, "40");
  putString(ds, 0x0028, 0x1051, gdcm::VR::DS, "400");
  putString(ds, 0x0028, 0x1052, gdcm::VR::DS, decimalString(g.intercept));
  putString(ds, 0x0028, 0x1053, gdcm::VR::DS, decimalString(g.slope));
  putString(ds, 0x0028, 0x1054, gdcm::VR::LO, "HU");
}

void putPadding(gdcm::DataSet& ds, const SyntheticSeriesSpec& spec) {
  if (!spec.pixelPaddingValue) return;
  const bool isSigned = spec.storage == SyntheticStorage::Int16;
  putUShort(ds, 0x0028, 0x0120, static_cast<uint16_t>(*spec.pixelPaddingValue),
            isSigned ? gdcm::VR::SS : gdcm::VR::US);
}

PixelLayout sliceLayout(const SyntheticSeriesSpec& spec, int frames) {
  PixelLayout layout;
  layout.rows = spec.rows;
  layout.columns = spec.columns;
  layout.frames = frames;
  layout.bitsStored = spec.bitsStored;
  layout.pixelSigned = spec.storage == SyntheticStorage::Int16;
  layout.monochrome1 = spec.monochrome1;
  return layout;
}

// The written slices in file order: positions in order (or reversed), a duplicate right
// after its original, the dropped position left out.
std::vector<SyntheticImage> plannedSlices(const SyntheticSeriesSpec& spec,
                                          const SeriesGeometry& g, const std::string& where) {
  const std::vector<double> distances = syntheticSliceDistances(spec);
  const int count = static_cast<int>(distances.size());
  auto checkIndex = [&](int index, const char* what) {
    if (index >= count) {
      throw Error(where, fmt::format("synthetic series: {} slice {} of {}", what, index, count));
    }
  };
  checkIndex(spec.duplicateSliceIndex, "duplicate");
  checkIndex(spec.dropSliceIndex, "dropped");
  if (spec.dropSliceIndex >= 0 && spec.dropSliceIndex == spec.duplicateSliceIndex) {
    throw Error(where, "synthetic series: the same slice cannot be dropped and duplicated");
  }
  std::vector<SyntheticImage> slices;
  for (int n = 0; n < count; ++n) {
    const int index = spec.reverseFileOrder ? count - 1 - n : n;
    if (index == spec.dropSliceIndex) continue;
    SyntheticImage image;
    image.positionIndex = index;
    image.distanceMm = distances[static_cast<std::size_t>(index)];
    image.positionMm = slicePosition(spec, g, image.distanceMm);
    slices.push_back(image);
    if (index == spec.duplicateSliceIndex) {
      image.duplicate = true;
      slices.push_back(image);
    }
  }
  if (slices.empty()) throw Error(where, "synthetic series: every slice was dropped");
  for (std::size_t n = 0; n < slices.size(); ++n) slices[n].instanceNumber = static_cast<int>(n) + 1;
  return slices;
}

void writeSingleFrameSlices(const std::filesystem::path& folder, const SyntheticSeriesSpec& spec,
                            const SeriesGeometry& g, std::vector<SyntheticImage> slices,
                            SyntheticSeries& out) {
  const PixelLayout layout = sliceLayout(spec, 1);
  for (SyntheticImage& image : slices) {
    image.path = folder / fmt::format("CT{:04d}.dcm", image.instanceNumber);
    const std::string where = image.path.string();
    gdcm::DataSet ds;
    putCommon(ds, spec, out, kCtImageStorage,
              deterministicUid(spec.seed, "ct-instance", static_cast<uint64_t>(image.instanceNumber)));
    putString(ds, 0x0008, 0x0008, gdcm::VR::CS, "ORIGINAL\\PRIMARY\\AXIAL");
    putString(ds, 0x0008, 0x0060, gdcm::VR::CS, "CT");
    putString(ds, 0x0008, 0x103E, gdcm::VR::LO, spec.seriesDescription);
    putString(ds, 0x0018, 0x0050, gdcm::VR::DS, decimalString(out.sliceThicknessMm));
    putString(ds, 0x0018, 0x1120, gdcm::VR::DS, decimalString(out.tiltDegrees));
    putString(ds, 0x0020, 0x000E, gdcm::VR::UI, out.seriesUid);
    putString(ds, 0x0020, 0x0011, gdcm::VR::IS, std::to_string(spec.seriesNumber));
    putString(ds, 0x0020, 0x0013, gdcm::VR::IS, std::to_string(image.instanceNumber));
    putString(ds, 0x0020, 0x0032, gdcm::VR::DS, vecString(image.positionMm));
    putString(ds, 0x0020, 0x0037, gdcm::VR::DS,
              vecString(g.rowDirection) + "\\" + vecString(g.columnDirection));
    putString(ds, 0x0020, 0x0052, gdcm::VR::UI, deterministicUid(spec.seed, "frame-of-reference"));
    putString(ds, 0x0020, 0x1041, gdcm::VR::DS, decimalString(image.distanceMm));
    putPixelModule(ds, layout);
    putString(ds, 0x0028, 0x0030, gdcm::VR::DS,
              decimalString(g.rowSpacingMm) + "\\" + decimalString(g.columnSpacingMm));
    putPadding(ds, spec);
    putRescale(ds, g);
    std::vector<char> bytes;
    appendFrame(bytes, spec, g, image.positionMm, g.rowDirection, g.columnDirection,
                g.rowSpacingMm, g.columnSpacingMm, true, where);
    ds.Replace(encodePixelData(std::move(bytes), layout, spec.transferSyntax, where));
    writeDataSet(image.path, ds, spec.transferSyntax);
    out.files.push_back(image.path);
    out.images.push_back(image);
  }
}

// One Enhanced CT Image object (PS3.3 A.38) holding every slice as a frame: geometry and
// rescale in the shared functional groups, one PlanePosition per frame.
void writeEnhancedSlices(const std::filesystem::path& folder, const SyntheticSeriesSpec& spec,
                         const SeriesGeometry& g, std::vector<SyntheticImage> slices,
                         SyntheticSeries& out) {
  const std::filesystem::path path = folder / "ECT0001.dcm";
  const std::string where = path.string();
  const PixelLayout layout = sliceLayout(spec, static_cast<int>(slices.size()));
  gdcm::DataSet ds;
  putCommon(ds, spec, out, kEnhancedCtImageStorage, deterministicUid(spec.seed, "enhanced-ct"));
  putString(ds, 0x0008, 0x0008, gdcm::VR::CS, "ORIGINAL\\PRIMARY\\AXIAL\\NONE");
  putString(ds, 0x0008, 0x0023, gdcm::VR::DA, "20240101");
  putString(ds, 0x0008, 0x0033, gdcm::VR::TM, "120000");
  putString(ds, 0x0008, 0x0060, gdcm::VR::CS, "CT");
  putString(ds, 0x0008, 0x103E, gdcm::VR::LO, spec.seriesDescription);
  putString(ds, 0x0008, 0x9205, gdcm::VR::CS, "MONOCHROME");
  putString(ds, 0x0008, 0x9206, gdcm::VR::CS, "VOLUME");
  putString(ds, 0x0008, 0x9207, gdcm::VR::CS, "NONE");
  putString(ds, 0x0020, 0x000E, gdcm::VR::UI, out.seriesUid);
  putString(ds, 0x0020, 0x0011, gdcm::VR::IS, std::to_string(spec.seriesNumber));
  putString(ds, 0x0020, 0x0013, gdcm::VR::IS, "1");
  putString(ds, 0x0020, 0x0052, gdcm::VR::UI, deterministicUid(spec.seed, "frame-of-reference"));
  putString(ds, 0x0028, 0x0008, gdcm::VR::IS, std::to_string(slices.size()));
  putPixelModule(ds, layout);
  putPadding(ds, spec);

  gdcm::DataSet measures;
  putString(measures, 0x0028, 0x0030, gdcm::VR::DS,
            decimalString(g.rowSpacingMm) + "\\" + decimalString(g.columnSpacingMm));
  putString(measures, 0x0018, 0x0050, gdcm::VR::DS, decimalString(out.sliceThicknessMm));
  gdcm::DataSet orientation;
  putString(orientation, 0x0020, 0x0037, gdcm::VR::DS,
            vecString(g.rowDirection) + "\\" + vecString(g.columnDirection));
  gdcm::DataSet transformation;
  putString(transformation, 0x0028, 0x1052, gdcm::VR::DS, decimalString(g.intercept));
  putString(transformation, 0x0028, 0x1053, gdcm::VR::DS, decimalString(g.slope));
  putString(transformation, 0x0028, 0x1054, gdcm::VR::LO, "HU");
  gdcm::DataSet acquisition;
  putString(acquisition, 0x0018, 0x1120, gdcm::VR::DS, decimalString(out.tiltDegrees));
  gdcm::DataSet window;
  putString(window, 0x0028, 0x1050, gdcm::VR::DS, "40");
  putString(window, 0x0028, 0x1051, gdcm::VR::DS, "400");
  gdcm::DataSet shared;
  putSequence(shared, 0x0028, 0x9132, {window});          // FrameVOILUTSequence
  putSequence(shared, 0x0028, 0x9110, {measures});        // PixelMeasuresSequence
  putSequence(shared, 0x0020, 0x9116, {orientation});     // PlaneOrientationSequence
  putSequence(shared, 0x0028, 0x9145, {transformation});  // PixelValueTransformationSequence
  putSequence(shared, 0x0018, 0x9301, {acquisition});     // CTAcquisitionDetailsSequence
  putSequence(ds, 0x5200, 0x9229, {shared});

  std::vector<gdcm::DataSet> perFrame;
  std::vector<char> bytes;
  for (std::size_t frame = 0; frame < slices.size(); ++frame) {
    SyntheticImage& image = slices[frame];
    image.path = path;
    image.frameIndex = static_cast<int>(frame);
    gdcm::DataSet position;
    putString(position, 0x0020, 0x0032, gdcm::VR::DS, vecString(image.positionMm));
    gdcm::DataSet content;
    const auto stackPosition = static_cast<uint32_t>(image.positionIndex + 1);
    gdcm::DataElement inStack(gdcm::Tag(0x0020, 0x9057));  // InStackPositionNumber (UL)
    inStack.SetVR(gdcm::VR::UL);
    inStack.SetByteValue(reinterpret_cast<const char*>(&stackPosition), 4);
    content.Replace(inStack);
    gdcm::DataSet group;
    putSequence(group, 0x0020, 0x9111, {content});   // FrameContentSequence
    putSequence(group, 0x0020, 0x9113, {position});  // PlanePositionSequence
    if (static_cast<int>(frame) < spec.framesWithOwnWindow) {
      gdcm::DataSet own;
      putString(own, 0x0028, 0x1050, gdcm::VR::DS, decimalString(spec.ownWindow.first));
      putString(own, 0x0028, 0x1051, gdcm::VR::DS, decimalString(spec.ownWindow.second));
      putString(own, 0x0028, 0x1055, gdcm::VR::LO, "LUNG");
      putSequence(group, 0x0028, 0x9132, {own});  // FrameVOILUTSequence
    }
    perFrame.push_back(group);
    appendFrame(bytes, spec, g, image.positionMm, g.rowDirection, g.columnDirection,
                g.rowSpacingMm, g.columnSpacingMm, true, where);
  }
  putSequence(ds, 0x5200, 0x9230, perFrame);
  ds.Replace(encodePixelData(std::move(bytes), layout, spec.transferSyntax, where));
  writeDataSet(path, ds, spec.transferSyntax);
  out.files.push_back(path);
  out.images.insert(out.images.end(), slices.begin(), slices.end());
}

// A coronal scout through the centre of the stack (ImageType ...\LOCALIZER), explicit VR LE.
void writeLocalizer(const std::filesystem::path& folder, const SyntheticSeriesSpec& spec,
                    const SeriesGeometry& g, const std::vector<double>& distances,
                    SyntheticSeries& out) {
  const auto [nearIt, farIt] = std::minmax_element(distances.begin(), distances.end());
  const double midDistanceMm = 0.5 * (*nearIt + *farIt);
  const double extentMm = std::max(*farIt - *nearIt, 1.0);
  const Vec3 rowDir{1, 0, 0}, colDir{0, 0, -1};
  const double columnSpacingMm = g.columnSpacingMm;
  const double rowSpacingMm = writtenDecimal(spec.rows > 1 ? extentMm / (spec.rows - 1) : 1.0);
  const Vec3 centre = spec.centreMm + midDistanceMm * g.normal;
  const Vec3 first = writtenVec(centre - (0.5 * (spec.columns - 1) * columnSpacingMm) * rowDir -
                                (0.5 * (spec.rows - 1) * rowSpacingMm) * colDir);

  SyntheticImage image;
  image.object = SyntheticObject::Localizer;
  image.path = folder / "LOC0001.dcm";
  image.instanceNumber = 1;
  image.positionMm = first;
  const std::string where = image.path.string();
  gdcm::DataSet ds;
  putCommon(ds, spec, out, kCtImageStorage, deterministicUid(spec.seed, "localizer-instance"));
  putString(ds, 0x0008, 0x0008, gdcm::VR::CS, "ORIGINAL\\PRIMARY\\LOCALIZER");
  putString(ds, 0x0008, 0x0060, gdcm::VR::CS, "CT");
  putString(ds, 0x0008, 0x103E, gdcm::VR::LO, "Topogram");
  putString(ds, 0x0020, 0x000E, gdcm::VR::UI, out.localizerSeriesUid);
  putString(ds, 0x0020, 0x0011, gdcm::VR::IS, "1");
  putString(ds, 0x0020, 0x0013, gdcm::VR::IS, "1");
  putString(ds, 0x0020, 0x0032, gdcm::VR::DS, vecString(first));
  putString(ds, 0x0020, 0x0037, gdcm::VR::DS, vecString(rowDir) + "\\" + vecString(colDir));
  putString(ds, 0x0020, 0x0052, gdcm::VR::UI, deterministicUid(spec.seed, "frame-of-reference"));
  PixelLayout layout = sliceLayout(spec, 1);
  layout.monochrome1 = false;
  putPixelModule(ds, layout);
  putString(ds, 0x0028, 0x0030, gdcm::VR::DS,
            decimalString(rowSpacingMm) + "\\" + decimalString(columnSpacingMm));
  putRescale(ds, g);
  std::vector<char> bytes;
  appendFrame(bytes, spec, g, first, rowDir, colDir, rowSpacingMm, columnSpacingMm, false, where);
  ds.Replace(encodePixelData(std::move(bytes), layout,
                             SyntheticTransferSyntax::ExplicitVRLittleEndian, where));
  writeDataSet(image.path, ds, SyntheticTransferSyntax::ExplicitVRLittleEndian);
  out.files.push_back(image.path);
  out.images.push_back(image);
}

// An 8-bit Secondary Capture "screenshot" without plane geometry, explicit VR LE.
void writeSecondaryCapture(const std::filesystem::path& folder, const SyntheticSeriesSpec& spec,
                           SyntheticSeries& out) {
  SyntheticImage image;
  image.object = SyntheticObject::SecondaryCapture;
  image.path = folder / "SC0001.dcm";
  image.instanceNumber = 1;
  gdcm::DataSet ds;
  putCommon(ds, spec, out, kSecondaryCaptureStorage, deterministicUid(spec.seed, "sc-instance"));
  putString(ds, 0x0008, 0x0008, gdcm::VR::CS, "DERIVED\\SECONDARY");
  putString(ds, 0x0008, 0x0060, gdcm::VR::CS, "OT");
  putString(ds, 0x0008, 0x0064, gdcm::VR::CS, "WSD");
  putString(ds, 0x0008, 0x103E, gdcm::VR::LO, "Exam summary");
  putString(ds, 0x0020, 0x000E, gdcm::VR::UI, out.secondaryCaptureSeriesUid);
  putString(ds, 0x0020, 0x0011, gdcm::VR::IS, "99");
  putString(ds, 0x0020, 0x0013, gdcm::VR::IS, "1");
  PixelLayout layout;
  layout.rows = spec.rows;
  layout.columns = spec.columns;
  layout.bitsAllocated = 8;
  layout.bitsStored = 8;
  putPixelModule(ds, layout);
  std::vector<char> bytes;
  for (int r = 0; r < spec.rows; ++r) {
    for (int c = 0; c < spec.columns; ++c) bytes.push_back(static_cast<char>((4 * (r + c)) & 0xFF));
  }
  if (bytes.size() % 2 != 0) bytes.push_back(0);  // OB values have even length
  ds.Replace(encodePixelData(std::move(bytes), layout,
                             SyntheticTransferSyntax::ExplicitVRLittleEndian, image.path.string()));
  writeDataSet(image.path, ds, SyntheticTransferSyntax::ExplicitVRLittleEndian);
  out.files.push_back(image.path);
  out.images.push_back(image);
}

}  // namespace

double syntheticHu(Vec3 p, SyntheticPattern pattern) {
  // Distinct slopes along x, y and z, so swapped or mirrored axes show at once.
  const double linear = 3 * p.x - 2 * p.y + 5 * p.z;
  if (pattern == SyntheticPattern::Linear) return linear;
  return linear + 150 * std::sin(0.07 * p.x + 0.05 * p.y) + 100 * std::sin(0.09 * p.z - 0.03 * p.x);
}

double syntheticHuSecondDerivativeBound(SyntheticPattern pattern) {
  if (pattern == SyntheticPattern::Linear) return 0;
  // A sin(w.p) has |d²/ds²| <= A |w|² along any unit direction.
  return 150 * (0.07 * 0.07 + 0.05 * 0.05) + 100 * (0.09 * 0.09 + 0.03 * 0.03);
}

const char* transferSyntaxUid(SyntheticTransferSyntax syntax) {
  return gdcm::TransferSyntax::GetTSString(gdcmSyntax(syntax));
}

std::vector<double> syntheticSliceDistances(const SyntheticSeriesSpec& spec) {
  if (!spec.sliceDistancesMm.empty()) return spec.sliceDistancesMm;
  std::vector<double> distances;
  for (int k = 0; k < spec.sliceCount; ++k) distances.push_back(k * spec.sliceSpacingMm);
  return distances;
}

double syntheticWrittenHu(const SyntheticSeriesSpec& spec, Vec3 patientMm) {
  const double slope = writtenDecimal(spec.rescaleSlope);
  const double intercept = writtenDecimal(spec.rescaleIntercept);
  return slope * std::round((syntheticHu(patientMm, spec.pattern) - intercept) / slope) + intercept;
}

bool syntheticIsPadding(const SyntheticSeriesSpec& spec, int column, int row) {
  const double u = (column - 0.5 * (spec.columns - 1)) / (0.5 * spec.columns);
  const double v = (row - 0.5 * (spec.rows - 1)) / (0.5 * spec.rows);
  return u * u + v * v > 1;
}

std::vector<SyntheticImage> SyntheticSeries::slices() const {
  std::vector<SyntheticImage> result;
  for (const SyntheticImage& image : images) {
    if (image.object == SyntheticObject::Slice) result.push_back(image);
  }
  return result;
}

Vec3 SyntheticSeries::pixelPositionMm(const SyntheticImage& image, double column,
                                      double row) const {
  return image.positionMm + (column * columnSpacingMm) * rowDirection +
         (row * rowSpacingMm) * columnDirection;
}

SyntheticSeries writeSyntheticSeries(const std::filesystem::path& folder,
                                     const SyntheticSeriesSpec& spec) {
  const std::string where = folder.string();
  const SeriesGeometry g = resolveGeometry(spec, where);
  const std::vector<double> distances = syntheticSliceDistances(spec);
  std::vector<SyntheticImage> slices = plannedSlices(spec, g, where);

  std::error_code ec;
  std::filesystem::create_directories(folder, ec);
  if (ec) throw Error(where, "cannot create the folder: " + ec.message());

  SyntheticSeries out;
  out.studyUid = deterministicUid(spec.seed, "study");
  out.seriesUid = deterministicUid(spec.seed, "series");
  out.localizerSeriesUid = deterministicUid(spec.seed, "localizer-series");
  out.secondaryCaptureSeriesUid = deterministicUid(spec.seed, "sc-series");
  out.rowDirection = g.rowDirection;
  out.columnDirection = g.columnDirection;
  out.rowSpacingMm = g.rowSpacingMm;
  out.columnSpacingMm = g.columnSpacingMm;
  out.tiltDegrees = writtenDecimal(spec.tiltDegrees);
  out.transferSyntaxUid = transferSyntaxUid(spec.transferSyntax);

  // Nominal SliceThickness: the smallest non-zero gap, or the spacing for a single slice.
  double thicknessMm = spec.sliceThicknessMm;
  if (!(thicknessMm > 0)) {
    std::vector<double> sorted = distances;
    std::sort(sorted.begin(), sorted.end());
    thicknessMm = 0;
    for (std::size_t n = 1; n < sorted.size(); ++n) {
      const double gap = sorted[n] - sorted[n - 1];
      if (gap > 0 && (thicknessMm == 0 || gap < thicknessMm)) thicknessMm = gap;
    }
    if (thicknessMm == 0) thicknessMm = spec.sliceSpacingMm > 0 ? spec.sliceSpacingMm : 1.0;
  }
  out.sliceThicknessMm = writtenDecimal(thicknessMm);

  if (spec.layout == SyntheticLayout::EnhancedMultiFrame) {
    writeEnhancedSlices(folder, spec, g, std::move(slices), out);
  } else {
    writeSingleFrameSlices(folder, spec, g, std::move(slices), out);
  }
  if (spec.withLocalizer) writeLocalizer(folder, spec, g, distances, out);
  if (spec.withSecondaryCapture) writeSecondaryCapture(folder, spec, out);
  return out;
}

}  // namespace octoray::dicom
