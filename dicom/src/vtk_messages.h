#pragma once
// Internal: collects the error and warning messages a VTK object emits, so a reader's failure
// becomes one octoray::Error naming the file instead of text on stderr.

#include <vtkCallbackCommand.h>
#include <vtkCommand.h>
#include <vtkNew.h>
#include <vtkObject.h>

#include <string>
#include <vector>

namespace octoray::detail {

class VtkMessages {
 public:
  explicit VtkMessages(vtkObject* object) : object_(object) {
    callback_->SetClientData(this);
    callback_->SetCallback(&VtkMessages::collect);
    errorTag_ = object->AddObserver(vtkCommand::ErrorEvent, callback_);
    warningTag_ = object->AddObserver(vtkCommand::WarningEvent, callback_);
  }
  ~VtkMessages() {
    object_->RemoveObserver(errorTag_);
    object_->RemoveObserver(warningTag_);
  }
  VtkMessages(const VtkMessages&) = delete;
  VtkMessages& operator=(const VtkMessages&) = delete;

  const std::vector<std::string>& errors() const { return errors_; }
  const std::vector<std::string>& warnings() const { return warnings_; }

 private:
  // VTK prefixes "ERROR: In <file>, line <n>\n<class> (<address>): "; keep only the reason.
  static std::string reasonOnly(const char* text) {
    std::string message = text ? text : "";
    const auto cut = message.find("): ");
    if (cut != std::string::npos) message = message.substr(cut + 3);
    while (!message.empty() && (message.back() == '\n' || message.back() == ' ')) {
      message.pop_back();
    }
    return message;
  }

  static void collect(vtkObject*, unsigned long event, void* self, void* callData) {
    auto* messages = static_cast<VtkMessages*>(self);
    auto text = reasonOnly(static_cast<const char*>(callData));
    (event == vtkCommand::ErrorEvent ? messages->errors_ : messages->warnings_)
        .push_back(std::move(text));
  }

  vtkObject* object_;
  unsigned long errorTag_ = 0;
  unsigned long warningTag_ = 0;
  vtkNew<vtkCallbackCommand> callback_;
  std::vector<std::string> errors_;
  std::vector<std::string> warnings_;
};

}  // namespace octoray::detail
