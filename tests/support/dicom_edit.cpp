#include "dicom_edit.h"

#include <gdcmDicts.h>
#include <gdcmGlobal.h>
#include <gdcmReader.h>
#include <gdcmWriter.h>

#include <stdexcept>

namespace octoray::test {

void rewriteDicomStrings(const std::filesystem::path& path, const std::vector<std::pair<DicomTag, std::string>>& values) {
  gdcm::Reader reader;
  reader.SetFileName(path.c_str());
  if (!reader.Read()) throw std::runtime_error(path.string() + ": test could not read the DICOM file");
  gdcm::DataSet& ds = reader.GetFile().GetDataSet();
  for (const auto& [t, text] : values) {
    const gdcm::Tag tag(t.group, t.element);
    gdcm::DataElement de(tag);
    de.SetVR(ds.FindDataElement(tag) ? ds.GetDataElement(tag).GetVR()
                                     : gdcm::Global::GetInstance().GetDicts().GetDictEntry(tag).GetVR());
    std::string padded = text;
    if (padded.size() % 2) padded += (de.GetVR() == gdcm::VR::UI ? '\0' : ' ');
    de.SetByteValue(padded.data(), static_cast<uint32_t>(padded.size()));
    ds.Replace(de);
  }
  gdcm::Writer writer;
  writer.SetFileName(path.c_str());
  writer.SetFile(reader.GetFile());
  if (!writer.Write()) throw std::runtime_error(path.string() + ": test could not write the DICOM file");
}

}  // namespace octoray::test
