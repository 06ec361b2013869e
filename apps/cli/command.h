#pragma once
// Subcommand registry for the `nerfslam` CLI. Each apps/cli/cmd_<name>.cpp registers one subcommand:
//
//   static nerfslam::cli::Registrar reg("eval", "Evaluate a trajectory against ground truth",
//       [](CLI::App& sub) -> nerfslam::cli::Runner {
//         auto o = std::make_shared<EvalArgs>();
//         sub.add_option("--ref", o->ref, "Reference trajectory")->required();
//         return [o]() -> int { ...; return 0; };
//       });
//
// The runner returns the process exit code. Throwing nerfslam::Error prints "error: <message>" and
// exits with 1; the main program never lets an exception escape as a crash.
#include <CLI/CLI.hpp>
#include <functional>
#include <string>
#include <vector>

namespace nerfslam::cli {

using Runner = std::function<int()>;
using Setup = std::function<Runner(CLI::App&)>;

struct CommandSpec {
  std::string name;
  std::string help;
  Setup setup;
};

std::vector<CommandSpec>& registry();

struct Registrar {
  Registrar(std::string name, std::string help, Setup setup) {
    registry().push_back({std::move(name), std::move(help), std::move(setup)});
  }
};

}  // namespace nerfslam::cli
