#pragma once
// Options from the ROS parameter server (docs/ros.md, "Parameters"). A node's parameters are option
// structs with visit() (nerfslam/core/options.h), read from its private namespace in one pass:
//   1. ~config: a YAML file of the library's options (SystemOptions), read with loadOptionsFile: the
//      file `nerfslam run --config` takes;
//   2. every option by its path: option a.b.c from ~a/b/c (e.g. ~tracking/features/max_features);
//   3. the aliases (OptionAlias): one-word parameters for a library option (~max_features).
// ROS parameters override the file. Then every option is checked with the constraints its visit()
// declares (the library's validator); an error names where the value came from, the parameter or the
// file, as `nerfslam run --config` names the file:
//   ~nerf_threads: field 'nerf.train.threads': must be in [1, 256] (got 0)
// A value of the wrong type, an unknown key inside an option section (with a did-you-mean) and an
// option given twice (by its path and by an alias) are errors; an unknown top-level parameter is a
// warning (other code reads the private namespace too, e.g. image_transport's ~image_transport).
// A name that is both an alias and an option of the struct is the alias when the parameter is a
// single value and the option section when it is a namespace (~nerf: true, or ~nerf/train/threads: 2).
#include <cstdint>
#include <functional>
#include <map>
#include <string>
#include <vector>

#include <xmlrpcpp/XmlRpcValue.h>

#include "nerfslam/core/error.h"
#include "nerfslam/core/options_yaml.h"

namespace nerfslam::rosnode {

// A parameter of the private namespace (without the "~") that sets one option, by its path.
struct OptionAlias {
  std::string param;
  std::string path;
};

// A string option that must be given (frame names, folders).
inline Check<std::string> notEmpty() {
  return [](const std::string& s) -> std::string { return s.empty() ? "must not be empty" : ""; };
}

struct ParamReport {
  std::vector<std::string> errors;    // each names the parameter or file; the node must not start
  std::vector<std::string> warnings;  // unknown top-level parameters
  // Where each option given a value got it: "~param", or the config file (for the options the file
  // changed). Options at their defaults are not listed.
  std::map<std::string, std::string> origins;
  bool ok() const { return errors.empty(); }
};

namespace params_detail {

// Strict conversions from a parameter value (an int is accepted for a float or double); false when
// `v` is not of the type.
bool fromXml(const XmlRpc::XmlRpcValue& v, bool& out);
bool fromXml(const XmlRpc::XmlRpcValue& v, int& out);
bool fromXml(const XmlRpc::XmlRpcValue& v, int64_t& out);
bool fromXml(const XmlRpc::XmlRpcValue& v, float& out);
bool fromXml(const XmlRpc::XmlRpcValue& v, double& out);
bool fromXml(const XmlRpc::XmlRpcValue& v, std::string& out);
bool fromXml(const XmlRpc::XmlRpcValue& v, std::vector<double>& out);
bool fromXml(const XmlRpc::XmlRpcValue& v, std::vector<int>& out);
// What the user gave, for messages: "int 3", "string 'abc'", "a namespace (ns/...)".
std::string describeXml(const XmlRpc::XmlRpcValue& v);
// The member `key` of a struct value, or null (also when `v` is not a struct).
const XmlRpc::XmlRpcValue* member(const XmlRpc::XmlRpcValue* v, const std::string& key);
bool isStruct(const XmlRpc::XmlRpcValue* v);
std::vector<std::string> memberNames(const XmlRpc::XmlRpcValue* v);

inline std::string paramName(const std::string& path) {  // "nerf.train.threads" -> "~nerf/train/threads"
  std::string p = "~" + path;
  for (char& c : p)
    if (c == '.') c = '/';
  return p;
}

// Option path -> formatted value of every leaf (which options a config file changed).
struct Snapshot {
  std::string prefix;
  std::map<std::string, std::string>* out;
  template <typename T, typename... C>
  void operator()(const char* name, const T& field, const char* /*doc*/, const C&...) {
    const std::string path = options_detail::joinPath(prefix, name);
    if constexpr (options_detail::kIsLeaf<T>) {
      (*out)[path] = options_detail::formatValue(field);
    } else {
      Snapshot sub{path, out};
      const_cast<T&>(field).visit(sub);
    }
  }
};

template <class T>
std::map<std::string, std::string> snapshot(const T& options) {
  std::map<std::string, std::string> out;
  Snapshot s{"", &out};
  const_cast<T&>(options).visit(s);
  return out;
}

// Reads one namespace of the parameter tree into an options struct (steps 2 and 3 above).
struct Reader {
  const XmlRpc::XmlRpcValue* ns;  // the struct of this section's parameters (null: none given)
  std::string prefix;             // option path of this section ("" at the root)
  const std::vector<OptionAlias>* aliases;
  const XmlRpc::XmlRpcValue* root;
  ParamReport* report;
  std::vector<std::string>* used_aliases;
  std::vector<std::string> names;  // the section's option names, for the unknown-key check

  bool isAlias(const std::string& param) const {
    for (const auto& a : *aliases)
      if (a.param == param) return true;
    return false;
  }

  template <typename T, typename C>
  void operator()(const char* name, T& field, const char* doc, const C&) {
    (*this)(name, field, doc);
  }

