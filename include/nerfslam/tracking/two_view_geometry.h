#pragma once
// Two-view geometry (thesis ch. 3-4): normalised 8-point fundamental matrix solved as the SVD null
// vector of A f = 0 with rows a_i = x''_i (x) x'_i, RANSAC with Sampson error and an adaptive
// iteration count, homography DLT + RANSAC, essential decomposition with cheirality, triangulation.
// Convention: x1 = reference image, x2 = current image, x2^T F x1 = 0, x2 ~ H x1, and the relative
// pose (R, t) maps reference-camera coordinates into the current camera: X2 = R X1 + t.
#include <cstdint>
#include <vector>

#include <Eigen/Core>

namespace nerfslam {

using Points2d = std::vector<Eigen::Vector2d>;

// Normalised 8-point (Hartley): isotropic normalisation, SVD, rank-2 enforcement, denormalised.
// Needs >= 8 correspondences; F is scaled to unit Frobenius norm. Throws nerfslam::Error on < 8.
Eigen::Matrix3d eightPointFundamental(const Points2d& x1, const Points2d& x2);
// Normalised DLT homography, >= 4 correspondences, H(2,2) scaled to 1 when possible.
Eigen::Matrix3d dltHomography(const Points2d& x1, const Points2d& x2);

// Sampson (first-order geometric) error, squared pixels.
double sampsonError(const Eigen::Matrix3d& F, const Eigen::Vector2d& x1, const Eigen::Vector2d& x2);
// Symmetric transfer error |x2 - H x1|^2 + |x1 - H^-1 x2|^2, squared pixels.
double homographyTransferError(const Eigen::Matrix3d& H, const Eigen::Matrix3d& H_inv, const Eigen::Vector2d& x1,
                               const Eigen::Vector2d& x2);

struct RansacOptions {
  double threshold_px = 1.0;  // inlier threshold on the (Sampson / transfer) error, pixels
  double confidence = 0.999;  // for the adaptive iteration count
  int max_iterations = 500;
  uint64_t seed = 42;
};

// RANSAC's adaptive iteration count: the samples of `sample_size` to draw for one all-inlier sample
// with probability `confidence` when a fraction `inlier_ratio` of the data are inliers, at most
// max_iterations (capped in double before the conversion: at low ratios the count exceeds INT_MAX).
// max_iterations when the ratio gives no bound (<= 0), 0 when every datum is an inlier.
int ransacIterations(double inlier_ratio, int sample_size, double confidence, int max_iterations);

struct ModelEstimate {
  Eigen::Matrix3d M = Eigen::Matrix3d::Zero();  // F or H
  std::vector<char> inliers;                    // one flag per correspondence
  int num_inliers = 0;
  double score = 0;  // ORB-SLAM style truncated chi-square score (higher is better)
  int iterations = 0;
  bool valid = false;
};

// RANSAC over 8-point samples, Sampson error; final F re-estimated on all inliers.
ModelEstimate findFundamentalRansac(const Points2d& x1, const Points2d& x2, const RansacOptions& options);
// RANSAC over 4-point samples, symmetric transfer error; final H re-estimated on all inliers.
ModelEstimate findHomographyRansac(const Points2d& x1, const Points2d& x2, const RansacOptions& options);

struct RelativePose {
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
  Eigen::Vector3d t = Eigen::Vector3d::Zero();  // unit length for F/E and H reconstructions
};

// The four (R, t) candidates of E = [t]x R (t unit length).
std::vector<RelativePose> decomposeEssential(const Eigen::Matrix3d& E);

// Linear (DLT) triangulation of a reference/current correspondence in normalised image
// coordinates (x, y) given X2 = R X1 + t. Returns the point in reference-camera coordinates.
Eigen::Vector3d triangulate(const RelativePose& pose, const Eigen::Vector2d& n1, const Eigen::Vector2d& n2);

struct Reconstruction {
  RelativePose pose;
  std::vector<Eigen::Vector3d> points;  // reference-camera coordinates (valid where good[i])
  std::vector<char> good;               // inlier, in front of both cameras, reprojection ok
  int num_good = 0;
  double parallax_deg = 0;   // median parallax of the good points
  int second_best_good = 0;  // good count of the runner-up candidate (ambiguity check)
};

// Picks the candidate with the most points passing cheirality + reprojection (< threshold px)
// among `inliers`, given intrinsics K (points in ideal pixels).
Reconstruction selectByCheirality(const std::vector<RelativePose>& candidates, const Eigen::Matrix3d& K,
                                  const Points2d& x1, const Points2d& x2, const std::vector<char>& inliers,
                                  double reprojection_threshold_px);

// E = K^T F K, decomposed and disambiguated by cheirality.
Reconstruction reconstructFromFundamental(const Eigen::Matrix3d& F, const Eigen::Matrix3d& K, const Points2d& x1,
                                          const Points2d& x2, const std::vector<char>& inliers,
                                          double reprojection_threshold_px);
// Homography decomposition (Faugeras / OpenCV decomposeHomographyMat candidates) + cheirality.
// The planar two-fold ambiguity (two candidates explaining >= 90% of the best count) is resolved
// by the epipolar geometry E = [t]x R of each candidate over all correspondences (x1, x2, not only
// the `inliers` of H): points off the plane reject the wrong twin. When that cannot tell them apart
// (a real plane), the plane that faces the reference camera (largest |n_z|) is taken.
// second_best_good then counts only the clearly worse candidates.
Reconstruction reconstructFromHomography(const Eigen::Matrix3d& H, const Eigen::Matrix3d& K, const Points2d& x1,
                                         const Points2d& x2, const std::vector<char>& inliers,
                                         double reprojection_threshold_px);

}  // namespace nerfslam
