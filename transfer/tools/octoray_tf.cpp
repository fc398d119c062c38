// octoray-tf: inspect and convert transfer-function files.
//   octoray-tf list FILE                               names of the functions in FILE
//   octoray-tf convert FILE [--tf-name NAME] -o OUT.json   export one (or the only) function
//   octoray-tf convert FILE --all -o OUT.json          export every function in FILE
// Reads octoray JSON, Slicer presets.xml / .vp / .vp.json and ParaView colour-map JSON.

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include <string>

#include "cli_support.h"
#include "octoray/core/atomic_file.h"
#include "octoray/transfer/transfer_function_io.h"

int main(int argc, char** argv) {
  return octoray::cli::runTool("octoray-tf", [&] {
    CLI::App app{"Inspect and convert transfer-function presets"};
    app.footer(
        "Examples:\n"
        "  octoray-tf list presets.xml                    # the functions in Slicer's presets\n"
        "  octoray-tf convert presets.xml --tf-name CT-AAA -o ct-aaa.json\n"
        "  octoray-render head.octoray --tf ct-aaa.json -o head.png\n");
    app.require_subcommand(1);

    std::string listFile;
    CLI::App* list = app.add_subcommand("list", "Print the names of the functions in a file");
    list->add_option("file", listFile, "Transfer-function file")->required();

    std::string convertFile, outputFile, tfName;
    bool all = false;
    CLI::App* convert = app.add_subcommand("convert", "Export to octoray transfer-function JSON");
    convert->add_option("file", convertFile, "Transfer-function file")->required();
    convert->add_option("-o,--output", outputFile, "Output .json file")->required();
    auto* nameOption =
        convert->add_option("--tf-name", tfName, "Function to export (needed when several)");
    convert->add_flag("--all", all, "Export every function in the file")->excludes(nameOption);

    try {
      app.parse(argc, argv);
    } catch (const CLI::ParseError& e) {
      return app.exit(e);
    }

    namespace tf = octoray::transfer;
    if (*list) {
      for (const tf::TransferFunction& function : tf::loadTransferFunctions(listFile)) {
        fmt::print("{}\n", function.name);
      }
      return 0;
    }
    octoray::checkOutputIsNotAnInput(outputFile, {convertFile});
    const std::vector<tf::TransferFunction> functions = tf::loadTransferFunctions(convertFile);
    if (all) {
      tf::saveTransferFunctions(functions, outputFile);
    } else {
      tf::saveTransferFunction(tf::selectTransferFunction(functions, tfName, convertFile),
                               outputFile);
    }
    return 0;
  });
}
