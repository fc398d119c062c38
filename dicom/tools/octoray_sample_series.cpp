// octoray-sample-series: writes a small synthetic CT exam (the built-in sample) whose pixel
// values are a known function of patient position, so every other tool can be tried at once.

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include <cstdio>
#include <string>
#include <vector>

#include "cli_support.h"
#include "octoray/core/error.h"
#include "octoray/dicom/synthetic_series.h"

namespace {

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Writes a small synthetic CT exam (DICOM) whose values are a known function of "
               "patient position: the built-in sample for trying octoray."};
  app.footer(
      "Examples:\n"
      "  octoray-sample-series sample/             # 64x64x40 CT exam, 0.5 x 0.5 x 1.25 mm\n"
      "  octoray-sample-series tilted/ --tilt 15 --variable-gaps --with-localizer\n"
      "  octoray-import sample/ -o sample.octoray   # then view or render it\n");
  std::string outDir;
  std::string size = "64x64x40";
  std::string spacing = "0.5,0.5,1.25";
  double tiltDegrees = 0;
  uint64_t seed = 1;
  bool variableGaps = false;
  bool withLocalizer = false;
  app.add_option("OUT_DIR", outDir, "folder to write the DICOM files into")->required();
  app.add_option("--size", size, "columns x rows x slices")->capture_default_str();
  app.add_option("--spacing", spacing, "column, row and slice spacing in mm")
      ->capture_default_str();
  app.add_option("--tilt", tiltDegrees, "gantry tilt in degrees")->capture_default_str();
  app.add_option("--seed", seed, "seed of the generated UIDs")->capture_default_str();
  app.add_flag("--variable-gaps", variableGaps,
               "every third gap is 1.5 times the slice spacing (the reader resamples)");
  app.add_flag("--with-localizer", withLocalizer, "also write a coronal localizer image");
  bool multiFrame = false;
  app.add_flag("--multi-frame", multiFrame,
               "one Enhanced CT object holding every slice as a frame, not one file per slice");
  std::string patientName = "OCTORAY^SYNTHETIC", patientId;
  app.add_option("--patient-name", patientName, "PatientName (DICOM person name, e.g. DOE^JANE)")
      ->capture_default_str();
  app.add_option("--patient-id", patientId, "PatientID (default: SYN and the seed)");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? 0 : 2;  // command-line mistakes exit 2, as in every octoray tool
  }

  return octoray::cli::runTool("octoray-sample-series", [&] {
    using namespace octoray::dicom;
    const auto dims = octoray::cli::parseDims(size, "--size");
    const auto spacingMm = octoray::cli::parseTriple(spacing, "--spacing");
    for (int64_t d : dims) {
      if (d > 65535) throw octoray::Error("", fmt::format("--size \"{}\": at most 65535", size));
    }
    SyntheticSeriesSpec spec;
    spec.columns = static_cast<int>(dims[0]);
    spec.rows = static_cast<int>(dims[1]);
    const int slices = static_cast<int>(dims[2]);
    spec.columnSpacingMm = spacingMm[0];
    spec.rowSpacingMm = spacingMm[1];
    spec.sliceSpacingMm = spacingMm[2];
    spec.tiltDegrees = tiltDegrees;
    spec.seed = seed;
    spec.withLocalizer = withLocalizer;
    spec.patientName = patientName;
    spec.patientId = patientId;
    spec.sliceCount = slices;
    if (multiFrame) spec.layout = SyntheticLayout::EnhancedMultiFrame;
    if (variableGaps) {
      // Gaps of 1, 1, 1.5 times the spacing, repeating: not an affine grid.
      double distanceMm = 0;
      for (int k = 0; k < slices; ++k) {
        spec.sliceDistancesMm.push_back(distanceMm);
        distanceMm += (k % 3 == 2 ? 1.5 : 1.0) * spec.sliceSpacingMm;
      }
    }
    // Centre the stack on the patient origin.
    const std::vector<double> distances = syntheticSliceDistances(spec);
    const double midMm = 0.5 * (distances.front() + distances.back());
    spec.centreMm = {0, 0, -midMm};

    const SyntheticSeries series = writeSyntheticSeries(outDir, spec);
    const std::vector<SyntheticImage> written = series.slices();
    fmt::print("wrote {} CT slices{} ({} x {} pixels, {} x {} mm, slice spacing {} mm{}{}) to {}\n",
               written.size(), multiFrame ? " as frames of one Enhanced CT object" : "",
               spec.columns, spec.rows, spec.columnSpacingMm, spec.rowSpacingMm,
               spec.sliceSpacingMm, variableGaps ? ", variable gaps" : "",
               tiltDegrees != 0 ? fmt::format(", gantry tilt {} deg", tiltDegrees) : "", outDir);
    fmt::print("  study  {}\n  series {}\n", series.studyUid, series.seriesUid);
    fmt::print("  first slice {} at ({:.3f}, {:.3f}, {:.3f}) mm\n",
               written.front().path.filename().string(), written.front().positionMm.x,
               written.front().positionMm.y, written.front().positionMm.z);
    fmt::print("  last slice  {} at ({:.3f}, {:.3f}, {:.3f}) mm\n",
               written.back().path.filename().string(), written.back().positionMm.x,
               written.back().positionMm.y, written.back().positionMm.z);
    if (withLocalizer) fmt::print("  localizer {} (series {})\n", "LOC0001.dcm",
                                  series.localizerSeriesUid);
    return 0;
  });
}
