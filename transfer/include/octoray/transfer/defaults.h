#pragma once
// The transfer function a tool uses when none is given: what a first-time user of a CT
// viewer expects to see, and a neutral grey for values that are not Hounsfield units.
//   CT (HU):  DVR the shipped "bone" preset; isosurface a shaded bone-coloured surface;
//             MIP a grey ramp from -200 HU (black) to 1000 HU (white).
//   other:    DVR a grey ramp whose opacity rises over the upper three quarters of the value
//             range; isosurface the same bone-coloured surface; MIP a grey ramp over the range.

#include <string>

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

}  // namespace octoray::transfer
