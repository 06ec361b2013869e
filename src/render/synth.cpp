#include "nerfslam/render/synth.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <deque>
#include <exception>
#include <mutex>
#include <random>
#include <thread>

#include <fmt/format.h>

#include <spdlog/spdlog.h>
#include <nlohmann/json.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include "nerfslam/render/scene.h"

#include "nerfslam/core/atomic_file.h"
#include "nerfslam/core/error.h"
#include "nerfslam/io/image_io.h"

namespace nerfslam {
namespace fs = std::filesystem;

namespace {

uint64_t synthSeed(uint64_t a, uint64_t b) { return mixSeed(a, b, 0x2545F4914F6CDD1Dull); }

std::string listNames(const std::vector<std::string>& v) {
  std::string s;
  for (const auto& n : v) s += (s.empty() ? "" : ", ") + n;
  return s;
}

constexpr int kWriterThreads = 4;

std::string stampName(double t) { return fmt::format("{:.6f}", t); }

}  // namespace

void SynthOptions::validate() const {
  const auto& sn = sceneNames();
  if (std::find(sn.begin(), sn.end(), scene) == sn.end())
    fail("unknown scene '{}' (valid scenes: {})", scene, listNames(sn));
  const auto& tn = trajectoryNames();
  if (!trajectory.empty() && std::find(tn.begin(), tn.end(), trajectory) == tn.end())
    fail("unknown trajectory '{}' (valid trajectories: {})", trajectory, listNames(tn));
  if (frames < 1) fail("frames must be >= 1 (got {})", frames);
  if (frames > 1000000) fail("frames must be <= 1000000 (got {})", frames);
  if (laps < 1 || laps > 10000) fail("laps must be in 1..10000 (got {})", laps);
  if (laps > 1) {
    const std::string t = trajectory.empty() ? defaultTrajectory(scene) : trajectory;
    if (!trajectoryHasLaps(t)) fail("laps: trajectory '{}' has no laps (only loop has)", t);
    if ((frames - 1) % laps != 0)
      fail("laps: {} frames do not split into {} equal laps (frames - 1 must be a multiple of the laps, e.g. {})",
           frames, laps, ((frames - 1) / laps) * laps + 1);
  }
  if (!(fps > 0) || !std::isfinite(fps) || fps > 10000) fail("fps must be in (0, 10000] (got {})", fps);
  if (camera_yaml.empty() && (width < 1 || height < 1 || width > 8192 || height > 8192))
    fail("image size {}x{} invalid: width and height must be in 1..8192", width, height);
  if (!distortion.empty() && distortion.size() != 4)
    fail("distortion needs 4 coefficients k1,k2,p1,p2 (got {})", distortion.size());
  for (double d : distortion)
    if (!std::isfinite(d) || std::abs(d) > 10) fail("distortion coefficient {} out of range [-10, 10]", d);
  if (blur_samples < 2 || blur_samples > 64) fail("blur_samples must be in 2..64 (got {})", blur_samples);
  if (!(shutter > 0) || shutter > 1) fail("shutter must be in (0, 1] (got {})", shutter);
  if (!(noise_sigma >= 0) || noise_sigma > 100) fail("noise sigma must be in [0, 100] (got {})", noise_sigma);
  if (!(shot_noise >= 0) || shot_noise > 100) fail("shot noise must be in [0, 100] (got {})", shot_noise);
  if (index_every < 1) fail("index_every must be >= 1");
  parseTextureFilter(texture_filter);
  if (queue_size < 1) fail("queue_size must be >= 1");
  odometry.validate();
}

SE3 SynthOdometry::defaultBaseToCamera() {
  Eigen::Matrix3d R;  // columns: the camera's x (right), y (down), z (forward) in the base frame
  R << 0, 0, 1, -1, 0, 0, 0, -1, 0;
  return SE3(R, Eigen::Vector3d(0.1, 0.0, 0.5));
}

void SynthOdometry::validate() const {
  if (!(noise >= 0) || noise > 1) fail("odometry noise must be in [0, 1] (got {})", noise);
  if (!(rot_noise >= 0) || rot_noise > 1) fail("odometry rotation noise must be in [0, 1] (got {})", rot_noise);
  if (!(bias > -0.5) || bias > 0.5) fail("odometry bias must be in (-0.5, 0.5] (got {})", bias);
  if (!(slip >= 0) || slip > 1) fail("odometry slip must be in [0, 1] (got {})", slip);
  if (!(slip_seconds > 0) || slip_seconds > 3600)
    fail("odometry slip episodes must last (0, 3600] s (got {})", slip_seconds);
  if (!(slip_gain >= -1) || slip_gain > 10) fail("odometry slip gain must be in [-1, 10] (got {})", slip_gain);
  if (!T_base_cam.translation().allFinite() || !T_base_cam.rotation().coeffs().allFinite())
    fail("odometry extrinsic T_base_cam is not finite");
}

std::vector<SE3> synthOdometry(const std::vector<SE3>& T_world_cam, const SynthOdometry& o, uint64_t seed, double fps) {
  o.validate();
  if (!(fps > 0) || !std::isfinite(fps)) fail("odometry: fps must be > 0 (got {})", fps);
  const int slip_frames = std::max(1, static_cast<int>(std::lround(o.slip_seconds * fps)));
  int slip_left = 0;
  std::vector<SE3> out;
  if (T_world_cam.empty()) return out;
  const SE3 T_cam_base = o.T_base_cam.inverse();
  std::mt19937_64 rng(synthSeed(seed, 4242));
  std::normal_distribution<double> gauss(0.0, 1.0);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  const auto randn3 = [&] {
    const double x = gauss(rng), y = gauss(rng), z = gauss(rng);
    return Eigen::Vector3d(x, y, z);
  };
  out.reserve(T_world_cam.size());
  out.push_back(SE3());
  SE3 prev_base = T_world_cam[0] * T_cam_base;
  for (size_t i = 1; i < T_world_cam.size(); ++i) {
    const SE3 base = T_world_cam[i] * T_cam_base;
    const SE3 D = prev_base.inverse() * base;  // the true step in the previous base frame
    prev_base = base;
    // Every draw is made whatever the settings, so one setting changes nothing but its own term.
    const Eigen::Vector3d n = randn3(), m = randn3();
    // Slip in episodes of slip_frames steps, started so that a fraction `slip` of the steps slips.
    const double u = unit(rng);
    if (slip_left == 0 && o.slip > 0 && o.slip < 1 && u < o.slip / (slip_frames * (1.0 - o.slip) + o.slip))
      slip_left = slip_frames;
    const bool slipping = o.slip >= 1 || slip_left > 0;
    if (slip_left > 0) --slip_left;
    const Eigen::Vector3d& t = D.translation();
    Eigen::Vector3d tn =
        (1.0 + o.bias) * (slipping ? 1.0 + o.slip_gain : 1.0) * t + o.noise / std::sqrt(3.0) * t.norm() * n;
    Eigen::Quaterniond q = D.rotation();
    const double angle = Eigen::AngleAxisd(q).angle();
    if (o.rot_noise > 0 && angle > 0) {
      Vector6d xi = Vector6d::Zero();
      xi.tail<3>() = o.rot_noise / std::sqrt(3.0) * angle * m;
      q = q * SE3::exp(xi).rotation();
    }
    if (o.noise == 0 && o.bias == 0 && !(slipping && o.slip_gain != 0)) tn = t;  // exact: no arithmetic noise
    out.push_back(out.back() * SE3(q, tn));
  }
  if (o.noise == 0 && o.rot_noise == 0 && o.bias == 0 && (o.slip == 0 || o.slip_gain == 0)) {
    // Exact odometry: the true poses relative to the first base pose (no accumulated rounding).
    const SE3 inv0 = (T_world_cam[0] * T_cam_base).inverse();
    for (size_t i = 0; i < T_world_cam.size(); ++i) out[i] = inv0 * (T_world_cam[i] * T_cam_base);
  }
  return out;
}

Camera synthCamera(const SynthOptions& o) {
  Camera c;
  if (!o.camera_yaml.empty()) {
    c = loadCameraYaml(o.camera_yaml);
    if (c.distortion_model == DistortionModel::kEquidistant)
      fail("{}: synthetic rendering supports pinhole and radtan cameras, not equidistant", o.camera_yaml.string());
  } else {
    c.width = o.width;
    c.height = o.height;
    c.fx = 525.0 * o.width / 640.0;
    c.fy = 525.0 * o.height / 480.0;
    c.cx = (319.5 + 0.5) * o.width / 640.0 - 0.5;
    c.cy = (239.5 + 0.5) * o.height / 480.0 - 0.5;
  }
  if (!o.distortion.empty()) {
    const bool any = std::any_of(o.distortion.begin(), o.distortion.end(), [](double d) { return d != 0; });
    c.distortion_model = any ? DistortionModel::kRadTan : DistortionModel::kNone;
    c.distortion = any ? o.distortion : std::vector<double>{};
  }
  if (c.width > 8192 || c.height > 8192) fail("image size {}x{} invalid: at most 8192", c.width, c.height);
  c.validate("synthetic camera");
  return c;
}

cv::Mat depthToTum16(const cv::Mat& depth_m) {
  CV_Assert(depth_m.type() == CV_32F);
  cv::Mat out(depth_m.size(), CV_16U);
  for (int y = 0; y < depth_m.rows; ++y) {
    const float* d = depth_m.ptr<float>(y);
    uint16_t* o = out.ptr<uint16_t>(y);
    for (int x = 0; x < depth_m.cols; ++x) {
      const double v = std::round(static_cast<double>(d[x]) * 5000.0);
      o[x] = (d[x] > 0 && v <= 65535.0) ? static_cast<uint16_t>(v) : 0;
    }
  }
  return out;
}

struct SequenceRenderer::Impl {
  SynthOptions opts;
  Camera camera;         // output camera (maybe distorted)
  Camera render_cam;     // ideal pinhole that is rendered
  cv::Mat map_x, map_y;  // distorted output pixel -> render_cam pixel (empty: no distortion)
  Scene scene;
  CameraTrajectory traj;
  Renderer renderer;
  double exp_phase[3] = {0, 0, 0};

