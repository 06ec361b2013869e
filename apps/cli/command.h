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
#include <cmath>
#include <cstdlib>
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

// CLI11's PositiveNumber and NonNegativeNumber let NaN through and print the largest double with
// 309 digits when they refuse; these refuse nan and inf in a short message ("must be > 0 (got inf)").
inline CLI::Validator boundNumber(bool allow_zero) {
  return CLI::Validator(
      [allow_zero](std::string& s) -> std::string {
        char* end = nullptr;
        const double v = std::strtod(s.c_str(), &end);
        if (end == s.c_str()) return {};  // not a number: the option's type conversion says so
        if (!std::isfinite(v) || v < 0 || (!allow_zero && v == 0))
          return std::string("must be ") + (allow_zero ? ">= 0" : "> 0") + " (got " + s.substr(0, 40) + ")";
        return {};
      },
      allow_zero ? "NONNEGATIVE" : "POSITIVE");
}
inline const CLI::Validator kPositive = boundNumber(false);
inline const CLI::Validator kNonNegative = boundNumber(true);

struct Registrar {
  Registrar(std::string name, std::string help, Setup setup) {
    registry().push_back({std::move(name), std::move(help), std::move(setup)});
  }
};

}  // namespace nerfslam::cli
