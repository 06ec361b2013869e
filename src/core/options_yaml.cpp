#include "nerfslam/core/options_yaml.h"

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <map>
#include <sstream>
#include <vector>

#include "nerfslam/core/error.h"
#include "nerfslam/core/input_file.h"

namespace nerfslam {

size_t editDistance(std::string_view a, std::string_view b) {
  const size_t n = a.size(), m = b.size();
  std::vector<std::vector<size_t>> d(n + 1, std::vector<size_t>(m + 1, 0));
  for (size_t i = 0; i <= n; ++i) d[i][0] = i;
  for (size_t j = 0; j <= m; ++j) d[0][j] = j;
  for (size_t i = 1; i <= n; ++i) {
    for (size_t j = 1; j <= m; ++j) {
      const size_t cost = a[i - 1] == b[j - 1] ? 0 : 1;
      d[i][j] = std::min({d[i - 1][j] + 1, d[i][j - 1] + 1, d[i - 1][j - 1] + cost});
      if (i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1])
        d[i][j] = std::min(d[i][j], d[i - 2][j - 2] + 1);
    }
  }
  return d[n][m];
}

std::string didYouMean(const std::string& key, const std::vector<std::string>& candidates) {
  const size_t limit = std::max<size_t>(2, key.size() / 3);
  const std::string* best = nullptr;
  size_t best_d = limit + 1;
  for (const auto& c : candidates) {
    // The distance is at least the difference in length (and a long key must not cost its square).
    if (key.size() > c.size() + limit || c.size() > key.size() + limit) continue;
    const size_t d = editDistance(key, c);
    if (d < best_d) {
      best_d = d;
      best = &c;
    }
  }
  return best ? " (did you mean '" + *best + "'?)" : "";
}

std::vector<std::string> yamlKeys(const YAML::Node& map) {
  std::vector<std::string> keys;
  if (!map || !map.IsMap()) return keys;
  for (const auto& kv : map) keys.push_back(kv.first.Scalar());
  return keys;
}

namespace {

// yaml-cpp keeps every pair of a map whose key is given twice, and lookups find the first: refused
// instead, naming both lines. Iterative (a fuzzed file may nest deeply).
void refuseDuplicateKeys(const YAML::Node& root, const std::filesystem::path& path) {
  std::vector<YAML::Node> pending{root};
  while (!pending.empty()) {
    const YAML::Node n = pending.back();
    pending.pop_back();
    if (n.IsMap()) {
      std::map<std::string, int> first_line;
      for (const auto& kv : n) {
        if (kv.first.IsScalar()) {
          const int line = kv.first.Mark().line + 1;
          const auto [it, fresh] = first_line.emplace(kv.first.Scalar(), line);
          if (!fresh)
            fail("{}: line {}: key '{}' given twice (first at line {}); give each option once", path.string(), line,
                 cutForMessage(kv.first.Scalar()), it->second);
        }
        pending.push_back(kv.second);
      }
    } else if (n.IsSequence()) {
      for (const auto& e : n) pending.push_back(e);
    }
  }
}

}  // namespace

YAML::Node loadYamlFile(const std::filesystem::path& path) {
  const std::string text = readInputFile(path, "YAML file", kMaxYamlFileBytes);
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (const YAML::Exception& e) {
    fail("{}: invalid YAML at line {}, column {}: {}", path.string(), e.mark.line + 1, e.mark.column + 1, e.msg);
  }
  refuseDuplicateKeys(root, path);
  return root;
}

std::string formatDouble(double x) {
  if (std::isnan(x)) return "nan";
  if (std::isinf(x)) return x > 0 ? "inf" : "-inf";
  std::string s = fmt::format("{}", x);
  return s;
}

namespace options_detail {

std::string describeNode(const YAML::Node& node) {
  if (!node || node.IsNull()) return "nothing (null)";
  if (node.IsScalar()) return "'" + cutForMessage(node.Scalar()) + "'";
  if (node.IsSequence()) return "a list";
  if (node.IsMap()) return "a section (map)";
  return "an unknown node";
}

namespace {

bool scalarText(const YAML::Node& node, std::string& text) {
  if (!node || !node.IsScalar()) return false;
  text = node.Scalar();
  return true;
}

template <typename I>
bool parseInteger(const YAML::Node& node, I& out) {
  std::string s;
  if (!scalarText(node, s) || s.empty()) return false;
  errno = 0;
  char* end = nullptr;
  const long long v = std::strtoll(s.c_str(), &end, 10);
  if (errno == ERANGE || end != s.c_str() + s.size()) return false;
  if (v < static_cast<long long>(std::numeric_limits<I>::min()) ||
      v > static_cast<long long>(std::numeric_limits<I>::max()))
    return false;
  out = static_cast<I>(v);
  return true;
}

bool parseFloating(const YAML::Node& node, double& out) {
  std::string s;
  if (!scalarText(node, s) || s.empty()) return false;
  // YAML 1.2 spellings of the special values.
  if (s == ".nan" || s == ".NaN" || s == ".NAN") {
    out = std::numeric_limits<double>::quiet_NaN();
    return true;
  }
  if (s == ".inf" || s == ".Inf" || s == ".INF" || s == "+.inf" || s == "+.Inf" || s == "+.INF") {
    out = std::numeric_limits<double>::infinity();
    return true;
  }
  if (s == "-.inf" || s == "-.Inf" || s == "-.INF") {
    out = -std::numeric_limits<double>::infinity();
    return true;
  }
  errno = 0;
  char* end = nullptr;
  const double v = std::strtod(s.c_str(), &end);
  if (end != s.c_str() + s.size()) return false;
  // strtod accepts "nan"/"inf" spellings too; those are fine (validation rejects non-finite values).
  out = v;
  return true;
}

}  // namespace

bool parseScalar(const YAML::Node& node, bool& out) {
  std::string s;
  if (!scalarText(node, s)) return false;
  if (s == "true" || s == "True" || s == "TRUE" || s == "yes" || s == "Yes" || s == "on" || s == "On") {
    out = true;
    return true;
  }
  if (s == "false" || s == "False" || s == "FALSE" || s == "no" || s == "No" || s == "off" || s == "Off") {
    out = false;
    return true;
  }
  return false;
}

bool parseScalar(const YAML::Node& node, int& out) { return parseInteger(node, out); }
bool parseScalar(const YAML::Node& node, int64_t& out) { return parseInteger(node, out); }

bool parseScalar(const YAML::Node& node, float& out) {
  double d = 0;
  if (!parseFloating(node, d)) return false;
  out = static_cast<float>(d);
  return true;
}

bool parseScalar(const YAML::Node& node, double& out) { return parseFloating(node, out); }

bool parseScalar(const YAML::Node& node, std::string& out) {
  std::string s;
  if (!scalarText(node, s)) return false;
  out = s;
  return true;
}

void throwJoined(const std::vector<std::string>& errors) {
  std::string msg;
  for (const auto& e : errors) msg += (msg.empty() ? "" : "\n") + e;
  throw Error(msg);
}

}  // namespace options_detail
}  // namespace nerfslam
