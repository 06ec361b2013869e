#include "nerfslam/nerf/model_io.h"

#include <gtest/gtest.h>

#include <sys/stat.h>

#include <cstring>
#include <fstream>
#include <functional>
#include <random>
#include <thread>

#include <nlohmann/json.hpp>

#include "nerfslam/core/crc32.h"
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
  scene.cone_angle = 1.0 / 32;  // the march is the model's: renders use what training used
  scene.max_step = 0.01;
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
  EXPECT_EQ(b.scene.cone_angle, 1.0 / 32);
  EXPECT_EQ(b.scene.max_step, 0.01);
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
  expectLoadError(dir / "missing.nerf", "NeRF model file not found");
}

// The file with its JSON header edited by `edit` and the checksum made right again, so that only the
// edited sizes are wrong.
std::string withHeader(const std::string& file, const std::function<void(nlohmann::json&)>& edit) {
  uint64_t hlen;
  std::memcpy(&hlen, file.data() + 16, 8);
  nlohmann::json h = nlohmann::json::parse(file.substr(24, hlen));
  edit(h);
  const std::string header = h.dump();
  const uint64_t n = header.size();
  std::string out = file.substr(0, 16) + std::string(reinterpret_cast<const char*>(&n), 8) + header +
                    file.substr(24 + hlen, file.size() - 24 - hlen - 4);
  const uint32_t crc = crc32(out);
  return out + std::string(reinterpret_cast<const char*>(&crc), 4);
}

// What a header declares is checked against the file before it is allocated: a 16 MB file whose
// header asks for a 32-level, 2^22-entry hash grid (869 MB of parameters, three times that with the
// optimiser's moments) or 8 occupancy cascades is refused at once, as is a directory given as the model (an
// ifstream opens a directory, and seeking to its "end" made the loader allocate 2^63 bytes:
// std::bad_alloc). A model read through a pipe, whose size is not known, still loads.
TEST(ModelIo, RefusesHeadersDeclaringMoreThanTheFileHoldsAndDirectories) {
  test::TempDir dir;
  NerfModel a = randomModel();
  saveModel(a, dir / "m.nerf");
  const std::string good = readAll(dir / "m.nerf");
  ASSERT_EQ(withHeader(good, [](nlohmann::json&) {}), good);

  writeAll(dir / "count.nerf", withHeader(good, [](nlohmann::json& h) { h["arrays"][0]["count"] = 1000000000000ull; }));
  expectLoadError(dir / "count.nerf", "declares 1000000000000 values of 4 bytes, but only");
  writeAll(dir / "grid.nerf", withHeader(good, [](nlohmann::json& h) {
             h["field_config"]["n_levels"] = 32;
             h["field_config"]["log2_hashmap_size"] = 22;
             h["field_config"]["finest_resolution"] = 1e6;
           }));
  expectLoadError(dir / "grid.nerf",
                  "field 'header.field_config': declares 869 MB of parameters, but the file's arrays hold 17.7 MB");
  writeAll(dir / "cascades.nerf", withHeader(good, [](nlohmann::json& h) { h["grid"]["cascades"] = 8; }));
  expectLoadError(dir / "cascades.nerf", "field 'grid.cascades': declares 67.1 MB of parameters");
  writeAll(dir / "cascades0.nerf", withHeader(good, [](nlohmann::json& h) { h["grid"]["cascades"] = -1; }));
  expectLoadError(dir / "cascades0.nerf", "field 'grid.cascades': -1 is not in [1, 8]");
  writeAll(dir / "levels.nerf", withHeader(good, [](nlohmann::json& h) { h["field_config"]["n_levels"] = 9; }));
  expectLoadError(dir / "levels.nerf", "field 'n_levels': must be a multiple of 8");

  std::filesystem::create_directory(dir / "model_dir.nerf");
  expectLoadError(dir / "model_dir.nerf", "model_dir.nerf: is a directory, not a NeRF model file");

  const std::filesystem::path fifo = dir / "pipe.nerf";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  std::thread writer([&] { writeAll(fifo, good); });
  NerfModel b = loadModel(fifo);
  writer.join();
  EXPECT_EQ(b.grid->values(), a.grid->values());
  std::thread short_writer([&] { writeAll(fifo, good.substr(0, good.size() - 100)); });
  expectLoadError(fifo, "truncated model file");
  short_writer.join();
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
