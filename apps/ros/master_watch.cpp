// MasterWatch (master_watch.h): re-registers a node with a restarted ROS master.
#include "nerfslam_ros/master_watch.h"

#include <algorithm>
#include <chrono>
#include <set>
#include <sstream>

#include <ros/connection_manager.h>
#include <ros/master.h>
#include <ros/network.h>
#include <ros/ros.h>
#include <ros/this_node.h>
#include <ros/xmlrpc_manager.h>
#include <xmlrpcpp/XmlRpcClient.h>

namespace nerfslam::rosnode {

namespace {

// Calls `method` of this node's own slave API (as the master or another node would) and returns the
// value part of the [code, message, value] reply; false when the call or the code fails.
bool callSelf(const std::string& method, const XmlRpc::XmlRpcValue& args, XmlRpc::XmlRpcValue& value) {
  std::string host;
  uint32_t port = 0;
  if (!ros::network::splitURI(ros::XMLRPCManager::instance()->getServerURI(), host, port)) return false;
  XmlRpc::XmlRpcClient client(host.c_str(), static_cast<int>(port), "/");
  XmlRpc::XmlRpcValue result;
  const bool ok = client.execute(method.c_str(), args, result);
  client.close();
  if (!ok || result.getType() != XmlRpc::XmlRpcValue::TypeArray || result.size() < 3) return false;
  if (result[0].getType() != XmlRpc::XmlRpcValue::TypeInt || int(result[0]) != 1) return false;
  value = result[2];
  return true;
}

bool callMaster(const std::string& method, const XmlRpc::XmlRpcValue& args, XmlRpc::XmlRpcValue& payload) {
  XmlRpc::XmlRpcValue result;
  return ros::master::execute(method, args, result, payload, false);
}

XmlRpc::XmlRpcValue args2(const std::string& a) {
  XmlRpc::XmlRpcValue v;
  v[0] = ros::this_node::getName();
  v[1] = a;
  return v;
}

// [[name, type], ...] from getPublications / getSubscriptions.
std::vector<std::pair<std::string, std::string>> topicList(const std::string& method) {
  std::vector<std::pair<std::string, std::string>> out;
  XmlRpc::XmlRpcValue args, value;
  args[0] = ros::this_node::getName();
  if (!callSelf(method, args, value) || value.getType() != XmlRpc::XmlRpcValue::TypeArray) return out;
  for (int i = 0; i < value.size(); ++i)
    if (value[i].getType() == XmlRpc::XmlRpcValue::TypeArray && value[i].size() >= 2)
      out.emplace_back(std::string(value[i][0]), std::string(value[i][1]));
  return out;
}

// Publisher URIs this node's subscription of `topic` is connected to (getBusInfo, inbound).
std::set<std::string> connectedPublishers(const std::string& topic) {
  std::set<std::string> out;
  XmlRpc::XmlRpcValue args, value;
  args[0] = ros::this_node::getName();
  if (!callSelf("getBusInfo", args, value) || value.getType() != XmlRpc::XmlRpcValue::TypeArray) return out;
  for (int i = 0; i < value.size(); ++i) {
    XmlRpc::XmlRpcValue& c = value[i];
    if (c.getType() != XmlRpc::XmlRpcValue::TypeArray || c.size() < 5) continue;
    if (c[1].getType() != XmlRpc::XmlRpcValue::TypeString || c[2].getType() != XmlRpc::XmlRpcValue::TypeString ||
        c[4].getType() != XmlRpc::XmlRpcValue::TypeString)
      continue;
    if (std::string(c[2]) == "i" && std::string(c[4]) == topic) out.insert(std::string(c[1]));
  }
  return out;
}

}  // namespace

MasterWatch::MasterWatch(double period) : period_(period) {
  thread_ = std::thread([this] { run(); });
}

MasterWatch::~MasterWatch() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
  }
  cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

void MasterWatch::run() {
  std::unique_lock<std::mutex> lock(mutex_);
  while (!stopping_) {
    lock.unlock();
    if (ros::ok()) poll();
    lock.lock();
    cv_.wait_for(lock, std::chrono::duration<double>(period_), [this] { return stopping_; });
  }
}

