#include "octoray/dicom/dicom_volume.h"

#include <tbb/parallel_for.h>
#include <algorithm>
#include <cmath>
#include <deque>
#include <map>
#include <mutex>
#include <numeric>
#include <thread>

#include <fmt/format.h>

#include "octoray/dicom/dicom_decode.h"
#include "gdcm_support.h"
#include "octoray/core/error.h"

namespace octoray::dicom {
namespace {

constexpr double kPi = 3.14159265358979323846;
// A resampled stack has at most this many slices per image of the series (or the second
// number, for short series): finer spacings only interpolate, and a mistyped one such as
// 1e-6 mm would otherwise make a volume too large to ever finish.
constexpr int64_t kMaxResampledSlicesPerImage = 16;
constexpr int64_t kMaxResampledSlicesAlways = 4096;

std::string firstPath(const DicomSeries& series) {
  return series.frames.empty() ? series.seriesUid : series.frames.front().path;
}

std::string frameName(const FrameRef& f) {
  return f.frameIndex > 0 ? fmt::format("{} frame {}", f.path, f.frameIndex + 1) : f.path;
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

}  // namespace

StackGeometry resolveStack(const DicomSeries& series, const StackOptions& options) {
  const std::string where = firstPath(series);
  if (series.frames.empty()) throw Error(where, "series has no images");
  if (!series.hasGeometry) {
    throw Error(where, "images lack ImagePositionPatient/ImageOrientationPatient/PixelSpacing: "
                       "no geometry in patient space");
  }
  if (!(series.rowSpacingMm > 0) || !(series.columnSpacingMm > 0)) {
    throw Error(where, fmt::format("invalid PixelSpacing {}\\{}", series.rowSpacingMm,
                                   series.columnSpacingMm));
  }
  StackGeometry g;
  const double rowLength = length(series.rowDirection), colLength = length(series.columnDirection);
  if (std::abs(rowLength - 1) > 1e-2 || std::abs(colLength - 1) > 1e-2) {
    throw Error(where, "ImageOrientationPatient direction cosines are not unit vectors");
  }
  const Vec3 rowDir = normalize(series.rowDirection);
  const Vec3 colDir = normalize(series.columnDirection);
  if (std::abs(dot(rowDir, colDir)) > 1e-3) {
    throw Error(where, "ImageOrientationPatient row and column directions are not orthogonal");
  }
  if (std::abs(rowLength - 1) > 1e-4 || std::abs(colLength - 1) > 1e-4) {
    g.warnings.push_back("ImageOrientationPatient cosines were not unit length; normalised");
  }
  const Vec3 normal = normalize(cross(rowDir, colDir));
  const double pixelMm = std::min(series.rowSpacingMm, series.columnSpacingMm);

  // Sort along the normal (not by file name or InstanceNumber); ties by InstanceNumber.
  std::vector<FrameRef> sorted = series.frames;
  std::stable_sort(sorted.begin(), sorted.end(), [&](const FrameRef& a, const FrameRef& b) {
    const double da = dot(a.positionMm, normal), db = dot(b.positionMm, normal);
    if (da != db) return da < db;
    return a.instanceNumber < b.instanceNumber;
  });

  // Duplicate positions: keep the first (lowest InstanceNumber), report the rest.
  const double samePositionMm = std::max(1e-4, 1e-3 * pixelMm);
  for (const FrameRef& f : sorted) {
    if (!g.slices.empty()) {
      const FrameRef& last = g.slices.back();
      if (std::abs(dot(f.positionMm - last.positionMm, normal)) < samePositionMm) {
        if (length(f.positionMm - last.positionMm) > 0.5 * pixelMm) {
          throw Error(f.path, fmt::format("shares its slice position with {} but is shifted "
                                          "in-plane: two interleaved stacks in one series",
                                          frameName(last)));
        }
        g.duplicates.push_back(f);
        continue;
      }
    }
    g.slices.push_back(f);
  }
  if (!g.duplicates.empty()) {
    std::string names;
    for (std::size_t i = 0; i < g.duplicates.size() && i < 5; ++i) {
      names += (i ? ", " : "") + frameName(g.duplicates[i]);
    }
    if (g.duplicates.size() > 5) names += fmt::format(" and {} more", g.duplicates.size() - 5);
    g.warnings.push_back(fmt::format("{} image(s) duplicate another's slice position and were "
                                     "dropped (the lower InstanceNumber is kept): {}",
                                     g.duplicates.size(), names));
  }

  if (!std::isfinite(options.sliceSpacingMm)) {
    throw Error(where, fmt::format("slice spacing (--slice-spacing) {} mm is not a finite number",
                                   options.sliceSpacingMm));
  }
  const std::size_t n = g.slices.size();
  const Vec3 origin = g.slices.front().positionMm;
  for (const FrameRef& f : g.slices) g.distancesMm.push_back(dot(f.positionMm - origin, normal));

  if (n == 1) {
    g.outputSpacingMm = options.sliceSpacingMm > 0 ? options.sliceSpacingMm : 1.0;
    g.sliceStepMm = g.outputSpacingMm * normal;
    g.outputSlices = 1;
    g.warnings.push_back(fmt::format("single slice: its thickness along the normal is unknown; "
                                     "{} mm is used as the slice spacing", g.outputSpacingMm));
  } else {
    std::vector<double> gaps;
    for (std::size_t k = 1; k < n; ++k) gaps.push_back(g.distancesMm[k] - g.distancesMm[k - 1]);
    g.minGapMm = *std::min_element(gaps.begin(), gaps.end());
    g.maxGapMm = *std::max_element(gaps.begin(), gaps.end());
    g.medianGapMm = median(gaps);
    const double span = g.distancesMm.back();

    // In-plane offset per mm along the normal (gantry tilt) from the end slices; every other
    // slice must lie on that line, or the stack is not a (sheared) grid at all.
    const Vec3 endOffset = g.slices.back().positionMm - origin;
    const Vec3 shearPerMm = (1.0 / span) * (endOffset - span * normal);
    double offLineMm = 0;
    for (std::size_t k = 0; k < n; ++k) {
      const Vec3 predicted = origin + g.distancesMm[k] * (normal + shearPerMm);
      offLineMm = std::max(offLineMm, length(g.slices[k].positionMm - predicted));
    }
    if (offLineMm > 0.25 * pixelMm) {
      throw Error(where, fmt::format("slice positions do not lie on one line (a slice is {:.3f} "
                                     "mm off it): not a regular or sheared stack", offLineMm));
    }
    if (offLineMm > 0.05 * pixelMm) {
      g.warnings.push_back(fmt::format("slice positions deviate up to {:.3f} mm from a straight "
                                       "line; the best line through the end slices is used",
                                       offLineMm));
    }

    // Even spacing: every gap within rounding of the DS strings (a few micrometres).
    const double gapTolerance = std::max(5e-3, 1e-3 * g.medianGapMm);
    g.uniform = (g.maxGapMm - g.minGapMm) <= gapTolerance && options.sliceSpacingMm <= 0;
    for (std::size_t k = 0; k + 1 < n; ++k) {
      const double ratio = gaps[k] / g.medianGapMm;
      const double whole = std::round(ratio);
      if (whole >= 2 && std::abs(ratio - whole) < 0.1) {
        g.missingSlices += static_cast<int>(whole) - 1;
        g.warnings.push_back(fmt::format("{} slice(s) missing between {} and {} (gap {:.3f} mm, "
                                         "usual {:.3f} mm)", static_cast<int>(whole) - 1,
                                         frameName(g.slices[k]), frameName(g.slices[k + 1]),
                                         gaps[k], g.medianGapMm));
      }
    }
    if (g.minGapMm < 0.01 * pixelMm) {
      throw Error(where, fmt::format("two slices are only {:.4f} mm apart", g.minGapMm));
    }
    if (g.uniform) {
      // Step from the end slices: the affine reproduces every slice's own position.
      g.outputSpacingMm = span / static_cast<double>(n - 1);
      g.outputSlices = static_cast<int64_t>(n);
    } else {
      g.outputSpacingMm = options.sliceSpacingMm > 0 ? options.sliceSpacingMm : g.minGapMm;
      const double slices = std::floor(span / g.outputSpacingMm + 1e-6) + 1;
      const auto maxSlices = std::max<int64_t>(
          kMaxResampledSlicesPerImage * static_cast<int64_t>(n), kMaxResampledSlicesAlways);
      if (!(slices <= static_cast<double>(maxSlices))) {
        throw Error(
            where,
            fmt::format(
                "a slice spacing of {} mm ({}) would resample {} images over {:.3f} mm into {:.0f} "
                "slices, over the limit of {} (the larger of {} per image and {}): choose a larger "
                "--slice-spacing",
                g.outputSpacingMm,
                options.sliceSpacingMm > 0 ? "--slice-spacing" : "the smallest gap, by default", n,
                span, slices, maxSlices, kMaxResampledSlicesPerImage, kMaxResampledSlicesAlways));
      }
      g.outputSlices = static_cast<int64_t>(slices);
      const std::string spacing =
          (g.maxGapMm - g.minGapMm) <= gapTolerance
              ? fmt::format("the slices are {:.3f} mm apart; --slice-spacing", g.medianGapMm)
              : fmt::format("slice spacing varies from {:.3f} to {:.3f} mm (median {:.3f})",
                            g.minGapMm, g.maxGapMm, g.medianGapMm);
      g.warnings.push_back(fmt::format("{}; resampled to {} slices {:.4f} mm apart by linear "
                                       "interpolation along the stack",
                                       spacing, g.outputSlices, g.outputSpacingMm));
    }
    g.sliceStepMm = g.outputSpacingMm * (normal + shearPerMm);
  }

  // Tilt: the angle between the slice step and the normal, signed along the column direction.
  const Vec3 stepDir = normalize(g.sliceStepMm);
  const double inPlane = dot(stepDir, colDir), alongNormal = dot(stepDir, normal);
  const double tiltAll = std::acos(std::clamp(alongNormal, -1.0, 1.0)) * 180.0 / kPi;
  g.tiltDegrees = inPlane < 0 ? -tiltAll : tiltAll;
  if (std::abs(g.tiltDegrees) > 0.01) {
    g.warnings.push_back(fmt::format("gantry tilt of {:.2f} degrees kept exactly as a shear in "
                                     "the index-to-patient affine (no resampling)",
                                     g.tiltDegrees));
  }
  g.patientFromIndex = Mat4::fromColumns(series.columnSpacingMm * rowDir,
                                         series.rowSpacingMm * colDir, g.sliceStepMm, origin);
  checkGeometry(g.patientFromIndex, where);  // PixelSpacing 1e308, positions near 1e300, ...
  return g;
}

namespace {

// Streams a resolved stack: decodes the frames each slab needs (in parallel), maps stored
// values to physical values, and interpolates where the output grid falls between slices.
class DicomVolumeSource final : public VolumeSource {
 public:
  DicomVolumeSource(const DicomSeries& series, StackGeometry geometry, std::size_t frameRunBytes)
      : series_(series), geometry_(std::move(geometry)), frameRunBytes_(frameRunBytes) {
    VolumeInfo& info = info_;
    info.dims = {series.columns, series.rows, geometry_.outputSlices};
    info.patientFromIndex = geometry_.patientFromIndex;
    info.format = "dicom";
    info.sourcePath = firstPath(series);
    for (const FrameRef& frame : series.frames) info.sourceFiles.push_back(frame.path);
    std::sort(info.sourceFiles.begin(), info.sourceFiles.end());
    info.sourceFiles.erase(std::unique(info.sourceFiles.begin(), info.sourceFiles.end()),
                           info.sourceFiles.end());
    info.modality = series.modality;
    info.description = series.description;
    info.seriesUid = series.seriesUid;
    info.unit = series.modality == "CT" ? "HU" : "";
    info.windows = series.windows;
    info.tiltDegrees = geometry_.tiltDegrees;
    info.resampled = !geometry_.uniform && geometry_.slices.size() > 1;
    info.warnings = geometry_.warnings;
    if (!series.windowWarning.empty()) info.warnings.push_back(series.windowWarning);
    // Interpolated values are rounded to whole units, so integer data stays integer.
    info.integerValues = std::all_of(geometry_.slices.begin(), geometry_.slices.end(),
                                     [](const FrameRef& f) {
                                       return f.rescaleSlope == std::round(f.rescaleSlope) &&
                                              f.rescaleIntercept == std::round(f.rescaleIntercept);
                                     });
    // Stored values span BitsStored bits; with the rescale of every frame that bounds HU.
    if (series.bitsStored > 0 && series.bitsStored <= 32) {
      const double lo = series.pixelSigned ? -std::ldexp(1.0, series.bitsStored - 1) : 0.0;
      const double hi = series.pixelSigned ? std::ldexp(1.0, series.bitsStored - 1) - 1
                                           : std::ldexp(1.0, series.bitsStored) - 1;
      double lower = std::numeric_limits<double>::infinity(), upper = -lower;
      for (const FrameRef& f : geometry_.slices) {
        const double a = f.rescaleSlope * lo + f.rescaleIntercept;
        const double b = f.rescaleSlope * hi + f.rescaleIntercept;
        lower = std::min({lower, a, b});
        upper = std::max({upper, a, b});
      }
      // Padded pixels become air for CT.
      if (info.unit == "HU") lower = std::min(lower, -1024.0);
      info.valueLowerBound = lower;
      info.valueUpperBound = upper;
    }
    if (series.photometric == "MONOCHROME1") {
      info.warnings.push_back("MONOCHROME1: values are the modality LUT output (high = dense); "
                              "the inversion is a display setting, not applied to values");
    }
  }

