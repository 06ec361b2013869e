#pragma once
// Rendering a NeRF model from any pinhole camera and pose (multi-threaded).
//
// Rays are processed in tiles, wavefront style as instant-ngp: every live ray of a tile marches a
// chunk of samples (8, 16, then 32 per round) through the occupancy grid, the field is queried on
// all of them at once, and each ray composites front to back until its transmittance drops below
// 1e-4 or it leaves the scene box. Pixels are independent, so the image does not depend on the
// thread count.
#include <opencv2/core.hpp>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/pose.h"
#include "nerfslam/nerf/model_io.h"
#include "nerfslam/nerf/nerf_options.h"

namespace nerfslam::nerf {

struct RenderResult {
  cv::Mat rgb;          // CV_32FC3, RGB order, [0,1], composited over the background
  cv::Mat depth;        // CV_32FC1, z-depth (along the optical axis) in world units; 0 where opacity < min_opacity
  cv::Mat normals;      // CV_32FC3, unit normals in the world frame (weighted by compositing weights); 0 where
                        // opacity < min_opacity or normals were not requested
  cv::Mat uncertainty;  // CV_32FC1, standard deviation of the termination distance along the ray (world units)
  cv::Mat opacity;      // CV_32FC1, accumulated opacity 1 - T
  int64_t samples = 0;  // field queries made
};

// The camera's distortion, when any, is honoured through Camera::unproject.
RenderResult renderView(const NerfModel& model, const Camera& camera, const SE3& T_world_cam,
                        const RenderOptions& options = {});

// 8-bit BGR image from a rendered RGB (for cv::imwrite).
cv::Mat toBgr8(const cv::Mat& rgb);

}  // namespace nerfslam::nerf
