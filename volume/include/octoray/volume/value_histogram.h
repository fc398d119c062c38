#pragma once
// The histogram of a volume's values that its automatic defaults read: the viewer's automatic
// window/level and isovalue (viewer/presets.h, transfer/defaults.h), and octoray-render's
// isovalue for a volume without Hounsfield units. One binning rule for every histogram of
// them, the store's and the viewer's import preview's (viewer/dataset.h), so the defaults do not
// move when the preview gives way to the store.

#include <cstdint>
#include <string>
#include <vector>

namespace octoray::volume {

class StoreReader;

// Equal bins over the values' range [lo, histogramTop(lo, hi)], values outside it counted in
// the end bins. An empty range (a constant volume) is taken as one unit wide.
double histogramTop(double lo, double hi);
int histogramBin(double value, double lo, double hi, int bins);

// At most this many samples are read for a histogram (4 Mi): the store's finest level this
// small, the preview's every n-th row.
inline constexpr int64_t kHistogramSamples = int64_t{1} << 22;

struct ValueHistogram {
  std::vector<int> counts;  // `bins` counts (all 0 where the first brick could not be read)
  double lo = 0, hi = 1;    // the bins span [lo, hi]
  int level = 0;            // the octree level counted
  // Where a brick could not be read: the store's message; `counts` holds the bricks before it.
  std::string problem;
};

// The histogram of the store's physical values (its unit: HU for CT) in `bins` bins over the
// root node's [min, max], counted over the finest level of at most kHistogramSamples samples
// and 256 bricks (each brick is decoded whole, so a thin volume's level of 4 Mi samples could
// mean thousands): the whole volume where it is that small. The 1 mm head (512 x 512 x 140) is
// counted at 128 x 128 x 35, the 5 mm one (512 x 512 x 28) at 256 x 256 x 14 (64 bricks,
// 29 ms), a 640^3 phantom at 160^3 (125 bricks, 40 ms). Level 0's box-filtered means where
// no level is that small.
ValueHistogram storeHistogram(const StoreReader& store, int bins = 256);

}  // namespace octoray::volume
