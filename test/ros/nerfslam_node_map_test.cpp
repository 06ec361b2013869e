// gtest node started by test/ros/nerfslam_node_map.test (rostest): saved maps on the robot
// (docs/ros.md, "Saved maps"). The test renders a synthetic room (`nerfslam synth`, 320x240, no data
// needed), maps it with the CLI (`nerfslam run --no-nerf --save-map`), localises in that map with
// the CLI (`--map --localize`: the reference ATE), then starts the nodes itself:
//   1. `roslaunch nerfslam nerfslam.launch map:=MAP map_mode:=localize` on a second visit: the same
//      walk rendered at 23 frames/s (other poses and images; image_folder_publisher, its stamps):
//      relocalised within 1 s (stamps) of the first frame, no keyframe added, ~pose within 1.2x the
//      ATE of the CLI's --localize on the same frames (Sim(3)-aligned RMSE, both against the ground
//      truth), ~path published;
//   2. nerfslam_node with ~map_mode extend and ~save_on_shutdown: SIGINT after 60 frames, exit status
//      0, the folder it wrote loads (with the camera) and has at least the map's keyframes;
//   3. bad input: a missing ~map folder, a corrupt one (a flipped byte in the keyframes file), an
//      unknown ~map_mode, and a map from another camera (camera_info with fx, fy x 1.1, while
//      ~save_on_shutdown names the map folder itself): each a ROS_FATAL naming the parameter and the
//      path (and the file or field), exit status 1, and the map folder left as it was.
#include <gtest/gtest.h>

#include <sys/wait.h>

#include <csignal>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <string>
#include <vector>

#include <geometry_msgs/PoseStamped.h>
#include <nav_msgs/Path.h>
#include <ros/ros.h>

#include "nerfslam/eval/trajectory_metrics.h"
#include "nerfslam/io/dataset.h"
#include "nerfslam/io/trajectory.h"
#include "nerfslam/system/map_store.h"
#include "ros_test_util.h"
#include "test_support.h"

