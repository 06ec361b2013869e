// core/input_file.h: the one way readers open outside input, and the message helpers of error.h.
#include "nerfslam/core/input_file.h"

#include <gtest/gtest.h>
#include <sys/stat.h>

#include <fstream>
#include <thread>

#include "nerfslam/core/error.h"
#include "test_support.h"

namespace nerfslam {
namespace {

namespace fs = std::filesystem;

// Missing, a directory, a regular file (with its size), and a pipe (no size).
TEST(InputFile, NamesTheFileWhenMissingOrADirectory) {
  test::TempDir dir;
  EXPECT_EQ(test::errorOf([&] { openInputFile(dir / "none.txt", "trajectory file"); }),
            (dir / "none.txt").string() + ": trajectory file not found");
  EXPECT_EQ(test::errorOf([&] { openInputFile(dir.path(), "NeRF model file"); }),
            dir.path().string() + ": is a directory, not a NeRF model file");
  EXPECT_EQ(test::errorOf([&] { openInputFile(dir.path()); }), dir.path().string() + ": is a directory");
  // A file that exists but does not open: the reason.
  fs::create_symlink(dir / "loop_b", dir / "loop_a");
  fs::create_symlink(dir / "loop_a", dir / "loop_b");
  EXPECT_EQ(test::errorOf([&] { openInputFile(dir / "loop_a"); }),
            (dir / "loop_a").string() + ": cannot open (Too many levels of symbolic links)");
  test::writeText(dir / "f.txt", "12345");
  InputFile f = openInputFile(dir / "f.txt");
  ASSERT_TRUE(f.size.has_value());
  EXPECT_EQ(*f.size, 5u);
  EXPECT_EQ(readInputFile(dir / "f.txt"), "12345");

  const fs::path fifo = dir / "pipe";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  std::thread writer([&] { std::ofstream(fifo) << "from a pipe"; });
  EXPECT_EQ(readInputFile(fifo), "from a pipe");
  writer.join();
}

// A size cap: a regular file is refused before it is read, a pipe as soon as it passes the cap.
TEST(InputFile, RefusesFilesAboveTheCap) {
  test::TempDir dir;
  test::writeText(dir / "big.yaml", std::string(2500000, '#'));
  EXPECT_EQ(test::errorOf([&] { readInputFile(dir / "big.yaml", "YAML file", 1000000); }),
            (dir / "big.yaml").string() + ": 2.50 MB, more than the 1.00 MB a YAML file may have");
  EXPECT_EQ(readInputFile(dir / "big.yaml", "YAML file", 2500000).size(), 2500000u);

  const fs::path fifo = dir / "pipe";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  // One byte over the cap, so the writer is done when the reader refuses (and does not die of
  // SIGPIPE writing to a pipe nobody reads).
  std::thread writer([&] { std::ofstream(fifo) << std::string(1000001, 'x'); });
  EXPECT_EQ(test::errorOf([&] { readInputFile(fifo, "YAML file", 1000000); }),
            fifo.string() + ": more than the 1.00 MB a YAML file may have");
  writer.join();
}

TEST(InputFile, FormatBytes) {
  EXPECT_EQ(formatBytes(0), "0 bytes");
  EXPECT_EQ(formatBytes(999), "999 bytes");
  EXPECT_EQ(formatBytes(1300), "1.30 KB");
  EXPECT_EQ(formatBytes(10000018), "10.0 MB");
  EXPECT_EQ(formatBytes(2450000000ull), "2.45 GB");
  EXPECT_EQ(formatBytes(~0ull), "18.4 EB");
}

// Outside text and numbers in messages stay short (issue 22: a 50 MB YAML scalar was echoed whole,
// a timestamp of 1e300 printed with 301 digits).
TEST(ErrorMessages, LongValuesAreCutAndHugeNumbersShort) {
  EXPECT_EQ(cutForMessage("short"), "short");
  const std::string cut = cutForMessage(std::string(50000000, 'x'));
  EXPECT_EQ(cut.size(), 80u);
  EXPECT_EQ(cut.substr(77), "...");
  EXPECT_EQ(cutForMessage(std::string(100, 'y'), 10), "yyyyyyy...");
  // Never inside a UTF-8 sequence ("é" is two bytes).
  std::string accents;
  for (int i = 0; i < 50; ++i) accents += "\xc3\xa9";
  const std::string a = cutForMessage(accents, 10);
  EXPECT_EQ(a, "\xc3\xa9\xc3\xa9\xc3\xa9...");
  EXPECT_EQ(numberForMessage(1.5), "1.500000");
  EXPECT_EQ(numberForMessage(1.5, 9), "1.500000000");
  EXPECT_EQ(numberForMessage(1e300), "1e+300");
  EXPECT_EQ(numberForMessage(-1e300, 9), "-1e+300");
  EXPECT_EQ(numberForMessage(std::numeric_limits<double>::infinity()), "inf");
}

}  // namespace
}  // namespace nerfslam
