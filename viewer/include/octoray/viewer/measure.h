#pragma once
// Measurements on MPR views, in patient space (mm) and physical values (HU):
//   distance  |b - a|;
//   angle     between the arms vertex->first and vertex->third, in degrees [0, 180];
//   ellipse / rectangle ROI in a view's plane: the values of the leaf level sampled on a grid
//             of the volume's smallest voxel spacing, aligned with the ROI's bounding box
//             (sample centres at half a step from its edges), over the samples inside the
//             shape; mean, SD (population: divided by n), min, max, n, and the shape's area
//             (pi a b for the ellipse, w h for the rectangle, mm^2).

#include <functional>
#include <string>
#include <vector>

#include "octoray/viewer/session.h"

namespace octoray::viewer {

struct RoiStats {
  int64_t samples = 0;
  double mean = 0, sd = 0, min = 0, max = 0;
  double areaMm2 = 0;
};

double distanceMm(const Measurement& m);
double angleDegrees(const Measurement& m);

// The grid positions of an ROI (patient space), inside its shape.
std::vector<Vec3> roiSamplePositions(const Measurement& m, double stepMm);
// Statistics of `values` (NaN entries — outside the volume — are left out) for ROI `m`.
RoiStats roiStats(const Measurement& m, const std::vector<double>& values);

// A one-line result for the panel and the image ("52.31 mm", "90.0°",
// "mean 40.2 SD 3.1 HU, min 31 max 50, 314.2 mm²"). An ROI's values carry `valueUnit`, the
// volume's ("HU" for CT); without one they are plain numbers. Minimum and maximum have
// `decimals` decimals, mean and SD one more (a volume whose values are not integers needs some).
std::string describe(const Measurement& m, const RoiStats* stats = nullptr,
                     const std::string& valueUnit = "", int decimals = 0);
// " HU" for "HU", nothing for no unit: what follows a value in a label.
std::string unitSuffix(const std::string& valueUnit);

}  // namespace octoray::viewer
