#include "octoray/batch/plan.h"

#include <algorithm>
#include <cctype>
#include <chrono>
#include <fstream>
#include <map>
#include <mutex>
#include <regex>
#include <set>
#include <sstream>

#include <fmt/format.h>
#include <tbb/parallel_for.h>
#include <openssl/evp.h>
#include <openssl/hmac.h>

#include "octoray/core/atomic_file.h"
#include "octoray/core/error.h"
#include "octoray/core/text.h"
#include "octoray/dicom/dicom_series.h"
#include "octoray/dicom/dicom_volume.h"
#include "octoray/dicom/formats.h"

namespace octoray::batch {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

bool endsWith(const std::string& s, const std::string& tail) {
  return s.size() >= tail.size() && s.compare(s.size() - tail.size(), tail.size(), tail) == 0;
}

// Volume files that are read by openVolume rather than scanned as DICOM.
bool isVolumeFileName(const fs::path& path) {
  const std::string name = asciiLower(path.filename().string());
  for (const char* ext : {".nrrd", ".nhdr", ".mhd", ".mha", ".nii", ".nii.gz", ".vdb"}) {
    if (endsWith(name, ext)) return true;
  }
  return false;
}

bool isTiffName(const fs::path& path) {
  const std::string name = asciiLower(path.filename().string());
  return endsWith(name, ".tif") || endsWith(name, ".tiff");
}

std::string isoNow() {
  const auto now = std::chrono::system_clock::now();
  const std::time_t t = std::chrono::system_clock::to_time_t(now);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char text[32];
  std::strftime(text, sizeof text, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return text;
}

// The deepest folder holding every path.
fs::path commonFolder(const std::vector<std::string>& paths) {
  fs::path common = fs::path(paths.front()).parent_path();
  for (const auto& p : paths) {
    const fs::path parent = fs::path(p).parent_path();
    while (!common.empty()) {
      auto [a, b] = std::mismatch(common.begin(), common.end(), parent.begin(), parent.end());
      if (a == common.end()) break;
      common = common.parent_path();
    }
  }
  return common;
}

void checkDate(const std::string& date, const char* what) {
  if (date.empty()) return;
  const bool digits = date.size() == 8 && std::all_of(date.begin(), date.end(), ::isdigit);
  if (!digits) throw Error("", fmt::format("{} '{}' is not a date YYYYMMDD", what, date));
}

// What one series or volume file contributes before filters, names and hashes.
struct Candidate {
  WorkItem item;
  std::string firstFile;  // for messages and the patient fields
  std::string patientId, patientName;
  std::string fileName;   // file items: the file's name without its extension
};

struct Collector {
  Plan plan;
  std::vector<Candidate> candidates;
  std::set<std::string> volumeFileInputs;  // every file a volume-file item reads
};

void addVolumeFile(const std::string& path, Collector& c) {
  try {
    auto source = openVolume(path);
    const VolumeInfo& info = source->info();
    Candidate cand;
    cand.item.kind = "file";
    cand.item.path = path;
    cand.item.dims = info.dims;
    cand.item.modality = info.modality;
    cand.item.description = info.description;
    cand.item.seriesUid = info.seriesUid;
    std::vector<std::string> files = info.sourceFiles.empty() ? std::vector<std::string>{path}
                                                              : info.sourceFiles;
    for (auto& f : files) f = fs::absolute(f).lexically_normal().string();
    cand.item.files = files;
    cand.firstFile = path;
    std::string stem = fs::path(path).filename().string();
    for (const char* ext : {".nii.gz", ".nrrd", ".nhdr", ".mhd", ".mha", ".nii", ".vdb", ".tiff", ".tif"}) {
      if (endsWith(asciiLower(stem), ext)) {
        stem.resize(stem.size() - std::string(ext).size());
        break;
      }
    }
    cand.fileName = stem;
    for (const auto& f : files) c.volumeFileInputs.insert(f);
    c.candidates.push_back(std::move(cand));
  } catch (const Error& e) {
    c.plan.skipped.push_back({path, "", 0, fs::path(path).filename().string(), e.reason()});
  } catch (const std::exception& e) {
    c.plan.skipped.push_back({path, "", 0, fs::path(path).filename().string(), e.what()});
  }
}

void addDicomScan(const std::string& archive, const dicom::DicomScan& scan, Collector& c) {
  for (const auto& s : scan.skipped) c.plan.unreadableFiles.push_back({s.path, "", 0, "", s.reason});
  for (const auto& w : scan.warnings) c.plan.warnings.push_back(w);
  for (const dicom::DicomSeries& series : scan.series) {
    const std::string first = series.frames.empty() ? archive : series.frames.front().path;
    auto skip = [&](const std::string& reason) {
      c.plan.skipped.push_back({first, series.seriesUid, series.seriesNumber, series.description, reason});
    };
    if (series.kind != dicom::SeriesKind::Volume) {
      skip(fmt::format("{}: {}", dicom::toString(series.kind), series.kindReason));
      continue;
    }
    Candidate cand;
    try {
      const dicom::StackGeometry g = dicom::resolveStack(series);
      cand.item.dims = {series.columns, series.rows, g.outputSlices};
      const dicom::PatientIdentity who = dicom::readPatientIdentity(first);
      cand.patientId = who.id;
      cand.patientName = who.name;
      cand.item.studyUid = who.studyUid;
      cand.item.studyDate = who.studyDate;
    } catch (const Error& e) {
      skip(e.what());
      continue;
    }
    cand.item.kind = "dicom";
    cand.item.path = archive;
    cand.item.seriesUid = series.seriesUid;
    cand.item.seriesNumber = series.seriesNumber;
    cand.item.modality = series.modality;
    cand.item.description = series.description;
    for (const auto& frame : series.frames) {
      cand.item.files.push_back(fs::absolute(frame.path).lexically_normal().string());
    }
    cand.firstFile = first;
    c.candidates.push_back(std::move(cand));
  }
}

void scanArchive(const std::string& archive, const PlanOptions& options, Collector& c) {
  std::error_code ec;
  if (!fs::exists(archive, ec)) throw Error(archive, "no such file or folder");
  const fs::path outDir = fs::absolute(options.outDir).lexically_normal();
  auto progress = [&](std::size_t done, std::size_t total) {
    if (options.progress) options.progress("reading headers", done, total);
  };
  if (!fs::is_directory(archive, ec)) {
    if (isVolumeFileName(archive) || isTiffName(archive)) {
      addVolumeFile(archive, c);
    } else {
      addDicomScan(archive, dicom::scanDicom(archive, {progress}), c);
    }
    return;
  }
  // Volume files and TIFF folders first: their files are not DICOM candidates.
  std::map<fs::path, std::vector<std::string>> tiffFolders;
  std::vector<std::string> dicomFiles;
  bool hasDicomDir = false;
  fs::recursive_directory_iterator it(archive, fs::directory_options::skip_permission_denied, ec);
  if (ec) throw Error(archive, "folder cannot be read: " + ec.message());
  for (; it != fs::recursive_directory_iterator(); it.increment(ec)) {
    if (ec) throw Error(archive, "folder cannot be read: " + ec.message());
    const fs::path& p = it->path();
    const std::string name = p.filename().string();
    const bool inOutDir = fs::absolute(p).lexically_normal().string().starts_with(outDir.string() + "/");
    if (name.starts_with(".") || inOutDir) {
      if (it->is_directory(ec)) it.disable_recursion_pending();
      continue;
    }
    if (!it->is_regular_file(ec)) continue;
    if (endsWith(asciiLower(name), ".octoray")) continue;  // stores (an earlier run's output)
    if (isVolumeFileName(p)) {
      addVolumeFile(p.string(), c);
    } else if (isTiffName(p)) {
      tiffFolders[p.parent_path()].push_back(p.string());
    } else {
      dicomFiles.push_back(fs::absolute(p).lexically_normal().string());
      hasDicomDir = hasDicomDir || name == "DICOMDIR";
    }
  }
  for (const auto& [folder, files] : tiffFolders) {
    addVolumeFile(files.size() == 1 ? files.front() : folder.string(), c);
  }
  // Data files named by the headers above (e.g. a .raw beside an .nhdr) are not DICOM.
  std::erase_if(dicomFiles, [&](const std::string& f) { return c.volumeFileInputs.contains(f); });
  if (dicomFiles.empty()) return;
  dicom::DicomScan scan = dicom::scanDicomFiles(dicomFiles, {progress});
  if (hasDicomDir) {
    // The DICOMDIRs' own check (entries whose files are missing) comes from scanDicom.
    for (const auto& f : dicomFiles) {
      if (fs::path(f).filename() == "DICOMDIR") {
        for (auto& w : dicom::scanDicom(fs::path(f).parent_path() / "DICOMDIR").warnings) {
          scan.warnings.push_back(std::move(w));
        }
      }
    }
  }
  addDicomScan(archive, scan, c);
}

}  // namespace

std::vector<std::string> WorkItem::absoluteFiles() const {
  std::vector<std::string> out;
  out.reserve(files.size());
  for (const auto& f : files) out.push_back((fs::path(folder) / f).string());
  return out;
}

int64_t Plan::totalVoxels() const {
  int64_t total = 0;
  for (const auto& item : items) total += item.voxels();
  return total;
}

std::string sanitizeComponent(const std::string& value) {
  std::string out;
  for (char ch : value) {
    const auto c = static_cast<unsigned char>(ch);
    const bool keep = std::isalnum(c) || c == '.' || c == '_' || c == '+' || c == '-';
    const char next = keep ? ch : '_';
    if (next == '_' && !out.empty() && out.back() == '_') continue;
    out += next;
  }
  while (!out.empty() && (out.front() == '_' || out.front() == '.')) out.erase(out.begin());
  if (out.size() > 64) out.resize(64);
  while (!out.empty() && (out.back() == '_' || out.back() == '.')) out.pop_back();
  return out.empty() ? "none" : out;
}

std::string patientIdHash(const std::string& patientId, const std::string& salt) {
  // HMAC-SHA256 keyed with the salt (a fixed key without one), first 8 bytes as hex.
  const std::string key = salt.empty() ? std::string("octoray-patient-id") : salt;
  unsigned char digest[EVP_MAX_MD_SIZE];
  unsigned int length = 0;
  HMAC(EVP_sha256(), key.data(), static_cast<int>(key.size()),
       reinterpret_cast<const unsigned char*>(patientId.data()), patientId.size(), digest, &length);
  std::string hex;
  for (unsigned int i = 0; i < 8 && i < length; ++i) hex += fmt::format("{:02x}", digest[i]);
  return hex;
}

std::string expandTemplate(const std::string& outputTemplate,
                           const std::function<std::optional<std::string>(const std::string&)>& field) {
  if (outputTemplate.empty() || outputTemplate.front() == '/') {
    throw Error("", fmt::format("output template '{}' must be a relative path", outputTemplate));
  }
  std::string out;
  for (std::size_t i = 0; i < outputTemplate.size();) {
    const char ch = outputTemplate[i];
    if (ch != '{') {
      if (ch == '}') throw Error("", fmt::format("output template '{}': '}}' without '{{'", outputTemplate));
      out += ch;
      ++i;
      continue;
    }
    const std::size_t close = outputTemplate.find('}', i);
    if (close == std::string::npos) {
      throw Error("", fmt::format("output template '{}': '{{' without '}}'", outputTemplate));
    }
    const std::string name = outputTemplate.substr(i + 1, close - i - 1);
    const std::optional<std::string> value = field(name);
    if (!value) throw Error("", fmt::format("output template '{}': unknown field {{{}}}", outputTemplate, name));
    out += sanitizeComponent(*value);
    i = close + 1;
  }
  // The literal parts may make folders, never leave the output folder.
  std::string checked;
  for (const auto& part : fs::path(out)) {
    const std::string s = part.string();
    if (s == ".." || s == ".") {
      throw Error("", fmt::format("output template '{}' must not contain '.' or '..' folders", outputTemplate));
    }
    if (s.empty() || s == "/") continue;
    if (!checked.empty()) checked += '/';
    checked += s;
  }
  if (!endsWith(checked, ".octoray")) checked += ".octoray";
  return checked;
}

namespace {

// The options' checks that need no scan: dates, the description regex, the template's fields.
std::optional<std::regex> checkPlanOptions(const PlanOptions& options) {
  if (options.outDir.empty()) throw Error("", "no output folder for the stores");
  checkDate(options.studyDateFrom, "study date");
  checkDate(options.studyDateTo, "study date");
  std::optional<std::regex> description;
  if (!options.descriptionRegex.empty()) {
    try {
      description.emplace(options.descriptionRegex, std::regex::ECMAScript | std::regex::icase);
    } catch (const std::regex_error& e) {
      throw Error("", fmt::format("description regex '{}': {}", options.descriptionRegex, e.what()));
    }
  }
  expandTemplate(options.outputTemplate, [](const std::string& name) -> std::optional<std::string> {
    static const std::set<std::string> known = {
        "PatientID-hash", "PatientID", "PatientName", "StudyInstanceUID", "StudyDate",
        "SeriesInstanceUID", "SeriesNumber", "SeriesDescription", "Modality", "Index", "FileName"};
    if (known.contains(name)) return "x";
    return std::nullopt;
  });
  return description;
}

json filtersJson(const PlanOptions& options) {
  json filters = json::object();
  if (!options.modalities.empty()) filters["modality"] = options.modalities;
  if (options.minSlices > 0) filters["minSlices"] = options.minSlices;
  if (!options.studyDateFrom.empty()) filters["studyDateFrom"] = options.studyDateFrom;
  if (!options.studyDateTo.empty()) filters["studyDateTo"] = options.studyDateTo;
  if (!options.descriptionRegex.empty()) filters["description"] = options.descriptionRegex;
  return filters;
}

// Why the filters leave a candidate out, or "" when they keep it.
std::string filteredOut(const WorkItem& it, const PlanOptions& options, const std::optional<std::regex>& description) {
  if (!options.modalities.empty() && it.kind == "dicom" &&
      std::find(options.modalities.begin(), options.modalities.end(), it.modality) == options.modalities.end()) {
    return fmt::format("filtered out: modality {} is not {}", it.modality.empty() ? "(none)" : it.modality,
                       fmt::join(options.modalities, " or "));
  }
  if (options.minSlices > 0 && it.dims[2] < options.minSlices) {
    return fmt::format("filtered out: {} slices, fewer than {}", it.dims[2], options.minSlices);
  }
  if ((!options.studyDateFrom.empty() || !options.studyDateTo.empty()) &&
      (it.studyDate.empty() || (!options.studyDateFrom.empty() && it.studyDate < options.studyDateFrom) ||
       (!options.studyDateTo.empty() && it.studyDate > options.studyDateTo))) {
    return fmt::format("filtered out: study date {} outside {}..{}", it.studyDate.empty() ? "(none)" : it.studyDate,
                       options.studyDateFrom, options.studyDateTo);
  }
  if (description && !std::regex_search(it.description, *description)) {
    return fmt::format("filtered out: description does not match '{}'", options.descriptionRegex);
  }
  return "";
}

// Content hashes (every byte of every file: the slow part of planning), in parallel; an
// item's error (a file gone or unreadable) in `errors`.
std::vector<std::string> hashContents(std::vector<Candidate>& kept, const PlanOptions& options) {
  std::vector<std::string> errors(kept.size());
  std::mutex progressMutex;
  std::size_t hashed = 0;
  tbb::parallel_for(std::size_t{0}, kept.size(), [&](std::size_t i) {
    WorkItem& it = kept[i].item;
    try {
      std::sort(it.files.begin(), it.files.end());
      it.files.erase(std::unique(it.files.begin(), it.files.end()), it.files.end());
      for (const auto& f : it.files) {
        it.fileHashes.push_back(fileContentHash(f));
        it.bytes += fs::file_size(f);
      }
      it.contentHash = combinedContentHash(it.fileHashes);
    } catch (const std::exception& e) {
      errors[i] = e.what();
    }
    if (options.progress) {
      std::lock_guard lock(progressMutex);
      options.progress("hashing", ++hashed, kept.size());
    }
  });
  return errors;
}

// The store's path relative to the output folder, from the template; `taken` makes clashing
// names unique (-2, -3, ...).
std::string outputName(const Candidate& cand, const PlanOptions& options, std::set<std::string>& taken) {
  const WorkItem& it = cand.item;
  auto field = [&](const std::string& name) -> std::optional<std::string> {
    if (name == "PatientID-hash") return it.kind == "dicom" ? it.patientIdHash : "no-patient-id";
    if (name == "PatientID") return cand.patientId;
    if (name == "PatientName") return cand.patientName;
    if (name == "StudyInstanceUID") return it.kind == "dicom" ? it.studyUid : "files";
    if (name == "StudyDate") return it.studyDate;
    if (name == "SeriesInstanceUID") return it.seriesUid;
    if (name == "SeriesNumber") return std::to_string(it.seriesNumber);
    if (name == "SeriesDescription") return it.kind == "dicom" ? it.description : cand.fileName;
    if (name == "Modality") return it.modality;
    if (name == "Index") return std::to_string(it.index);
    if (name == "FileName") return cand.fileName;
    return std::nullopt;
  };
  std::string relative = expandTemplate(options.outputTemplate, field);
  const std::string stem = relative.substr(0, relative.size() - std::string(".octoray").size());
  for (int n = 2; taken.contains(relative); ++n) relative = fmt::format("{}-{}.octoray", stem, n);
  taken.insert(relative);
  return relative;
}

// Items in a stable order (archive, then series number, UID, path), with indices, names and
// files relative to their folder; candidates whose hashing failed are skipped with the reason.
void addItems(Plan& plan, std::vector<Candidate>& kept, const std::vector<std::string>& hashErrors,
              const PlanOptions& options) {
  std::vector<std::size_t> order(kept.size());
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
    const WorkItem& x = kept[a].item;
    const WorkItem& y = kept[b].item;
    return std::tie(x.path, x.studyUid, x.seriesNumber, x.seriesUid, x.files.front()) <
           std::tie(y.path, y.studyUid, y.seriesNumber, y.seriesUid, y.files.front());
  });
  std::set<std::string> outputs;
  for (std::size_t i : order) {
    Candidate& cand = kept[i];
    WorkItem& it = cand.item;
    if (!hashErrors[i].empty()) {
      plan.skipped.push_back({cand.firstFile, it.seriesUid, it.seriesNumber, it.description, hashErrors[i]});
      continue;
    }
    it.index = static_cast<int64_t>(plan.items.size());
    it.patientIdHash = it.kind == "dicom" ? patientIdHash(cand.patientId, options.idSalt) : "";
    it.output = (fs::path(plan.outDir) / outputName(cand, options, outputs)).string();
    const fs::path folder = commonFolder(it.files);
    it.folder = folder.string();
    for (auto& f : it.files) f = fs::path(f).lexically_relative(folder).string();
    plan.items.push_back(std::move(it));
  }
}

}  // namespace

