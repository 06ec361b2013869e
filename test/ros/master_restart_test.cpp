// A restart of the ROS master under a running nerfslam_node and image_folder_publisher. Not a rostest
// (rostest owns its master): this gtest starts `roscore -p <free port>` itself, the node and a
// publisher (a synthetic room it renders, 320x240, looping, 15 Hz), and once the node tracks:
//   1. kills the master (SIGKILL of rosmaster; roscore then stops rosout) and starts a new roscore on
//      the same port 3 s later;
//   2. checks that both nodes registered again with the new master (getSystemState: the node's
//      publishers, its image subscription and services, the publisher's image topic) and said so, that
//      the node's private parameters are back, and that a new subscriber gets ~pose (a connection only
//      the new master can make);
//   3. kills the publisher and starts a new one: the node's subscription, known only through the
//      re-registration, connects to it and the node tracks its frames; ~set_localization_only answers
//      (the service is registered with the new master).
// Every process it starts is stopped at the end, also when a check fails (ChildProcess).
#include <gtest/gtest.h>

#include <atomic>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <set>
#include <string>
#include <vector>

#include <geometry_msgs/PoseStamped.h>
#include <ros/master.h>
#include <ros/ros.h>
#include <std_srvs/SetBool.h>

#include "ros_test_util.h"
#include "test_support.h"

