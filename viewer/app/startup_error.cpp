// When the display cannot give an OpenGL 4.5 core context, the viewer still opens a window —
// with whatever context the display offers and Dear ImGui's OpenGL 2 backend — that says
// what is missing, instead of a black window or a silent exit.
#include <epoxy/gl.h>
#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>
#include <imgui.h>
#include <imgui_impl_glfw.h>
#include <imgui_impl_opengl2.h>

#include <chrono>
#include <cstdio>
#include <iostream>
#include <string>
#include <thread>
#include <vector>

#include "app.h"
#include "octoray/gpu/gl_context.h"
#include "octoray/gpu/image_io.h"

namespace octoray::viewer {

int showStartupError(const std::string& message, const std::string& screenshot, bool exitAfter) {
  std::cerr << "octoray-view: " << message << "\n";
  // The viewer's own attempt closed the display connection, and an X server that resets when
  // its last client leaves (Xvfb, a bare xinit session) refuses connections while it does:
  // try again for up to 5 s before concluding there is no display.
  bool initialised = glfwInit() == GLFW_TRUE;
  for (int attempt = 0; !initialised && attempt < 50; ++attempt) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    initialised = glfwInit() == GLFW_TRUE;
  }
  if (!initialised) {  // no display at all: stderr is all there is
    const char* why = nullptr;
    glfwGetError(&why);
    std::cerr << "octoray-view: no display to show this on" << (why ? std::string(": ") + why : "") << "\n";
    return 1;
  }
  glfwDefaultWindowHints();
  GLFWwindow* window = glfwCreateWindow(760, 260, "octoray-view: cannot start", nullptr, nullptr);
  if (!window) {
    const char* why = nullptr;
    glfwGetError(&why);
    std::cerr << "octoray-view: no window to show this in either" << (why ? std::string(": ") + why : "") << "\n";
    glfwTerminate();
    return 1;
  }
  glfwMakeContextCurrent(window);
  gpu::keepGlDriversResident();
  const char* version = reinterpret_cast<const char*>(glGetString(GL_VERSION));
  const char* renderer = reinterpret_cast<const char*>(glGetString(GL_RENDERER));
  const std::string offered = std::string(version ? version : "unknown") + " (" + (renderer ? renderer : "unknown") + ")";
  ImGui::CreateContext();
  ImGui::GetIO().IniFilename = nullptr;
  ImGui::StyleColorsDark();
  ImGui_ImplGlfw_InitForOpenGL(window, true);
  ImGui_ImplOpenGL2_Init();
  bool quit = false;
  for (int frame = 0; !quit && !glfwWindowShouldClose(window); ++frame) {
    if (exitAfter) glfwPollEvents();
    else glfwWaitEventsTimeout(0.5);
    ImGui_ImplOpenGL2_NewFrame();
    ImGui_ImplGlfw_NewFrame();
    ImGui::NewFrame();
    int w = 0, h = 0;
    glfwGetFramebufferSize(window, &w, &h);
    ImGui::SetNextWindowPos(ImVec2(0, 0));
    ImGui::SetNextWindowSize(ImVec2(static_cast<float>(w), static_cast<float>(h)));
    ImGui::PushStyleColor(ImGuiCol_WindowBg, ImVec4(0.45f, 0.08f, 0.08f, 1.0f));
    ImGui::Begin("##error", nullptr, ImGuiWindowFlags_NoDecoration | ImGuiWindowFlags_NoMove);
    ImGui::TextWrapped("octoray-view cannot start on this display.");
    ImGui::Spacing();
    ImGui::TextWrapped("%s", message.c_str());
    ImGui::Spacing();
    ImGui::TextWrapped("This display offers OpenGL %s. octoray-view needs an OpenGL 4.5 core context "
                       "(Mesa 20 or later, or a current GPU driver). octoray-render draws the same "
                       "pictures headless.", offered.c_str());
    ImGui::Spacing();
    if (ImGui::Button("Quit")) quit = true;
    ImGui::End();
    ImGui::PopStyleColor();
    ImGui::Render();
    glViewport(0, 0, w, h);
    glClearColor(0, 0, 0, 1);
    glClear(GL_COLOR_BUFFER_BIT);
    ImGui_ImplOpenGL2_RenderDrawData(ImGui::GetDrawData());
    if (exitAfter && frame == 3) {
      if (!screenshot.empty()) {
        std::vector<unsigned char> pixels(static_cast<std::size_t>(w * h) * 4);
        glPixelStorei(GL_PACK_ALIGNMENT, 1);
        glReadPixels(0, 0, w, h, GL_RGBA, GL_UNSIGNED_BYTE, pixels.data());
        gpu::Image image(w, h);
        image.hasAlpha = false;
        for (int y = 0; y < h; ++y) {
          for (int x = 0; x < w; ++x) {
            const unsigned char* p = &pixels[static_cast<std::size_t>(((h - 1 - y) * w + x) * 4)];
            float* q = image.pixel(x, y);
            q[0] = p[0] / 255.0f, q[1] = p[1] / 255.0f, q[2] = p[2] / 255.0f, q[3] = 1.0f;
          }
        }
        gpu::writePng(image, screenshot);
      }
      quit = true;
    }
    glfwSwapBuffers(window);
  }
  ImGui_ImplOpenGL2_Shutdown();
  ImGui_ImplGlfw_Shutdown();
  ImGui::DestroyContext();
  glfwDestroyWindow(window);
  glfwTerminate();
  return 1;
}

}  // namespace octoray::viewer
