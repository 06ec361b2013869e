#include "nerfslam/tracking/initializer.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <functional>
#include <set>
#include <sstream>

#include <Eigen/Geometry>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "nerfslam/tracking/tracker.h"
#include "nerfslam/tracking/two_view_geometry.h"
#include "test_support.h"

namespace nerfslam {
namespace {

std::vector<SE3> readKittiPoses(const std::filesystem::path& file) {
  std::ifstream in(file);
  std::vector<SE3> out;
  std::string line;
  while (std::getline(in, line)) {
    std::istringstream is(line);
    Eigen::Matrix<double, 3, 4> T;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 4; ++c) is >> T(r, c);
    if (is) out.push_back(SE3::fromMatrix3x4(T));
  }
  return out;
}

// New Tsukuba: centre in cm in the first camera's frame; camera-to-world rotation S*M*S.
std::vector<SE3> readTsukubaPoses(const std::filesystem::path& file) {
  std::ifstream in(file);
  std::vector<SE3> out;
  std::string line;
  const Eigen::Matrix3d S = Eigen::Vector3d(1, -1, -1).asDiagonal();
  while (std::getline(in, line)) {
    std::istringstream is(line);
    Eigen::Vector3d t;
    Eigen::Matrix3d M;
    is >> t.x() >> t.y() >> t.z();
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) is >> M(r, c);
    if (is) out.push_back(SE3(S * M * S, t / 100.0));
  }
  return out;
}

double rotDeg(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
  return Eigen::AngleAxisd(a.transpose() * b).angle() * 180.0 / M_PI;
}
double dirDeg(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::acos(std::clamp(a.normalized().dot(b.normalized()), -1.0, 1.0)) * 180.0 / M_PI;
}

// Checks a successful result against the ground-truth relative pose T_ref_cur.
void expectMatchesGroundTruth(const InitializationResult& r, const SE3& T_ref_cur, double rot_tol_deg,
                              double dir_tol_deg) {
  ASSERT_TRUE(r.success) << r.reason;
  const double rot_err = rotDeg(r.T_world_cur.rotationMatrix(), T_ref_cur.rotationMatrix());
  const double dir_err = dirDeg(r.T_world_cur.translation(), T_ref_cur.translation());
  std::printf("init frames %llu->%llu: %s, %zu points, parallax %.2f deg, rot err %.3f deg, dir err %.2f deg\n",
              static_cast<unsigned long long>(r.ref_frame_id), static_cast<unsigned long long>(r.cur_frame_id),
              r.model.c_str(), r.points.size(), r.parallax_deg, rot_err, dir_err);
  EXPECT_LT(rot_err, rot_tol_deg);
  EXPECT_LT(dir_err, dir_tol_deg);
  // Map scaled to median depth 1 and every point in front of both cameras with a small reprojection error.
  std::vector<double> depth;
  const SE3 T_cur_world = r.T_world_cur.inverse();
  for (const InitialPoint& p : r.points) {
    depth.push_back(p.p_world.z());
    EXPECT_GT((T_cur_world * p.p_world).z(), 0);
  }
  std::nth_element(depth.begin(), depth.begin() + static_cast<long>(depth.size() / 2), depth.end());
  EXPECT_NEAR(depth[depth.size() / 2], 1.0, 0.02);
  int with_cur = 0;
  for (const InitialPoint& p : r.points) with_cur += p.cur_feature >= 0;
  EXPECT_GT(with_cur, static_cast<int>(r.points.size()) / 3);  // most points get a current keypoint
}

// Feeds frames 0..last of `dir` (file names from the printf `pattern`) until the initialiser
// succeeds; `on_frame` sees each frame with its result. A missing image ends it unsuccessfully.
InitializationResult initialiseOn(
    const std::filesystem::path& dir, const char* pattern, int last, const Camera& cam, const FeatureOptions& fo,
    Initializer& init, const std::function<void(int, const Frame&, const InitializationResult&)>& on_frame = {}) {
  InitializationResult r;
  for (int i = 0; i <= last && !r.success; ++i) {
    char name[64];
    std::snprintf(name, sizeof(name), pattern, i);
    const cv::Mat img = cv::imread((dir / name).string(), cv::IMREAD_GRAYSCALE);
    if (img.empty()) {
      r.reason = "missing image " + (dir / name).string();
      return r;
    }
    const Frame f = extractFrame(img, cam, fo, static_cast<uint64_t>(i));
    r = init.addFrame(f);
    if (on_frame) on_frame(i, f, r);
  }
  return r;
}

