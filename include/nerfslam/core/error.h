#pragma once
// The one exception type for bad input and failed operations. Messages name the file and the field
// so a user can fix the input; the CLI prints them and exits non-zero.
#include <stdexcept>
#include <string>
#include <string_view>

#include <fmt/format.h>

namespace nerfslam {

class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// "FILE: field 'FIELD': WHAT"
Error fieldError(const std::string& file, const std::string& field, const std::string& what);

// Outside text quoted in a message, cut to at most `max` characters ending in "..." (a 50 MB YAML
// scalar must not be echoed whole).
std::string cutForMessage(std::string_view text, size_t max = 80);

// A number (a timestamp, a coordinate) for a message: `decimals` decimals while it is short, the
// shortest exact form otherwise ("{:.6f}" prints 1e300 with 301 digits).
std::string numberForMessage(double x, int decimals = 6);

template <typename... Args>
[[noreturn]] void fail(fmt::format_string<Args...> f, Args&&... args) {
  throw Error(fmt::format(f, std::forward<Args>(args)...));
}

}  // namespace nerfslam