  const VolumeInfo& info() const override { return info_; }

  void readSlab(int64_t firstSlice, int64_t sliceCount, std::span<float> out) override {
    checkSlabRequest(info_, firstSlice, sliceCount, out.size());
    std::vector<Blend> blends;
    std::vector<std::size_t> needed;
    for (int64_t k = firstSlice; k < firstSlice + sliceCount; ++k) {
      Blend blend = blendFor(k);
      blends.push_back(blend);
      needed.push_back(blend.a);
      if (blend.wb > 0) needed.push_back(blend.b);
    }
    std::sort(needed.begin(), needed.end());
    needed.erase(std::unique(needed.begin(), needed.end()), needed.end());
    std::map<std::size_t, std::shared_ptr<const std::vector<float>>> values;
    std::vector<std::shared_ptr<const std::vector<float>>> decoded(needed.size());
    tbb::parallel_for(std::size_t{0}, needed.size(),
                      [&](std::size_t i) { decoded[i] = physicalSlice(needed[i]); });
    for (std::size_t i = 0; i < needed.size(); ++i) values[needed[i]] = decoded[i];
    remember(values);

    const std::size_t sliceSamples = static_cast<std::size_t>(info_.sliceSamples());
    for (std::size_t s = 0; s < blends.size(); ++s) {
      float* dst = out.data() + s * sliceSamples;
      const auto& a = *values[blends[s].a];
      if (blends[s].wb <= 0) {
        std::copy(a.begin(), a.end(), dst);
        continue;
      }
      const auto& b = *values[blends[s].b];
      const double wb = blends[s].wb, wa = 1.0 - wb;
      for (std::size_t i = 0; i < sliceSamples; ++i) {
        const double v = wa * a[i] + wb * b[i];
        dst[i] = static_cast<float>(info_.integerValues ? std::round(v) : v);
      }
    }
  }

