#pragma once
// Random access to an octree store: the header and node table are read and verified when the
// store is opened; each brick is read with pread, checked against its checksum and
// decompressed on request. Safe to call from many threads at once.

#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "octoray/core/geometry.h"
#include "octoray/dicom/volume_source.h"
#include "octoray/volume/octree_layout.h"
#include "octoray/volume/store_format.h"

namespace octoray::volume {

// Whether `path` is a regular file that starts with the store's magic bytes, or is named
// *.octoray (what decides between opening a store and importing a volume; StoreReader verifies
// the rest, so a damaged store is reported as a store, not as a DICOM file it never was).
bool isStoreFile(const std::filesystem::path& path);

// One decompressed brick: (B + 2A)^3 samples, x fastest, as stored (UInt16 or Float32).
struct Brick {
  int64_t nodeId = -1;
  int edge = 0;                       // B + 2A
  SampleFormat format = SampleFormat::UInt16;
  std::vector<uint16_t> u16;          // when format == UInt16
  std::vector<float> f32;             // when format == Float32
  std::vector<uint8_t> gradients;     // RGBA8 per sample when the store has gradients

  std::size_t byteSize() const {
    return u16.size() * 2 + f32.size() * 4 + gradients.size() + sizeof(Brick);
  }
};

// What a store's provenance says about the volume it was built from: the builder's "source"
// object (docs/store-format.md). A field the provenance lacks, or holds as another JSON type,
// is empty; a provenance that is not a JSON object gives an empty StoreSource (the validator
// reports it). Never patient names or paths: the builder does not record them.
struct StoreSource {
  std::string format;       // the reader that opened the source ("DICOM", "NRRD", ...)
  std::string modality;     // DICOM modality ("CT", ...)
  std::string description;  // series description
  std::string seriesUid;
  std::string unit;                   // "HU" where the values are Hounsfield units
  std::string contentHash;            // of the source files, where the builder was given it
  std::optional<bool> integerValues;  // whether every source value was an integer
  // The display windows the source named (VolumeInfo::windows); entries that are not a finite
  // center with a positive finite width are left out.
  std::vector<SourceWindow> windows;
};

// Parses the source fields out of provenance JSON (what StoreReader::source() holds).
StoreSource parseStoreSource(const std::string& provenanceJson);

class StoreReader {
 public:
  // Opens and verifies header, node table and provenance; throws octoray::Error naming the
  // file and the check that failed.
  explicit StoreReader(const std::string& path);
  ~StoreReader();
  StoreReader(const StoreReader&) = delete;
  StoreReader& operator=(const StoreReader&) = delete;

  const std::string& path() const { return path_; }
  const StoreHeader& header() const { return header_; }
  const OctreeLayout& layout() const { return layout_; }
  const std::vector<NodeRecord>& nodes() const { return nodes_; }
  const NodeRecord& node(int64_t id) const;
  const std::string& provenanceJson() const { return provenance_; }
  // The provenance's source fields, parsed when the store is opened.
  const StoreSource& source() const { return source_; }
  Mat4 patientFromIndex() const;
  SampleFormat sampleFormat() const { return static_cast<SampleFormat>(header_.sampleFormat); }
  // Physical value of a stored sample.
  double physical(double stored) const {
    return sampleFormat() == SampleFormat::UInt16 ? stored * header_.valueScale + header_.valueOffset
                                                  : stored;
  }

  // Reads, verifies and decompresses node `id` (constant nodes are expanded). Throws
  // octoray::Error naming the file and node on a checksum or decompression failure, or when
  // the samples leave the node's recorded [min, max] (a lying node table).
  Brick readBrick(int64_t id) const;
  // The same without the range check: for the validator, whose own checks say which part of
  // the store is inconsistent.
  Brick readBrickUnchecked(int64_t id) const;

 private:
  void checkRange(const Brick& brick, const NodeRecord& n, int64_t id) const;

  std::string path_;
  int fd_ = -1;
  StoreHeader header_{};
  OctreeLayout layout_;
  std::vector<NodeRecord> nodes_;
  std::string provenance_;
  StoreSource source_;
};

// Whether every value of a store's source was an integer: from the provenance; stores from
// before it said are judged by their sample format (16-bit with an integer offset and scale 1).
bool storeHoldsIntegerValues(const StoreReader& store);

// Whether a store's values are Hounsfield units (holdsHounsfieldUnits of volume_source.h, from
// its provenance, storeHoldsIntegerValues and its root's minimum).
bool storeHoldsHounsfieldUnits(const StoreReader& store, bool* guessed = nullptr);

// Parses and checks a header from raw bytes (used by the reader and the fuzz target).
// `fileBytes` is the actual size of the file it came from.
StoreHeader parseStoreHeader(const void* bytes, std::size_t size, uint64_t fileBytes,
                             const std::string& path);

}  // namespace octoray::volume
