#pragma once
// Writing a small file so that readers see the old file or the whole new one, never a part:
// the bytes go to a hidden temporary in the same folder (".NAME.partial-PID", the name every
// octoray writer uses, so a killed run's leftovers are recognisable), are flushed to disk,
// and the temporary is renamed over NAME.

#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

namespace octoray {

// The hidden temporary `path` is written through by this process.
std::filesystem::path partialPathFor(const std::filesystem::path& path);

// Writes `bytes` to `path` atomically (see above). Throws octoray::Error naming `path` when the
// folder cannot be written or the disk is full; the temporary is removed then.
void writeFileAtomically(const std::filesystem::path& path, std::string_view bytes);

// Throws octoray::Error naming `output` when it is the same file as one of `inputs` (through
// a link, a hard link or another spelling of its path): writing it would destroy what is being
// read. The store builder, the NIfTI and VDB exports, octoray-render and octoray-tf call it
// before they create anything; an output that does not exist yet passes.
void checkOutputIsNotAnInput(const std::filesystem::path& output,
                             const std::vector<std::string>& inputs);

}  // namespace octoray
