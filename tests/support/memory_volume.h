#pragma once
// An in-memory VolumeSource for tests: samples from a function of the index, or given values.

#include <functional>
#include <vector>

#include "octoray/dicom/volume_source.h"

namespace octoray::test {

class MemoryVolume final : public VolumeSource {
 public:
  MemoryVolume(std::array<int64_t, 3> dims, std::function<float(int64_t, int64_t, int64_t)> value,
               std::string unit = "HU", bool integerValues = true) {
    info_.dims = dims;
    info_.format = "memory";
    info_.sourcePath = "memory";
    info_.unit = std::move(unit);
    info_.integerValues = integerValues;
    info_.patientFromIndex = Mat4::fromColumns({0.5, 0, 0}, {0, 0.5, 0}, {0, 0.1, 2.0}, {-10, 5, 100});
    values_.resize(static_cast<std::size_t>(info_.sampleCount()));
    std::size_t n = 0;
    for (int64_t k = 0; k < dims[2]; ++k)
      for (int64_t j = 0; j < dims[1]; ++j)
        for (int64_t i = 0; i < dims[0]; ++i) values_[n++] = value(i, j, k);
  }
  const VolumeInfo& info() const override { return info_; }
  void readSlab(int64_t first, int64_t count, std::span<float> out) override {
    checkSlabRequest(info_, first, count, out.size());
    std::copy_n(values_.begin() + first * info_.sliceSamples(), out.size(), out.begin());
    ++slabsRead;
  }
  float at(int64_t i, int64_t j, int64_t k) const {
    return values_[static_cast<std::size_t>(i + info_.dims[0] * (j + info_.dims[1] * k))];
  }
  // Another geometry (the default is a sheared grid of 0.5 x 0.5 x 2 mm).
  void setPatientFromIndex(const Mat4& m) { info_.patientFromIndex = m; }
  // The display windows the source names (DICOM's WindowCenter / WindowWidth).
  void setWindows(std::vector<SourceWindow> windows) { info_.windows = std::move(windows); }
  void setDescription(std::string description) { info_.description = std::move(description); }
  int slabsRead = 0;

 private:
  VolumeInfo info_;
  std::vector<float> values_;
};

}  // namespace octoray::test
