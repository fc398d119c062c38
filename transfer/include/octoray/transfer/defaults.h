#pragma once
// The transfer function a tool uses when none is given: what a first-time user of a CT
// viewer expects to see, and a neutral grey for values that are not Hounsfield units.
//   CT (HU):  DVR the shipped "bone" preset; isosurface a shaded bone-coloured surface;
//             MIP a grey ramp from -200 HU (black) to 1000 HU (white).
//   other:    DVR a grey ramp whose opacity rises over the upper three quarters of the value
//             range; isosurface the same bone-coloured surface; MIP a grey ramp over the range.

#include <string>
#include <vector>

#include "octoray/transfer/transfer_function.h"

namespace octoray::transfer {

enum class DefaultMode { Dvr, Iso, Mip };

struct DefaultTransferFunction {
  TransferFunction tf;
  std::string description;  // what was chosen, for the tool to say ("the bone preset (CT, DVR)")
};

// `hounsfield`: the values are CT Hounsfield units. [lo, hi]: the volume's value range, used
// for volumes that are not CT; ignored for CT. Throws octoray::Error when a non-CT range is
// not finite and increasing (no sensible default then: the caller should ask for --preset/--tf).
DefaultTransferFunction defaultTransferFunction(DefaultMode mode, bool hounsfield, double lo,
                                                double hi);

// The isovalue a CT isosurface defaults to: 300 HU, where cancellous bone begins (the
// threshold Slicer's and Horos's bone surface presets start from).
inline constexpr double kDefaultCtIsoValueHu = 300.0;

// The isovalue a volume without Hounsfield units (MR, a file without units) defaults to: Otsu's
// threshold of its values (N. Otsu, IEEE Trans. SMC 9(1), 1979; the automatic threshold of
// Slicer's Segment Editor and ITK-SNAP), the value that best splits them into two classes, so
// the surface is the boundary of the object against its background. `histogram` counts the
// values in equal bins over [lo, hi]; the threshold is the upper edge of the last bin of the
// lower class (the classes are bins 0..t and t+1..), or, where empty bins follow that one,
// the middle of the gap before the upper class. An empty histogram, or one with a single
// occupied bin, gives the middle of the range. A CT's isosurface opens at
// kDefaultCtIsoValueHu instead. The viewer and octoray-render count the histogram with
// volume::storeHistogram (value_histogram.h).
double automaticIsoValue(const std::vector<int>& histogram, double lo, double hi);

}  // namespace octoray::transfer
