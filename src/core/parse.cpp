#include "nerfslam/core/parse.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>

#include "nerfslam/core/error.h"

namespace nerfslam {

std::vector<double> parseNumberList(const std::string& text, const std::string& what) {
  std::vector<double> v;
  if (text.find_first_not_of(" \t") == std::string::npos) return v;
  size_t start = 0;
  while (start <= text.size()) {
    const size_t end = std::min(text.find(',', start), text.size());
    std::string item = text.substr(start, end - start);
    const size_t a = item.find_first_not_of(" \t"), b = item.find_last_not_of(" \t");
    item = a == std::string::npos ? std::string() : item.substr(a, b - a + 1);
    char* stop = nullptr;
    const double d = item.empty() ? 0.0 : std::strtod(item.c_str(), &stop);
    if (item.empty() || *stop != '\0' || !std::isfinite(d))
      fail("{} '{}': '{}' is not a finite number", what, text, item);
    v.push_back(d);
    start = end + 1;
  }
  return v;
}

void parseImageSize(const std::string& text, const std::string& what, int min_side, int* width, int* height) {
  constexpr int kMaxSide = 8192;
  const size_t x = text.find_first_of("xX");
  long side[2] = {0, 0};
  bool ok = x != std::string::npos;
  for (int i = 0; ok && i < 2; ++i) {
    const std::string part = i == 0 ? text.substr(0, x) : text.substr(x + 1);
    char* stop = nullptr;
    ok = !part.empty() && part.find_first_not_of("0123456789") == std::string::npos && part.size() <= 6;
    if (ok) side[i] = std::strtol(part.c_str(), &stop, 10);
  }
  if (!ok) fail("{} '{}': expected WIDTHxHEIGHT, e.g. 640x480", what, text);
  if (side[0] < min_side || side[1] < min_side || side[0] > kMaxSide || side[1] > kMaxSide)
    fail("{} {}: width and height must be in {}..{}", what, text, min_side, kMaxSide);
  *width = static_cast<int>(side[0]);
  *height = static_cast<int>(side[1]);
}

}  // namespace nerfslam
