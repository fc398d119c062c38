#include "octoray/dicom/dicom_decode.h"

#include <gdcmBoxRegion.h>
#include <gdcmImage.h>
#include <gdcmImageReader.h>
#include <gdcmImageRegionReader.h>
#include <gdcmPhotometricInterpretation.h>
#include <gdcmPixelFormat.h>
#include <gdcmSequenceOfFragments.h>
#include <gdcmTransferSyntax.h>

#include <algorithm>
#include <cstring>
#include <filesystem>
#include <limits>

#include <fmt/format.h>

#include "gdcm_support.h"
#include "octoray/core/error.h"

namespace octoray::dicom {
namespace {

template <typename T>
T loadLittleEndian(const char* p) {
  T v;
  std::memcpy(&v, p, sizeof(T));  // GDCM's decoded buffer is in host (little-endian) order
  return v;
}

constexpr const char* kNotDecodable =
    "not a decodable DICOM image (GDCM could not parse the file, or it has no pixel data)";

const char* syntaxName(const gdcm::TransferSyntax& ts) {
  const char* s = gdcm::TransferSyntax::GetTSString(ts);
  return s ? s : "unknown transfer syntax";
}

}  // namespace

double storedValueFromBits(uint32_t raw, const PixelFormat& format) {
  // PS3.5 §8.1.1: the value occupies bits [HighBit - BitsStored + 1, HighBit]; bits outside
  // (overlays, garbage) are not part of it.
  const int shift = format.highBit + 1 - format.bitsStored;
  const uint64_t mask = (uint64_t{1} << format.bitsStored) - 1;
  const uint64_t bits = (uint64_t{raw} >> shift) & mask;
  if (format.pixelSigned && (bits >> (format.bitsStored - 1)) & 1u) {
    return static_cast<double>(static_cast<int64_t>(bits) - static_cast<int64_t>(mask + 1));
  }
  return static_cast<double>(bits);
}

DecodedImage decodeDicomFile(const std::string& path) {
  detail::quietGdcm();
  if (!std::filesystem::is_regular_file(path)) throw Error(path, "no such file");
  detail::vetWithGdcm(path);
  DecodedImage image = detail::decodeVettedDicomFile(path);
  // GDCM pads truncated native pixel data silently: compare with what the file holds.
  const gdcm::TransferSyntax ts =
      gdcm::TransferSyntax::GetTSType(image.format.transferSyntaxUid.c_str());
  // Deflated data sets compress everything after the meta header: no length to compare.
  if (!ts.IsEncapsulated() && ts != gdcm::TransferSyntax::DeflatedExplicitVRLittleEndian) {
    const std::size_t offset = detail::pixelValueOffset(path);
    const uint64_t fileBytes = std::filesystem::file_size(path);
    const uint64_t needed = (image.stored.size() * static_cast<uint64_t>(image.format.bitsAllocated) + 7) / 8;
    if (offset == std::size_t(-1) || offset > fileBytes || fileBytes - offset < needed) {
      throw Error(path, fmt::format("pixel data holds {} bytes, {} needed (file truncated)",
                                    offset > fileBytes ? 0 : fileBytes - offset, needed));
    }
  }
  return image;
}

namespace {

// The pixel format of the image `reader` has read (at least its header), checked: the data
// set's own BitsStored, HighBit and PixelRepresentation, a scalar image, bits a CT can have,
// and the padding attributes.
PixelFormat readPixelFormat(const gdcm::ImageReader& reader, const std::string& path) {
  const gdcm::Image& image = reader.GetImage();
  const gdcm::PixelFormat& pf = image.GetPixelFormat();
  const unsigned int* dims = image.GetDimensions();
  const gdcm::TransferSyntax& ts = image.GetTransferSyntax();

  PixelFormat f;
  f.columns = static_cast<int>(dims[0]);
  f.rows = static_cast<int>(dims[1]);
  const unsigned int frames = image.GetNumberOfDimensions() == 3 ? dims[2] : 1;
  if (frames > static_cast<unsigned int>(std::numeric_limits<int>::max())) {
    throw Error(path, fmt::format("invalid NumberOfFrames {}", frames));
  }
  f.frames = static_cast<int>(frames);
  f.samplesPerPixel = pf.GetSamplesPerPixel();
  f.bitsAllocated = pf.GetBitsAllocated();
  f.bitsStored = pf.GetBitsStored();
  f.highBit = pf.GetHighBit();
  f.pixelSigned = pf.GetPixelRepresentation() == 1;
  // The data set's own BitsStored/HighBit/PixelRepresentation are the standard's truth;
  // GDCM replaces them with the JPEG 2000 codestream's precision ("correcting").
  {
    const gdcm::File& file = reader.GetFile();
    const gdcm::DataSet& ds = file.GetDataSet();
    const auto stored = detail::unsignedShort(file, ds, gdcm::Tag(0x0028, 0x0101));
    const auto high = detail::unsignedShort(file, ds, gdcm::Tag(0x0028, 0x0102));
    const auto representation = detail::unsignedShort(file, ds, gdcm::Tag(0x0028, 0x0103));
    // BitsStored above BitsAllocated cannot be: the header misdescribes the pixel data (GDCM
    // would go on with its own idea of the bits and decode garbage).
    if (stored && *stored > f.bitsAllocated) {
      throw Error(path, fmt::format("BitsStored {} exceeds BitsAllocated {}", *stored,
                                    f.bitsAllocated));
    }
    // A sign that is neither, or a high bit outside the allocated bits: no reading of the
    // samples is the file's (PixelRepresentation 7 read as unsigned turned a signed CT's
    // negative HU into large positive values, silently).
    if (representation && *representation > 1) {
      throw Error(path, fmt::format("PixelRepresentation {} is neither 0 (unsigned) nor 1 (signed)",
                                    *representation));
    }
    if (high && *high >= f.bitsAllocated) {
      throw Error(path,
                  fmt::format("HighBit {} is outside BitsAllocated {}", *high, f.bitsAllocated));
    }
    if (stored && high && *stored >= 1 && *stored <= f.bitsAllocated && *high < f.bitsAllocated &&
        *high >= *stored - 1) {
      f.bitsStored = *stored;
      f.highBit = *high;
    }
    if (representation && (*representation == 0 || *representation == 1)) {
      f.pixelSigned = *representation == 1;
    }
  }
  f.floatPixels = pf.GetScalarType() == gdcm::PixelFormat::FLOAT32 ||
                  pf.GetScalarType() == gdcm::PixelFormat::FLOAT64;
  const char* photometric = gdcm::PhotometricInterpretation::GetPIString(
      image.GetPhotometricInterpretation().GetType());
  f.photometric = photometric ? photometric : "";
  f.transferSyntaxUid = ts.GetString() ? ts.GetString() : "";

  if (f.samplesPerPixel != 1) {
    throw Error(path, fmt::format("colour image ({} samples per pixel, {}): not a scalar volume",
                                  f.samplesPerPixel, f.photometric));
  }
  if (f.rows <= 0 || f.columns <= 0 || f.frames <= 0) {
    throw Error(path, "image has zero rows, columns or frames");
  }
  const bool validBits = f.bitsAllocated == 1 || f.bitsAllocated == 8 || f.bitsAllocated == 16 ||
                         f.bitsAllocated == 32 || (f.floatPixels && f.bitsAllocated == 64);
  if (!validBits) {
    throw Error(path, fmt::format("unsupported BitsAllocated {} (1, 8, 16 or 32 expected)",
                                  f.bitsAllocated));
  }
  if (!f.floatPixels && (f.bitsStored < 1 || f.bitsStored > f.bitsAllocated ||
                         f.highBit < f.bitsStored - 1 || f.highBit >= f.bitsAllocated)) {
    throw Error(path, fmt::format("inconsistent BitsStored {} / HighBit {} for BitsAllocated {}",
                                  f.bitsStored, f.highBit, f.bitsAllocated));
  }

  // Padding attributes live in the data set, not in GDCM's image model.
  const gdcm::File& file = reader.GetFile();
  const gdcm::DataSet& ds = file.GetDataSet();
  if (auto pad = detail::unsignedShort(file, ds, gdcm::Tag(0x0028, 0x0120), f.pixelSigned)) {
    f.hasPadding = true;
    f.paddingValue = *pad;
    f.paddingRangeLimit = *pad;
    if (auto limit = detail::unsignedShort(file, ds, gdcm::Tag(0x0028, 0x0121), f.pixelSigned)) {
      f.paddingRangeLimit = *limit;
    }
  }
  return f;
}

// Stored values of `samples` samples of the decoded buffer `p` (GDCM's, in host order).
void convertSamples(const char* p, std::size_t samples, const PixelFormat& f,
                    const gdcm::TransferSyntax& ts, double* out) {
  if (f.floatPixels) {
    for (std::size_t i = 0; i < samples; ++i) {
      out[i] = f.bitsAllocated == 32 ? static_cast<double>(loadLittleEndian<float>(p + 4 * i))
                                     : loadLittleEndian<double>(p + 8 * i);
    }
  } else if (f.bitsAllocated == 1) {
    for (std::size_t i = 0; i < samples; ++i) {
      out[i] = (static_cast<unsigned char>(p[i / 8]) >> (i % 8)) & 1u;
    }
  } else if (f.bitsAllocated == 8) {
    for (std::size_t i = 0; i < samples; ++i) {
      out[i] = storedValueFromBits(static_cast<unsigned char>(p[i]), f);
    }
  } else if (f.bitsAllocated == 16) {
    for (std::size_t i = 0; i < samples; ++i) {
      out[i] = storedValueFromBits(loadLittleEndian<uint16_t>(p + 2 * i), f);
    }
  } else {
    // GDCM byte-swaps big-endian pixel data as 16-bit words: 32-bit values come out with
    // their halves exchanged.
    const bool halvesSwapped = ts == gdcm::TransferSyntax::ExplicitVRBigEndian;
    for (std::size_t i = 0; i < samples; ++i) {
      uint32_t raw = loadLittleEndian<uint32_t>(p + 4 * i);
      if (halvesSwapped) raw = (raw << 16) | (raw >> 16);
      out[i] = storedValueFromBits(raw, f);
    }
  }
}

}  // namespace

DecodedImage detail::decodeVettedDicomFile(const std::string& path) {
  detail::quietGdcm();
  gdcm::ImageReader reader;
  reader.SetFileName(path.c_str());
  if (!reader.Read()) {
    throw Error(path, kNotDecodable);
  }
  const gdcm::Image& image = reader.GetImage();
  const gdcm::TransferSyntax& ts = image.GetTransferSyntax();
  DecodedImage out;
  out.format = readPixelFormat(reader, path);
  const PixelFormat& f = out.format;

  // Sized by untrusted header values: checked against the pixel data's length, without
  // overflow, before anything is allocated. 1-bit samples are packed continuously across
  // frames, least significant bit first.
  std::size_t samples = 0, bits = 0;
  const bool overflow =
      __builtin_mul_overflow(out.frameSamples(), static_cast<std::size_t>(f.frames), &samples) ||
      __builtin_mul_overflow(samples, static_cast<std::size_t>(f.bitsAllocated), &bits) ||
      bits > std::numeric_limits<std::size_t>::max() - 7;
  const std::size_t expected = overflow ? std::numeric_limits<std::size_t>::max() : (bits + 7) / 8;
  const unsigned long length = image.GetBufferLength();
  if (overflow || length < expected) {
    throw Error(path, fmt::format("pixel data holds {} bytes, {} rows x {} columns x {} frames "
                                  "at {} bits need {}", length, f.rows, f.columns, f.frames,
                                  f.bitsAllocated, expected));
  }
  // GDCM sizes its buffer from Rows x Columns x NumberOfFrames; the pixel data itself must
  // back that: native data byte for byte, encapsulated data with a fragment per frame at least
  // (PS3.5 A.4; not video syntaxes, 1.2.840.10008.1.2.4.100-108, whose one stream spans them).
  const gdcm::DataElement& pixelData = image.GetDataElement();
  const bool video = f.transferSyntaxUid.starts_with("1.2.840.10008.1.2.4.10");
  if (const gdcm::ByteValue* native = pixelData.GetByteValue();
      native && native->GetLength() < expected) {
    throw Error(path, fmt::format("pixel data holds {} bytes, {} rows x {} columns x {} frames "
                                  "at {} bits need {}",
                                  native->GetLength(), f.rows, f.columns, f.frames, f.bitsAllocated,
                                  expected));
  }
  // Native bytes for twice the image or more: the header's sizes or bits do not describe the
  // data (16-bit samples under BitsAllocated 8, say), and its first half read as the image
  // would be a picture of garbage. Less excess is trailing padding, which some writers leave
  // (pydicom's MR_small_padded.dcm: 128 bytes) and readers drop, as here.
  if (const gdcm::ByteValue* native = pixelData.GetByteValue();
      native && expected > 0 && native->GetLength() / 2 >= expected) {
    throw Error(path, fmt::format("pixel data holds {} bytes, {} rows x {} columns x {} frames "
                                  "at {} bits fill {}: the header does not describe the data",
                                  native->GetLength(), f.rows, f.columns, f.frames, f.bitsAllocated,
                                  expected));
  }
  if (const gdcm::SequenceOfFragments* fragments = pixelData.GetSequenceOfFragments();
      fragments && !video &&
      fragments->GetNumberOfFragments() < static_cast<std::size_t>(f.frames)) {
    throw Error(path, fmt::format("NumberOfFrames {} but the pixel data has only {} fragment(s)",
                                  f.frames, fragments->GetNumberOfFragments()));
  }
  std::vector<char> buffer(length);
  if (!image.GetBuffer(buffer.data())) {
    throw Error(path, fmt::format("pixel data could not be decoded ({}, {})", syntaxName(ts),
                                  f.transferSyntaxUid));
  }

  out.stored.resize(samples);
  convertSamples(buffer.data(), samples, f, ts, out.stored.data());
  return out;
}

DecodedImage detail::decodeVettedDicomFrames(const std::string& path, int firstFrame,
                                             int frameCount) {
  detail::quietGdcm();
  // GDCM's region reader parses the header, then reads (and decodes) only the frames asked
  // for: native data from their offset, encapsulated data from their own fragments.
  gdcm::ImageRegionReader reader;
  reader.SetFileName(path.c_str());
  if (!reader.ReadInformation()) {
    throw Error(path, kNotDecodable);
  }
  DecodedImage out;
  out.format = readPixelFormat(reader, path);
  const PixelFormat& f = out.format;
  if (firstFrame < 0 || firstFrame >= f.frames || frameCount < 1) {
    throw Error(path, fmt::format("frame {} requested, file has {}", firstFrame + 1, f.frames));
  }
  const int count = std::min(frameCount, f.frames - firstFrame);
  out.firstFrame = firstFrame;
  const auto fromWholeFile = [&] {
    DecodedImage whole = decodeVettedDicomFile(path);
    const std::size_t n = whole.frameSamples();
    whole.stored.erase(whole.stored.begin() + static_cast<std::ptrdiff_t>(n * (firstFrame + count)),
                       whole.stored.end());
    whole.stored.erase(whole.stored.begin(),
                       whole.stored.begin() + static_cast<std::ptrdiff_t>(n * firstFrame));
    whole.stored.shrink_to_fit();
    whole.firstFrame = firstFrame;
    return whole;
  };
  // Whole bytes per sample, and a syntax whose frames GDCM finds alone: native (not deflated,
  // which must be inflated from its start), RLE, JPEG, JPEG-LS, JPEG 2000. Anything else (1-bit
  // samples packed across frames, video) is decoded whole and the frames cut out.
  const gdcm::TransferSyntax ts = reader.GetImage().GetTransferSyntax();
  const bool nativeData =
      !ts.IsEncapsulated() && ts != gdcm::TransferSyntax::DeflatedExplicitVRLittleEndian;
  using TS = gdcm::TransferSyntax;
  bool frameCodec = false;
  for (const TS::TSType codec :
       {TS::RLELossless, TS::JPEGBaselineProcess1, TS::JPEGExtendedProcess2_4,
        TS::JPEGLosslessProcess14, TS::JPEGLosslessProcess14_1, TS::JPEGLSLossless,
        TS::JPEGLSNearLossless, TS::JPEG2000Lossless, TS::JPEG2000}) {
    frameCodec = frameCodec || ts == codec;
  }
  if (f.bitsAllocated % 8 != 0 || !(nativeData || frameCodec)) return fromWholeFile();

  const std::size_t samples = out.frameSamples() * static_cast<std::size_t>(count);
  const std::size_t bytes = samples * static_cast<std::size_t>(f.bitsAllocated / 8);
  gdcm::BoxRegion box;
  box.SetDomain(0, static_cast<unsigned>(f.columns - 1), 0, static_cast<unsigned>(f.rows - 1),
                static_cast<unsigned>(firstFrame), static_cast<unsigned>(firstFrame + count - 1));
  reader.SetRegion(box);
  if (reader.ComputeBufferLength() != bytes) return fromWholeFile();
  std::vector<char> buffer(bytes);
  // GDCM declines frames it cannot find alone (encapsulated data without exactly one fragment
  // per frame, say): the whole file is decoded then, and says what is wrong with it, if anything.
  if (!reader.ReadIntoBuffer(buffer.data(), buffer.size())) return fromWholeFile();
  out.stored.resize(samples);
  convertSamples(buffer.data(), samples, f, ts, out.stored.data());
  return out;
}

}  // namespace octoray::dicom
