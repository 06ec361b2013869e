// `nerfslam <subcommand> ...`: the one command-line entry point. Subcommands live in cmd_*.cpp.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>

#include "command.h"
#include "nerfslam/core/error.h"
#include "nerfslam/core/logging.h"

namespace nerfslam::cli {
std::vector<CommandSpec>& registry() {
  static std::vector<CommandSpec> r;
  return r;
}
}  // namespace nerfslam::cli

int main(int argc, char** argv) {
  using namespace nerfslam::cli;
  CLI::App app{"nerfslam: monocular SLAM with a CPU-trained neural radiance field map"};
  app.require_subcommand(1);
  std::string log_level = "info";
  app.add_option("--log-level", log_level, "trace, debug, info, warn, error or off")
      ->check(CLI::IsMember(nerfslam::logLevelNames()));
  auto specs = registry();
  std::sort(specs.begin(), specs.end(), [](const auto& a, const auto& b) { return a.name < b.name; });
  std::map<CLI::App*, Runner> runners;
  for (const auto& s : specs) {
    CLI::App* sub = app.add_subcommand(s.name, s.help);
    runners[sub] = s.setup(*sub);
  }
  // Every floating-point option refuses nan and inf: CLI11's range checks let NaN through (a
  // `train --seconds nan` trained for ever).
  const CLI::Validator finite(
      [](std::string& s) -> std::string {
        char* end = nullptr;
        const double v = std::strtod(s.c_str(), &end);
        if (end != s.c_str() && !std::isfinite(v)) return "must be a finite number (got " + s + ")";
        return {};
      },
      "");
  for (CLI::App* sub : app.get_subcommands({}))
    for (CLI::Option* o : sub->get_options())
      if (o->get_type_name().find("FLOAT") != std::string::npos) o->check(finite);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }
  try {
    nerfslam::setupLogging(log_level);
    for (auto& [sub, run] : runners)
      if (sub->parsed()) return run();
  } catch (const nerfslam::Error& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
  return 1;
}
