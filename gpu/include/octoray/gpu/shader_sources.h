#pragma once
// The .glsl files of gpu/shaders/, embedded in the library at build time
// (cmake/EmbedShaders.cmake), looked up by file name.

#include <string_view>
#include <vector>

namespace octoray::gpu {

// The exact bytes of gpu/shaders/<name> (e.g. "fullscreen.vert.glsl"), valid for the whole
// program. Throws octoray::Error("", "no embedded shader <name>") when there is no such file.
std::string_view shaderSource(std::string_view name);

// Every embedded file name, sorted.
std::vector<std::string_view> shaderNames();

}  // namespace octoray::gpu
