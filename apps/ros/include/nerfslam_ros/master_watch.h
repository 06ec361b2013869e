#pragma once
// Surviving a restart of the ROS master (roscore). roscpp registers a node's publishers,
// subscribers and services with the master once, when they are created; a new master knows none of
// them, so no new connection to or from the node can be made (connections made before keep working).
// MasterWatch polls the master from a thread of its own (ros::master::check() and the /run_id
// parameter roslaunch sets, every `period` s) and, when the master comes back after being
// unreachable or its /run_id changed, registers again with it everything the node has: every
// advertised topic and every subscription (as the node's own slave API getPublications /
// getSubscriptions lists them, with their types), every service the node had registered with the
// previous master, and the node's private parameters when the new master has none. Subscriptions are
// then told about the publishers the new master knows (publisherUpdate, keeping the connections
// that are alive). It logs what happened (ROS_WARN) and counts it for the diagnostics.
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include <diagnostic_updater/diagnostic_updater.h>
#include <xmlrpcpp/XmlRpcValue.h>

namespace nerfslam::rosnode {

class MasterWatch {
 public:
  explicit MasterWatch(double period = 1.0);
  ~MasterWatch();
  MasterWatch(const MasterWatch&) = delete;
  MasterWatch& operator=(const MasterWatch&) = delete;

  uint64_t masterLosses() const { return losses_; }              // times the master became unreachable
  uint64_t reregistrations() const { return reregistrations_; }  // times the node registered again
  bool masterReachable() const { return reachable_; }
  // "master reachable", "master losses", "master re-registrations" (and the last one's summary).
  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& s) const;

 private:
  void run();
  void poll();
  // Registers everything again with the (new) master; returns a summary for the log.
  std::string reregister();

  double period_;
  std::thread thread_;
  std::mutex mutex_;
  std::condition_variable cv_;
  bool stopping_ = false;

  // Poll thread only.
  bool seen_ = false;  // the master was reached at least once
  std::string run_id_;
  std::vector<std::string> services_;  // resolved names registered by this node at the last poll
  XmlRpc::XmlRpcValue params_;         // this node's private parameters at the last poll
  bool have_params_ = false;

  std::atomic<bool> reachable_{false};
  std::atomic<uint64_t> losses_{0}, reregistrations_{0};
  mutable std::mutex last_mutex_;
  std::string last_;  // summary of the last re-registration
};

}  // namespace nerfslam::rosnode
