#pragma once
// YAML loading, validation, printing and documentation of option structs (see options.h for the
// `visit` contract). Everything here walks `T::visit`, so a field is named, typed, documented and
// constrained in exactly one place.
//
//   TrackerOptions o;                                   // defaults
//   loadOptionsFile("config/system/tum.yaml", o);      // overrides from YAML (sections = nested structs)
//   validateOptions(o, "config/system/tum.yaml");      // all constraint violations in one Error
//   spdlog::info("options:\n{}", printOptions(o));     // "fast_threshold = 20  # FAST corner ..."
//   writeStringAtomic("run.yaml", optionsYaml(o));      // "fast_threshold: 20  # FAST corner ..."
//   std::string md = documentOptions<TrackerOptions>(); // Markdown table for docs/options.md
//
// Loading rules: keys missing from the YAML keep their defaults; an unknown key is an error naming
// the source and the key with a "did you mean" hint; a value of the wrong type is an error naming the
// key and the expected type; a nested options struct is a YAML map (an empty or null section keeps
// the defaults). All loading errors of one document are reported together, one per line.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <limits>
#include <sstream>
#include <string>
#include <string_view>
#include <type_traits>
#include <utility>
#include <vector>

#include <fmt/format.h>
#include <yaml-cpp/yaml.h>

#include "nerfslam/core/error.h"
#include "nerfslam/core/options.h"

namespace nerfslam {

// Optimal-string-alignment edit distance (insertions, deletions, substitutions and transpositions
// of adjacent characters each cost 1). Case-sensitive.
size_t editDistance(std::string_view a, std::string_view b);

// " (did you mean 'x'?)" for the closest candidate when it is within max(2, |key|/3) edits (ties go
// to the first candidate), else "".
std::string didYouMean(const std::string& key, const std::vector<std::string>& candidates);

// The keys of a YAML map in document order (empty for anything that is not a map).
std::vector<std::string> yamlKeys(const YAML::Node& map);

// The largest YAML file loadYamlFile reads: our option and camera files are a few KB, and yaml-cpp
// needs about 250 bytes of memory per byte of a long list (a 10 MB list took 2.45 GB).
constexpr uint64_t kMaxYamlFileBytes = 1000000;

// Parses a YAML file, throwing an Error naming the file (missing, a directory, unreadable, larger
// than kMaxYamlFileBytes, syntax error with line and column, a key given twice).
YAML::Node loadYamlFile(const std::filesystem::path& path);

// Formats a double so that it parses back to the same value (shortest round-trip form).
std::string formatDouble(double x);

namespace options_detail {

template <typename T>
struct IsVector : std::false_type {};
template <typename T>
struct IsVector<std::vector<T>> : std::true_type {};

template <typename T>
constexpr bool kIsLeaf = std::is_same_v<T, bool> || std::is_same_v<T, int> || std::is_same_v<T, int64_t> ||
                         std::is_same_v<T, float> || std::is_same_v<T, double> || std::is_same_v<T, std::string> ||
                         std::is_same_v<T, std::vector<double>> || std::is_same_v<T, std::vector<int>>;

template <typename T>
const char* typeName() {
  if constexpr (std::is_same_v<T, bool>) return "bool";
  if constexpr (std::is_same_v<T, int>) return "int";
  if constexpr (std::is_same_v<T, int64_t>) return "int64";
  if constexpr (std::is_same_v<T, float>) return "float";
  if constexpr (std::is_same_v<T, double>) return "double";
  if constexpr (std::is_same_v<T, std::string>) return "string";
  if constexpr (std::is_same_v<T, std::vector<double>>) return "list of double";
  if constexpr (std::is_same_v<T, std::vector<int>>) return "list of int";
  return "section";
}

// What the user wrote, for error messages.
std::string describeNode(const YAML::Node& node);

// Strict scalar conversions: false when `node` is not a scalar of the type.
bool parseScalar(const YAML::Node& node, bool& out);
bool parseScalar(const YAML::Node& node, int& out);
bool parseScalar(const YAML::Node& node, int64_t& out);
bool parseScalar(const YAML::Node& node, float& out);
bool parseScalar(const YAML::Node& node, double& out);
bool parseScalar(const YAML::Node& node, std::string& out);

template <typename T>
bool parseValue(const YAML::Node& node, T& out) {
  if constexpr (IsVector<T>::value) {
    if (!node.IsSequence()) return false;
    T tmp;
    for (const auto& item : node) {
      typename T::value_type x{};
      if (!parseScalar(item, x)) return false;
      tmp.push_back(x);
    }
    out = std::move(tmp);
    return true;
  } else {
    return parseScalar(node, out);
  }
}

template <typename T>
std::string formatValue(const T& x) {
  if constexpr (std::is_same_v<T, bool>) {
    return x ? "true" : "false";
  } else if constexpr (std::is_same_v<T, float> || std::is_same_v<T, double>) {
    return formatDouble(static_cast<double>(x));
  } else if constexpr (std::is_same_v<T, std::string>) {
    std::string q = "\"";
    for (char c : x) {
      if (c == '"' || c == '\\') q += '\\';
      q += c;
    }
    return q + "\"";
  } else if constexpr (IsVector<T>::value) {
    std::string s = "[";
    for (size_t i = 0; i < x.size(); ++i) s += (i ? ", " : "") + formatValue(x[i]);
    return s + "]";
  } else {
    return std::to_string(x);
  }
}

inline std::string joinPath(const std::string& prefix, const char* name) {
  return prefix.empty() ? std::string(name) : prefix + "." + name;
}

// Reads one YAML map into a struct, collecting errors.
struct Loader {
  const YAML::Node& node;
  const std::string& source;
  std::string prefix;
  std::vector<std::string>* errors;
  std::vector<std::string> names;

