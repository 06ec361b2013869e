#pragma once
// Console logging set-up (spdlog's default logger).
#include <string>
#include <vector>

#include <spdlog/common.h>

namespace nerfslam {

// "trace", "debug", "info", "warn", "error", "off": the levels a user may ask for.
const std::vector<std::string>& logLevelNames();

// Parses one of logLevelNames(). Throws an Error naming `source` and the bad value, with a
// "did you mean" hint (spdlog::level::from_str would silently turn a typo into "off").
spdlog::level::level_enum parseLogLevel(const std::string& level, const std::string& source = "log level");

// Validates `level` and applies it to the default logger. Throws like parseLogLevel.
void setupLogging(const std::string& level);

}  // namespace nerfslam
