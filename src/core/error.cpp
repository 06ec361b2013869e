#include "nerfslam/core/error.h"

namespace nerfslam {

Error fieldError(const std::string& file, const std::string& field, const std::string& what) {
  return Error(fmt::format("{}: field '{}': {}", file, field, what));
}

}  // namespace nerfslam
