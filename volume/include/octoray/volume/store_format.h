#pragma once
// The octree store file, as it lies on disk (little-endian, version 1):
//
//   [StoreHeader, 256 bytes] [payloads ...] [NodeRecord × nodeCount] [provenance JSON]
//
// Payloads are compressed bricks (values, then optional gradients; each byte-shuffled before
// compression: byte 0 of every sample, then byte 1, ...), each with an XXH3-64
// checksum in its NodeRecord; the node table and the provenance have checksums in the header,
// and the header has its own. The file is written under a temporary name and renamed when
// complete, so a file at the final name is always whole.

#include <bit>
#include <cstddef>
#include <cstdint>

namespace octoray::volume {

static_assert(std::endian::native == std::endian::little,
              "the store is little-endian; a big-endian host needs byte swapping here");

inline constexpr char kStoreMagic[8] = {'O', 'C', 'T', 'O', 'R', 'A', 'Y', '\x1a'};
inline constexpr uint32_t kStoreVersion = 1;

enum class SampleFormat : uint32_t {
  UInt16 = 0,   // physical = stored * valueScale + valueOffset (CT: HU + 1024)
  Float32 = 1,  // physical = stored
};

enum class Codec : uint32_t { None = 0, Lz4 = 1, Zstd = 2 };

enum StoreFlags : uint32_t {
  kStoreHasGradients = 1u << 0,  // every non-constant node has an RGBA8 gradient payload
};

enum NodeFlags : uint32_t {
  kNodeConstant = 1u << 0,  // every stored sample equals constantSample; no payload
};

struct StoreHeader {
  char magic[8];                   //   8: kStoreMagic
  uint32_t version;                //   4: kStoreVersion
  uint32_t headerBytes;            //   4: sizeof(StoreHeader)
  int64_t dims[3];                 //  24: leaf-level samples along i, j, k
  double patientFromIndex[12];     //  96: rows 0..2 of the leaf index -> patient (LPS mm) affine
  uint32_t brickSize;              //   4: B, samples per brick edge (16, 32 or 64)
  uint32_t border;                 //   4: A, replicated samples on each side (1 or 2)
  uint32_t levels;                 //   4: octree levels; level 0 is the root
  uint32_t sampleFormat;           //   4: SampleFormat
  double valueScale;               //   8: physical = stored * scale + offset (UInt16)
  double valueOffset;              //   8
  uint32_t codec;                  //   4: Codec of every payload
  uint32_t flags;                  //   4: StoreFlags
  uint64_t nodeCount;              //   8: records in the node table
  uint64_t nodeTableOffset;        //   8
  uint64_t nodeTableBytes;         //   8: nodeCount * sizeof(NodeRecord)
  uint64_t provenanceOffset;       //   8
  uint64_t provenanceBytes;        //   8
  uint64_t nodeTableChecksum;      //   8: XXH3-64 of the node table bytes
  uint64_t provenanceChecksum;     //   8: XXH3-64 of the provenance bytes
  uint64_t fileBytes;              //   8: size of the whole file
  float gradientScale;             //   4: gradient magnitude (physical units/mm) mapped to 255
  uint32_t reserved;               //   4: zero
  uint64_t headerChecksum;         //   8: XXH3-64 of the 248 bytes before it
};
static_assert(sizeof(StoreHeader) == 256);
static_assert(offsetof(StoreHeader, dims) == 16);
static_assert(offsetof(StoreHeader, patientFromIndex) == 40);
static_assert(offsetof(StoreHeader, brickSize) == 136);
static_assert(offsetof(StoreHeader, valueScale) == 152);
static_assert(offsetof(StoreHeader, nodeCount) == 176);
static_assert(offsetof(StoreHeader, fileBytes) == 232);
static_assert(offsetof(StoreHeader, headerChecksum) == 248);

struct NodeRecord {
  uint64_t payloadOffset;    //  8: file offset of the compressed values (0 when constant)
  uint32_t payloadBytes;     //  4: compressed bytes of values (0 when constant)
  uint32_t gradientBytes;    //  4: compressed bytes of gradients, right after the values
  float minValue;            //  4: physical minimum over the brick's samples (border included)
  float maxValue;            //  4:   and its descendants' ranges: a sound emptiness bound
  uint32_t flags;            //  4: NodeFlags
  uint32_t constantSample;   //  4: a constant brick's stored sample (UInt16 value, or the
                             //     Float32 bit pattern); zero otherwise
  uint64_t payloadChecksum;  //  8: XXH3-64 of values and gradient payload bytes together
};
static_assert(sizeof(NodeRecord) == 40);
static_assert(offsetof(NodeRecord, minValue) == 16);
static_assert(offsetof(NodeRecord, payloadChecksum) == 32);

}  // namespace octoray::volume
