#pragma once
// The plan of a batch import: what `octoray-batch plan` finds in an archive and decides to
// build. One work item per volumetric DICOM series (or volume file / TIFF stack), with the
// files it is read from, their content hash and the store it becomes; every series that is
// not built (localisers, secondary captures, derived images, broken geometry, filtered out)
// listed with the reason. A plan carries no patient name: output paths use a hash of the
// patient ID unless the template asks otherwise (docs/batch.md).

#include <array>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace octoray::batch {

inline constexpr int kPlanSchemaVersion = 1;
inline constexpr const char* kDefaultOutputTemplate =
    "{PatientID-hash}/{StudyInstanceUID}/{SeriesNumber}-{SeriesDescription}.octoray";

struct WorkItem {
  int64_t index = 0;
  std::string kind;       // "dicom": a series; "file": a volume file or a TIFF folder
  std::string path;       // dicom: the archive path it was found under; file: what openVolume reads
  std::string folder;     // the folder `files` are relative to
  std::vector<std::string> files;  // every file the samples come from, relative to `folder`, sorted
  std::vector<std::string> fileHashes;  // fileContentHash() of each file, in the same order
  uint64_t bytes = 0;              // their total size
  std::string contentHash;         // sourceContentHash() of the files
  std::string seriesUid, studyUid, studyDate, modality, description;
  int seriesNumber = 0;
  std::string patientIdHash;       // keyed hash of PatientID (see PlanOptions::idSalt)
  std::array<int64_t, 3> dims{0, 0, 0};
  std::string output;              // absolute path of the store to build

  int64_t voxels() const { return dims[0] * dims[1] * dims[2]; }
  std::vector<std::string> absoluteFiles() const;
};

// A series or file that gets no store, and why.
struct SkippedSource {
  std::string path;        // the first file of the series, or the file
  std::string seriesUid;   // empty for files
  int seriesNumber = 0;
  std::string description;
  std::string reason;
};

struct Plan {
  std::string created;                  // ISO 8601 UTC
  std::vector<std::string> archives;    // absolute
  std::string outDir;                   // absolute
  std::string outputTemplate;
  nlohmann::json filters = nlohmann::json::object();
  std::vector<WorkItem> items;
  std::vector<SkippedSource> skipped;          // series and volume files not built
  std::vector<SkippedSource> unreadableFiles;  // files that are no usable image at all
  std::vector<std::string> warnings;           // e.g. DICOMDIR entries whose files are missing

  int64_t totalVoxels() const;
};

struct PlanOptions {
  std::string outDir;  // required: where the stores go
  std::string outputTemplate = kDefaultOutputTemplate;
  // Keys the patient-ID hash, so that IDs cannot be recovered by hashing candidate IDs
  // without it. Empty: a fixed key (the same ID hashes alike in every plan).
  std::string idSalt;
  // Filters (empty / 0: no filter). A series filtered out is listed in Plan::skipped.
  std::vector<std::string> modalities;  // e.g. {"CT"}
  int64_t minSlices = 0;
  std::string studyDateFrom, studyDateTo;  // YYYYMMDD, inclusive
  std::string descriptionRegex;            // ECMAScript, case-insensitive, searched in the description
  // Called as headers are read and files hashed: (done, total).
  std::function<void(const char* stage, std::size_t done, std::size_t total)> progress;
};

// Scans every archive (a folder, recursively; a DICOMDIR; a DICOM file; a volume file) and
// makes the plan. Throws octoray::Error for an archive that does not exist, an unknown field
// in the template, a bad regex or date, or when no archive holds anything to build.
Plan makePlan(const std::vector<std::string>& archives, const PlanOptions& options);

// The output path `outputTemplate` gives for these fields (sanitised, always ending in
// .octoray); throws octoray::Error for an unknown field or a template that leaves `outDir`.
// Fields: PatientID-hash PatientID PatientName StudyInstanceUID StudyDate SeriesInstanceUID
// SeriesNumber SeriesDescription Modality Index FileName.
std::string expandTemplate(const std::string& outputTemplate,
                           const std::function<std::optional<std::string>(const std::string&)>& field);

// One path component from a DICOM value: letters, digits and ._+- kept, anything else '_',
// runs of '_' merged, no leading or trailing '_' or '.', at most 64 characters; "none" when
// nothing is left.
std::string sanitizeComponent(const std::string& value);

// A keyed hash of a patient ID: HMAC-SHA256 with `salt` as the key (a fixed, public key when
// empty: then anyone can hash candidate IDs), its first 8 bytes as 16 hex digits.
std::string patientIdHash(const std::string& patientId, const std::string& salt);

// JSON text of `j` with any invalid UTF-8 (a header in Latin-1, a file name in another
// encoding) replaced by U+FFFD instead of an exception.
std::string dumpJson(const nlohmann::json& j, int indent = -1);

nlohmann::json toJson(const Plan& plan);
nlohmann::json toJson(const WorkItem& item);
// Throws octoray::Error naming `path` for a malformed item.
WorkItem itemFromJson(const nlohmann::json& j, const std::string& path);
Plan planFromJson(const nlohmann::json& j, const std::string& path);

// Writes the plan atomically; reads it back (throws octoray::Error naming the file).
void writePlan(const Plan& plan, const std::filesystem::path& path);
Plan readPlan(const std::filesystem::path& path);

}  // namespace octoray::batch