TEST(Initializer, Kitti06InitialisesWithGroundTruthMotion) {
  NERFSLAM_REQUIRE_DATA(dir, "kitti06_first51");
  const auto gt = readKittiPoses(dir / "poses.txt");
  ASSERT_GE(gt.size(), 6u);
  const Camera cam = Camera::pinhole(1226, 370, 707.0912, 707.0912, 601.8873, 183.1104);
  FeatureOptions fo;
  fo.max_features = 1500;
  Initializer init;
  const InitializationResult r = initialiseOn(dir, "image_l/%06d.png", 5, cam, fo, init);
  ASSERT_TRUE(r.success) << r.reason;
  EXPECT_EQ(r.model, "fundamental");
  EXPECT_EQ(r.ref_frame_id, 0u);
  EXPECT_GE(r.points.size(), 100u);
  expectMatchesGroundTruth(r, gt[0].inverse() * gt[r.cur_frame_id], 1.0, 3.0);
}

TEST(Initializer, NewTsukubaInitialisesWithGroundTruthMotion) {
  NERFSLAM_REQUIRE_DATA(dir, "new_tsukuba_150");
  const auto gt = readTsukubaPoses(dir / "cam_traj_truth.txt");
  ASSERT_GE(gt.size(), 40u);
  const Camera cam = Camera::pinhole(640, 480, 615, 615, 320, 240);
  Initializer init;
  const InitializationResult r = initialiseOn(dir, "images/rgb_%05d.png", 30, cam, {}, init);
  ASSERT_TRUE(r.success) << r.reason;
  expectMatchesGroundTruth(r, gt[r.ref_frame_id].inverse() * gt[r.cur_frame_id], 1.0, 5.0);
}

// With the system's 2,000 corners per frame the initialiser tracks max_tracks (1,000) of them,
// spread over the pyramid levels. (This subset once made New Tsukuba initialise on a homography at
// R_H 0.46 with the wrong one of its two decompositions: 2.6 % ATE in the system. The points off
// the dominant plane now choose the decomposition; see two_view_geometry_test.)
TEST(Initializer, NewTsukubaWithSystemFeatureCountTracksAThousandAndInitialises) {
  NERFSLAM_REQUIRE_DATA(dir, "new_tsukuba_150");
  const auto gt = readTsukubaPoses(dir / "cam_traj_truth.txt");
  ASSERT_GE(gt.size(), 40u);
  const Camera cam = Camera::pinhole(640, 480, 615, 615, 320, 240);
  FeatureOptions fo;
  fo.max_features = 2000;
  Initializer init;
  ASSERT_EQ(InitializerOptions{}.max_tracks, 1000);
  size_t reference_corners = 0;
  int reference_tracked = 0;
  const InitializationResult r = initialiseOn(dir, "images/rgb_%05d.png", 30, cam, fo, init,
                                              [&](int i, const Frame& f, const InitializationResult& ri) {
                                                if (i > 0) return;
                                                reference_corners = f.size();
                                                reference_tracked = ri.num_tracked;
                                              });
  EXPECT_GT(reference_corners, 1500u);
  EXPECT_EQ(reference_tracked, 1000);
  ASSERT_TRUE(r.success) << r.reason;
  std::set<int> levels;
  for (const InitialPoint& p : r.points) levels.insert(init.reference().keypoints[size_t(p.ref_feature)].octave);
  EXPECT_GE(levels.size(), 5u);
  expectMatchesGroundTruth(r, gt[r.ref_frame_id].inverse() * gt[r.cur_frame_id], 1.0, 5.0);
}

