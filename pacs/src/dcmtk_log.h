#pragma once
// DCMTK logs to the console by default; octoray's errors say what matters, so its log is off
// unless OCTORAY_DCMTK_LOG names a level (trace, debug, info, warn, error; at debug and below
// it prints datasets, patient data included). Call before any DCMTK use; idempotent.

namespace octoray::pacs {

void configureDcmtkLog();

}  // namespace octoray::pacs
