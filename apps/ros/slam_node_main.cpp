// main() of nerfslam_node and tracking_node (the mode is a compile definition, apps/ros/CMakeLists.txt);
// the node itself is apps/ros/nerfslam_node.cpp.
#include "nerfslam_ros/slam_node.h"

int main(int argc, char** argv) {
  return nerfslam::rosnode::runSlamNode(argc, argv, nerfslam::rosnode::SlamNodeMode::NERFSLAM_SLAM_NODE_MODE);
}
