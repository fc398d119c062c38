#include "dcmtk_log.h"

#include <dcmtk/config/osconfig.h>
#include <dcmtk/oflog/oflog.h>

#include <cctype>
#include <cstdlib>
#include <mutex>
#include <string>

namespace octoray::pacs {

void configureDcmtkLog() {
  static std::once_flag once;
  std::call_once(once, [] {
    OFLogger::LogLevel level = OFLogger::OFF_LOG_LEVEL;
    if (const char* wanted = std::getenv("OCTORAY_DCMTK_LOG")) {
      std::string name = wanted;
      for (char& c : name) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
      if (name == "trace") level = OFLogger::TRACE_LOG_LEVEL;
      if (name == "debug") level = OFLogger::DEBUG_LOG_LEVEL;
      if (name == "info") level = OFLogger::INFO_LOG_LEVEL;
      if (name == "warn") level = OFLogger::WARN_LOG_LEVEL;
      if (name == "error") level = OFLogger::ERROR_LOG_LEVEL;
    }
    OFLog::configure(level);
  });
}

}  // namespace octoray::pacs