  template <typename T, typename C>
  void operator()(const char* name, T& field, const char* doc, const C&) {
    (*this)(name, field, doc);
  }

  template <typename T>
  void operator()(const char* name, T& field, const char* /*doc*/) {
    names.emplace_back(name);
    const std::string path = joinPath(prefix, name);
    const YAML::Node value = node[name];
    if (!value) return;
    if constexpr (kIsLeaf<T>) {
      if (!parseValue(value, field))
        errors->push_back(
            fieldError(source, path, std::string("expected ") + typeName<T>() + ", got " + describeNode(value)).what());
    } else {
      load(value, field, source, path, errors);
    }
  }

  template <typename T>
  static void load(const YAML::Node& node, T& options, const std::string& source, const std::string& prefix,
                   std::vector<std::string>* errors) {
    if (!node || node.IsNull()) return;
    if (!node.IsMap()) {
      errors->push_back(fieldError(source, prefix.empty() ? "<root>" : prefix,
                                   "expected a section (YAML map), got " + describeNode(node))
                            .what());
      return;
    }
    Loader loader{node, source, prefix, errors, {}};
    options.visit(loader);
    for (const auto& key : yamlKeys(node)) {
      bool known = false;
      for (const auto& n : loader.names) known = known || n == key;
      if (!known)
        errors->push_back(fieldError(source, joinPath(prefix, cutForMessage(key).c_str()),
                                     "unknown option" + didYouMean(key, loader.names))
                              .what());
    }
  }
};

struct Validator {
  const std::string& source;
  std::string prefix;
  std::vector<std::string>* errors;

  template <typename T, typename C>
  void operator()(const char* name, const T& field, const char* /*doc*/, const C& check) {
    static_assert(kIsLeaf<T>, "constraints apply to leaf options, not sections");
    const std::string why = check(field);
    if (!why.empty())
      errors->push_back(
          fieldError(source, joinPath(prefix, name), why + " (got " + cutForMessage(formatValue(field)) + ")").what());
  }

  template <typename T>
  void operator()(const char* name, const T& field, const char* /*doc*/) {
    if constexpr (!kIsLeaf<T>) {
      Validator sub{source, joinPath(prefix, name), errors};
      const_cast<T&>(field).visit(sub);
    }
  }
};

struct Printer {
  std::string prefix;
  std::string* out;

  template <typename T, typename C>
  void operator()(const char* name, const T& field, const char* doc, const C&) {
    (*this)(name, field, doc);
  }

  template <typename T>
  void operator()(const char* name, const T& field, const char* doc) {
    if constexpr (kIsLeaf<T>) {
      *out += joinPath(prefix, name) + " = " + formatValue(field) + "  # " + doc + "\n";
    } else {
      Printer sub{joinPath(prefix, name), out};
      const_cast<T&>(field).visit(sub);
    }
  }
};

// YAML that loadOptions reads back: "name: value  # doc" per leaf, "name:  # doc" and an indent of
// two more spaces per section.
struct YamlWriter {
  std::string* out;
  int indent = 0;

