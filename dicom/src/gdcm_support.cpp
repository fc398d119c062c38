#include "gdcm_support.h"

#include <fcntl.h>
#include <gdcmImageReader.h>
#include <gdcmReader.h>
#include <gdcmSequenceOfItems.h>
#include <sys/wait.h>
#include <unistd.h>
#include <gdcmTrace.h>
#include <gdcmTransferSyntax.h>

#include <cmath>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <set>

#include "octoray/core/error.h"
#include <mutex>

namespace octoray::dicom::detail {

void quietGdcm() {
  static std::once_flag once;
  std::call_once(once, [] {
    gdcm::Trace::WarningOff();
    gdcm::Trace::DebugOff();
    gdcm::Trace::ErrorOff();
  });
}

std::string stringValue(const gdcm::DataSet& ds, const gdcm::Tag& tag) {
  if (!ds.FindDataElement(tag)) return {};
  const gdcm::DataElement& de = ds.GetDataElement(tag);
  const gdcm::ByteValue* bv = de.GetByteValue();
  if (!bv || bv->GetLength() == 0) return {};
  std::string s(bv->GetPointer(), bv->GetLength());
  while (!s.empty() && (s.back() == ' ' || s.back() == '\0')) s.pop_back();
  std::size_t start = 0;
  while (start < s.size() && s[start] == ' ') ++start;
  return s.substr(start);
}

std::vector<std::string> stringValues(const gdcm::DataSet& ds, const gdcm::Tag& tag) {
  std::vector<std::string> values;
  const std::string all = stringValue(ds, tag);
  if (all.empty()) return values;
  std::size_t begin = 0;
  while (true) {
    const std::size_t end = all.find('\\', begin);
    std::string v = all.substr(begin, end == std::string::npos ? std::string::npos : end - begin);
    while (!v.empty() && (v.back() == ' ' || v.back() == '\0')) v.pop_back();
    while (!v.empty() && v.front() == ' ') v.erase(v.begin());
    values.push_back(std::move(v));
    if (end == std::string::npos) break;
    begin = end + 1;
  }
  return values;
}

std::optional<std::vector<double>> numberValues(const gdcm::DataSet& ds, const gdcm::Tag& tag) {
  const auto strings = stringValues(ds, tag);
  if (strings.empty()) return std::nullopt;
  std::vector<double> numbers;
  for (const auto& s : strings) {
    // strtod accepts the DS grammar (sign, digits, '.', exponent); reject trailing junk.
    if (s.empty()) return std::nullopt;
    char* end = nullptr;
    const double v = std::strtod(s.c_str(), &end);
    if (end != s.c_str() + s.size() || !std::isfinite(v)) return std::nullopt;
    numbers.push_back(v);
  }
  return numbers;
}

std::optional<double> numberValue(const gdcm::DataSet& ds, const gdcm::Tag& tag) {
  auto values = numberValues(ds, tag);
  if (!values || values->empty()) return std::nullopt;
  return values->front();
}

std::optional<int> unsignedShort(const gdcm::File& /*file*/, const gdcm::DataSet& ds,
                                 const gdcm::Tag& tag, bool asSigned) {
  if (!ds.FindDataElement(tag)) return std::nullopt;
  const gdcm::ByteValue* bv = ds.GetDataElement(tag).GetByteValue();
  if (!bv || bv->GetLength() < 2) return std::nullopt;
  uint16_t v = 0;
  std::memcpy(&v, bv->GetPointer(), sizeof v);  // already swapped to host order by GDCM
  if (asSigned) return static_cast<int>(static_cast<int16_t>(v));
  return static_cast<int>(v);
}


std::size_t pixelValueOffset(const std::string& path) {
  gdcm::Reader reader;
  reader.SetFileName(path.c_str());
  const gdcm::Tag pixelData(0x7fe0, 0x0010);
  if (!reader.ReadUpToTag(pixelData, std::set<gdcm::Tag>{pixelData})) return std::size_t(-1);
  return reader.GetStreamCurrentPosition();
}

std::vector<gdcm::DataSet> sequenceItems(const gdcm::DataSet& ds, const gdcm::Tag& tag) {
  std::vector<gdcm::DataSet> items;
  if (!ds.FindDataElement(tag)) return items;
  gdcm::SmartPointer<gdcm::SequenceOfItems> sq = ds.GetDataElement(tag).GetValueAsSQ();
  if (!sq) return items;
  items.reserve(sq->GetNumberOfItems());
  for (gdcm::SequenceOfItems::SizeType i = 1; i <= sq->GetNumberOfItems(); ++i) {
    items.push_back(sq->GetItem(i).GetNestedDataSet());  // GDCM items are 1-based
  }
  return items;
}

std::optional<gdcm::DataSet> firstItem(const gdcm::DataSet& ds, const gdcm::Tag& tag) {
  if (!ds.FindDataElement(tag)) return std::nullopt;
  gdcm::SmartPointer<gdcm::SequenceOfItems> sq = ds.GetDataElement(tag).GetValueAsSQ();
  if (!sq || sq->GetNumberOfItems() == 0) return std::nullopt;
  return sq->GetItem(1).GetNestedDataSet();
}

}  // namespace octoray::dicom::detail
