#include "nerfslam/core/atomic_file.h"

#include <fstream>
#include <sstream>

#include "nerfslam/core/error.h"
#include "test_support.h"

namespace nerfslam {
namespace {
namespace fs = std::filesystem;

std::string slurp(const fs::path& p) {
  std::ifstream is(p, std::ios::binary);
  std::stringstream ss;
  ss << is.rdbuf();
  return ss.str();
}

size_t countFiles(const fs::path& dir) {
  size_t n = 0;
  for ([[maybe_unused]] const auto& e : fs::directory_iterator(dir)) ++n;
  return n;
}

TEST(AtomicFile, WritesAndReplaces) {
  test::TempDir tmp;
  writeStringAtomic(tmp / "a.txt", "first");
  EXPECT_EQ(slurp(tmp / "a.txt"), "first");
  writeStringAtomic(tmp / "a.txt", "second");
  EXPECT_EQ(slurp(tmp / "a.txt"), "second");
  EXPECT_EQ(countFiles(tmp.path()), 1u);  // no temporary file left behind
}

TEST(AtomicFile, WriterFailureKeepsPreviousFile) {
  test::TempDir tmp;
  writeStringAtomic(tmp / "a.txt", "good");
  EXPECT_THROW(writeFileAtomic(tmp / "a.txt",
                               [](std::ostream& os) {
                                 os << "half";
                                 throw Error("writer failed");
                               }),
               Error);
  EXPECT_EQ(slurp(tmp / "a.txt"), "good");
  EXPECT_EQ(countFiles(tmp.path()), 1u);
}

TEST(AtomicFile, MissingDirectoryNamesThePath) {
  test::TempDir tmp;
  try {
    writeStringAtomic(tmp / "no" / "such" / "a.txt", "x");
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("a.txt"), std::string::npos) << e.what();
  }
}

TEST(AtomicFile, UncommittedOutputIsRemoved) {
  test::TempDir tmp;
  {
    AtomicOutput out(tmp / "img.png");
    std::ofstream(out.tempPath()) << "partial";
    EXPECT_EQ(out.tempPath().extension(), ".png");
  }
  EXPECT_EQ(countFiles(tmp.path()), 0u);
}

TEST(AtomicFile, EnsureDirectoryReportsBlockedParent) {
  // A regular file where a parent directory should be: fails for root too (unlike permissions).
  test::TempDir tmp;
  std::ofstream(tmp / "blocker") << "x";
  try {
    ensureDirectory(tmp / "blocker" / "sub");
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("blocker"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace nerfslam
