#include "nerfslam_ros/node_params.h"

#include <sstream>

namespace nerfslam::rosnode {

namespace {

// The one table of aliases: the one-word parameters launch files, tests and users had before
// ~config, each with the library option it sets. When an option moves (e.g. nerf.train.threads into the
// NeRF's training options), change its path here: a node refuses to start with an alias naming no
// option, and the test ros.NodeParams.EveryAliasNamesAnOption says which.
struct AliasRow {
  const char* param;
  const char* path;
  bool slam_nodes;         // nerfslam_node, tracking_node
  bool nerf_mapping_node;  // where ~keyframe_queue is the NeRF's (SystemOptions::keyframe_queue is the
                           // sparse mapping's, which that node does not run)
};
constexpr AliasRow kAliases[] = {
    {"max_features", "tracking.features.max_features", true, false},
    {"nerf", "nerf.enabled", true, false},
    {"nerf_threads", "nerf.train.threads", true, true},
    {"nerf_nice", "nerf.nice_increment", true, true},
    {"keyframe_queue", "nerf.keyframe_queue", false, true},
};

// Read by other code from the private namespace (image_transport's CameraSubscriber).
const std::vector<std::string> kAlsoKnown = {"image_transport"};

std::string framesError(const NerfTopicsOptions& t) {
  if (!t.map_frame.empty() && t.map_frame == t.camera_frame)
    return "~map_frame and ~camera_frame must differ (both '" + t.map_frame + "')";
  return "";
}

void warnRenderNice(const NerfTopicsOptions& t, const NerfMappingOptions& nerf, ParamReport* r) {
  if (nerf.enabled && t.nerf_render_nice > nerf.nice_increment)
    r->warnings.push_back("~nerf_render_nice (" + std::to_string(t.nerf_render_nice) + ") > nerf.nice_increment (" +
                          std::to_string(nerf.nice_increment) +
                          "): NeRF training will starve the NeRF topics' renders");
}

std::string originOf(const ParamReport& r, const std::string& path) {
  const auto it = r.origins.find(path);
  return it == r.origins.end() ? "defaults" : it->second;
}

// Prints the effective options and what set them, and the warnings; returns the errors, one a line.
template <class P>
std::string finish(const char* node, const P& p, const ParamReport& r) {
  ROS_INFO("%s options (docs/ros.md; option a.b.c is the parameter ~a/b/c):", node);
  std::istringstream lines(printOptions(p));
  for (std::string line; std::getline(lines, line);) ROS_INFO("  %s", line.c_str());
  if (!r.origins.empty()) {
    ROS_INFO("%s: set by ~config or by parameters:", node);
    for (const auto& [path, from] : r.origins) ROS_INFO("  %s (from %s)", path.c_str(), from.c_str());
  }
  ROS_INFO("~map_dir is %s", resolveMapDir(p.topics.map_dir).c_str());
  for (const auto& w : r.warnings) ROS_WARN("%s", w.c_str());
  std::string err;
  for (const auto& e : r.errors) err += (err.empty() ? "" : "\n") + e;
  return err;
}

}  // namespace

const std::vector<OptionAlias>& optionAliases(NodeKind node) {
  static const std::vector<OptionAlias> slam = [] {
    std::vector<OptionAlias> v;
    for (const auto& a : kAliases)
      if (a.slam_nodes) v.push_back({a.param, a.path});
    return v;
  }();
  static const std::vector<OptionAlias> nerf_mapping = [] {
    std::vector<OptionAlias> v;
    for (const auto& a : kAliases)
      if (a.nerf_mapping_node) v.push_back({a.param, a.path});
    return v;
  }();
  return node == NodeKind::kSlam ? slam : nerf_mapping;
}

MapMode mapModeOf(const SlamNodeOptions& o) {
  if (o.map.empty()) return MapMode::kSlam;
  return o.map_mode == "extend" ? MapMode::kExtend : MapMode::kLocalize;
}

ParamReport readSlamNodeParams(const XmlRpc::XmlRpcValue& tree, SlamNodeParams& p) {
  ParamReport r = readParams(tree, p, &p.slam, optionAliases(NodeKind::kSlam), kAlsoKnown);
  if (p.node.map_mode != "localize" && p.node.map_mode != "extend")
    r.errors.push_back("~map_mode '" + p.node.map_mode + "' is neither localize nor extend (~map '" + p.node.map +
                       "')");
  if (p.mode == SlamNodeMode::kTracking) {
    // The NeRF runs in nerf_mapping_node.
    if (p.slam.nerf.enabled && r.origins.count("nerf.enabled"))
      r.warnings.push_back("tracking_node trains no NeRF (nerf_mapping_node does): nerf.enabled = true from " +
                           originOf(r, "nerf.enabled") + " is ignored");
    p.slam.nerf.enabled = false;
  }
  if (std::string e = framesError(p.topics); !e.empty()) r.errors.push_back(e);
  if (std::string e = checkMapToOdomParams(p.odom, p.topics.map_frame, p.topics.camera_frame); !e.empty())
    r.errors.push_back(e);
  warnRenderNice(p.topics, p.slam.nerf, &r);
  return r;
}

ParamReport readNerfMappingNodeParams(const XmlRpc::XmlRpcValue& tree, NerfMappingNodeParams& p) {
  ParamReport r = readParams(tree, p, &p.slam, optionAliases(NodeKind::kNerfMapping), kAlsoKnown);
  if (!p.slam.nerf.enabled)
    r.warnings.push_back("nerf_mapping_node always trains the NeRF: nerf.enabled = false from " +
                         originOf(r, "nerf.enabled") + " is ignored");
  p.slam.nerf.enabled = true;
  if (std::string e = framesError(p.topics); !e.empty()) r.errors.push_back(e);
  warnRenderNice(p.topics, p.slam.nerf, &r);
  return r;
}

std::string loadSlamNodeParams(ros::NodeHandle& pnh, SlamNodeParams& p) {
  const ParamReport r = readSlamNodeParams(privateParams(pnh.getNamespace()), p);
  return finish(p.mode == SlamNodeMode::kTracking ? "tracking_node" : "nerfslam_node", p, r);
}

std::string loadNerfMappingNodeParams(ros::NodeHandle& pnh, NerfMappingNodeParams& p) {
  const ParamReport r = readNerfMappingNodeParams(privateParams(pnh.getNamespace()), p);
  return finish("nerf_mapping_node", p, r);
}

}  // namespace nerfslam::rosnode
