#pragma once
// The one exception type for bad input and failed operations. Messages name the file and the field
// so a user can fix the input; the CLI prints them and exits non-zero.
#include <stdexcept>
#include <string>

#include <fmt/format.h>

namespace nerfslam {

class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// "FILE: field 'FIELD': WHAT"
Error fieldError(const std::string& file, const std::string& field, const std::string& what);

template <typename... Args>
[[noreturn]] void fail(fmt::format_string<Args...> f, Args&&... args) {
  throw Error(fmt::format(f, std::forward<Args>(args)...));
}

}  // namespace nerfslam
