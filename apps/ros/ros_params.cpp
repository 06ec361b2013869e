#include "nerfslam_ros/ros_params.h"

#include <algorithm>
#include <limits>

#include <ros/param.h>

namespace nerfslam::rosnode {
namespace params_detail {

using XmlRpc::XmlRpcValue;

bool fromXml(const XmlRpcValue& v, bool& out) {
  if (v.getType() != XmlRpcValue::TypeBoolean) return false;
  out = static_cast<const bool&>(v);
  return true;
}

bool fromXml(const XmlRpcValue& v, int& out) {
  if (v.getType() != XmlRpcValue::TypeInt) return false;
  out = static_cast<const int&>(v);
  return true;
}

bool fromXml(const XmlRpcValue& v, int64_t& out) {
  int x = 0;
  if (!fromXml(v, x)) return false;  // XML-RPC integers are 32-bit
  out = x;
  return true;
}

bool fromXml(const XmlRpcValue& v, double& out) {
  if (v.getType() == XmlRpcValue::TypeDouble) {
    out = static_cast<const double&>(v);
    return true;
  }
  int x = 0;
  if (!fromXml(v, x)) return false;
  out = x;
  return true;
}

bool fromXml(const XmlRpcValue& v, float& out) {
  double x = 0;
  if (!fromXml(v, x)) return false;
  out = static_cast<float>(x);
  return true;
}

bool fromXml(const XmlRpcValue& v, std::string& out) {
  if (v.getType() != XmlRpcValue::TypeString) return false;
  out = static_cast<const std::string&>(v);
  return true;
}

namespace {
template <class T>
bool listFromXml(const XmlRpcValue& v, std::vector<T>& out) {
  if (v.getType() != XmlRpcValue::TypeArray) return false;
  std::vector<T> tmp;
  for (int i = 0; i < v.size(); ++i) {
    T x{};
    if (!fromXml(v[i], x)) return false;
    tmp.push_back(x);
  }
  out = std::move(tmp);
  return true;
}
}  // namespace

bool fromXml(const XmlRpcValue& v, std::vector<double>& out) { return listFromXml(v, out); }
bool fromXml(const XmlRpcValue& v, std::vector<int>& out) { return listFromXml(v, out); }

std::string describeXml(const XmlRpcValue& v) {
  switch (v.getType()) {
    case XmlRpcValue::TypeBoolean:
      return std::string("bool ") + (static_cast<const bool&>(v) ? "true" : "false");
    case XmlRpcValue::TypeInt:
      return "int " + std::to_string(static_cast<const int&>(v));
    case XmlRpcValue::TypeDouble:
      return "double " + formatDouble(static_cast<const double&>(v));
    case XmlRpcValue::TypeString:
      return "string '" + static_cast<const std::string&>(v) + "'";
    case XmlRpcValue::TypeArray:
      return "a list of " + std::to_string(v.size());
    case XmlRpcValue::TypeStruct: {
      std::string keys;
      for (const auto& k : memberNames(&v)) keys += (keys.empty() ? "" : ", ") + k;
      return "a namespace (" + keys + ")";
    }
    default:
      return "a value of another type";
  }
}

bool isStruct(const XmlRpcValue* v) { return v && v->getType() == XmlRpcValue::TypeStruct; }

const XmlRpcValue* member(const XmlRpcValue* v, const std::string& key) {
  if (!isStruct(v) || !v->hasMember(key)) return nullptr;
  return &(*v)[key];  // hasMember: the const operator[] inserts nothing
}

std::vector<std::string> memberNames(const XmlRpcValue* v) {
  std::vector<std::string> out;
  if (!isStruct(v)) return out;
  for (auto it = v->begin(); it != v->end(); ++it) out.push_back(it->first);
  return out;
}

std::string loadConfig(const XmlRpcValue& tree, const std::function<void(const std::string&)>& load,
                       ParamReport* report) {
  const XmlRpcValue* v = member(&tree, "config");
  if (!v) return "";
  std::string file;
  if (!fromXml(*v, file)) {
    report->errors.push_back("~config: expected the path of an options YAML file, got " + describeXml(*v));
    return "";
  }
  if (file.empty()) return "";  // launch files pass "" for "no file"
  try {
    load(file);
  } catch (const std::exception& e) {
    report->errors.push_back(std::string("~config: ") + e.what());
  }
  return file;
}

void checkTopLevel(const XmlRpcValue& tree, const std::vector<std::string>& names,
                   const std::vector<OptionAlias>& aliases, const std::vector<std::string>& used_aliases,
                   const std::vector<std::string>& also_known, ParamReport* report) {
  for (const auto& a : aliases)
    if (std::find(used_aliases.begin(), used_aliases.end(), a.param) == used_aliases.end())
      report->errors.push_back("~" + a.param + " is an alias of option '" + a.path +
                               "', which does not exist (the alias table, apps/ros/node_params.cpp, is out of date)");
  std::vector<std::string> known = names;
  for (const auto& a : aliases) known.push_back(a.param);
  known.insert(known.end(), also_known.begin(), also_known.end());
  known.push_back("config");
  for (const auto& key : memberNames(&tree))
    if (std::find(known.begin(), known.end(), key) == known.end())
      report->warnings.push_back("unknown parameter ~" + key + " is ignored" + didYouMean(key, known) +
                                 " (docs/ros.md lists the parameters)");
}

}  // namespace params_detail

XmlRpc::XmlRpcValue privateParams(const std::string& private_namespace) {
  XmlRpc::XmlRpcValue v;
  if (!ros::param::get(private_namespace, v) || v.getType() != XmlRpc::XmlRpcValue::TypeStruct) {
    XmlRpc::XmlRpcValue empty;
    empty.begin();  // makes it an empty struct
    return empty;
  }
  return v;
}

}  // namespace nerfslam::rosnode