  explicit Impl(const SynthOptions& o) : opts(o) {
    opts.validate();
    camera = synthCamera(opts);
    SynthSceneOptions so;
    so.name = opts.scene;
    so.seed = opts.seed;
    so.textures = opts.textures;
    so.data_dir = opts.data_dir;
    scene = makeScene(so);
    const std::string tname = opts.trajectory.empty() ? defaultTrajectory(opts.scene) : opts.trajectory;
    traj = makeTrajectory(scene, tname, std::max(1, opts.frames - 1) / opts.fps, opts.seed, opts.laps);
    renderer.setTextureFilter(parseTextureFilter(opts.texture_filter));
    uploadScene(scene, renderer);
    render_cam = camera.undistorted();
    if (camera.hasDistortion()) setupDistortion();
    cv::RNG rng(synthSeed(opts.seed, 777));
    for (double& p : exp_phase) p = rng.uniform(0.0, 2 * M_PI);
  }

  void setupDistortion() {
    const int w = camera.width, h = camera.height;
    std::vector<cv::Point2d> px(static_cast<size_t>(w) * h), ideal;
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) px[static_cast<size_t>(y) * w + x] = cv::Point2d(x, y);
    cv::undistortPoints(px, ideal, camera.cvK(), camera.cvDist(), cv::noArray(), camera.cvK());
    double x0 = 1e18, y0 = 1e18, x1 = -1e18, y1 = -1e18;
    for (const auto& p : ideal) {
      if (!std::isfinite(p.x) || !std::isfinite(p.y)) fail("distortion coefficients do not invert over the image");
      x0 = std::min(x0, p.x), y0 = std::min(y0, p.y), x1 = std::max(x1, p.x), y1 = std::max(y1, p.y);
    }
    const int ox = static_cast<int>(std::floor(x0)) - 2, oy = static_cast<int>(std::floor(y0)) - 2;
    const int rw = static_cast<int>(std::ceil(x1)) + 3 - ox, rh = static_cast<int>(std::ceil(y1)) + 3 - oy;
    if (rw > 8192 || rh > 8192)
      fail("distortion too strong: the ideal render would need {}x{} pixels (max 8192)", rw, rh);
    render_cam.width = rw;
    render_cam.height = rh;
    render_cam.cx = camera.cx - ox;
    render_cam.cy = camera.cy - oy;
    map_x.create(h, w, CV_32F);
    map_y.create(h, w, CV_32F);
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        const auto& p = ideal[static_cast<size_t>(y) * w + x];
        map_x.at<float>(y, x) = static_cast<float>(p.x - ox);
        map_y.at<float>(y, x) = static_cast<float>(p.y - oy);
      }
  }

  double gain(double t) const {
    if (!opts.exposure_change) return 1.0;
    const double g = 0.5 * std::sin(2 * M_PI * 0.11 * t + exp_phase[0]) +
                     0.3 * std::sin(2 * M_PI * 0.23 * t + exp_phase[1]) +
                     0.2 * std::sin(2 * M_PI * 0.05 * t + exp_phase[2]);
    return 1.0 + 0.3 * g;
  }
};

