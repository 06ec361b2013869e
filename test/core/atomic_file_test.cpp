#include "nerfslam/core/atomic_file.h"

#include <unistd.h>

#include <fstream>
#include <sstream>

#include <fmt/format.h>

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

TEST(AtomicFile, CommitRemovesTemporariesOfDeadWritersOnly) {
  test::TempDir tmp;
  // A writer killed mid-write leaves <stem>.tmp.<pid>.<n><ext>. A dead pid: a child that has exited.
  const auto child = test::runCommand("sh -c 'echo $$'");
  const long dead = std::stol(child.output);
  writeStringAtomic(tmp / fmt::format("a.tmp.{}.3.txt", dead), "partial");  // (itself written atomically)
  writeStringAtomic(tmp / "a.tmp.1.0.txt", "pid 1 is alive: kept");
  writeStringAtomic(tmp / fmt::format("a.tmp.{}.9.txt", static_cast<long>(::getpid())), "ours: kept");
  writeStringAtomic(tmp / fmt::format("b.tmp.{}.1.txt", dead), "another file's: kept");
  writeStringAtomic(tmp / fmt::format("a.tmp.{}.1.bin", dead), "another extension: kept");
  writeStringAtomic(tmp / "a.txt", "complete");
  EXPECT_EQ(slurp(tmp / "a.txt"), "complete");
  EXPECT_FALSE(fs::exists(tmp / fmt::format("a.tmp.{}.3.txt", dead)));
  EXPECT_TRUE(fs::exists(tmp / "a.tmp.1.0.txt"));
  EXPECT_TRUE(fs::exists(tmp / fmt::format("a.tmp.{}.9.txt", static_cast<long>(::getpid()))));
  EXPECT_TRUE(fs::exists(tmp / fmt::format("b.tmp.{}.1.txt", dead)));
  EXPECT_TRUE(fs::exists(tmp / fmt::format("a.tmp.{}.1.bin", dead)));
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