 private:
  // Output slice k sits at distance k * spacing along the normal from the first slice; it is
  // slice a, or a blend of the sorted slices a and b around it.
  struct Blend {
    std::size_t a, b;
    double wb;
  };
  Blend blendFor(int64_t k) const {
    const auto index = static_cast<std::size_t>(k);
    if (!info_.resampled) return {index, index, 0.0};
    const auto& d = geometry_.distancesMm;
    const double s = static_cast<double>(k) * geometry_.outputSpacingMm;
    const auto upper = std::lower_bound(d.begin(), d.end(), s - 1e-6);
    const std::size_t b = std::min(static_cast<std::size_t>(upper - d.begin()), d.size() - 1);
    if (std::abs(d[b] - s) <= 1e-6 || b == 0) return {b, b, 0.0};
    const std::size_t a = b - 1;
    return {a, b, std::clamp((s - d[a]) / (d[b] - d[a]), 0.0, 1.0)};
  }

  // Physical values of sorted slice `index`: modality LUT, padding to background.
  std::shared_ptr<const std::vector<float>> physicalSlice(std::size_t index) {
    if (auto it = recent_.find(index); it != recent_.end()) return it->second;
    const FrameRef& frame = geometry_.slices[index];
    std::shared_ptr<const DecodedImage> image = decodedFrames(frame);
    const PixelFormat& f = image->format;
    if (f.rows != series_.rows || f.columns != series_.columns) {
      throw Error(frame.path, fmt::format("image is {}x{}, the rest of its series {}x{}", f.columns,
                                          f.rows, series_.columns, series_.rows));
    }
    if (frame.frameIndex >= f.frames) {
      throw Error(frame.path, fmt::format("frame {} requested, file has {}", frame.frameIndex + 1,
                                          f.frames));
    }
    const std::size_t count = image->frameSamples();
    const auto held = static_cast<int>(image->stored.size() / std::max<std::size_t>(count, 1));
    if (frame.frameIndex < image->firstFrame || frame.frameIndex >= image->firstFrame + held) {
      throw Error(frame.path, fmt::format("frame {} was not decoded", frame.frameIndex + 1));
    }
    const double* stored = image->stored.data() +
                           count * static_cast<std::size_t>(frame.frameIndex - image->firstFrame);
    auto result = std::make_shared<std::vector<float>>(count);
    const double lo = std::min(f.paddingValue, f.paddingRangeLimit);
    const double hi = std::max(f.paddingValue, f.paddingRangeLimit);
    // Padding marks pixels outside the reconstructed field: they become air for CT, else 0.
    const float background = info_.unit == "HU" ? -1024.0f : 0.0f;
    for (std::size_t i = 0; i < count; ++i) {
      const double v = stored[i];
      (*result)[i] = f.hasPadding && v >= lo && v <= hi
                         ? background
                         : static_cast<float>(frame.rescaleSlope * v + frame.rescaleIntercept);
    }
    return result;
  }