void MasterWatch::poll() {
  const bool up = ros::master::check();
  if (!up) {
    if (reachable_.exchange(false) || !seen_) {
      if (seen_) {
        ++losses_;
        ROS_WARN(
            "the ROS master at %s is unreachable: existing connections keep working, new ones cannot be made; "
            "waiting for it to come back to register again",
            ros::master::getURI().c_str());
      }
    }
    return;
  }
  XmlRpc::XmlRpcValue payload;
  std::string run_id;
  if (callMaster("getParam", args2("/run_id"), payload) && payload.getType() == XmlRpc::XmlRpcValue::TypeString)
    run_id = std::string(payload);
  const bool came_back = seen_ && !reachable_;
  // A new /run_id is a new master even when the restart fell between two polls ("" -> id is a master
  // that roslaunch has not finished setting up, not a new one).
  const bool new_run = seen_ && !run_id_.empty() && !run_id.empty() && run_id != run_id_;
  reachable_ = true;
  if (came_back || new_run) {
    const std::string what = reregister();
    ++reregistrations_;
    ROS_WARN("the ROS master at %s %s (run_id %s -> %s): registered again: %s", ros::master::getURI().c_str(),
             came_back ? "is back" : "was restarted", run_id_.empty() ? "?" : run_id_.c_str(),
             run_id.empty() ? "?" : run_id.c_str(), what.c_str());
    std::lock_guard<std::mutex> lock(last_mutex_);
    last_ = what;
  }
  seen_ = true;
  if (!run_id.empty()) run_id_ = run_id;

  // What to restore at the next restart: the services this node has registered, its parameters.
  XmlRpc::XmlRpcValue me;
  me[0] = ros::this_node::getName();
  if (callMaster("getSystemState", me, payload) && payload.getType() == XmlRpc::XmlRpcValue::TypeArray &&
      payload.size() >= 3) {
    std::vector<std::string> services;
    XmlRpc::XmlRpcValue& srvs = payload[2];
    for (int i = 0; i < srvs.size(); ++i) {
      if (srvs[i].getType() != XmlRpc::XmlRpcValue::TypeArray || srvs[i].size() < 2) continue;
      for (int j = 0; j < srvs[i][1].size(); ++j)
        if (std::string(srvs[i][1][j]) == ros::this_node::getName()) services.push_back(std::string(srvs[i][0]));
    }
    services_ = std::move(services);
  }
  XmlRpc::XmlRpcValue params;
  if (callMaster("getParam", args2(ros::this_node::getName()), params)) {
    params_ = params;
    have_params_ = true;
  }
}

std::string MasterWatch::reregister() {
  const std::string me = ros::this_node::getName();
  const std::string my_uri = ros::XMLRPCManager::instance()->getServerURI();
  int pubs = 0, subs = 0, srvs = 0, failed = 0;
  // registerPublisher / registerSubscriber(caller_id, topic, type, caller_api).
  auto registerTopic = [&](const char* method, const std::string& topic, const std::string& type,
                           XmlRpc::XmlRpcValue& payload) {
    XmlRpc::XmlRpcValue a;
    a[0] = me;
    a[1] = topic;
    a[2] = type;
    a[3] = my_uri;
    return callMaster(method, a, payload);
  };
  for (const auto& [topic, type] : topicList("getPublications")) {
    XmlRpc::XmlRpcValue payload;
    registerTopic("registerPublisher", topic, type, payload) ? ++pubs : ++failed;
  }
  for (const auto& [topic, type] : topicList("getSubscriptions")) {
    XmlRpc::XmlRpcValue payload;
    if (!registerTopic("registerSubscriber", topic, type, payload)) {
      ++failed;
      continue;
    }
    ++subs;
    // The publishers the new master knows, plus those still connected (not yet registered again):
    // publisherUpdate drops the connections to publishers it does not list.
    std::set<std::string> uris = connectedPublishers(topic);
    if (payload.getType() == XmlRpc::XmlRpcValue::TypeArray)
      for (int i = 0; i < payload.size(); ++i)
        if (payload[i].getType() == XmlRpc::XmlRpcValue::TypeString) uris.insert(std::string(payload[i]));
    XmlRpc::XmlRpcValue u, value;
    u[0] = "/master";
    u[1] = topic;
    u[2].setSize(0);
    int k = 0;
    for (const auto& uri : uris) u[2][k++] = uri;
    callSelf("publisherUpdate", u, value);
  }
  const std::string service_api =
      "rosrpc://" + ros::network::getHost() + ":" + std::to_string(ros::ConnectionManager::instance()->getTCPPort());
  for (const auto& service : services_) {
    XmlRpc::XmlRpcValue a, payload;
    a[0] = me;
    a[1] = service;
    a[2] = service_api;
    a[3] = my_uri;
    callMaster("registerService", a, payload) ? ++srvs : ++failed;
  }
  std::string params = "no private parameters";
  if (have_params_) {
    XmlRpc::XmlRpcValue payload;
    if (callMaster("hasParam", args2(me), payload) && payload.getType() == XmlRpc::XmlRpcValue::TypeBoolean &&
        bool(payload)) {
      params = "private parameters already set";
    } else {
      XmlRpc::XmlRpcValue a;
      a[0] = me;
      a[1] = me;
      a[2] = params_;
      params = callMaster("setParam", a, payload) ? "private parameters restored" : "private parameters not restored";
    }
  }
  std::ostringstream os;
  os << pubs << " publishers, " << subs << " subscribers, " << srvs << " services, " << params;
  if (failed > 0) os << " (" << failed << " registrations failed)";
  return os.str();
}

void MasterWatch::diagnose(diagnostic_updater::DiagnosticStatusWrapper& s) const {
  s.add("master reachable", reachable_ ? "yes" : "no");
  s.add("master losses", static_cast<uint64_t>(losses_));
  s.add("master re-registrations", static_cast<uint64_t>(reregistrations_));
  std::lock_guard<std::mutex> lock(last_mutex_);
  if (!last_.empty()) s.add("last re-registration", last_);
}

}  // namespace nerfslam::rosnode
