#pragma once
// Internal: collects the messages VTK objects emit, so a reader's failure becomes
// one octoray::Error naming the file instead of text (and object dumps) on stderr.

#include <vtkAlgorithm.h>
#include <vtkCallbackCommand.h>
#include <vtkCommand.h>
#include <vtkExecutive.h>
#include <vtkNew.h>
#include <vtkObject.h>

#include <string>
#include <vector>

namespace octoray::detail {

// Observes the error and warning events of a VTK object, and for an algorithm those of its
// executive too: a failed pipeline request is reported by the executive, with a dump of the
// request, which VTK would otherwise print.
class VtkMessages {
 public:
  explicit VtkMessages(vtkObject* object) { observe(object); }
  explicit VtkMessages(vtkAlgorithm* algorithm) {
    observe(algorithm);
    observe(algorithm->GetExecutive());
  }
  ~VtkMessages() {
    for (const auto& o : observed_) {
      o.object->RemoveObserver(o.errorTag);
      o.object->RemoveObserver(o.warningTag);
    }
  }
  VtkMessages(const VtkMessages&) = delete;
  VtkMessages& operator=(const VtkMessages&) = delete;

  const std::vector<std::string>& errors() const { return errors_; }
  const std::vector<std::string>& warnings() const { return warnings_; }

 private:
  struct Observed {
    vtkObject* object;
    unsigned long errorTag, warningTag;
  };

  void observe(vtkObject* object) {
    if (!object) return;
    callback_->SetClientData(this);
    callback_->SetCallback(&VtkMessages::collect);
    observed_.push_back({object, object->AddObserver(vtkCommand::ErrorEvent, callback_),
                         object->AddObserver(vtkCommand::WarningEvent, callback_)});
  }

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

  std::vector<Observed> observed_;
  vtkNew<vtkCallbackCommand> callback_;
  std::vector<std::string> errors_;
  std::vector<std::string> warnings_;
};

}  // namespace octoray::detail
