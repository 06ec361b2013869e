// kill -9 at random points while the outputs of a run are written (issue: hardening). A child process
// (the helper test below) rewrites, in a loop, every kind of output file the system writes besides
// the map folder (map_folder_test has its own loop): a TUM trajectory, a NeRF model, a PLY and a PCD
// point cloud and a PLY mesh, alternating between two different contents A and B. The parent kills
// it with SIGKILL at random times, >= 50 times; after every kill each file must be absent (never
// written yet) or load and equal A or B exactly: a killed write never leaves a truncated file in
// place of a good one (the writers write a temporary file and rename it).
//
// The kill times follow the child, not the clock: the child appends a byte to rounds.log after every
// round of the five writes; the parent measures one round's duration, and every kill lands at a
// uniformly random moment of the two rounds after the child's first one. So the kills spread over
// every writer whatever the build's speed (Release, or ~5x slower under AddressSanitizer).
#include <gtest/gtest.h>

#include <pcl/io/pcd_io.h>
#include <pcl/io/ply_io.h>

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <random>
#include <thread>

#include <fmt/format.h>

#include "nerfslam/io/trajectory.h"
#include "nerfslam/nerf/export.h"
#include "nerfslam/nerf/model_io.h"
#include "test_support.h"

namespace nerfslam {
namespace {

namespace fs = std::filesystem;
constexpr const char* kEnv = "NERFSLAM_TEST_OUTPUT_KILL_DIR";

Trajectory trajectory(int variant) {
  Trajectory t;
  for (int i = 0; i < 2000; ++i)
    t.push_back({0.1 * i, SE3(Eigen::Quaterniond::Identity(), Eigen::Vector3d(i, variant, 0.5 * i))});
  return t;
}

nerf::NerfModel model(int variant) {
  nerf::FieldConfig c;
  c.n_levels = 8;
  c.log2_hashmap_size = 16;
  c.finest_resolution = 256;
  c.hidden = 16;
  nerf::SceneTransform scene;
  scene.aabb_scale = 1;
  nerf::NerfModel m = nerf::NerfModel::create(c, scene, uint64_t(variant) + 7);
  m.training_steps = uint64_t(variant) + 100;
  return m;
}

pcl::PointCloud<pcl::PointXYZRGB> cloud(int variant) {
  pcl::PointCloud<pcl::PointXYZRGB> c;
  for (int i = 0; i < 200000; ++i) {
    pcl::PointXYZRGB p;
    p.x = float(i);
    p.y = float(variant);
    p.z = 0.25f * float(i % 97);
    p.r = uint8_t(i);
    p.g = uint8_t(variant);
    p.b = 7;
    c.push_back(p);
  }
  return c;
}

pcl::PolygonMesh mesh(int variant) {
  pcl::PointCloud<pcl::PointXYZ> v;
  pcl::PolygonMesh m;
  for (int i = 0; i < 60000; ++i) {
    v.push_back(pcl::PointXYZ(float(i), float(variant), float(i % 13)));
    if (i >= 2) {
      pcl::Vertices f;
      f.vertices = {i - 2, i - 1, i};  // pcl::index_t is int
      m.polygons.push_back(f);
    }
  }
  pcl::toPCLPointCloud2(v, m.cloud);
  return m;
}

// What identifies a loaded file's content: 0 (A), 1 (B) or -1 (neither).
int whichTrajectory(const fs::path& p) {
  const Trajectory t = readTumTrajectory(p);
  if (t.size() != 2000) return -1;
  const int v = int(std::lround(t[5].pose.translation().y()));
  return (v == 0 || v == 1) && t.back().pose.translation().x() == 1999 ? v : -1;
}
int whichModel(const fs::path& p) {
  const nerf::NerfModel m = nerf::loadModel(p);  // checksummed: throws on any damage
  return m.training_steps == 100 ? 0 : m.training_steps == 101 ? 1 : -1;
}
int whichCloud(const fs::path& p) {
  pcl::PointCloud<pcl::PointXYZRGB> c;
  const int rc = p.extension() == ".pcd" ? pcl::io::loadPCDFile(p.string(), c) : pcl::io::loadPLYFile(p.string(), c);
  if (rc != 0 || c.size() != 200000) return -1;
  const int v = int(c[3].y);
  return (v == 0 || v == 1) && c.back().x == 199999.f && c.back().g == v ? v : -1;
}
int whichMesh(const fs::path& p) {
  pcl::PolygonMesh m;
  if (pcl::io::loadPLYFile(p.string(), m) != 0 || m.polygons.size() != 59998) return -1;
  pcl::PointCloud<pcl::PointXYZ> v;
  pcl::fromPCLPointCloud2(m.cloud, v);
  if (v.size() != 60000) return -1;
  const int variant = int(v[1].y);
  return (variant == 0 || variant == 1) && v.back().x == 59999.f ? variant : -1;
}

TEST(OutputKillHelper, WriteLoopChild) {
  const char* env = std::getenv(kEnv);
  if (!env) GTEST_SKIP() << "helper process of OutputKill.EveryWriterSurvivesSigkill";
  const fs::path dir(env);
  nerf::NerfModel models[2] = {model(0), model(1)};
  const pcl::PointCloud<pcl::PointXYZRGB> clouds[2] = {cloud(0), cloud(1)};
  const pcl::PolygonMesh meshes[2] = {mesh(0), mesh(1)};
  const Trajectory trajs[2] = {trajectory(0), trajectory(1)};
  for (uint64_t i = 0;; ++i) {
    const int v = int(i % 2);
    writeTumTrajectory(dir / "trajectory.txt", trajs[v]);
    nerf::saveModel(models[v], dir / "model.nerf");
    nerf::savePointCloud(clouds[v], dir / "cloud.ply");
    nerf::savePointCloud(clouds[v], dir / "cloud.pcd");
    nerf::saveMesh(meshes[v], dir / "mesh.ply");
    std::FILE* f = std::fopen((dir / "rounds.log").c_str(), "ab");
    if (!f) std::abort();
    std::fputc('.', f);
    std::fclose(f);
  }
}

// Rounds of writes the helper children have completed so far (bytes of rounds.log).
uint64_t roundsDone(const fs::path& dir) {
  std::error_code ec;
  const auto n = fs::file_size(dir / "rounds.log", ec);
  return ec ? 0 : uint64_t(n);
}

// Starts the helper child writing into `dir`; returns its pid.
pid_t startWriter(const fs::path& self, const fs::path& dir) {
  const pid_t pid = fork();
  if (pid == 0) {
    setenv(kEnv, dir.c_str(), 1);
    execl(self.c_str(), self.c_str(), "--gtest_filter=OutputKillHelper.WriteLoopChild", static_cast<char*>(nullptr));
    _exit(127);
  }
  return pid;
}

// Waits until the writers have completed more than `rounds` rounds; false after `timeout_s` or when
// the child `pid` ended.
bool waitForRound(const fs::path& dir, uint64_t rounds, pid_t pid, double timeout_s) {
  const auto t0 = std::chrono::steady_clock::now();
  while (roundsDone(dir) <= rounds) {
    if (waitpid(pid, nullptr, WNOHANG) == pid) return false;
    if (std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() > timeout_s) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  return true;
}

TEST(OutputKill, EveryWriterSurvivesSigkill) {
  test::TempDir tmp;
  const fs::path self = fs::read_symlink("/proc/self/exe");
  const std::vector<std::pair<std::string, int (*)(const fs::path&)>> files = {{"trajectory.txt", whichTrajectory},
                                                                               {"model.nerf", whichModel},
                                                                               {"cloud.ply", whichCloud},
                                                                               {"cloud.pcd", whichCloud},
                                                                               {"mesh.ply", whichMesh}};
  std::map<std::string, std::array<int, 2>> seen;
  std::mt19937 rng(2024);
  double round_s = 0.0;  // one round of the five writes, measured in the first child
  int kills = 0, temp_left = 0;
  for (int it = 0; it < 50; ++it) {
    const pid_t pid = startWriter(self, tmp.path());
    ASSERT_GT(pid, 0) << "fork failed";
    // A failed assertion below must not leave the endless writer running.
    struct Reaper {
      pid_t pid;
      bool reaped = false;
      ~Reaper() {
        if (!reaped) {
          kill(pid, SIGKILL);
          waitpid(pid, nullptr, 0);
        }
      }
    } reaper{pid};
    const uint64_t before = roundsDone(tmp.path());
    ASSERT_TRUE(waitForRound(tmp.path(), before, pid, 300.0)) << "the helper did not complete a round of writes";
    if (it == 0) {
      const auto t1 = std::chrono::steady_clock::now();
      ASSERT_TRUE(waitForRound(tmp.path(), before + 1, pid, 300.0)) << "the helper did not complete a second round";
      round_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
    }
    const double after = std::uniform_real_distribution<double>(0.0, 2.0 * round_s)(rng);
    std::this_thread::sleep_for(std::chrono::duration<double>(after));
    ASSERT_EQ(kill(pid, SIGKILL), 0);
    int status = 0;
    ASSERT_EQ(waitpid(pid, &status, 0), pid);
    reaper.reaped = true;
    ASSERT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL)
        << "the helper was expected to be killed " << after << " s after its first round (status " << status << ")";
    ++kills;
    for (const auto& [name, which] : files) {
      const fs::path p = tmp / name;
      if (!fs::exists(p)) continue;  // not written yet
      int v = -1;
      try {
        v = which(p);
      } catch (const std::exception& e) {
        ADD_FAILURE() << name << " does not load after a kill at " << after << " s: " << e.what();
        continue;
      }
      EXPECT_GE(v, 0) << name << " holds neither content after a kill at " << after << " s";
      if (v >= 0) ++seen[name][size_t(v)];
    }
    // Temporary files of killed writes: at most the one per file each kill interrupted (a later
    // successful write of that file removes those of dead processes).
    int temps = 0;
    for (const auto& e : fs::directory_iterator(tmp.path()))
      temps += e.path().filename().string().find(".tmp") != std::string::npos;
    EXPECT_LE(temps, int(files.size())) << "temporary files pile up after kill " << kills;
    temp_left = std::max(temp_left, temps);
  }
  std::printf("%d kills; loaded A/B:", kills);
  for (const auto& [name, n] : seen) std::printf(" %s %d/%d", name.c_str(), n[0], n[1]);
  std::printf("; at most %d temporary files present after a kill\n", temp_left);
  EXPECT_GE(kills, 50);
  // Every writer was interrupted at different points: both contents were seen for each file.
  for (const auto& [name, which] : files) {
    EXPECT_GT(seen[name][0], 0) << name;
    EXPECT_GT(seen[name][1], 0) << name;
  }
}

}  // namespace
}  // namespace nerfslam