  template <typename T>
  void operator()(const char* name, T& field, const char* /*doc*/) {
    names.emplace_back(name);
    const std::string path = options_detail::joinPath(prefix, name);
    const XmlRpc::XmlRpcValue* v = member(ns, name);
    // At the root, a name that is also an alias: its single value is the alias (read below).
    const bool shadowed = prefix.empty() && isAlias(name) && !(!options_detail::kIsLeaf<T> && isStruct(v));
    if constexpr (options_detail::kIsLeaf<T>) {
      std::string from;
      if (v && !shadowed) {
        set(*v, paramName(path), path, field);
        from = paramName(path);
      }
      for (const auto& a : *aliases) {
        if (a.path != path) continue;
        used_aliases->push_back(a.param);
        const XmlRpc::XmlRpcValue* av = member(root, a.param);
        if (!av || isStruct(av)) continue;
        if (!from.empty()) {
          report->errors.push_back(fieldError(from + " and ~" + a.param, path, "set twice: give one of them").what());
          continue;
        }
        from = "~" + a.param;
        set(*av, from, path, field);
      }
    } else {
      if (v && !shadowed && !isStruct(v)) {
        report->errors.push_back(
            fieldError(paramName(path), path, "expected a namespace of options, got " + describeXml(*v)).what());
        return;
      }
      Reader sub{shadowed ? nullptr : v, path, aliases, root, report, used_aliases, {}};
      field.visit(sub);
      sub.unknownKeys();
    }
  }

  template <typename T>
  void set(const XmlRpc::XmlRpcValue& v, const std::string& from, const std::string& path, T& field) {
    if (fromXml(v, field))
      report->origins[path] = from;
    else
      report->errors.push_back(
          fieldError(from, path, std::string("expected ") + options_detail::typeName<T>() + ", got " + describeXml(v))
              .what());
  }

  // Inside a section every key must be an option (at the root the caller warns instead).
  void unknownKeys() const {
    for (const auto& key : memberNames(ns)) {
      bool known = false;
      for (const auto& n : names) known = known || n == key;
      if (!known)
        report->errors.push_back(fieldError(paramName(options_detail::joinPath(prefix, key.c_str())),
                                            options_detail::joinPath(prefix, key.c_str()),
                                            "unknown option" + didYouMean(key, names))
                                     .what());
    }
  }
};

// The library's validator, leaf by leaf, each error naming where the value came from.
struct Validator {
  std::string prefix;
  const std::map<std::string, std::string>* origins;
  std::vector<std::string>* errors;

  template <typename T, typename C>
  void operator()(const char* name, const T& field, const char* doc, const C& check) {
    const std::string path = options_detail::joinPath(prefix, name);
    const auto it = origins->find(path);
    options_detail::Validator v{it == origins->end() ? std::string("defaults") : it->second, prefix, errors};
    v(name, field, doc, check);
  }
  template <typename T>
  void operator()(const char* name, const T& field, const char* /*doc*/) {
    if constexpr (!options_detail::kIsLeaf<T>) {
      Validator sub{options_detail::joinPath(prefix, name), origins, errors};
      const_cast<T&>(field).visit(sub);
    }
  }
};

// Step 1: calls load(file) for ~config; returns the file ("" when ~config is not given). An error
// (not a string, the loader's Error naming the file and key) goes to the report.
std::string loadConfig(const XmlRpc::XmlRpcValue& tree, const std::function<void(const std::string&)>& load,
                       ParamReport* report);
// Unknown top-level parameters (warnings) and aliases that name no option (errors: the alias table
// is out of date).
void checkTopLevel(const XmlRpc::XmlRpcValue& tree, const std::vector<std::string>& names,
                   const std::vector<OptionAlias>& aliases, const std::vector<std::string>& used_aliases,
                   const std::vector<std::string>& also_known, ParamReport* report);

}  // namespace params_detail

// Reads `params` from `tree`, the node's private namespace as one struct (privateParams()):
// ~config into `*library` (the part of `params` a config file holds, its SystemOptions, whose visit()
// `params` calls at its own root so that the paths are the same; null: no ~config), then
// every option by its path and the aliases, then validates. `also_known`: top-level parameters
// read elsewhere (no warning). Nothing is thrown: see the report.
template <class P, class L>
ParamReport readParams(const XmlRpc::XmlRpcValue& tree, P& params, L* library, const std::vector<OptionAlias>& aliases,
                       const std::vector<std::string>& also_known = {}) {
  ParamReport report;
  if (library) {
    const auto before = params_detail::snapshot(*library);
    const std::string file = params_detail::loadConfig(
        tree, [&](const std::string& f) { loadOptionsFile(f, *library); }, &report);
    for (const auto& [path, value] : params_detail::snapshot(*library))
      if (before.at(path) != value) report.origins[path] = file;
  }
  std::vector<std::string> used_aliases;
  const XmlRpc::XmlRpcValue* root = params_detail::isStruct(&tree) ? &tree : nullptr;
  params_detail::Reader reader{root, "", &aliases, root, &report, &used_aliases, {}};
  params.visit(reader);
  params_detail::checkTopLevel(tree, reader.names, aliases, used_aliases, also_known, &report);
  params_detail::Validator validator{"", &report.origins, &report.errors};
  params.visit(validator);
  return report;
}

// The node's private namespace as one struct (empty when it holds no parameter).
XmlRpc::XmlRpcValue privateParams(const std::string& private_namespace);

}  // namespace nerfslam::rosnode
