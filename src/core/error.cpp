#include "nerfslam/core/error.h"

#include <algorithm>
#include <cmath>

namespace nerfslam {

Error fieldError(const std::string& file, const std::string& field, const std::string& what) {
  return Error(fmt::format("{}: field '{}': {}", file, field, what));
}

std::string cutForMessage(std::string_view text, size_t max) {
  if (text.size() <= max) return std::string(text);
  max = std::max<size_t>(max, 4);
  size_t n = max - 3;
  // Not inside a UTF-8 sequence.
  while (n > 0 && (static_cast<unsigned char>(text[n]) & 0xC0) == 0x80) --n;
  return std::string(text.substr(0, n)) + "...";
}

std::string numberForMessage(double x, int decimals) {
  if (std::isfinite(x) && std::abs(x) < 1e15) return fmt::format("{:.{}f}", x, decimals);
  return fmt::format("{}", x);  // shortest round-trip form: "1e+300", "inf", "nan"
}

}  // namespace nerfslam