Plan makePlan(const std::vector<std::string>& archives, const PlanOptions& options) {
  const std::optional<std::regex> description = checkPlanOptions(options);  // before the (long) scan
  Collector c;
  c.plan.created = isoNow();
  c.plan.outDir = fs::absolute(options.outDir).lexically_normal().string();
  c.plan.outputTemplate = options.outputTemplate;
  for (const auto& archive : archives) {
    c.plan.archives.push_back(fs::absolute(archive).lexically_normal().string());
    scanArchive(c.plan.archives.back(), options, c);
  }
  c.plan.filters = filtersJson(options);

  std::vector<Candidate> kept;
  for (auto& cand : c.candidates) {
    const std::string reason = filteredOut(cand.item, options, description);
    if (reason.empty()) {
      kept.push_back(std::move(cand));
    } else {
      const WorkItem& it = cand.item;
      c.plan.skipped.push_back({cand.firstFile, it.seriesUid, it.seriesNumber, it.description, reason});
    }
  }
  addItems(c.plan, kept, hashContents(kept, options), options);
  std::stable_sort(c.plan.skipped.begin(), c.plan.skipped.end(),
                   [](const SkippedSource& a, const SkippedSource& b) { return a.path < b.path; });
  if (c.plan.items.empty()) {
    throw Error(archives.size() == 1 ? archives.front() : "",
                fmt::format("nothing to build: no volumetric series or volume file ({} skipped, {} "
                            "unreadable files)",
                            c.plan.skipped.size(), c.plan.unreadableFiles.size()));
  }
  return c.plan;
}

