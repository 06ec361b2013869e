// The nodes' parameters (apps/ros/node_params.h, ros_params.h) from hand-made parameter trees (no ROS
// master): ~config read with the library's loader, ROS parameters by option path and by alias
// overriding it, the library's validator naming where a bad value came from, and docs/ros.md listing
// every parameter.
#include <gtest/gtest.h>

#include <fstream>
#include <sstream>

#include "nerfslam_ros/node_params.h"
#include "test_support.h"

namespace {

using nerfslam::rosnode::NerfMappingNodeParams;
using nerfslam::rosnode::ParamReport;
using nerfslam::rosnode::SlamNodeParams;
using XmlRpc::XmlRpcValue;

XmlRpcValue str(const std::string& s) { return XmlRpcValue(s); }

std::string joined(const std::vector<std::string>& lines) {
  std::string out;
  for (const auto& l : lines) out += l + "\n";
  return out;
}

bool contains(const std::vector<std::string>& lines, const std::string& part) {
  return joined(lines).find(part) != std::string::npos;
}

TEST(NodeParams, ConfigThenParametersByPathAndAlias) {
  nerfslam::test::TempDir dir;
  const auto config = dir / "system.yaml";
  nerfslam::test::writeText(config,
                            "tracking:\n  features:\n    max_features: 1500\n"
                            "nerf:\n  train:\n    threads: 3\n  nice_increment: 5\n"
                            "local_map_keyframes: 7\n");
  XmlRpcValue tree;
  tree["config"] = str(config.string());
  tree["tracking"]["features"]["max_features"] = 1700;  // by path, over the file
  tree["nerf_nice"] = 12;                               // alias of nerf.nice_increment, over the file
  tree["queue_size"] = 9;                               // a ROS-only option
  tree["map_points_period"] = 2;                        // an int for a double
  tree["nerf_cloud_source"] = str("density");
  SlamNodeParams p;
  const ParamReport r = nerfslam::rosnode::readSlamNodeParams(tree, p);
  EXPECT_TRUE(r.ok()) << joined(r.errors);
  EXPECT_TRUE(r.warnings.empty()) << joined(r.warnings);
  EXPECT_EQ(p.slam.tracking.features.max_features, 1700);
  EXPECT_EQ(p.slam.nerf.train.threads, 3);
  EXPECT_EQ(p.slam.nerf.nice_increment, 12);
  EXPECT_EQ(p.slam.local_map_keyframes, 7);
  EXPECT_EQ(p.node.queue_size, 9);
  EXPECT_EQ(p.node.map_points_period, 2.0);
  EXPECT_EQ(p.topics.nerf_cloud_source, "density");
  EXPECT_EQ(p.slam.keyframe_queue, nerfslam::SystemOptions{}.keyframe_queue);  // untouched
  EXPECT_EQ(r.origins.at("tracking.features.max_features"), "~tracking/features/max_features");
  EXPECT_EQ(r.origins.at("nerf.train.threads"), config.string());
  EXPECT_EQ(r.origins.at("nerf.nice_increment"), "~nerf_nice");
  EXPECT_EQ(r.origins.at("local_map_keyframes"), config.string());
  EXPECT_EQ(r.origins.at("queue_size"), "~queue_size");
  EXPECT_EQ(r.origins.count("mapping.local_ba_keyframes"), 0u);
}

TEST(NodeParams, DefaultsAreTheLibrarysAndValid) {
  SlamNodeParams p;
  const ParamReport r = nerfslam::rosnode::readSlamNodeParams(XmlRpcValue(), p);
  EXPECT_TRUE(r.ok()) << joined(r.errors);
  EXPECT_TRUE(r.origins.empty());
  EXPECT_EQ(nerfslam::printOptions(p.slam), nerfslam::printOptions(nerfslam::SystemOptions{}));
  EXPECT_EQ(p.slam.tracking.features.max_features, 2000);
  EXPECT_TRUE(p.slam.nerf.enabled);
}

TEST(NodeParams, MapAndMapModeGiveTheLibrarysMapMode) {
  auto read = [](const std::string& map, const std::string& mode, SlamNodeParams* p) {
    XmlRpcValue tree;
    if (!map.empty()) tree["map"] = str(map);
    if (!mode.empty()) tree["map_mode"] = str(mode);
    return nerfslam::rosnode::readSlamNodeParams(tree, *p);
  };
  SlamNodeParams none, localize, extend, unknown;
  EXPECT_TRUE(read("", "", &none).ok());
  EXPECT_EQ(nerfslam::rosnode::mapModeOf(none.node), nerfslam::MapMode::kSlam);
  EXPECT_FALSE(none.node.save_on_shutdown);
  EXPECT_TRUE(read("/maps/lab", "", &localize).ok());  // localize by default
  EXPECT_EQ(nerfslam::rosnode::mapModeOf(localize.node), nerfslam::MapMode::kLocalize);
  EXPECT_TRUE(read("/maps/lab", "extend", &extend).ok());
  EXPECT_EQ(nerfslam::rosnode::mapModeOf(extend.node), nerfslam::MapMode::kExtend);
  const ParamReport r = read("/maps/lab", "Localise", &unknown);
  EXPECT_TRUE(contains(r.errors, "~map_mode 'Localise' is neither localize nor extend (~map '/maps/lab')"))
      << joined(r.errors);
}

TEST(NodeParams, InvalidValuesAreRefusedNamingWhereTheyCameFrom) {
  {
    XmlRpcValue tree;
    tree["nerf_threads"] = 0;
    SlamNodeParams p;
    const ParamReport r = nerfslam::rosnode::readSlamNodeParams(tree, p);
    EXPECT_TRUE(contains(r.errors, "~nerf_threads: field 'nerf.train.threads': must be in [1, 256] (got 0)"))
        << joined(r.errors);
  }
  {
    XmlRpcValue tree;
    tree["tracking"]["features"]["max_features"] = 10;
    tree["queue_size"] = 0;
    SlamNodeParams p;
    const ParamReport r = nerfslam::rosnode::readSlamNodeParams(tree, p);
    EXPECT_TRUE(contains(r.errors,
                         "~tracking/features/max_features: field 'tracking.features.max_features': must be in "
                         "[50, 20000] (got 10)"))
        << joined(r.errors);
    EXPECT_TRUE(contains(r.errors, "~queue_size: field 'queue_size': must be > 0 (got 0)")) << joined(r.errors);
    EXPECT_EQ(r.errors.size(), 2u) << joined(r.errors);
  }
  {
    nerfslam::test::TempDir dir;
    const auto config = dir / "bad.yaml";
    nerfslam::test::writeText(config, "nerf:\n  train:\n    threads: 0\n");
    XmlRpcValue tree;
    tree["config"] = str(config.string());
    SlamNodeParams p;
    const ParamReport r = nerfslam::rosnode::readSlamNodeParams(tree, p);
    EXPECT_TRUE(contains(r.errors, config.string() + ": field 'nerf.train.threads': must be in [1, 256] (got 0)"))
        << joined(r.errors);
    // The same value from the file, corrected by a parameter: accepted.
    tree["nerf_threads"] = 2;
    SlamNodeParams q;
    EXPECT_TRUE(nerfslam::rosnode::readSlamNodeParams(tree, q).ok());
    EXPECT_EQ(q.slam.nerf.train.threads, 2);
  }
  {
    XmlRpcValue tree;
    tree["map_frame"] = str("same");
    tree["camera_frame"] = str("same");
    tree["nerf_cloud_source"] = str("mesh");
    SlamNodeParams p;
    const ParamReport r = nerfslam::rosnode::readSlamNodeParams(tree, p);
    EXPECT_TRUE(contains(r.errors, "~map_frame and ~camera_frame must differ")) << joined(r.errors);
    EXPECT_TRUE(contains(r.errors,
                         "~nerf_cloud_source: field 'nerf_cloud_source': must be one of: depth, density (got "
                         "\"mesh\")"))
        << joined(r.errors);
  }
}

TEST(NodeParams, WrongTypesUnknownKeysAndOptionsGivenTwice) {
  XmlRpcValue tree;
  tree["queue_size"] = str("two");
  tree["tracking"]["featurs"]["max_features"] = 1500;
  tree["nerf_threads"] = 2;
  tree["nerf"]["train"]["threads"] = 3;
  tree["max_featres"] = 1500;
  tree["image_transport"] = str("compressed");  // read by image_transport: no warning
  SlamNodeParams p;
  const ParamReport r = nerfslam::rosnode::readSlamNodeParams(tree, p);
  EXPECT_TRUE(contains(r.errors, "~queue_size: field 'queue_size': expected int, got string 'two'"))
      << joined(r.errors);
  EXPECT_TRUE(contains(r.errors,
                       "~tracking/featurs: field 'tracking.featurs': unknown option (did you mean "
                       "'features'?)"))
      << joined(r.errors);
  EXPECT_TRUE(contains(r.errors, "~nerf/train/threads and ~nerf_threads: field 'nerf.train.threads': set twice"))
      << joined(r.errors);
  EXPECT_EQ(r.errors.size(), 3u) << joined(r.errors);
  ASSERT_EQ(r.warnings.size(), 1u) << joined(r.warnings);
  EXPECT_TRUE(contains(r.warnings, "unknown parameter ~max_featres is ignored (did you mean 'max_features'?)"))
      << joined(r.warnings);
}

TEST(NodeParams, NerfIsTheSwitchAsAValueAndTheSectionAsANamespace) {
  {
    XmlRpcValue tree;
    tree["nerf"] = false;
    SlamNodeParams p;
    EXPECT_TRUE(nerfslam::rosnode::readSlamNodeParams(tree, p).ok());
    EXPECT_FALSE(p.slam.nerf.enabled);
  }
  {
    XmlRpcValue tree;
    tree["nerf"]["enabled"] = false;
    tree["nerf"]["train"]["threads"] = 2;
    SlamNodeParams p;
    const ParamReport r = nerfslam::rosnode::readSlamNodeParams(tree, p);
    EXPECT_TRUE(r.ok()) << joined(r.errors);
    EXPECT_FALSE(p.slam.nerf.enabled);
    EXPECT_EQ(p.slam.nerf.train.threads, 2);
    EXPECT_EQ(r.origins.at("nerf.enabled"), "~nerf/enabled");
  }
  {
    XmlRpcValue tree;
    tree["tracking"] = 3;  // not an alias: a section must be a namespace
    SlamNodeParams p;
    const ParamReport r = nerfslam::rosnode::readSlamNodeParams(tree, p);
    EXPECT_TRUE(contains(r.errors, "~tracking: field 'tracking': expected a namespace of options, got int 3"))
        << joined(r.errors);
  }
}

TEST(NodeParams, TrackingNodeTrainsNoNerfAndNerfMappingNodeAlways) {
  XmlRpcValue tree;
  tree["nerf"] = true;
  SlamNodeParams t;
  t.mode = nerfslam::rosnode::SlamNodeMode::kTracking;
  const ParamReport rt = nerfslam::rosnode::readSlamNodeParams(tree, t);
  EXPECT_TRUE(rt.ok()) << joined(rt.errors);
  EXPECT_FALSE(t.slam.nerf.enabled);
  EXPECT_TRUE(contains(rt.warnings, "tracking_node trains no NeRF")) << joined(rt.warnings);

  // nerf_mapping_node: ~keyframe_queue is the NeRF's queue (its alias), not the sparse mapping's.
  XmlRpcValue m;
  m["keyframe_queue"] = 50;
  m["nerf_threads"] = 4;
  m["nerf"]["enabled"] = false;
  NerfMappingNodeParams n;
  const ParamReport rn = nerfslam::rosnode::readNerfMappingNodeParams(m, n);
  EXPECT_TRUE(rn.ok()) << joined(rn.errors);
  EXPECT_EQ(n.slam.nerf.keyframe_queue, 50);
  EXPECT_EQ(n.slam.keyframe_queue, nerfslam::SystemOptions{}.keyframe_queue);
  EXPECT_EQ(n.slam.nerf.train.threads, 4);
  EXPECT_TRUE(n.slam.nerf.enabled);
  EXPECT_TRUE(contains(rn.warnings, "nerf_mapping_node always trains the NeRF")) << joined(rn.warnings);
}

TEST(NodeParams, ConfigErrorsNameTheFile) {
  XmlRpcValue missing;
  missing["config"] = str("/nonexistent/nerfslam_system.yaml");
  SlamNodeParams p;
  const ParamReport r = nerfslam::rosnode::readSlamNodeParams(missing, p);
  EXPECT_TRUE(contains(r.errors, "~config: ")) << joined(r.errors);
  EXPECT_TRUE(contains(r.errors, "/nonexistent/nerfslam_system.yaml")) << joined(r.errors);

  nerfslam::test::TempDir dir;
  nerfslam::test::writeText(dir / "typo.yaml", "tracking:\n  featurs: {}\n");
  XmlRpcValue typo;
  typo["config"] = str((dir / "typo.yaml").string());
  SlamNodeParams q;
  const ParamReport rt = nerfslam::rosnode::readSlamNodeParams(typo, q);
  EXPECT_TRUE(contains(rt.errors, "field 'tracking.featurs': unknown option (did you mean 'features'?)"))
      << joined(rt.errors);

  XmlRpcValue not_a_path;
  not_a_path["config"] = 3;
  SlamNodeParams s;
  EXPECT_TRUE(contains(nerfslam::rosnode::readSlamNodeParams(not_a_path, s).errors,
                       "~config: expected the path of an options YAML file, got int 3"));
}

TEST(NodeParams, EveryAliasNamesAnOption) {
  using nerfslam::rosnode::NodeKind;
  using nerfslam::rosnode::optionAliases;
  // The table as the launch files and docs/ros.md use it.
  std::map<std::string, std::string> slam, mapping;
  for (const auto& a : optionAliases(NodeKind::kSlam)) slam[a.param] = a.path;
  for (const auto& a : optionAliases(NodeKind::kNerfMapping)) mapping[a.param] = a.path;
  EXPECT_EQ(slam.size(), 4u);
  EXPECT_EQ(slam["max_features"], "tracking.features.max_features");
  EXPECT_EQ(mapping.count("keyframe_queue"), 1u);
  // Each resolves to an option of its node (an empty tree reads without errors) ...
  SlamNodeParams p;
  EXPECT_TRUE(nerfslam::rosnode::readSlamNodeParams(XmlRpcValue(), p).ok());
  NerfMappingNodeParams n;
  EXPECT_TRUE(nerfslam::rosnode::readNerfMappingNodeParams(XmlRpcValue(), n).ok());
  // ... and one that does not is refused, naming the table.
  nerfslam::SystemOptions o;
  const ParamReport r = nerfslam::rosnode::readParams(XmlRpcValue(), o, &o, {{"nerf_steps", "nerf.no_such_option"}});
  EXPECT_TRUE(contains(r.errors, "~nerf_steps is an alias of option 'nerf.no_such_option', which does not exist"))
      << joined(r.errors);
}

struct NameCollector {
  std::vector<std::string>* out;
  template <class T, class... C>
  void operator()(const char* name, T&, const char*, const C&...) {
    out->emplace_back(name);
  }
};

// Every parameter a node reads at the root of its private namespace (the ROS-only options and the
// aliases) has its row in docs/ros.md.
TEST(NodeParams, DocsListEveryParameter) {
  std::ifstream in(nerfslam::test::sourceDir() / "docs" / "ros.md");
  ASSERT_TRUE(in) << "docs/ros.md";
  std::stringstream ss;
  ss << in.rdbuf();
  const std::string doc = ss.str();
  std::vector<std::string> names;
  NameCollector v{&names};
  nerfslam::rosnode::SlamNodeOptions node;
  nerfslam::rosnode::NerfTopicsOptions topics;
  nerfslam::rosnode::MapToOdomParams odom;
  node.visit(v);
  topics.visit(v);
  odom.visit(v);
  for (const auto kind : {nerfslam::rosnode::NodeKind::kSlam, nerfslam::rosnode::NodeKind::kNerfMapping})
    for (const auto& a : nerfslam::rosnode::optionAliases(kind)) names.push_back(a.param);
  names.push_back("config");
  for (const auto& n : names) EXPECT_NE(doc.find("| `~" + n + "` |"), std::string::npos) << "~" << n;
}

}  // namespace
