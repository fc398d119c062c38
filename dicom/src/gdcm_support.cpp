#include "gdcm_support.h"

#include <gdcmSequenceOfItems.h>
#include <gdcmTrace.h>
#include <gdcmTransferSyntax.h>

#include <cmath>
#include <cstdlib>
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

std::optional<int> unsignedShort(const gdcm::File& file, const gdcm::DataSet& ds,
                                 const gdcm::Tag& tag, bool asSigned) {
  if (!ds.FindDataElement(tag)) return std::nullopt;
  const gdcm::ByteValue* bv = ds.GetDataElement(tag).GetByteValue();
  if (!bv || bv->GetLength() < 2) return std::nullopt;
  const auto* p = reinterpret_cast<const unsigned char*>(bv->GetPointer());
  // GDCM keeps element bytes in the file's byte order; only explicit big endian differs.
  const bool bigEndian =
      file.GetHeader().GetDataSetTransferSyntax() == gdcm::TransferSyntax::ExplicitVRBigEndian;
  const unsigned v = bigEndian ? (unsigned(p[0]) << 8 | p[1]) : (unsigned(p[1]) << 8 | p[0]);
  if (asSigned) return static_cast<int>(static_cast<int16_t>(v));
  return static_cast<int>(v);
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
