#pragma once
// The SLAM node (apps/ros/nerfslam_node.cpp), run by two executables:
//   nerfslam_node  kFull: tracking, sparse mapping and the NeRF mapping thread in one process
//   tracking_node  kTracking: the same without the NeRF (nerf.enabled is false), publishing every keyframe
//                  the mapping inserts on ~keyframes_out (nerfslam/MapKeyframe) and the keyframes'
//                  poses after bundle adjustment on ~keyframe_poses (nerfslam/KeyframePoses), for
//                  nerf_mapping_node on this or another computer (keyframe_link.h)
namespace nerfslam::rosnode {

enum class SlamNodeMode { kFull, kTracking };

// ros::init (node name "nerfslam_node" or "tracking_node"), parameters, spin; the process's exit code.
int runSlamNode(int argc, char** argv, SlamNodeMode mode);

}  // namespace nerfslam::rosnode
