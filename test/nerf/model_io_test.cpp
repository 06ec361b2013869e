#include "nerfslam/nerf/model_io.h"

#include <gtest/gtest.h>

#include <cstring>
#include <fstream>
#include <random>

#include "nerfslam/core/error.h"
#include "test_support.h"

namespace nerfslam::nerf {
namespace {

FieldConfig smallConfig() {
  FieldConfig c;
  c.n_levels = 8;
  c.log2_hashmap_size = 14;
  c.finest_resolution = 256;
  c.hidden = 16;
  return c;
}

NerfModel randomModel() {
  SceneTransform scene;
  scene.aabb_scale = 2;
  scene.scale = 0.25;
  NerfModel m = NerfModel::create(smallConfig(), scene, 42);
  std::mt19937 rng(1);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  for (auto& a : m.field->parameters())
    for (size_t i = 0; i < a.size; ++i) a.data[i] = u(rng);
  m.field->parametersChanged();
  std::vector<float> values(m.grid->values().size());
  for (auto& v : values) v = 0.5f * (u(rng) + 1.f) * 0.02f;
  m.grid->setValues(values, 0.01f);
  m.training_steps = 1234;
  return m;
}

std::string readAll(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}
void writeAll(const std::filesystem::path& p, const std::string& s) { std::ofstream(p, std::ios::binary) << s; }

void expectLoadError(const std::filesystem::path& p, const std::string& what) {
  try {
    loadModel(p);
    FAIL() << "loading " << p << " should fail (" << what << ")";
  } catch (const Error& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find(p.string()), std::string::npos) << msg;
    EXPECT_NE(msg.find(what), std::string::npos) << msg;
  }
}

TEST(ModelIo, RoundTripIsBitExact) {
  test::TempDir dir;
  NerfModel a = randomModel();
  saveModel(a, dir / "m.nerf");
  NerfModel b = loadModel(dir / "m.nerf");
  EXPECT_EQ(b.training_steps, 1234u);
  EXPECT_EQ(b.scene.aabb_scale, 2.0);
  EXPECT_EQ(b.scene.scale, 0.25);
  EXPECT_EQ(b.field_config.n_levels, 8);
  EXPECT_EQ(b.field_config.hidden, 16);
  const auto pa = a.field->parameters(), pb = b.field->parameters();
  ASSERT_EQ(pa.size(), pb.size());
  for (size_t i = 0; i < pa.size(); ++i) {
    ASSERT_EQ(pa[i].size, pb[i].size);
    EXPECT_EQ(std::memcmp(pa[i].data, pb[i].data, pa[i].size * 4), 0) << pa[i].name;
  }
  ASSERT_EQ(a.grid->values(), b.grid->values());
  EXPECT_EQ(a.grid->threshold(), b.grid->threshold());
  EXPECT_EQ(a.grid->occupiedFraction(), b.grid->occupiedFraction());
  // Same outputs for the same inputs.
  std::vector<float> pos = {0.1f, 0.2f, 0.3f, 0.7f, 0.5f, 0.9f}, dirs = {0, 0, 1, 1, 0, 0};
  std::vector<float> sa(2), sb(2), ca(6), cb(6);
  a.field->query(pos.data(), dirs.data(), 2, sa.data(), ca.data());
  b.field->query(pos.data(), dirs.data(), 2, sb.data(), cb.data());
  EXPECT_EQ(sa, sb);
  EXPECT_EQ(ca, cb);
  // Saving the loaded model gives the identical file.
  saveModel(b, dir / "m2.nerf");
  EXPECT_EQ(readAll(dir / "m.nerf"), readAll(dir / "m2.nerf"));
}

TEST(ModelIo, RejectsTruncatedForeignWrongVersionAndCorruptFiles) {
  test::TempDir dir;
  NerfModel a = randomModel();
  saveModel(a, dir / "m.nerf");
  const std::string good = readAll(dir / "m.nerf");

  writeAll(dir / "trunc.nerf", good.substr(0, good.size() / 2));
  expectLoadError(dir / "trunc.nerf", "truncated");
  writeAll(dir / "short.nerf", good.substr(0, 10));
  expectLoadError(dir / "short.nerf", "too short");
  writeAll(dir / "foreign.nerf", "PK\x03\x04 this is a zip file, not a model........................");
  expectLoadError(dir / "foreign.nerf", "not a nerfslam model");
  std::string v = good;
  v[8] = 7;  // format version 7
  writeAll(dir / "version.nerf", v);
  expectLoadError(dir / "version.nerf", "unsupported model format version 7");
  std::string c = good;
  c[good.size() / 2] ^= 0x10;  // one flipped bit in the parameters
  writeAll(dir / "corrupt.nerf", c);
  expectLoadError(dir / "corrupt.nerf", "checksum mismatch");
  expectLoadError(dir / "missing.nerf", "cannot open");
}

TEST(ModelIo, RefusesToSaveNonFiniteParametersAndLeavesOldFile) {
  test::TempDir dir;
  NerfModel a = randomModel();
  saveModel(a, dir / "m.nerf");
  const std::string before = readAll(dir / "m.nerf");
  a.field->parameters()[1].data[3] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_THROW(saveModel(a, dir / "m.nerf"), Error);
  EXPECT_EQ(readAll(dir / "m.nerf"), before);
}

TEST(ModelIo, UnwritableDestinationIsAnError) {
  NerfModel a = randomModel();
  EXPECT_THROW(saveModel(a, "/proc/nonexistent_dir/m.nerf"), Error);
}

}  // namespace
}  // namespace nerfslam::nerf
