#pragma once
// Typed option structs. Every module's options are a plain struct with defaults and a `visit`
// method that names, documents and constrains each field:
//
//   struct TrackerOptions {
//     int fast_threshold = 20;
//     double min_parallax_deg = 1.0;
//     std::string matcher = "patch";
//     template <class V> void visit(V& v) {
//       v("fast_threshold", fast_threshold, "FAST corner threshold on 8-bit intensities", check::range(1, 255));
//       v("min_parallax_deg", min_parallax_deg, "Smallest median parallax accepted by initialisation",
//       check::positive<double>()); v("matcher", matcher, "Map-point matcher", check::oneOf({"patch", "orb"}));
//     }
//   };
//
// A field that is itself an options struct is visited as a YAML section: v("tracker", tracker, "doc").
// Loading from YAML, printing at start-up, validation and the option reference
// (docs/options.md, `nerfslam options`) all walk `visit`, so a field is documented in one place.
// Supported field types: bool, int, int64_t, float, double, std::string, std::vector<double>,
// std::vector<int>, and nested option structs.
#include <cmath>
#include <functional>
#include <sstream>
#include <string>
#include <vector>

namespace nerfslam {

// A constraint returns "" when the value is valid, otherwise the reason (e.g. "must be > 0").
template <typename T>
using Check = std::function<std::string(const T&)>;

namespace check {

template <typename T>
Check<T> range(T lo, T hi) {
  return [lo, hi](const T& x) -> std::string {
    if constexpr (std::is_floating_point_v<T>) {
      if (!std::isfinite(x)) return "must be a finite number";
    }
    if (x < lo || x > hi) {
      std::ostringstream os;
      os << "must be in [" << lo << ", " << hi << "]";
      return os.str();
    }
    return "";
  };
}

template <typename T>
Check<T> positive() {
  return [](const T& x) -> std::string {
    if constexpr (std::is_floating_point_v<T>) {
      if (!std::isfinite(x)) return "must be a finite number";
    }
    return x > T(0) ? "" : "must be > 0";
  };
}

template <typename T>
Check<T> nonNegative() {
  return [](const T& x) -> std::string {
    if constexpr (std::is_floating_point_v<T>) {
      if (!std::isfinite(x)) return "must be a finite number";
    }
    return x >= T(0) ? "" : "must be >= 0";
  };
}

inline Check<std::string> oneOf(std::vector<std::string> valid) {
  return [valid](const std::string& s) -> std::string {
    for (const auto& v : valid)
      if (s == v) return "";
    std::string list;
    for (const auto& v : valid) list += (list.empty() ? "" : ", ") + v;
    return "must be one of: " + list;
  };
}

}  // namespace check
}  // namespace nerfslam