SequenceRenderer::SequenceRenderer(const SynthOptions& opts) : impl_(std::make_unique<Impl>(opts)) {}
SequenceRenderer::~SequenceRenderer() = default;
const Camera& SequenceRenderer::camera() const { return impl_->camera; }
const Scene& SequenceRenderer::scene() const { return impl_->scene; }
const CameraTrajectory& SequenceRenderer::trajectory() const { return impl_->traj; }
double SequenceRenderer::timestamp(int i) const { return i / impl_->opts.fps; }
SE3 SequenceRenderer::pose(int i) const { return impl_->traj.pose(timestamp(i)); }

SynthFrame SequenceRenderer::render(int i) {
  Impl& I = *impl_;
  SynthFrame f;
  f.index = i;
  f.timestamp = timestamp(i);
  f.T_world_cam = I.traj.pose(f.timestamp);
  cv::Mat bgr, depth;
  I.renderer.render(I.render_cam, f.T_world_cam, &bgr, &depth);
  const bool post = I.opts.motion_blur || I.opts.exposure_change || I.opts.noise_sigma > 0 || I.opts.shot_noise > 0;
  if (post) {
    cv::Mat acc;
    bgr.convertTo(acc, CV_32FC3);
    if (I.opts.motion_blur) {
      const int n = I.opts.blur_samples;
      cv::Mat sub;
      for (int k = 0; k < n; ++k) {
        const double tk = f.timestamp + I.opts.shutter / I.opts.fps * (static_cast<double>(k) / (n - 1) - 0.5);
        if (std::abs(tk - f.timestamp) < 1e-12) continue;  // the centre sample is `bgr`
        I.renderer.render(I.render_cam, I.traj.pose(tk), &sub, nullptr);
        cv::accumulate(sub, acc);
      }
      const int used = (n % 2 == 1) ? n : n + 1;
      acc /= static_cast<double>(used);
    }
    acc *= I.gain(f.timestamp);
    if (I.opts.noise_sigma > 0 || I.opts.shot_noise > 0) {
      cv::RNG rng(synthSeed(I.opts.seed, 1000003ull + static_cast<uint64_t>(i)));
      const float s2 = static_cast<float>(I.opts.noise_sigma * I.opts.noise_sigma),
                  k = static_cast<float>(I.opts.shot_noise);
      for (int y = 0; y < acc.rows; ++y) {
        float* p = acc.ptr<float>(y);
        for (int x = 0; x < acc.cols * 3; ++x) {
          const float v = std::max(0.f, p[x]);
          p[x] = v + static_cast<float>(rng.gaussian(std::sqrt(s2 + k * v)));
        }
      }
    }
    acc.convertTo(bgr, CV_8UC3);  // saturating
  }
  if (!I.map_x.empty()) {
    cv::remap(bgr, f.bgr, I.map_x, I.map_y, cv::INTER_LINEAR, cv::BORDER_REPLICATE);
    cv::remap(depth, f.depth, I.map_x, I.map_y, cv::INTER_NEAREST, cv::BORDER_CONSTANT, 0);
  } else {
    f.bgr = bgr;
    f.depth = depth;
  }
  return f;
}

