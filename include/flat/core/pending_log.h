// A tool's log file that appears only when the tool succeeds. For tools whose
// log lies in an input folder (flat_latents and flat_pack: beside the scenes
// they read): a run that fails leaves that folder exactly as it was. The
// lines go to the console and to a temporary file outside it; keep() appends
// them to the real log file (and logs there from then on). A run that ends
// without keep() says where its log is instead.
#pragma once
#include <string>

namespace flat {

class PendingLog {
 public:
  PendingLog() = default;
  ~PendingLog();  // without keep(): names the temporary log on stderr
  PendingLog(const PendingLog&) = delete;
  PendingLog& operator=(const PendingLog&) = delete;

  // Console logging at `level` plus the temporary file; `log_file` is where keep() puts it.
  void start(const std::string& level, const std::string& log_file);
  // The run succeeded: append what was logged to log_file (its folder must
  // exist; when it cannot be written, a warning names the temporary file).
  void keep();

 private:
  std::string level_, final_, temp_;
  bool kept_ = false;
};

}  // namespace flat
