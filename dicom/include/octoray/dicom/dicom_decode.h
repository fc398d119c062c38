#pragma once
// Decoding one DICOM file's pixel data (any transfer syntax GDCM decodes) into stored values,
// and the separate, named steps that turn stored values into physical values: the bit mask
// and sign extension of BitsStored, then the modality LUT (RescaleSlope/RescaleIntercept).

#include <cstdint>
#include <string>
#include <vector>

namespace octoray::dicom {

// Pixel-value attributes of an image (module "Image Pixel" and "CT Image").
struct PixelFormat {
  int rows = 0;
  int columns = 0;
  int frames = 1;
  int samplesPerPixel = 1;
  int bitsAllocated = 16;
  int bitsStored = 16;
  int highBit = 15;
  bool pixelSigned = false;          // PixelRepresentation == 1
  bool floatPixels = false;          // Float Pixel Data / Double Float Pixel Data
  std::string photometric;           // "MONOCHROME2", "MONOCHROME1", "RGB", ...
  bool hasPadding = false;           // PixelPaddingValue present
  double paddingValue = 0;           // PixelPaddingValue, as a stored value
  double paddingRangeLimit = 0;      // PixelPaddingRangeLimit, or paddingValue if absent
  std::string transferSyntaxUid;
};

struct DecodedImage {
  PixelFormat format;
  // Stored values after masking to BitsStored and sign extension, frame-major, then row-major.
  // Doubles hold every integer storage type (up to 32 bits) and float pixel data exactly.
  std::vector<double> stored;
  // The frames `stored` holds: from firstFrame on, as many as it holds (every frame from 0 for
  // decodeDicomFile; format.frames is the file's NumberOfFrames either way).
  int firstFrame = 0;

  std::size_t frameSamples() const {
    return static_cast<std::size_t>(format.rows) * static_cast<std::size_t>(format.columns);
  }
};

// Decodes every frame of `path`. Throws octoray::Error naming the file when the file is not
// DICOM, has no pixel data, is truncated, uses a codec GDCM cannot decode, has more than one
// sample per pixel (colour is not a CT volume), or its pixel data length does not match.
DecodedImage decodeDicomFile(const std::string& path);

// The stored value of the raw bits `raw` (BitsAllocated wide) after taking BitsStored bits
// below HighBit and sign-extending them when pixels are signed (PS3.5 §8.1.1).
double storedValueFromBits(uint32_t raw, const PixelFormat& format);

}  // namespace octoray::dicom