namespace {

namespace fs = std::filesystem;
using nerfslam::rostest_util::ChildProcess;
using nerfslam::rostest_util::DiagnosticsValues;
using nerfslam::rostest_util::readText;
using nerfslam::rostest_util::waitFor;

// Publishers, subscribers and services the master lists for `node` ("P /topic", "S /topic", "V /srv").
std::set<std::string> registrationsOf(const std::string& node) {
  std::set<std::string> out;
  XmlRpc::XmlRpcValue args, result, payload;
  args[0] = ros::this_node::getName();
  if (!ros::master::execute("getSystemState", args, result, payload, false)) return out;
  const char* kinds[] = {"P ", "S ", "V "};
  for (int k = 0; k < 3 && k < payload.size(); ++k)
    for (int i = 0; i < payload[k].size(); ++i)
      for (int j = 0; j < payload[k][i][1].size(); ++j)
        if (std::string(payload[k][i][1][j]) == node) out.insert(kinds[k] + std::string(payload[k][i][0]));
  return out;
}

int masterPid() {
  XmlRpc::XmlRpcValue args, result, payload;
  args[0] = ros::this_node::getName();
  if (!ros::master::execute("getPid", args, result, payload, false)) return -1;
  return int(payload);
}

TEST(MasterRestart, NodesRegisterAgainAndTrackAfterTheMasterRestarts) {
  const int port = nerfslam::rostest_util::freePort();
  ASSERT_GT(port, 0);
  const std::string uri = "http://127.0.0.1:" + std::to_string(port);
  setenv("ROS_MASTER_URI", uri.c_str(), 1);
  setenv("ROS_IP", "127.0.0.1", 1);
  unsetenv("ROS_HOSTNAME");
  nerfslam::test::TempDir tmp;
  const char* log_dir = std::getenv("ROS_LOG_DIR");
  const fs::path logs = log_dir ? fs::path(log_dir) : tmp.path();
  const std::string core_log = (logs / "master_restart_roscore.log").string(),
                    node_log = (logs / "master_restart_node.log").string(),
                    pub_log = (logs / "master_restart_publisher.log").string();
  for (const auto& l : {core_log, node_log, pub_log}) fs::remove(l);

  auto roscore =
      std::make_unique<ChildProcess>(std::vector<std::string>{"roscore", "-p", std::to_string(port)}, core_log);
  int argc = 1;
  char name[] = "master_restart_test";
  char* argv[] = {name, nullptr};
  ros::init(argc, argv, "master_restart_test", ros::init_options::NoSigintHandler);
  ASSERT_TRUE(waitFor(30.0, [] { return ros::master::check(); })) << "roscore did not start: " << readText(core_log);
  ASSERT_TRUE(waitFor(10.0, [] { return ros::param::has("/run_id"); }));
  ros::AsyncSpinner spinner(2);
  spinner.start();

  const fs::path seq = tmp / "room";
  const auto synth = nerfslam::test::runCli(
      "synth --scene room --frames 120 --fps 15 --size 320x240 --textures "
      "procedural --out '" +
      seq.string() + "'");
  ASSERT_EQ(synth.exit_code, 0) << synth.output;
  const std::vector<std::string> pub_args = {NERFSLAM_PUBLISHER_PATH, "__name:=master_camera",
                                             "_dataset:=" + seq.string(), "_rate:=15", "_loop:=true"};
  ChildProcess node({NERFSLAM_NODE_PATH, "__name:=nerfslam_node", "_nerf:=false", "_queue_size:=10"}, node_log);
  auto publisher = std::make_unique<ChildProcess>(pub_args, pub_log);

  // The node tracks.
  double tracked_before = 0;
  {
    ros::NodeHandle nh;
    DiagnosticsValues diag(nh, "nerfslam_node");
    ASSERT_TRUE(waitFor(60.0, [&] { return diag.num("frames tracked") >= 30; }))
        << "the node does not track: " << readText(node_log);
    tracked_before = diag.num("frames tracked");
  }  // the test's own subscriptions end with the old master
  const std::set<std::string> before = registrationsOf("/nerfslam_node");
  std::printf("before: the master lists %zu registrations of /nerfslam_node; %.0f frames tracked\n", before.size(),
              tracked_before);
  ASSERT_TRUE(before.count("S /image") && before.count("P /nerfslam_node/pose") &&
              before.count("V /nerfslam_node/reset"));

  // 1. The master dies; a new one starts on the same port 3 s later.
  const std::string run_id_before = [] {
    std::string s;
    ros::param::get("/run_id", s);
    return s;
  }();
  const int pid = masterPid();
  ASSERT_GT(pid, 0);
  ASSERT_EQ(kill(pid, SIGKILL), 0);
  roscore->stop(SIGINT, 15.0);  // roslaunch stops rosout
  ASSERT_FALSE(ros::master::check());
  ros::WallDuration(3.0).sleep();
  ASSERT_TRUE(node.running()) << "the node died with the master: " << readText(node_log);
  roscore = std::make_unique<ChildProcess>(std::vector<std::string>{"roscore", "-p", std::to_string(port)}, core_log);
  ASSERT_TRUE(waitFor(30.0, [] { return ros::master::check() && ros::param::has("/run_id"); }))
      << "roscore did not start again: " << readText(core_log);
  std::string run_id_after;
  ros::param::get("/run_id", run_id_after);
  EXPECT_NE(run_id_after, run_id_before);
  const ros::WallTime t_restart = ros::WallTime::now();

  // 2. Both nodes registered again, and said so.
  EXPECT_TRUE(waitFor(15.0, [&] {
    const auto now = registrationsOf("/nerfslam_node");
    for (const auto& r : before)
      if (!now.count(r)) return false;
    return true;
  })) << "the node did not register everything again";
  const double t_reregistered = (ros::WallTime::now() - t_restart).toSec();
  EXPECT_TRUE(waitFor(10.0, [&] { return registrationsOf("/master_camera").count("P /image") > 0; }))
      << "the publisher did not register again";
  // The node logs its re-registration after the last registration reaches the master: wait for it.
  std::string node_out;
  waitFor(10.0, [&] {
    node_out = readText(node_log);
    return node_out.find("registered again") != std::string::npos;
  });
  const size_t said = node_out.find("registered again");
  EXPECT_NE(said, std::string::npos) << "the node did not say it registered again";
  EXPECT_NE(node_out.find("is unreachable"), std::string::npos) << "the node did not say the master went away";
  if (said != std::string::npos) {
    const size_t a = node_out.rfind('\n', said) + 1, b = node_out.find('\n', said);
    std::printf("node said: %s\n", node_out.substr(a, b - a).c_str());
  }
  std::printf("after the restart: %zu registrations of /nerfslam_node on the new master %.1f s after it came up\n",
              registrationsOf("/nerfslam_node").size(), t_reregistered);
  EXPECT_TRUE(ros::param::has("/nerfslam_node/queue_size")) << "the node's private parameters were not restored";

  ros::NodeHandle nh;
  DiagnosticsValues diag(nh, "nerfslam_node");
  std::atomic<int> poses{0};
  ros::Subscriber pose_sub = nh.subscribe<geometry_msgs::PoseStamped>(
      "/nerfslam_node/pose", 10, [&](const geometry_msgs::PoseStampedConstPtr&) { ++poses; });
  EXPECT_TRUE(waitFor(20.0, [&] { return poses > 5; })) << "no ~pose through the new master";
  EXPECT_TRUE(waitFor(10.0, [&] { return diag.num("master re-registrations") >= 1; }));
  std::printf("through the new master: %d poses; diagnostics: master losses %.0f, re-registrations %.0f\n", int(poses),
              diag.num("master losses"), diag.num("master re-registrations"));

  // 3. A new publisher: only the re-registered subscription can connect the node to it.
  publisher->stop(SIGKILL);
  ros::WallDuration(1.0).sleep();
  const double tracked_mid = diag.num("frames tracked");
  publisher =
      std::make_unique<ChildProcess>(std::vector<std::string>{NERFSLAM_PUBLISHER_PATH, "__name:=master_camera_2",
                                                              "_dataset:=" + seq.string(), "_rate:=15", "_loop:=true"},
                                     pub_log);
  EXPECT_TRUE(waitFor(30.0, [&] { return diag.num("frames tracked") >= tracked_mid + 30; }))
      << "the node did not track the new publisher's frames (" << diag.num("frames tracked") - tracked_mid << ")";
  std::printf("new publisher after the restart: %.0f frames tracked (%.0f received in all)\n",
              diag.num("frames tracked") - tracked_mid, diag.num("frames received"));
  std_srvs::SetBool srv;
  srv.request.data = false;
  EXPECT_TRUE(ros::service::call("/nerfslam_node/set_localization_only", srv))
      << "~set_localization_only unreachable through the new master";

  pose_sub.shutdown();
  EXPECT_EQ(node.stop(SIGINT, 20.0), 0) << "the node did not exit cleanly: " << readText(node_log);
  publisher->stop();
  spinner.stop();
  ros::shutdown();
  roscore->stop(SIGINT, 15.0);
}

}  // namespace