std::string dumpJson(const json& j, int indent) {
  return j.dump(indent, ' ', false, json::error_handler_t::replace);
}

json toJson(const WorkItem& it) {
  return {{"index", it.index}, {"kind", it.kind}, {"path", it.path},
          {"seriesUid", it.seriesUid}, {"seriesNumber", it.seriesNumber},
          {"studyUid", it.studyUid}, {"studyDate", it.studyDate},
          {"modality", it.modality}, {"description", it.description},
          {"patientIdHash", it.patientIdHash}, {"dims", it.dims},
          {"estimatedVoxels", it.voxels()}, {"bytes", it.bytes},
          {"contentHash", it.contentHash}, {"output", it.output},
          {"folder", it.folder}, {"files", it.files}, {"fileHashes", it.fileHashes}};
}

WorkItem itemFromJson(const json& e, const std::string& path) {
  try {
    WorkItem it;
    it.index = e.at("index").get<int64_t>();
    it.kind = e.at("kind").get<std::string>();
    it.path = e.at("path").get<std::string>();
    it.seriesUid = e.at("seriesUid").get<std::string>();
    it.seriesNumber = e.at("seriesNumber").get<int>();
    it.studyUid = e.at("studyUid").get<std::string>();
    it.studyDate = e.at("studyDate").get<std::string>();
    it.modality = e.at("modality").get<std::string>();
    it.description = e.at("description").get<std::string>();
    it.patientIdHash = e.at("patientIdHash").get<std::string>();
    it.dims = e.at("dims").get<std::array<int64_t, 3>>();
    it.bytes = e.at("bytes").get<uint64_t>();
    it.contentHash = e.at("contentHash").get<std::string>();
    it.output = e.at("output").get<std::string>();
    it.folder = e.at("folder").get<std::string>();
    it.files = e.at("files").get<std::vector<std::string>>();
    it.fileHashes = e.at("fileHashes").get<std::vector<std::string>>();
    if (it.fileHashes.size() != it.files.size()) {
      throw Error(path, fmt::format("item {}: {} files but {} file hashes", it.index, it.files.size(),
                                    it.fileHashes.size()));
    }
    if (it.kind != "dicom" && it.kind != "file") {
      throw Error(path, fmt::format("item {}: unknown kind '{}'", it.index, it.kind));
    }
    if (it.files.empty() || it.output.empty()) {
      throw Error(path, fmt::format("item {}: no files or no output", it.index));
    }
    for (int64_t d : it.dims) {
      if (d <= 0 || d > (int64_t{1} << 24)) {
        throw Error(path, fmt::format("item {}: dimensions must be in 1..16777216", it.index));
      }
    }
    if (it.dims[0] * it.dims[1] > (int64_t{1} << 40) / it.dims[2]) {
      throw Error(path, fmt::format("item {}: more than 2^40 voxels", it.index));
    }
    // The plan names where the runner writes: an absolute .octoray path, nothing else.
    const fs::path out(it.output);
    if (!out.is_absolute() || out.extension() != ".octoray" || out.lexically_normal() != out) {
      throw Error(path, fmt::format("item {}: output '{}' is not an absolute, normalised .octoray path",
                                    it.index, it.output));
    }
    for (const auto& f : it.files) {
      const fs::path rel(f);
      if (f.empty() || rel.is_absolute() || rel.lexically_normal().string().starts_with("..")) {
        throw Error(path, fmt::format("item {}: file '{}' is not inside the item's folder", it.index, f));
      }
    }
    return it;
  } catch (const json::exception& x) {
    throw Error(path, fmt::format("not a valid work item: {}", x.what()));
  }
}

