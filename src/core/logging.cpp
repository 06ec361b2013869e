#include "nerfslam/core/logging.h"

#include <spdlog/spdlog.h>

#include "nerfslam/core/error.h"
#include "nerfslam/core/options_yaml.h"

namespace nerfslam {

const std::vector<std::string>& logLevelNames() {
  static const std::vector<std::string> names = {"trace", "debug", "info", "warn", "error", "off"};
  return names;
}

spdlog::level::level_enum parseLogLevel(const std::string& level, const std::string& source) {
  static const spdlog::level::level_enum levels[] = {spdlog::level::trace, spdlog::level::debug, spdlog::level::info,
                                                     spdlog::level::warn,  spdlog::level::err,   spdlog::level::off};
  const auto& names = logLevelNames();
  for (size_t i = 0; i < names.size(); ++i)
    if (names[i] == level) return levels[i];
  fail("{}: '{}' is not a log level (trace, debug, info, warn, error, off){}", source, level, didYouMean(level, names));
}

void setupLogging(const std::string& level) { spdlog::set_level(parseLogLevel(level)); }

}  // namespace nerfslam