namespace {

namespace fs = std::filesystem;
using nerfslam::SE3;
using nerfslam::rostest_util::ChildProcess;
using nerfslam::rostest_util::DiagnosticsValues;
using nerfslam::rostest_util::readText;
using nerfslam::rostest_util::waitFor;

constexpr int kFrames = 100;  // played from frame 1 (renderSyntheticRoom)
// The second visit: the same walk rendered at 23 frames/s (other poses, other images), 3.3 s.
constexpr int kSecondFrames = 76;  // played from frame 1
constexpr double kSecondFps = 23.0;

// What every case shares: the room, its map (made once by the CLI) and the CLI's --localize ATE.
struct MapFixture {
  nerfslam::test::TempDir tmp;
  nerfslam::rostest_util::SyntheticRoom room;
  fs::path second_dir;  // the second visit
  nerfslam::Trajectory second_gt;
  fs::path map_dir, config;
  nerfslam::Camera camera;
  size_t map_keyframes = 0;
  double cli_ate_rmse = 0, cli_ate_percent = 0;
  size_t cli_tracked = 0;
  bool ok = false;
};

nerfslam::TrajectoryReport ateOf(const nerfslam::Trajectory& gt, const nerfslam::Trajectory& est) {
  nerfslam::TrajectoryEvalOptions eo;
  eo.align = "sim3";
  eo.max_dt = 1e-4;
  return nerfslam::evaluateTrajectory(gt, est, eo);
}

MapFixture& setup() {
  static MapFixture s;
  static bool done = false;
  if (done) return s;
  done = true;
  s.room = nerfslam::rostest_util::renderSyntheticRoom(s.tmp.path(), kFrames);
  if (!s.room.dataset) return s;
  s.camera = s.room.dataset->camera();
  s.config = nerfslam::test::sourceDir() / "config/system/synthetic.yaml";
  s.map_dir = s.tmp / "map";
  const auto t0 = ros::WallTime::now();
  const auto slam =
      nerfslam::test::runCli("run --no-nerf --dataset '" + s.room.dir.string() + "' --config '" + s.config.string() +
                             "' --out '" + (s.tmp / "slam").string() + "' --save-map '" + s.map_dir.string() + "'");
  if (slam.exit_code != 0) {
    ADD_FAILURE() << slam.output;
    return s;
  }
  s.second_dir = s.tmp / "room23";
  const auto synth =
      nerfslam::test::runCli("synth --scene room --frames " + std::to_string(kSecondFrames + 1) +
                             " --fps 23 --size 320x240 --textures procedural --out '" + s.second_dir.string() + "'");
  if (synth.exit_code != 0) {
    ADD_FAILURE() << synth.output;
    return s;
  }
  {
    nerfslam::DatasetOptions opts;
    opts.start = 1;  // as played (frame 0's stamp is 0)
    const auto second = nerfslam::openDataset(s.second_dir.string(), opts);
    for (size_t i = 0; i < second->size(); ++i) s.second_gt.push_back({second->timestamp(i), *second->groundTruth(i)});
  }
  const auto loc = nerfslam::test::runCli("run --no-nerf --dataset '" + s.second_dir.string() + "' --map '" +
                                          s.map_dir.string() + "' --localize --out '" + (s.tmp / "loc").string() + "'");
  if (loc.exit_code != 0) {
    ADD_FAILURE() << loc.output;
    return s;
  }
  s.map_keyframes = nerfslam::loadMapFolder(s.map_dir, s.camera).map->numKeyframes();
  const nerfslam::Trajectory cli = nerfslam::readTumTrajectory(s.tmp / "loc" / "trajectory.txt");
  const auto ate = ateOf(s.second_gt, cli);
  s.cli_ate_rmse = ate.ape.rmse;
  s.cli_ate_percent = ate.ape_rmse_percent;
  s.cli_tracked = ate.matched;
  std::printf(
      "map: %zu keyframes (CLI, %d frames at 30 fps); CLI --localize on the walk at 23 fps: %zu frames matched, "
      "ATE %.5f m = %.3f %% (%.1f s for both runs)\n",
      s.map_keyframes, kFrames + 1, s.cli_tracked, s.cli_ate_rmse, s.cli_ate_percent,
      (ros::WallTime::now() - t0).toSec());
  s.ok = true;
  return s;
}

std::string logPath(const std::string& name) {
  const char* log_dir = std::getenv("ROS_LOG_DIR");
  const fs::path p = (log_dir ? fs::path(log_dir) : fs::temp_directory_path()) / ("nerfslam_map_" + name + ".log");
  fs::remove(p);
  return p.string();
}

// image_folder_publisher playing the room (dataset stamps, from frame 1) on `ns`/image.
std::unique_ptr<ChildProcess> play(const std::string& name, const std::string& ns, int max_frames,
                                   const std::vector<std::string>& extra = {}, const fs::path& dataset = {},
                                   double rate = 30.0) {
  ros::param::del("/" + name);
  std::vector<std::string> argv = {NERFSLAM_PUBLISHER_PATH,
                                   "__name:=" + name,
                                   "_dataset:=" + (dataset.empty() ? setup().room.dir : dataset).string(),
                                   "_rate:=" + std::to_string(rate),
                                   "_use_dataset_stamps:=true",
                                   "_start:=1",
                                   "_max_frames:=" + std::to_string(max_frames),
                                   "_wait_for_subscribers:=true",
                                   "_exit_when_done:=true",
                                   "image:=" + ns + "/image"};
  argv.insert(argv.end(), extra.begin(), extra.end());
  return std::make_unique<ChildProcess>(argv, logPath(name));
}

// Exit code of a process that ends by itself within `seconds` (-1: still running, then stopped).
int exitCodeWithin(ChildProcess& p, double seconds) {
  if (!waitFor(seconds, [&] { return !p.running(); })) {
    p.stop(SIGKILL, 1.0);
    return -1;
  }
  const int status = p.stop();
  return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
}

// Every byte of every file under `dir`, by relative path (to see that nothing was written over a map).
std::map<std::string, std::string> snapshot(const fs::path& dir) {
  std::map<std::string, std::string> files;
  for (const auto& e : fs::recursive_directory_iterator(dir))
    if (e.is_regular_file()) files[fs::relative(e.path(), dir).string()] = readText(e.path().string());
  return files;
}

TEST(NerfslamNodeMap, LocalizesInTheSavedMapFromRoslaunch) {
  MapFixture& s = setup();
  ASSERT_TRUE(s.ok);
  ros::NodeHandle nh;
  std::mutex mutex;
  nerfslam::Trajectory poses;
  size_t path_poses = 0;
  ros::Subscriber pose_sub = nh.subscribe<geometry_msgs::PoseStamped>(
      "/nerfslam_node/pose", 500, [&](const geometry_msgs::PoseStampedConstPtr& m) {
        const auto& p = m->pose;
        std::lock_guard<std::mutex> lock(mutex);
        poses.push_back({m->header.stamp.toSec(),
                         SE3(Eigen::Quaterniond(p.orientation.w, p.orientation.x, p.orientation.y, p.orientation.z),
                             Eigen::Vector3d(p.position.x, p.position.y, p.position.z))});
      });
  ros::Subscriber path_sub =
      nh.subscribe<nav_msgs::Path>("/nerfslam_node/path", 5, [&](const nav_msgs::PathConstPtr& m) {
        std::lock_guard<std::mutex> lock(mutex);
        path_poses = m->poses.size();
      });
  DiagnosticsValues diag(nh, "nerfslam_node");
  // The sparse SLAM (the map has no NeRF model); set before roslaunch, which keeps it.
  ros::param::del("/nerfslam_node");
  ros::param::set("/nerfslam_node/nerf", false);
  const std::string log = logPath("roslaunch");
  ChildProcess launch(
      {"roslaunch", "nerfslam", "nerfslam.launch", "image:=/maploc/image", "camera_info:=/maploc/camera_info",
       "map:=" + s.map_dir.string(), "map_mode:=localize", "config:=" + s.config.string(), "queue_size:=200",
       "wait_for_mapping:=true", "map_frame:=maploc_map", "camera_frame:=maploc_camera"},
      log);
  ASSERT_TRUE(waitFor(40.0, [&] { return diag.count() > 0; })) << readText(log);
  EXPECT_EQ(diag.str("map mode"), "localize");
  auto cam = play("maploc_camera", "/maploc", kSecondFrames, {}, s.second_dir, kSecondFps);
  EXPECT_TRUE(waitFor(60.0, [&] { return !cam->running(); })) << "the publisher did not finish";
  EXPECT_TRUE(
      waitFor(20.0, [&] { return diag.num("frames received") >= kSecondFrames && diag.accounted() >= kSecondFrames; }))
      << diag.num("frames received") << " received, " << diag.accounted() << " accounted for";
  ros::WallDuration(1.5).sleep();  // the last diagnostics and ~path

  const double reloc_frame = diag.num("relocalised at frame"), reloc_s = diag.num("relocalised after s");
  EXPECT_EQ(diag.str("relocalised"), "yes");
  EXPECT_GE(reloc_frame, 0);
  EXPECT_LE(reloc_s, 1.0) << "relocalised " << reloc_s << " s after the first frame";
  EXPECT_GE(reloc_s, 0.0);
  // Localisation only: the map keeps its keyframes.
  EXPECT_EQ(diag.num("map keyframes loaded"), double(s.map_keyframes));
  EXPECT_EQ(diag.num("keyframes"), double(s.map_keyframes)) << "keyframes were added in localize mode";
  nerfslam::Trajectory est;
  size_t path_n = 0;
  {
    std::lock_guard<std::mutex> lock(mutex);
    est = poses;
    path_n = path_poses;
  }
  EXPECT_GT(path_n, 0u) << "no ~path";
  ASSERT_GE(est.size(), size_t(0.9 * kSecondFrames)) << "too few poses on ~pose";
  const auto ate = ateOf(s.second_gt, est);
  std::printf(
      "node (roslaunch map:= map_mode:=localize): relocalised at frame %.0f, %.3f s after the first frame; %.0f "
      "keyframes (map: %zu); %zu poses, ATE %.5f m = %.3f %% (CLI --localize %.5f m = %.3f %%, ratio %.2f); ~path "
      "%zu poses\n",
      reloc_frame, reloc_s, diag.num("keyframes"), s.map_keyframes, est.size(), ate.ape.rmse, ate.ape_rmse_percent,
      s.cli_ate_rmse, s.cli_ate_percent, s.cli_ate_rmse > 0 ? ate.ape.rmse / s.cli_ate_rmse : 0.0, path_n);
  EXPECT_LE(ate.ape.rmse, 1.2 * s.cli_ate_rmse);
  launch.stop(SIGINT, 20.0);
  if (HasFailure()) std::printf("roslaunch output:\n%s\n", readText(log).c_str());
}

TEST(NerfslamNodeMap, ExtendsAndSavesOnShutdown) {
  MapFixture& s = setup();
  ASSERT_TRUE(s.ok);
  ros::NodeHandle nh;
  const fs::path saved = s.tmp / "saved_on_shutdown";
  const std::string log = logPath("save_node");
  ros::param::del("/map_save_node");
  ChildProcess node({NERFSLAM_NODE_PATH, "__name:=map_save_node", "_nerf:=false", "_queue_size:=200",
                     "_wait_for_mapping:=true", "_config:=" + s.config.string(), "_map:=" + s.map_dir.string(),
                     "_map_mode:=extend", "_save_on_shutdown:=true", "_save_on_shutdown_dir:=" + saved.string(),
                     "_map_frame:=mapsave_map", "_camera_frame:=mapsave_camera", "image:=/mapsave/image"},
                    log);
  DiagnosticsValues diag(nh, "map_save_node");
  ASSERT_TRUE(waitFor(30.0, [&] { return diag.count() > 0; })) << readText(log);
  auto cam = play("mapsave_camera", "/mapsave", 60);
  EXPECT_TRUE(waitFor(40.0, [&] { return !cam->running(); }));
  EXPECT_TRUE(waitFor(20.0, [&] { return diag.accounted() >= 60; }));
  ros::WallDuration(1.2).sleep();
  EXPECT_EQ(diag.str("map mode"), "extend");
  EXPECT_EQ(diag.str("relocalised"), "yes");
  const double keyframes = diag.num("keyframes");
  EXPECT_FALSE(fs::exists(saved)) << "saved before the shutdown";
  const auto t0 = ros::WallTime::now();
  const int status = node.stop(SIGINT, 30.0);
  const double stop_s = (ros::WallTime::now() - t0).toSec();
  const std::string out = readText(log);
  ASSERT_TRUE(WIFEXITED(status)) << out;
  EXPECT_EQ(WEXITSTATUS(status), 0) << out;
  EXPECT_NE(out.find("shutdown: map saved: " + saved.string()), std::string::npos) << out;
  const nerfslam::LoadedMap loaded = nerfslam::loadMapFolder(saved, s.camera);
  ASSERT_TRUE(loaded.map);
  EXPECT_GE(loaded.map->numKeyframes(), s.map_keyframes);
  EXPECT_EQ(double(loaded.map->numKeyframes()), keyframes);
  std::printf("~save_on_shutdown (extend): stopped in %.2f s, saved %zu keyframes, %zu points (the map had %zu)\n",
              stop_s, loaded.map->numKeyframes(), loaded.map->numPoints(), s.map_keyframes);

  // A shutdown that takes longer than ~save_on_shutdown_timeout (1 ms: the save alone takes about 0.3
  // s): exit status 1 with the reason, and the folder keeps the map saved above.
  const std::string log2 = logPath("save_timeout_node");
  ros::param::del("/map_timeout_node");
  ChildProcess slow(
      {NERFSLAM_NODE_PATH, "__name:=map_timeout_node", "_nerf:=false", "_queue_size:=200",
       "_config:=" + s.config.string(), "_map:=" + s.map_dir.string(), "_map_mode:=extend", "_save_on_shutdown:=true",
       "_save_on_shutdown_dir:=" + saved.string(), "_save_on_shutdown_timeout:=0.001", "_map_frame:=maptimeout_map",
       "_camera_frame:=maptimeout_camera", "image:=/maptimeout/image"},
      log2);
  DiagnosticsValues diag2(nh, "map_timeout_node");
  ASSERT_TRUE(waitFor(30.0, [&] { return diag2.count() > 0; })) << readText(log2);
  auto cam2 = play("maptimeout_camera", "/maptimeout", 20);
  EXPECT_TRUE(waitFor(30.0, [&] { return diag2.num("frames tracked") >= 10; }));
  const int status2 = slow.stop(SIGINT, 30.0);
  const std::string out2 = readText(log2);
  ASSERT_TRUE(WIFEXITED(status2)) << out2;
  EXPECT_EQ(WEXITSTATUS(status2), 1) << out2;
  EXPECT_NE(out2.find("~save_on_shutdown_timeout (0.0 s) reached before the map was saved into " + saved.string()),
            std::string::npos)
      << out2;
  const nerfslam::LoadedMap kept = nerfslam::loadMapFolder(saved, s.camera);
  EXPECT_EQ(kept.generation, loaded.generation);
  EXPECT_EQ(kept.map->numKeyframes(), loaded.map->numKeyframes());
  std::printf("~save_on_shutdown_timeout 1 ms: exit %d; the folder keeps generation %lu\n", WEXITSTATUS(status2),
              static_cast<unsigned long>(kept.generation));
}

TEST(NerfslamNodeMap, BadMapInputIsFatalAndLeavesTheMap) {
  MapFixture& s = setup();
  ASSERT_TRUE(s.ok);
  struct Case {
    std::string name;
    fs::path map;
    std::vector<std::string> args;
    std::vector<std::string> expected;  // in the node's output
    bool camera_change = false;
  };
  // A corrupt map: one byte of the keyframes file flipped (its CRC-32 no longer matches).
  const fs::path corrupt = s.tmp / "corrupt_map";
  fs::copy(s.map_dir, corrupt, fs::copy_options::recursive);
  std::string keyframes_file;
  for (const auto& e : fs::directory_iterator(corrupt))
    if (e.path().filename().string().rfind("keyframes.", 0) == 0) keyframes_file = e.path().filename().string();
  ASSERT_FALSE(keyframes_file.empty());
  {
    std::fstream f(corrupt / keyframes_file, std::ios::in | std::ios::out | std::ios::binary);
    f.seekg(100);
    char c = 0;
    f.get(c);
    f.seekp(100);
    f.put(static_cast<char>(c ^ 0x5a));
  }
  // Another camera: fx, fy x 1.1 on camera_info; ~save_on_shutdown names the map folder itself.
  const fs::path other_cam_map = s.tmp / "other_camera_map";
  fs::copy(s.map_dir, other_cam_map, fs::copy_options::recursive);
  nerfslam::Camera changed = s.camera;
  changed.fx *= 1.1;
  changed.fy *= 1.1;
  nerfslam::saveCameraYaml(changed, s.tmp / "changed_camera.yaml");
  const fs::path missing = s.tmp / "no_such_map";
  const std::vector<Case> cases = {
      {"missing", missing, {}, {"~map " + missing.string(), "map folder not found"}},
      {"corrupt", corrupt, {}, {"~map " + corrupt.string(), keyframes_file}},
      {"mode", s.map_dir, {"_map_mode:=locate"}, {"~map_mode 'locate'", s.map_dir.string()}},
      {"camera",
       other_cam_map,
       {"_save_on_shutdown:=true", "_save_on_shutdown_dir:=" + other_cam_map.string()},
       {"~map " + other_cam_map.string(), "fx"},
       true},
  };
  for (const auto& c : cases) {
    SCOPED_TRACE(c.name);
    const bool exists = fs::exists(c.map);
    const auto before = exists ? snapshot(c.map) : std::map<std::string, std::string>{};
    const std::string name = "badmap_" + c.name;
    const std::string log = logPath(name);
    ros::param::del("/" + name);
    std::vector<std::string> argv = {NERFSLAM_NODE_PATH, "__name:=" + name, "_nerf:=false", "_map:=" + c.map.string(),
                                     "image:=/" + name + "/image"};
    argv.insert(argv.end(), c.args.begin(), c.args.end());
    const auto t0 = ros::WallTime::now();
    ChildProcess node(argv, log);
    std::unique_ptr<ChildProcess> cam;
    if (c.camera_change)
      cam = play(name + "_camera", "/" + name, 20, {"_camera:=" + (s.tmp / "changed_camera.yaml").string()});
    const int code = exitCodeWithin(node, 30.0);
    const double took = (ros::WallTime::now() - t0).toSec();
    const std::string out = readText(log);
    EXPECT_EQ(code, 1) << out;
    std::string fatal_line;
    for (size_t pos = out.find("FATAL"); pos != std::string::npos && fatal_line.empty();
         pos = out.find("FATAL", pos + 1))
      fatal_line = out.substr(pos, out.find('\n', pos) - pos);
    EXPECT_FALSE(fatal_line.empty()) << out;
    for (const auto& e : c.expected)
      EXPECT_NE(fatal_line.find(e), std::string::npos) << "'" << e << "' not in: " << out;
    EXPECT_EQ(out.find("Segmentation"), std::string::npos) << out;
    if (exists) {
      EXPECT_TRUE(snapshot(c.map) == before) << "the map folder " << c.map << " was changed";
    }
    EXPECT_FALSE(!exists && fs::exists(c.map)) << c.map << " was created";
    std::printf("bad input %s: exit %d after %.2f s: %s\n", c.name.c_str(), code, took, fatal_line.c_str());
  }
}

}  // namespace

int main(int argc, char** argv) { return nerfslam::rostest_util::runRosGtest(argc, argv, "nerfslam_node_map_test"); }
