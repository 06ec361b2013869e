// Synthetic sequences: multi-view geometric and photometric consistency against the ground truth,
// determinism, depth encoding, the written TUM/instant-ngp layout read back by the io readers,
// distortion, trajectories and bad input.
#include <gtest/gtest.h>

#include <algorithm>
#include <fstream>
#include <sstream>

#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "nerfslam/core/error.h"
#include "nerfslam/io/dataset.h"
#include "nerfslam/io/image_io.h"
#include "nerfslam/io/trajectory.h"
#include "nerfslam/render/synth.h"
#include "test_support.h"

namespace nerfslam {
namespace {
namespace fs = std::filesystem;

SynthOptions small(const std::string& scene, const std::string& traj, int frames = 12) {
  SynthOptions o;
  o.scene = scene;
  o.trajectory = traj;
  o.frames = frames;
  o.width = 160;
  o.height = 120;
  o.textures = "procedural";
  o.seed = 7;
  return o;
}

float bilinear(const cv::Mat& g, double u, double v) {
  const int x = static_cast<int>(std::floor(u)), y = static_cast<int>(std::floor(v));
  const double a = u - x, b = v - y;
  auto at = [&](int yy, int xx) { return static_cast<double>(g.at<uchar>(yy, xx)); };
  return static_cast<float>((1 - a) * (1 - b) * at(y, x) + a * (1 - b) * at(y, x + 1) + (1 - a) * b * at(y + 1, x) +
                            a * b * at(y + 1, x + 1));
}

double median(std::vector<double> v) {
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

// Back-project frame i with its depth and GT pose, reproject into frame j: co-visible pixels agree
// in depth (geometry within a pixel) and intensity (photometry).
void checkConsistency(SequenceRenderer& seq, int i, int j) {
  const SynthFrame a = seq.render(i), b = seq.render(j);
  const Camera& cam = seq.camera();
  cv::Mat ga, gb;
  cv::cvtColor(a.bgr, ga, cv::COLOR_BGR2GRAY);
  cv::cvtColor(b.bgr, gb, cv::COLOR_BGR2GRAY);
  const SE3 T_b_a = b.T_world_cam.inverse() * a.T_world_cam;
  std::vector<double> pix_err, photo_err;
  int projected = 0;
  for (int v = 2; v < cam.height - 2; v += 2)
    for (int u = 2; u < cam.width - 2; u += 2) {
      const float z = a.depth.at<float>(v, u);
      if (z <= 0) continue;
      const Eigen::Vector3d Xa = cam.unproject({u, v}) * z;
      const Eigen::Vector3d Xb = T_b_a * Xa;
      Eigen::Vector2d p;
      if (!cam.projectInImage(Xb, &p, 2.0)) continue;
      ++projected;
      const int qu = static_cast<int>(std::lround(p.x())), qv = static_cast<int>(std::lround(p.y()));
      const float zb = b.depth.at<float>(qv, qu);
      if (zb <= 0 || std::abs(zb - Xb.z()) > 0.03 * Xb.z()) continue;  // occluded in b
      // Geometric: the surface point b sees at the nearest pixel, mapped back into a.
      const Eigen::Vector3d Yb = cam.unproject({qu, qv}) * zb;
      const Eigen::Vector2d back = cam.project(T_b_a.inverse() * Yb);
      pix_err.push_back((back - Eigen::Vector2d(u, v)).norm());
      photo_err.push_back(std::abs(bilinear(gb, p.x(), p.y()) - ga.at<uchar>(v, u)));
    }
  ASSERT_GT(projected, 500);
  ASSERT_GT(pix_err.size(), 0.6 * projected) << "too few co-visible pixels";
  EXPECT_LT(median(pix_err), 0.5);
  std::vector<double> sorted = pix_err;
  std::sort(sorted.begin(), sorted.end());
  EXPECT_LT(sorted[sorted.size() * 95 / 100], 1.0) << "95th percentile reprojection error (px)";
  EXPECT_LT(median(photo_err), 8.0) << "median |I_a - I_b| (gray levels)";
}

TEST(Synth, RoomHandheldIsGeometricallyAndPhotometricallyConsistent) {
  SequenceRenderer seq(small("room", "handheld", 30));
  checkConsistency(seq, 0, 6);
  checkConsistency(seq, 10, 29);
}

TEST(Synth, CorridorLoopAndTurntableOrbitAreConsistent) {
  // Long sequences (the loop spans the whole sequence); only a few frames are rendered.
  SequenceRenderer corridor(small("corridor", "loop", 900));
  checkConsistency(corridor, 100, 106);
  SequenceRenderer turntable(small("turntable", "orbit", 300));
  checkConsistency(turntable, 0, 8);
}

TEST(Synth, SameSeedGivesIdenticalImagesOtherSeedDiffers) {
  SynthOptions o = small("room", "handheld", 5);
  o.noise_sigma = 2.0;
  o.shot_noise = 0.2;
  o.exposure_change = true;
  SequenceRenderer a(o), b(o);
  const SynthFrame fa = a.render(4), fb = b.render(4);
  EXPECT_EQ(cv::norm(fa.bgr, fb.bgr, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(fa.depth, fb.depth, cv::NORM_INF), 0.0);
  EXPECT_TRUE(fa.T_world_cam.isApprox(fb.T_world_cam, 0));
  o.seed = 8;
  SequenceRenderer c(o);
  EXPECT_GT(cv::norm(fa.bgr, c.render(4).bgr, cv::NORM_L1), 0.0);
}

TEST(Synth, TexturesGiveCornersEverywhere) {
  SequenceRenderer seq(small("room", "handheld", 20));
  for (int i : {0, 10, 19}) {
    cv::Mat g;
    cv::cvtColor(seq.render(i).bgr, g, cv::COLOR_BGR2GRAY);
    // Every 40x40 cell of the image has intensity structure (no flat walls).
    for (int y = 0; y + 40 <= g.rows; y += 40)
      for (int x = 0; x + 40 <= g.cols; x += 40) {
        cv::Mat lap;
        cv::Laplacian(g(cv::Rect(x, y, 40, 40)), lap, CV_32F);
        cv::Scalar mean, sd;
        cv::meanStdDev(lap, mean, sd);
        EXPECT_GT(sd[0], 3.0) << "flat cell at " << x << "," << y << " in frame " << i;
      }
  }
}

TEST(Synth, DepthPngUsesTumFactor) {
  cv::Mat d = (cv::Mat_<float>(1, 6) << 0.f, 1.f, 0.0002f, 2.34567f, 13.107f, 14.f);
  const cv::Mat t = depthToTum16(d);
  ASSERT_EQ(t.type(), CV_16U);
  EXPECT_EQ(t.at<uint16_t>(0), 0);
  EXPECT_EQ(t.at<uint16_t>(1), 5000);
  EXPECT_EQ(t.at<uint16_t>(2), 1);
  EXPECT_EQ(t.at<uint16_t>(3), 11728);
  EXPECT_EQ(t.at<uint16_t>(4), 65535);
  EXPECT_EQ(t.at<uint16_t>(5), 0);  // beyond 65535 / 5000 m: no depth
}

TEST(Synth, WritesTumLayoutThatTheReadersLoad) {
  test::TempDir tmp;
  SynthOptions o = small("room", "handheld", 12);
  o.index_every = 5;
  const auto r = writeSynthSequence(o, tmp.path());
  EXPECT_EQ(r.frames, 12);
  SequenceRenderer seq(o);

  auto ds = openDataset("tum", tmp.path());
  ASSERT_EQ(ds->size(), 12u);
  EXPECT_EQ(ds->camera().width, 160);
  EXPECT_NEAR(ds->camera().fx, 131.25, 1e-12);
  EXPECT_NEAR(ds->camera().cx, 79.5, 1e-12);
  for (size_t i = 0; i < ds->size(); ++i) {
    EXPECT_NEAR(ds->timestamp(i), i / 30.0, 1e-6);
    ASSERT_TRUE(ds->groundTruth(i).has_value());
    EXPECT_TRUE(ds->groundTruth(i)->isApprox(seq.pose(static_cast<int>(i)), 1e-9));
  }
  // Images and depth as rendered (PNG is lossless; depth quantised to 0.2 mm).
  const SynthFrame f = seq.render(7);
  EXPECT_EQ(cv::norm(ds->load(7, ImageMode::kColor).image, f.bgr, cv::NORM_INF), 0.0);
  cv::Mat d16 = cv::imread((tmp.path() / "depth" / "0.233333.png").string(), cv::IMREAD_UNCHANGED);
  ASSERT_EQ(d16.type(), CV_16U);
  cv::Mat dm;
  d16.convertTo(dm, CV_32F, 1.0 / 5000);
  EXPECT_LE(cv::norm(dm, f.depth, cv::NORM_INF), 0.5 / 5000 + 1e-6);

  // transforms.json: instant-ngp conventions.
  std::ifstream jf(tmp.path() / "transforms.json");
  const auto j = nlohmann::json::parse(jf);
  EXPECT_DOUBLE_EQ(j["cx"].get<double>(), 80.0);
  EXPECT_DOUBLE_EQ(j["fl_x"].get<double>(), 131.25);
  EXPECT_EQ(j["w"].get<int>(), 160);
  ASSERT_EQ(j["frames"].size(), 12u);
  Eigen::Matrix4d M;
  for (int rr = 0; rr < 4; ++rr)
    for (int c = 0; c < 4; ++c) M(rr, c) = j["frames"][3]["transform_matrix"][rr][c].get<double>();
  const Eigen::Matrix4d expected = seq.pose(3).matrix() * Eigen::Vector4d(1, -1, -1, 1).asDiagonal();
  EXPECT_LT((M - expected).cwiseAbs().maxCoeff(), 1e-12);
  auto ngp = openDataset("transforms", tmp.path() / "transforms.json");
  ASSERT_EQ(ngp->size(), 12u);
  EXPECT_NEAR(ngp->camera().cx, 79.5, 1e-9);
  ASSERT_TRUE(ngp->groundTruth(3).has_value());
  EXPECT_TRUE(ngp->groundTruth(3)->isApprox(seq.pose(3), 1e-9));

  // odometry.txt: the simulated odometry, at the frames' timestamps.
  const Trajectory odo = readTumTrajectory(tmp.path() / "odometry.txt");
  ASSERT_EQ(odo.size(), 12u);
  std::vector<SE3> cams;
  for (int i = 0; i < 12; ++i) cams.push_back(seq.pose(i));
  const auto expected_odo = synthOdometry(cams, o.odometry, o.seed, o.fps);
  for (size_t i = 0; i < odo.size(); ++i) {
    EXPECT_NEAR(odo[i].timestamp, ds->timestamp(i), 1e-9);
    EXPECT_TRUE(odo[i].pose.isApprox(expected_odo[i], 1e-12)) << i;
  }
}

// Simulated wheel odometry: exact without noise (the base under the camera by T_base_cam, odom at
// the first base pose), and the noise, bias and slip it was asked for.
TEST(Synth, OdometryIsExactWithoutNoiseAndNoisyAsAsked) {
  SynthSceneOptions so;
  so.textures = "procedural";
  const auto traj = makeTrajectory(makeScene(so), "handheld", 20.0, 1, 1);
  std::vector<SE3> cams;
  for (int i = 0; i < 601; ++i) cams.push_back(traj.pose(i / 30.0));
  SynthOdometry exact;
  exact.noise = exact.rot_noise = 0;
  const auto odo = synthOdometry(cams, exact, 1, 30);
  ASSERT_EQ(odo.size(), cams.size());
  const SE3 Tbc = SynthOdometry::defaultBaseToCamera();
  EXPECT_TRUE(odo[0].isApprox(SE3(), 1e-15));
  // The camera looks along the base's x axis, 0.5 m above it.
  EXPECT_NEAR((Tbc.rotationMatrix() * Eigen::Vector3d::UnitZ() - Eigen::Vector3d::UnitX()).norm(), 0, 1e-12);
  EXPECT_NEAR(Tbc.translation().z(), 0.5, 1e-12);
  for (size_t i = 0; i < cams.size(); i += 37) {
    // T_world_cam = T_world_base0 T_odom_base T_base_cam
    const SE3 back = cams[0] * Tbc.inverse() * odo[i] * Tbc;
    EXPECT_TRUE(back.isApprox(cams[i], 1e-9)) << i;
  }
  // Noise: the RMS error of the frame steps' translations, relative to the step.
  const auto stepRatio = [&](const std::vector<SE3>& o, size_t i, double* rel_err) {
    const Eigen::Vector3d t_true = (odo[i - 1].inverse() * odo[i]).translation();
    const Eigen::Vector3d t = (o[i - 1].inverse() * o[i]).translation();
    if (rel_err) *rel_err = (t - t_true).norm() / t_true.norm();
    return t.norm() / t_true.norm();
  };
  SynthOdometry noisy;  // the defaults: 2 % noise
  const auto on = synthOdometry(cams, noisy, 1, 30);
  double sq = 0;
  int n = 0;
  for (size_t i = 1; i < cams.size(); ++i) {
    if ((odo[i - 1].inverse() * odo[i]).translation().norm() < 1e-4) continue;
    double e = 0;
    stepRatio(on, i, &e);
    sq += e * e;
    ++n;
  }
  ASSERT_GT(n, 500);
  EXPECT_NEAR(std::sqrt(sq / n), 0.02, 0.002);
  EXPECT_FALSE(on.back().isApprox(odo.back(), 1e-3)) << "noise must accumulate";
  SynthOdometry biased = exact;
  biased.bias = 0.05;
  const auto ob = synthOdometry(cams, biased, 1, 30);
  for (size_t i = 1; i < cams.size(); i += 50) EXPECT_NEAR(stepRatio(ob, i, nullptr), 1.05, 1e-9) << i;
  SynthOdometry slipping = exact;
  slipping.slip = 0.1;
  slipping.slip_gain = 0.5;
  const auto os = synthOdometry(cams, slipping, 1, 30);
  // Slip in episodes of 0.5 s (15 steps): 10 % of the steps in all.
  int slips = 0, episodes = 0;
  bool prev = false;
  for (size_t i = 1; i < cams.size(); ++i) {
    const double r = stepRatio(os, i, nullptr);
    EXPECT_TRUE(std::abs(r - 1) < 1e-9 || std::abs(r - 1.5) < 1e-9) << r;
    const bool slip = std::abs(r - 1.5) < 1e-9;
    slips += slip;
    episodes += slip && !prev;
    prev = slip;
  }
  EXPECT_NEAR(slips / 600.0, 0.1, 0.05);
  EXPECT_GE(episodes, 1);
  EXPECT_LE(episodes, slips / 15 + 1) << "slip comes in episodes of 15 steps";
  SynthOdometry bad;
  bad.noise = -1;
  EXPECT_THROW(synthOdometry(cams, bad, 1, 30), Error);
}

TEST(Synth, DistortedImagesMatchTheIdealCameraThroughUnproject) {
  SynthOptions o = small("room", "handheld", 3);
  SequenceRenderer ideal(o);
  o.distortion = {-0.25, 0.08, 0.001, -0.0015};
  SequenceRenderer dist(o);
  ASSERT_TRUE(dist.camera().hasDistortion());
  const SynthFrame fi = ideal.render(2), fd = dist.render(2);
  ASSERT_TRUE(fi.T_world_cam.isApprox(fd.T_world_cam, 0));
  const Camera& cd = dist.camera();
  const Camera& ci = ideal.camera();
  cv::Mat gi, gd;
  cv::cvtColor(fi.bgr, gi, cv::COLOR_BGR2GRAY);
  cv::cvtColor(fd.bgr, gd, cv::COLOR_BGR2GRAY);
  std::vector<double> dz, di;
  for (int v = 0; v < cd.height; v += 3)
    for (int u = 0; u < cd.width; u += 3) {
      const float z = fd.depth.at<float>(v, u);
      ASSERT_GT(z, 0.f);  // the room is closed: every pixel sees a surface
      const Eigen::Vector3d X = cd.unproject({u, v}) * z;
      Eigen::Vector2d p;
      if (!ci.projectInImage(X, &p, 2.0)) continue;
      const float zi = fi.depth.at<float>(static_cast<int>(std::lround(p.y())), static_cast<int>(std::lround(p.x())));
      dz.push_back(std::abs(zi - z) / z);
      di.push_back(std::abs(bilinear(gi, p.x(), p.y()) - gd.at<uchar>(v, u)));
    }
  ASSERT_GT(dz.size(), 500u);
  EXPECT_LT(median(dz), 0.01);
  EXPECT_LT(median(di), 6.0);
}

TEST(Synth, MotionBlurSmoothsAndKeepsDepth) {
  SynthOptions o = small("room", "fast", 40);
  SequenceRenderer sharp(o);
  o.motion_blur = true;
  SequenceRenderer blurred(o);
  double gs = 0, gb = 0;
  for (int i = 0; i < 40; i += 8) {
    const SynthFrame a = sharp.render(i), b = blurred.render(i);
    EXPECT_EQ(cv::norm(a.depth, b.depth, cv::NORM_INF), 0.0);
    cv::Mat ga, gbm, la, lb;
    cv::cvtColor(a.bgr, ga, cv::COLOR_BGR2GRAY);
    cv::cvtColor(b.bgr, gbm, cv::COLOR_BGR2GRAY);
    cv::Laplacian(ga, la, CV_32F);
    cv::Laplacian(gbm, lb, CV_32F);
    gs += cv::norm(la, cv::NORM_L1);
    gb += cv::norm(lb, cv::NORM_L1);
  }
  EXPECT_LT(gb, 0.95 * gs) << "blur must remove high-frequency energy";
}

TEST(Synth, NoiseHasTheRequestedSigma) {
  SynthOptions o = small("plane", "rotation", 2);
  SequenceRenderer clean(o);
  o.noise_sigma = 4.0;
  SequenceRenderer noisy(o);
  cv::Mat a, b, d;
  clean.render(1).bgr.convertTo(a, CV_32F);
  noisy.render(1).bgr.convertTo(b, CV_32F);
  d = b - a;
  // Ignore saturated pixels (clamped noise).
  cv::Mat mask = (a > 20) & (a < 235);
  cv::Scalar mean, sd;
  cv::meanStdDev(d.reshape(1), mean, sd, mask.reshape(1));
  EXPECT_NEAR(sd[0], 4.0, 0.35);  // rounding to 8 bit adds 1/12 variance
  EXPECT_NEAR(mean[0], 0.0, 0.2);
}

TEST(Trajectories, LoopClosesRotationKeepsCentreHandheldStaysInside) {
  SynthSceneOptions so;
  so.textures = "procedural";
  so.texture_size = 32;
  for (const std::string& scene : sceneNames()) {
    so.name = scene;
    const Scene sc = makeScene(so);
    const CameraTrajectory loop = makeTrajectory(sc, "loop", 10.0, 3);
    EXPECT_TRUE(loop.pose(0).isApprox(loop.pose(10.0), 1e-9)) << scene;
    EXPECT_GT((loop.pose(0).translation() - loop.pose(5.0).translation()).norm(), 0.5) << scene;
    const CameraTrajectory rot = makeTrajectory(sc, "rotation", 10.0, 3);
    for (double t = 0; t < 10; t += 0.7) {
      EXPECT_LT((rot.pose(t).translation() - rot.pose(0).translation()).norm(), 1e-12);
    }
    EXPECT_GT(rot.pose(0).rotation().angularDistance(rot.pose(3.3).rotation()), 0.02) << scene;
    for (const std::string& name : trajectoryNames()) {
      const CameraTrajectory t = makeTrajectory(sc, name, 20.0, 5);
      for (double s = 0; s <= 20.0; s += 0.25) {
        const Eigen::Vector3d c = t.pose(s).translation();
        EXPECT_TRUE(((c.array() >= sc.camera_min.array() - 0.35) && (c.array() <= sc.camera_max.array() + 0.35)).all())
            << scene << "/" << name << " t=" << s << " camera at " << c.transpose();
        if (scene == "corridor") {  // never inside the inner block
          EXPECT_TRUE(std::abs(c.x()) > 4.2 || std::abs(c.y()) > 2.2) << name << " t=" << s << " " << c.transpose();
        }
        // Upright camera: image y axis points downwards in the world.
        EXPECT_GT(t.pose(s).rotationMatrix().col(1).dot(-Eigen::Vector3d::UnitZ()), 0.5) << scene << "/" << name;
      }
      // Determinism.
      EXPECT_TRUE(t.pose(7.7).isApprox(makeTrajectory(sc, name, 20.0, 5).pose(7.7), 0));
    }
  }
  // Handheld in the room covers a few metres over 600 frames at 30 fps.
  so.name = "room";
  const CameraTrajectory h = makeTrajectory(makeScene(so), "handheld", 599 / 30.0, 1);
  double len = 0;
  for (int i = 1; i < 600; ++i) len += (h.pose(i / 30.0).translation() - h.pose((i - 1) / 30.0).translation()).norm();
  EXPECT_GT(len, 2.0);
  EXPECT_LT(len, 20.0);
}

TEST(Synth, BadNamesListTheValidOnes) {
  SynthSceneOptions so;
  so.name = "kitchen";
  try {
    makeScene(so);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("room, turntable, plane, corridor"), std::string::npos) << e.what();
  }
  SynthOptions o = small("room", "zigzag");
  try {
    o.validate();
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("handheld, orbit, forward, rotation, fast, loop"), std::string::npos);
  }
  o = small("room", "handheld", 0);
  EXPECT_THROW(o.validate(), Error);
  o = small("room", "handheld");
  o.width = 0;
  EXPECT_THROW(o.validate(), Error);
  o.width = 9000;
  EXPECT_THROW(o.validate(), Error);
  o.width = 160;
  o.fps = -1;
  EXPECT_THROW(o.validate(), Error);
  o = small("room", "handheld");
  o.texture_filter = "anisotropic";
  try {
    o.validate();
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("trilinear, mip-nearest"), std::string::npos) << e.what();
  }
}

// The two texture filters see the same scene: the images differ only where a texture is minified
// (measured 45 dB PSNR on the 640x480 room), never in geometry (depth identical).
TEST(Synth, TextureFiltersDifferOnlyInTexturing) {
  SynthOptions a = small("room", "handheld");
  SynthOptions b = a;
  b.texture_filter = "mip-nearest";
  SequenceRenderer ra(a), rb(b);
  for (int i : {0, 5}) {
    const SynthFrame fa = ra.render(i), fb = rb.render(i);
    EXPECT_EQ(cv::norm(fa.depth, fb.depth, cv::NORM_INF), 0.0) << "frame " << i;
    const double psnr = cv::PSNR(fa.bgr, fb.bgr);
    EXPECT_GT(psnr, 35.0) << "frame " << i;
    EXPECT_LT(psnr, 100.0) << "frame " << i << ": the filters gave identical images";
  }
}

TEST(Synth, UnwritableOutputFailsCleanly) {
  test::TempDir tmp;
  { std::ofstream(tmp / "file") << "x"; }
  EXPECT_THROW(writeSynthSequence(small("plane", "rotation", 2), tmp / "file" / "seq"), Error);
}

// Second column of every data line of a TUM index file (rgb.txt, depth.txt); empty when absent.
std::vector<std::string> indexedFiles(const fs::path& index) {
  std::vector<std::string> files;
  std::ifstream is(index);
  std::string line;
  while (std::getline(is, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream ls(line);
    std::string stamp, file;
    ls >> stamp >> file;
    files.push_back(file);
  }
  return files;
}

TEST(SynthCli, KilledHalfWayNeverIndexesFramesNotWritten) {
  if (!fs::exists(test::cliPath())) GTEST_SKIP() << "nerfslam binary not built";
  test::TempDir tmp;
  size_t partial_runs = 0;
  for (const char* after : {"2", "4", "6"}) {
    const fs::path out = tmp / (std::string("seq") + after);
    // SIGKILL: no handler, no flush, no clean-up gets to run.
    const auto r = test::runCommand(std::string("timeout -s KILL ") + after + " '" + test::cliPath().string() +
                                    "' synth --scene room --frames 600 --size 640x480 --textures procedural --out '" +
                                    out.string() + "'");
    ASSERT_EQ(r.exit_code, 128 + 9) << "synth was expected to be killed after " << after << " s: " << r.output;
    size_t listed = 0;
    for (const char* index : {"rgb.txt", "depth.txt"}) {
      for (const auto& f : indexedFiles(out / index)) {
        const cv::Mat img = cv::imread((out / f).string(), cv::IMREAD_UNCHANGED);
        EXPECT_FALSE(img.empty()) << index << " names " << f << ", which is missing or unreadable after the kill";
        ++listed;
      }
    }
    if (listed > 0) ++partial_runs;
    std::printf("killed after %s s: %zu indexed images, all complete\n", after, listed);
  }
  // At least one kill landed after an index was written, so the check above saw real index files.
  EXPECT_GT(partial_runs, 0u);
}

// A full disk (a file-size limit below a frame's PNG, `ulimit -f 64` in /bin/sh's 512-byte blocks,
// SIGXFSZ ignored: a write past it fails with EFBIG as a full disk fails with ENOSPC): synth stops
// with an error naming the frame it could not write, exit 1, and leaves no temporary or cut-off PNG
// (each is written to a temporary file and renamed when complete).
TEST(SynthCli, FullDiskFailsNamingTheFrameAndLeavesNoCutOffPng) {
  if (!fs::exists(test::cliPath())) GTEST_SKIP() << "nerfslam binary not built";
  test::TempDir tmp;
  const fs::path out = tmp / "seq";
  const auto r = test::runCommand("trap '' XFSZ; ulimit -f 64; '" + test::cliPath().string() +
                                  "' synth --scene room --frames 40 --size 320x240 --textures procedural --out '" +
                                  out.string() + "'");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find(".png: write failed (disk full?)"), std::string::npos) << r.output;
  size_t pngs = 0;
  for (const char* sub : {"rgb", "depth"}) {
    if (!fs::exists(out / sub)) continue;
    for (const auto& e : fs::directory_iterator(out / sub)) {
      EXPECT_EQ(e.path().extension(), ".png") << e.path() << ": a temporary file was left";
      EXPECT_NO_THROW(readImage(e.path(), ImageMode::kUnchanged)) << e.path();
      ++pngs;
    }
  }
  std::printf("full disk: %zu complete PNGs left\n", pngs);
}

TEST(SynthCli, WritesASequenceAndRejectsBadInput) {
  if (!fs::exists(test::cliPath())) GTEST_SKIP() << "nerfslam binary not built";
  test::TempDir tmp;
  auto ok =
      test::runCli("synth --scene plane --trajectory forward --frames 4 --size 80x60 --textures procedural --out '" +
                   (tmp / "seq").string() + "'");
  ASSERT_EQ(ok.exit_code, 0) << ok.output;
  EXPECT_TRUE(fs::exists(tmp / "seq" / "rgb" / "0.100000.png"));
  EXPECT_TRUE(fs::exists(tmp / "seq" / "camera.yaml"));
  EXPECT_TRUE(fs::exists(tmp / "seq" / "odometry.txt"));
  ok = test::runCli(
      "synth --scene plane --trajectory forward --frames 3 --size 80x60 --textures procedural "
      "--no-odometry --out '" +
      (tmp / "seq2").string() + "'");
  ASSERT_EQ(ok.exit_code, 0) << ok.output;
  EXPECT_FALSE(fs::exists(tmp / "seq2" / "odometry.txt"));

  auto r = test::runCli("synth --scene kitchen --frames 3 --out '" + (tmp / "a").string() + "'");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("room, turntable, plane, corridor"), std::string::npos) << r.output;
  r = test::runCli("synth --trajectory zigzag --frames 3 --out '" + (tmp / "a").string() + "'");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("handheld, orbit"), std::string::npos) << r.output;
  for (const char* size : {"0x480", "-5x10", "9000x480", "640"}) {
    r = test::runCli(std::string("synth --frames 3 --size=") + size + " --out '" + (tmp / "a").string() + "'");
    EXPECT_EQ(r.exit_code, 1) << size;
    EXPECT_NE(r.output.find("--size"), std::string::npos) << r.output;
  }
  r = test::runCli("synth --frames 0 --out '" + (tmp / "a").string() + "'");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("frames"), std::string::npos) << r.output;
  r = test::runCli("synth --frames 3 --odometry-noise -0.1 --out '" + (tmp / "a").string() + "'");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("odometry noise must be in [0, 1]"), std::string::npos) << r.output;
  r = test::runCli("synth --distortion 0.1,x,0,0 --frames 3 --out '" + (tmp / "a").string() + "'");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_FALSE(fs::exists(tmp / "a")) << "bad input must not leave output behind";
  { std::ofstream(tmp / "file") << "x"; }
  r = test::runCli("synth --frames 3 --size 80x60 --out '" + (tmp / "file" / "seq").string() + "'");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("error"), std::string::npos) << r.output;
}

}  // namespace
}  // namespace nerfslam

namespace nerfslam {
namespace {

TEST(Synth, PhotoTexturesFromTheSharedData) {
  NERFSLAM_REQUIRE_DATA(strecha, "strecha_fountain-P11");
  SynthOptions o = small("room", "handheld", 5);
  o.textures = "photo";
  o.data_dir = test::dataDir();
  SequenceRenderer seq(o);
  EXPECT_TRUE(seq.scene().photographic);
  cv::Mat g;
  cv::cvtColor(seq.render(2).bgr, g, cv::COLOR_BGR2GRAY);
  cv::Mat lap;
  cv::Laplacian(g, lap, CV_32F);
  cv::Scalar mean, sd;
  cv::meanStdDev(lap, mean, sd);
  EXPECT_GT(sd[0], 5.0);
  o.data_dir = "/nonexistent";
  EXPECT_THROW(SequenceRenderer bad(o), Error);
}

}  // namespace
}  // namespace nerfslam