namespace {

struct Job {
  int index;
  cv::Mat bgr;
  cv::Mat depth16;
};

class IndexWriter {
 public:
  IndexWriter(fs::path out, const Camera& cam, const Scene& scene, std::vector<double> stamps, std::vector<SE3> poses,
              std::vector<SE3> odometry, std::string odometry_header, std::string header)
      : out_(std::move(out)),
        cam_(cam),
        scene_bbox_min_(scene.bbox_min),
        scene_bbox_max_(scene.bbox_max),
        stamps_(std::move(stamps)),
        poses_(std::move(poses)),
        odometry_(std::move(odometry)),
        odometry_header_(std::move(odometry_header)),
        header_(std::move(header)) {}

  void write(int n) const {
    // Images are complete for frames 0..n-1. Write the indices atomically.
    std::string rgb = "# color images\n# " + header_ + "\n# timestamp filename\n";
    std::string depth = "# depth maps (16-bit, metres x 5000, 0 = no depth)\n# " + header_ + "\n# timestamp filename\n";
    std::string gt = "# ground truth trajectory (T_world_cam, OpenCV optical axes)\n# " + header_ +
                     "\n# timestamp tx ty tz qx qy qz qw\n";
    std::string odom = "# simulated wheel odometry (T_odom_base)\n# " + header_ + "\n# " + odometry_header_ +
                       "\n# timestamp tx ty tz qx qy qz qw\n";
    nlohmann::json frames = nlohmann::json::array();
    for (int i = 0; i < n; ++i) {
      const std::string s = stampName(stamps_[i]);
      if (!odometry_.empty()) {
        const auto& oq = odometry_[i].rotation();
        const auto& ot = odometry_[i].translation();
        odom += fmt::format("{} {:.17g} {:.17g} {:.17g} {:.17g} {:.17g} {:.17g} {:.17g}\n", s, ot.x(), ot.y(), ot.z(),
                            oq.x(), oq.y(), oq.z(), oq.w());
      }
      rgb += fmt::format("{} rgb/{}.png\n", s, s);
      depth += fmt::format("{} depth/{}.png\n", s, s);
      const auto& q = poses_[i].rotation();
      const auto& t = poses_[i].translation();
      gt += fmt::format("{} {:.17g} {:.17g} {:.17g} {:.17g} {:.17g} {:.17g} {:.17g}\n", s, t.x(), t.y(), t.z(), q.x(),
                        q.y(), q.z(), q.w());
      Eigen::Matrix4d M = poses_[i].matrix();
      M.col(1) *= -1.0;  // OpenCV -> OpenGL camera axes: T * diag(1, -1, -1, 1)
      M.col(2) *= -1.0;
      nlohmann::json rows = nlohmann::json::array();
      for (int r = 0; r < 4; ++r) rows.push_back({M(r, 0), M(r, 1), M(r, 2), M(r, 3)});
      frames.push_back({{"file_path", "rgb/" + s + ".png"},
                        {"depth_path", "depth/" + s + ".png"},
                        {"timestamp", stamps_[i]},
                        {"transform_matrix", rows}});
    }
    writeStringAtomic(out_ / "rgb.txt", rgb);
    writeStringAtomic(out_ / "depth.txt", depth);
    writeStringAtomic(out_ / "groundtruth.txt", gt);
    if (!odometry_.empty()) writeStringAtomic(out_ / "odometry.txt", odom);
    writeStringAtomic(out_ / "transforms.json", transformsJson(frames).dump(2) + "\n");
  }

