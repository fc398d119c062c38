// Geometry primitives and the bit-level step of decoding (BitsStored / HighBit / sign).
#include <gtest/gtest.h>

#include <random>

#include "octoray/dicom/dicom_decode.h"
#include "octoray/core/error.h"
#include "octoray/core/geometry.h"

namespace octoray {
namespace {

TEST(Geometry, InverseOfShearedAffineRoundTrips) {
  // A tilted CT affine: anisotropic spacing, a shear in the slice column, an offset origin.
  const Mat4 patientFromIndex = Mat4::fromColumns({0.45, 0, 0}, {0, 0.43, -0.15}, {0, 0, 2.5},
                                                  {-115.5, -1.85, 694.21});
  const Mat4 indexFromPatient = patientFromIndex.inverseAffine();
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-600, 600);
  for (int n = 0; n < 1000; ++n) {
    const Vec3 index{u(rng), u(rng), u(rng)};
    const Vec3 back = indexFromPatient.transformPoint(patientFromIndex.transformPoint(index));
    EXPECT_NEAR(back.x, index.x, 1e-9);
    EXPECT_NEAR(back.y, index.y, 1e-9);
    EXPECT_NEAR(back.z, index.z, 1e-9);
  }
  const Mat4 identity = indexFromPatient * patientFromIndex;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) EXPECT_NEAR(identity.m[r][c], r == c ? 1.0 : 0.0, 1e-12);
}

TEST(Geometry, SingularAffineIsAnError) {
  const Mat4 flat = Mat4::fromColumns({1, 0, 0}, {0, 1, 0}, {0, 0, 0}, {0, 0, 0});
  EXPECT_THROW(flat.inverseAffine(), Error);
}

TEST(Geometry, CrossAndNormalize) {
  const Vec3 n = cross({1, 0, 0}, {0, 1, 0});
  EXPECT_EQ(n.z, 1.0);
  EXPECT_NEAR(length(normalize({3, 4, 12})), 1.0, 1e-15);
}

TEST(StoredValue, MasksBitsAboveHighBitAndSignExtends) {
  dicom::PixelFormat f;
  f.bitsAllocated = 16;
  f.bitsStored = 12;
  f.highBit = 11;
  f.pixelSigned = false;
  // Garbage in the top 4 bits (overlay planes, noise) is not part of the value.
  EXPECT_EQ(dicom::storedValueFromBits(0xF123, f), 0x123);
  f.pixelSigned = true;
  EXPECT_EQ(dicom::storedValueFromBits(0x0FFF, f), -1);
  EXPECT_EQ(dicom::storedValueFromBits(0xA800, f), -2048);
  EXPECT_EQ(dicom::storedValueFromBits(0x07FF, f), 2047);
  // High bit not at the top of the stored bits' usual place: bits [4, 15].
  f.highBit = 15;
  f.pixelSigned = false;
  EXPECT_EQ(dicom::storedValueFromBits(0xFFF0, f), 0xFFF);
  f.bitsAllocated = f.bitsStored = 32;
  f.highBit = 31;
  EXPECT_EQ(dicom::storedValueFromBits(0xFFFFFFFFu, f), 4294967295.0);
  f.pixelSigned = true;
  EXPECT_EQ(dicom::storedValueFromBits(0xFFFFFFFFu, f), -1.0);
}

}  // namespace
}  // namespace octoray