json toJson(const Plan& plan) {
  json j = {{"format", "octoray-batch-plan"}, {"schemaVersion", kPlanSchemaVersion},
            {"created", plan.created}, {"archives", plan.archives}, {"outDir", plan.outDir},
            {"outputTemplate", plan.outputTemplate}, {"filters", plan.filters},
            {"totalVoxels", plan.totalVoxels()}};
  j["items"] = json::array();
  for (const WorkItem& it : plan.items) j["items"].push_back(toJson(it));
  auto sources = [](const std::vector<SkippedSource>& list) {
    json a = json::array();
    for (const auto& s : list) {
      json e = {{"path", s.path}, {"reason", s.reason}};
      if (!s.seriesUid.empty()) {
        e["seriesUid"] = s.seriesUid;
        e["seriesNumber"] = s.seriesNumber;
      }
      if (!s.description.empty()) e["description"] = s.description;
      a.push_back(std::move(e));
    }
    return a;
  };
  j["skipped"] = sources(plan.skipped);
  j["unreadableFiles"] = sources(plan.unreadableFiles);
  j["warnings"] = plan.warnings;
  return j;
}

Plan planFromJson(const json& j, const std::string& path) {
  try {
    if (!j.is_object() || j.value("format", "") != "octoray-batch-plan") {
      throw Error(path, "not an octoray-batch plan (no \"format\": \"octoray-batch-plan\")");
    }
    const int version = j.at("schemaVersion").get<int>();
    if (version != kPlanSchemaVersion) {
      throw Error(path, fmt::format("plan schema version {} (this octoray-batch reads {})", version,
                                    kPlanSchemaVersion));
    }
    Plan plan;
    plan.created = j.at("created").get<std::string>();
    plan.archives = j.at("archives").get<std::vector<std::string>>();
    plan.outDir = j.at("outDir").get<std::string>();
    plan.outputTemplate = j.at("outputTemplate").get<std::string>();
    plan.filters = j.at("filters");
    for (const json& e : j.at("items")) {
      WorkItem it = itemFromJson(e, path);
      if (it.index != static_cast<int64_t>(plan.items.size())) {
        throw Error(path, fmt::format("item {} is out of order (expected index {})", it.index,
                                      plan.items.size()));
      }
      plan.items.push_back(std::move(it));
    }
    for (const char* list : {"skipped", "unreadableFiles"}) {
      for (const json& e : j.at(list)) {
        SkippedSource s{e.at("path").get<std::string>(), e.value("seriesUid", ""),
                        e.value("seriesNumber", 0), e.value("description", ""),
                        e.at("reason").get<std::string>()};
        (std::string(list) == "skipped" ? plan.skipped : plan.unreadableFiles).push_back(std::move(s));
      }
    }
    plan.warnings = j.at("warnings").get<std::vector<std::string>>();
    return plan;
  } catch (const json::exception& e) {
    throw Error(path, fmt::format("not a valid plan: {}", e.what()));
  }
}

void writePlan(const Plan& plan, const fs::path& path) {
  writeFileAtomically(path, dumpJson(toJson(plan), 1) + "\n");
}

Plan readPlan(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error(path.string(), "cannot read the plan");
  std::stringstream text;
  text << in.rdbuf();
  const json j = json::parse(text.str(), nullptr, false);
  if (j.is_discarded()) throw Error(path.string(), "not a valid plan: the file is not JSON");
  return planFromJson(j, path.string());
}

}  // namespace octoray::batch