TEST(Initializer, RefusesStaticEurocDrone) {
  NERFSLAM_REQUIRE_DATA(dir, "euroc_V1_01_piece");
  Camera cam = Camera::pinhole(752, 480, 458.654, 457.296, 367.215, 248.375);
  cam.distortion_model = DistortionModel::kRadTan;
  cam.distortion = {-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05};
  std::ifstream csv(dir / "mav0/cam0/data.csv");
  std::string line;
  Initializer init;
  int frames = 0, static_refusals = 0;
  while (std::getline(csv, line)) {
    if (line.empty() || line[0] == '#') continue;
    const std::string file = line.substr(line.find(',') + 1);
    const cv::Mat img = cv::imread(
        (dir / "mav0/cam0/data" / file.substr(0, file.find_last_not_of("\r\n ") + 1)).string(), cv::IMREAD_GRAYSCALE);
    ASSERT_FALSE(img.empty()) << file;
    const InitializationResult r = init.addFrame(extractFrame(img, cam, {}, static_cast<uint64_t>(frames)));
    EXPECT_FALSE(r.success) << "initialised a map from a static camera at frame " << frames;
    if (frames > 0) {
      EXPECT_FALSE(r.reason.empty());
      static_refusals += r.reason.find("static") != std::string::npos;
    }
    ++frames;
  }
  EXPECT_EQ(frames, 48);
  EXPECT_GT(static_refusals, 40);
}

cv::Mat tsukubaFrame0() {
  return cv::imread((test::dataDir() / "new_tsukuba_150/images/rgb_00000.png").string(), cv::IMREAD_GRAYSCALE);
}

TEST(Initializer, RefusesPureRotation) {
  NERFSLAM_REQUIRE_DATA(dir, "new_tsukuba_150");
  const cv::Mat img = tsukubaFrame0();
  ASSERT_FALSE(img.empty());
  const Camera cam = Camera::pinhole(640, 480, 615, 615, 320, 240);
  const Eigen::Matrix3d K = cam.K();
  Initializer init;
  InitializationResult r = init.addFrame(extractFrame(img, cam, {}, 0));
  for (int i = 1; i <= 8; ++i) {  // up to 8 degrees of yaw + some roll, no translation
    const Eigen::Matrix3d R = (Eigen::AngleAxisd(i * M_PI / 180, Eigen::Vector3d::UnitY()) *
                               Eigen::AngleAxisd(0.3 * i * M_PI / 180, Eigen::Vector3d::UnitZ()))
                                  .toRotationMatrix();
    const Eigen::Matrix3d H = K * R * K.inverse();
    cv::Mat Hcv(3, 3, CV_64F), warped;
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b) Hcv.at<double>(a, b) = H(a, b);
    cv::warpPerspective(img, warped, Hcv, img.size(), cv::INTER_LINEAR);
    r = init.addFrame(extractFrame(warped, cam, {}, static_cast<uint64_t>(i)));
    EXPECT_FALSE(r.success) << "frame " << i;
  }
  EXPECT_EQ(r.model, "homography");
  EXPECT_NE(r.reason.find("pure rotation"), std::string::npos) << r.reason;
  EXPECT_GT(r.median_flow_px, 50);  // a large image motion, yet no parallax
  std::printf("pure rotation: %s\n", r.reason.c_str());
}