 private:
  nlohmann::json transformsJson(const nlohmann::json& frames) const {
    nlohmann::json j;
    const Eigen::Vector3d c = 0.5 * (scene_bbox_min_ + scene_bbox_max_);
    const double extent = (scene_bbox_max_ - scene_bbox_min_).maxCoeff();
    // The scene box (with 10% margin) maps into the unit cube: x_ngp = scale * x + offset.
    const double scale = 1.0 / (1.1 * extent);
    j["camera_angle_x"] = 2.0 * std::atan(0.5 * cam_.width / cam_.fx);
    j["camera_angle_y"] = 2.0 * std::atan(0.5 * cam_.height / cam_.fy);
    j["fl_x"] = cam_.fx;
    j["fl_y"] = cam_.fy;
    j["cx"] = cam_.cx + 0.5;  // instant-ngp: pixel corners at integers
    j["cy"] = cam_.cy + 0.5;
    j["w"] = cam_.width;
    j["h"] = cam_.height;
    const auto d = [&](size_t k) { return k < cam_.distortion.size() ? cam_.distortion[k] : 0.0; };
    j["k1"] = d(0);
    j["k2"] = d(1);
    j["p1"] = d(2);
    j["p2"] = d(3);
    j["aabb_scale"] = 1;
    j["scale"] = scale;
    j["offset"] = {0.5 - scale * c.x(), 0.5 - scale * c.y(), 0.5 - scale * c.z()};
    j["scene_aabb_min"] = {scene_bbox_min_.x(), scene_bbox_min_.y(), scene_bbox_min_.z()};
    j["scene_aabb_max"] = {scene_bbox_max_.x(), scene_bbox_max_.y(), scene_bbox_max_.z()};
    j["integer_depth_scale"] = 1.0 / 5000.0;
    j["frames"] = frames;
    return j;
  }

