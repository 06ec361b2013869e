#include "nerfslam/core/parse.h"

#include <algorithm>
#include <charconv>
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
    const double d = std::strtod(item.c_str(), &stop);
    if (item.empty() || *stop != '\0' || !std::isfinite(d))
      fail("{} '{}': '{}' is not a finite number", what, cutForMessage(text), cutForMessage(item));
    v.push_back(d);
    start = end + 1;
  }
  return v;
}

void parseImageSize(const std::string& text, const std::string& what, int min_side, int* width, int* height) {
  constexpr int kMaxSide = 8192;
  const size_t x = text.find_first_of("xX");
  int side[2] = {0, 0};
  bool ok = x != std::string::npos;
  for (int i = 0; ok && i < 2; ++i) {
    const char* first = text.data() + (i == 0 ? 0 : x + 1);
    const char* last = text.data() + (i == 0 ? x : text.size());
    const auto r = std::from_chars(first, last, side[i]);  // digits only: no sign, no space
    ok = first != last && *first != '-' && r.ec == std::errc() && r.ptr == last;
  }
  if (!ok) fail("{} '{}': expected WIDTHxHEIGHT, e.g. 640x480", what, cutForMessage(text));
  if (side[0] < min_side || side[1] < min_side || side[0] > kMaxSide || side[1] > kMaxSide)
    fail("{} {}: width and height must be in {}..{}", what, text, min_side, kMaxSide);
  *width = side[0];
  *height = side[1];
}

}  // namespace nerfslam
