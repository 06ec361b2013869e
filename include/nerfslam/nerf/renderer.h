#pragma once
// Rendering a NeRF model from any pinhole camera and pose (multi-threaded).
//
// Rays are processed in 32x16-pixel blocks, wavefront style as instant-ngp: every live ray of a
// block marches a chunk of samples (8, then 4 per round) through the occupancy grid, the
// density network is queried on all of them at once, and each ray composites front to back until
// its transmittance drops below 1e-4 or it leaves the scene box. The colour network then runs only
// on the samples whose compositing weight matters: samples lighter than 1e-4 are left out while
// a ray's left-out weight stays within 1e-3, so the colour is within 1e-3 (of [0,1]) of compositing
// every sample; depth, opacity and uncertainty use every sample. Normals (density gradients, the
// costly part) are computed only when RenderOptions::normals is set. Pixels are independent, so the
// image does not depend on the thread count.
#include <opencv2/core.hpp>

#include "nerfslam/core/camera.h"
#include "nerfslam/core/pose.h"
#include "nerfslam/nerf/model_io.h"
#include "nerfslam/nerf/nerf_options.h"

namespace nerfslam::nerf {

struct RenderResult {
  cv::Mat rgb;          // CV_32FC3, RGB order, [0,1], composited over the background (the model's learned one
                        // when it has one and RenderOptions::learned_background is set)
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