  fs::path out_;
  Camera cam_;
  Eigen::Vector3d scene_bbox_min_, scene_bbox_max_;
  std::vector<double> stamps_;
  std::vector<SE3> poses_;
  std::vector<SE3> odometry_;  // empty: no odometry.txt
  std::string odometry_header_;
  std::string header_;
};

}  // namespace

SynthResult writeSynthSequence(const SynthOptions& opts, const fs::path& out,
                               const std::function<void(int, int)>& progress) {
  const auto t0 = std::chrono::steady_clock::now();
  opts.validate();
  if (out.empty()) fail("no output folder given");
  const Camera cam = synthCamera(opts);  // bad camera YAML fails before anything is created
  ensureDirectory(out);
  ensureDirectory(out / "rgb");
  ensureDirectory(out / "depth");
  SequenceRenderer seq(opts);
  saveCameraYaml(seq.camera(), out / "camera.yaml");

  std::vector<double> stamps;
  std::vector<SE3> poses;
  for (int i = 0; i < opts.frames; ++i) {
    stamps.push_back(seq.timestamp(i));
    poses.push_back(seq.pose(i));
  }
  const std::string tname = seq.trajectory().name();
  const auto& od = opts.odometry;
  std::vector<SE3> odometry;
  std::string odometry_header;
  if (od.enabled) {
    odometry = synthOdometry(poses, od, opts.seed, opts.fps);
    const Eigen::Matrix4d E = od.T_base_cam.matrix();
    std::string e;
    for (int r = 0; r < 4; ++r)
      for (int c = 0; c < 4; ++c) e += fmt::format("{}{:.9g}", e.empty() ? "" : ", ", E(r, c));
    odometry_header =
        fmt::format("noise {} rot_noise {} bias {} slip {} slip_gain {}; T_base_cam (odometry.T_base_cam): [{}]",
                    od.noise, od.rot_noise, od.bias, od.slip, od.slip_gain, e);
  }
  const IndexWriter index(
      out, seq.camera(), seq.scene(), stamps, poses, std::move(odometry), odometry_header,
      fmt::format("nerfslam synth: scene {} trajectory {}{} seed {} {}x{} @ {} fps", opts.scene, tname,
                  opts.laps > 1 ? fmt::format(" laps {}", opts.laps) : "", opts.seed, cam.width, cam.height, opts.fps));
  index.write(0);  // a valid, empty sequence from the start

  std::mutex mu;
  std::condition_variable cv_push, cv_pop;
  std::deque<Job> queue;
  bool closed = false;
  std::exception_ptr worker_error;
  std::vector<char> done(opts.frames, 0);
  int written = 0;  // frames 0..written-1 have both PNGs committed
  std::mutex index_mu;
  int indexed = 0;

  // PNG encoding + atomic commits (each commit fsyncs) run on a few threads: the fsyncs dominate on
  // slow disks and overlap well. Frames finish out of order; the index lists the complete prefix.
  auto work = [&] {
    try {
      for (;;) {
        Job job;
        {
          std::unique_lock<std::mutex> lk(mu);
          cv_pop.wait(lk, [&] { return !queue.empty() || closed; });
          if (queue.empty()) break;
          job = std::move(queue.front());
          queue.pop_front();
        }
        cv_push.notify_one();
        const std::string s = stampName(stamps[job.index]);
        for (int k = 0; k < 2; ++k) {
          // Every write checked, atomic: a full disk is an Error naming the frame, never a cut-off PNG.
          writeImageAtomic(out / (k == 0 ? "rgb" : "depth") / (s + ".png"), k == 0 ? job.bgr : job.depth16);
        }
        int prefix;
        {
          std::lock_guard<std::mutex> lk(mu);
          done[job.index] = 1;
          while (written < opts.frames && done[written]) ++written;
          prefix = written;
        }
        {
          // `indexed` is read and written under index_mu only (a TSan finding: the check used to
          // read it unlocked while another writer thread updated it).
          std::lock_guard<std::mutex> lk(index_mu);
          if (prefix > indexed && prefix / opts.index_every > indexed / opts.index_every) {
            index.write(prefix);
            indexed = prefix;
          }
        }
      }
    } catch (...) {
      std::lock_guard<std::mutex> lk(mu);
      if (!worker_error) worker_error = std::current_exception();
      closed = true;
      queue.clear();
      cv_push.notify_all();
      cv_pop.notify_all();
    }
  };
  std::vector<std::thread> workers;
  for (int k = 0; k < kWriterThreads; ++k) workers.emplace_back(work);

  std::exception_ptr main_error;
  try {
    for (int i = 0; i < opts.frames; ++i) {
      SynthFrame f = seq.render(i);
      // The job owns its images outright (moved, not a shared cv::Mat), so the writer thread frees
      // them: a reference left here would be dropped concurrently through OpenCV's reference count,
      // which ThreadSanitizer cannot see into (uninstrumented libopencv_core).
      Job job{i, std::move(f.bgr), depthToTum16(f.depth)};
      {
        std::unique_lock<std::mutex> lk(mu);
        cv_push.wait(lk, [&] { return queue.size() < static_cast<size_t>(opts.queue_size) || worker_error; });
        if (worker_error) break;
        queue.push_back(std::move(job));
      }
      cv_pop.notify_one();
      if (progress) progress(i + 1, opts.frames);
      if ((i + 1) % 100 == 0) spdlog::info("synth: rendered {}/{} frames", i + 1, opts.frames);
    }
  } catch (...) {
    main_error = std::current_exception();
  }
  {
    std::lock_guard<std::mutex> lk(mu);
    closed = true;
  }
  cv_pop.notify_all();
  for (auto& w : workers) w.join();
  if (worker_error) std::rethrow_exception(worker_error);
  if (main_error) {
    index.write(written);
    std::rethrow_exception(main_error);
  }
  index.write(written);
  SynthResult r;
  r.frames = written;
  r.camera = seq.camera();
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return r;
}

}  // namespace nerfslam