  static std::string comment(const char* doc) {
    std::string s(doc);
    std::replace(s.begin(), s.end(), '\n', ' ');
    return s;
  }
  template <typename T, typename C>
  void operator()(const char* name, const T& field, const char* doc, const C&) {
    (*this)(name, field, doc);
  }
  template <typename T>
  void operator()(const char* name, const T& field, const char* doc) {
    const std::string pad(static_cast<size_t>(indent), ' ');
    if constexpr (kIsLeaf<T>) {
      *out += pad + name + ": " + formatValue(field) + "  # " + comment(doc) + "\n";
    } else {
      *out += pad + name + ":  # " + comment(doc) + "\n";
      YamlWriter sub{out, indent + 2};
      const_cast<T&>(field).visit(sub);
    }
  }
};

// The reason a check gives for the most extreme values of the type: this is how a constraint
// describes itself ("must be in [1, 255]" -> "in [1, 255]"). Empty when every probe passes.
template <typename T, typename C>
std::string describeCheck(const C& check) {
  std::vector<T> probes;
  if constexpr (std::is_same_v<T, bool>) {
    probes = {false, true};
  } else if constexpr (std::is_arithmetic_v<T>) {
    probes = {std::numeric_limits<T>::lowest(), std::numeric_limits<T>::max(), T(0), T(-1)};
    if constexpr (std::is_floating_point_v<T>) probes.push_back(std::numeric_limits<T>::quiet_NaN());
  } else if constexpr (std::is_same_v<T, std::string>) {
    probes = {std::string("\x01"), std::string()};
  } else {
    probes = {T{}};
  }
  for (const auto& p : probes) {
    std::string why = check(p);
    if (!why.empty()) {
      if (why.rfind("must be ", 0) == 0) why = why.substr(8);
      return why;
    }
  }
  return "";
}

inline std::string escapeMarkdown(std::string s) {
  std::string out;
  for (char c : s) {
    if (c == '|')
      out += "\\|";
    else if (c == '\n')
      out += ' ';
    else
      out += c;
  }
  return out;
}

struct Documenter {
  std::string prefix;
  std::string* out;

  template <typename T, typename C>
  void operator()(const char* name, const T& field, const char* doc, const C& check) {
    row<T>(name, field, doc, describeCheck<T>(check));
  }

  template <typename T>
  void operator()(const char* name, const T& field, const char* doc) {
    if constexpr (kIsLeaf<T>) {
      row<T>(name, field, doc, "");
    } else {
      *out += "| `" + joinPath(prefix, name) + "` | section | | | " + escapeMarkdown(doc) + " |\n";
      Documenter sub{joinPath(prefix, name), out};
      const_cast<T&>(field).visit(sub);
    }
  }

  template <typename T>
  void row(const char* name, const T& field, const char* doc, const std::string& constraint) {
    *out += "| `" + joinPath(prefix, name) + "` | " + typeName<T>() + " | `" + escapeMarkdown(formatValue(field)) +
            "` | " + escapeMarkdown(constraint) + " | " + escapeMarkdown(doc) + " |\n";
  }
};

[[noreturn]] void throwJoined(const std::vector<std::string>& errors);

}  // namespace options_detail

// Overrides fields of `options` from a YAML map. Throws one Error listing every problem.
template <typename T>
void loadOptions(const YAML::Node& node, T& options, const std::string& source) {
  std::vector<std::string> errors;
  options_detail::Loader::load(node, options, source, "", &errors);
  if (!errors.empty()) options_detail::throwJoined(errors);
}

template <typename T>
void loadOptionsFile(const std::filesystem::path& path, T& options) {
  loadOptions(loadYamlFile(path), options, path.string());
}

// Runs every check; throws one Error naming every violated field path (e.g. tracker.fast_threshold).
template <typename T>
void validateOptions(const T& options, const std::string& source) {
  std::vector<std::string> errors;
  options_detail::Validator v{source, "", &errors};
  const_cast<T&>(options).visit(v);
  if (!errors.empty()) options_detail::throwJoined(errors);
}

// One line per leaf option: "path = value  # doc".
template <typename T>
std::string printOptions(const T& options) {
  std::string out;
  options_detail::Printer p{"", &out};
  const_cast<T&>(options).visit(p);
  return out;
}

// The options as a YAML document that loadOptions reads back to the same values (the one way to
// write options as YAML): a first line "# " + title when `title` is not empty, then one
// "name: value  # doc" line per leaf option, a "name:  # doc" line per section and its options
// indented by two more spaces. Newlines in docs become spaces.
template <typename T>
std::string optionsYaml(const T& options, const std::string& title = "") {
  std::string out = title.empty() ? std::string() : "# " + title + "\n";
  options_detail::YamlWriter w{&out, 0};
  const_cast<T&>(options).visit(w);
  return out;
}

// Markdown table (option path, type, default, constraint, description) of a default-constructed T.
template <typename T>
std::string documentOptions() {
  T defaults{};
  std::string out = "| Option | Type | Default | Constraint | Description |\n|---|---|---|---|---|\n";
  options_detail::Documenter d{"", &out};
  defaults.visit(d);
  return out;
}

}  // namespace nerfslam