TEST(Initializer, PlanarSceneUsesHomographyAndRecoversMotion) {
  NERFSLAM_REQUIRE_DATA(dir, "new_tsukuba_150");
  const cv::Mat img = tsukubaFrame0();
  ASSERT_FALSE(img.empty());
  const Camera cam = Camera::pinhole(640, 480, 615, 615, 320, 240);
  const Eigen::Matrix3d K = cam.K();
  // The image as a textured plane n^T X = d in front of the camera, seen after a motion (R, t).
  const Eigen::Vector3d n = Eigen::Vector3d(0.1, -0.2, 1).normalized();
  const double d = 1.0;
  Initializer init;
  InitializationResult r = init.addFrame(extractFrame(img, cam, {}, 0));
  RelativePose truth;
  for (int i = 1; i <= 6 && !r.success; ++i) {
    truth.R = Eigen::AngleAxisd(-0.6 * i * M_PI / 180, Eigen::Vector3d::UnitY()).toRotationMatrix();
    truth.t = Eigen::Vector3d(0.025 * i, 0.004 * i, 0.01 * i);
    const Eigen::Matrix3d H = K * (truth.R + truth.t * n.transpose() / d) * K.inverse();
    cv::Mat Hcv(3, 3, CV_64F), warped;
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b) Hcv.at<double>(a, b) = H(a, b);
    cv::warpPerspective(img, warped, Hcv, img.size(), cv::INTER_LINEAR);
    r = init.addFrame(extractFrame(warped, cam, {}, static_cast<uint64_t>(i)));
  }
  ASSERT_TRUE(r.success) << r.reason;
  EXPECT_EQ(r.model, "homography");
  // T_world_cur = T_cur_ref^-1 with X_cur = R X_ref + t.
  expectMatchesGroundTruth(r, SE3(truth.R, truth.t).inverse(), 0.5, 3.0);
}

// The real front-end path: initialise, hand the initial points to the tracker as its map, track
// the next frames; positions (scaled by the initialisation's scale) against ground truth.
TEST(Initializer, TsukubaInitialMapTracksFollowingFrames) {
  NERFSLAM_REQUIRE_DATA(dir, "new_tsukuba_150");
  const auto gt = readTsukubaPoses(dir / "cam_traj_truth.txt");
  const Camera cam = Camera::pinhole(640, 480, 615, 615, 320, 240);
  auto load = [&](int i) {
    char name[32];
    std::snprintf(name, sizeof(name), "images/rgb_%05d.png", i);
    return extractFrame(cv::imread((dir / name).string(), cv::IMREAD_GRAYSCALE), cam, {}, static_cast<uint64_t>(i));
  };
  Initializer init;
  InitializationResult r;
  int i = 0;
  for (; i <= 30 && !r.success; ++i) r = init.addFrame(load(i));
  ASSERT_TRUE(r.success) << r.reason;
  std::vector<TrackingMapPoint> map;
  for (size_t k = 0; k < r.points.size(); ++k) {
    TrackingMapPoint p;
    p.id = k;
    p.p_world = r.points[k].p_world;
    p.descriptor = init.reference().descriptors.row(r.points[k].ref_feature).clone();
    p.angle = init.reference().keypoints[static_cast<size_t>(r.points[k].ref_feature)].angle;
    map.push_back(p);
  }
  const SE3 T_gt_ref = gt[r.ref_frame_id];
  const double scale = (gt[r.cur_frame_id].translation() - T_gt_ref.translation()).norm() /
                       r.T_world_cur.translation().norm();  // metres per map unit
  Tracker tracker;
  tracker.setPose(r.T_world_cur);
  const int last = i + 15;
  double max_err = 0, max_rot = 0;
  for (; i <= last; ++i) {
    const TrackingResult t = tracker.track(load(i), map);
    ASSERT_NE(t.quality, TrackingQuality::kLost) << "frame " << i << ": " << t.message;
    const SE3 T_gt = T_gt_ref.inverse() * gt[static_cast<size_t>(i)];
    max_err = std::max(max_err, (t.T_world_cam.translation() * scale - T_gt.translation()).norm());
    max_rot = std::max(max_rot, rotDeg(t.T_world_cam.rotationMatrix(), T_gt.rotationMatrix()));
  }
  const double travelled = (gt[static_cast<size_t>(last)].translation() - T_gt_ref.translation()).norm();
  std::printf("tracked to frame %d: %.3f m travelled, max position error %.4f m, max rotation error %.3f deg\n", last,
              travelled, max_err, max_rot);
  EXPECT_LT(max_err, 0.1 * travelled);
  EXPECT_LT(max_rot, 1.0);
}

}  // namespace
}  // namespace nerfslam