  // A single-frame file is decoded for its slice. A multi-frame object is decoded a run of
  // frames at a time (StackOptions::frameRunBytes), and the last runs (one per thread) are kept
  // while their frames are read: its memory is that of the frames in use, not of the whole
  // object (importing 800 frames of 512 x 512, 400 MiB, took 2.4 GiB decoded whole, 210 MiB by
  // runs of 8 MiB; the same volume from a raw file 137 MiB).
  std::shared_ptr<const DecodedImage> decodedFrames(const FrameRef& frame) {
    if (!series_.multiFrame) {
      return std::make_shared<const DecodedImage>(detail::decodeVettedDicomFile(frame.path));
    }
    const std::size_t frameBytes = sizeof(double) * static_cast<std::size_t>(series_.rows) *
                                   static_cast<std::size_t>(series_.columns);
    const int runFrames = static_cast<int>(
        std::clamp<std::size_t>(frameRunBytes_ / std::max<std::size_t>(frameBytes, 1), 1, 4096));
    const int first = frame.frameIndex / runFrames * runFrames;
    std::lock_guard lock(fileMutex_);
    for (const auto& run : frameRuns_) {
      if (run.path == frame.path && run.image->firstFrame == first) return run.image;
    }
    auto image = std::make_shared<const DecodedImage>(
        detail::decodeVettedDicomFrames(frame.path, first, runFrames));
    frameRuns_.push_front({frame.path, image});
    if (frameRuns_.size() > runsKept_) frameRuns_.pop_back();
    return image;
  }

  // Keeps the slices of the last slab: the next slab's interpolation starts from them.
  void remember(const std::map<std::size_t, std::shared_ptr<const std::vector<float>>>& values) {
    recent_.clear();
    if (!values.empty()) recent_.insert(*values.rbegin());
  }

  const DicomSeries series_;
  const StackGeometry geometry_;
  VolumeInfo info_;
  std::map<std::size_t, std::shared_ptr<const std::vector<float>>> recent_;
  const std::size_t frameRunBytes_;
  // A run for each thread that reads slices of a slab at once, so none evicts another's.
  const std::size_t runsKept_ = std::max(2u, std::thread::hardware_concurrency());
  struct FrameRun {
    std::string path;
    std::shared_ptr<const DecodedImage> image;
  };
  std::mutex fileMutex_;
  std::deque<FrameRun> frameRuns_;  // most recently decoded first
};

}  // namespace

std::unique_ptr<VolumeSource> openDicomSeries(const DicomSeries& series,
                                              const StackOptions& options) {
  return std::make_unique<DicomVolumeSource>(series, resolveStack(series, options),
                                             options.frameRunBytes);
}

}  // namespace octoray::dicom
