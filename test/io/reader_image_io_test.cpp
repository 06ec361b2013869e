#include "nerfslam/io/image_io.h"

#include <fstream>

#include <opencv2/imgcodecs.hpp>

#include "nerfslam/core/error.h"
#include "test_support.h"

namespace nerfslam {
namespace {
namespace fs = std::filesystem;

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

void spit(const fs::path& p, const std::string& s) {
  std::ofstream o(p, std::ios::binary);
  o << s;
}

TEST(ImageIo, NaturalOrder) {
  EXPECT_TRUE(naturalLess("img2.png", "img10.png"));
  EXPECT_FALSE(naturalLess("img10.png", "img2.png"));
  EXPECT_TRUE(naturalLess("a.png", "b.png"));
  EXPECT_TRUE(naturalLess("img2", "img2.png"));
  EXPECT_TRUE(naturalLess("000009.png", "000010.png"));
  EXPECT_TRUE(naturalLess("x1y2", "x1y10"));
  EXPECT_FALSE(naturalLess("same", "same"));
  // Equal values with different zero padding still order strictly, in one direction only.
  EXPECT_NE(naturalLess("a01", "a1"), naturalLess("a1", "a01"));
}

TEST(ImageIo, ListImagesFiltersAndSorts) {
  test::TempDir tmp;
  cv::Mat img(4, 4, CV_8UC1, cv::Scalar(7));
  for (const char* n : {"f10.png", "f2.JPG", "f1.tif", "notes.txt", "f3.pgm"}) {
    if (fs::path(n).extension() == ".txt")
      spit(tmp / n, "x");
    else
      ASSERT_TRUE(cv::imwrite((tmp / n).string(), img));
  }
  const auto list = listImages(tmp.path());
  ASSERT_EQ(list.size(), 4u);
  EXPECT_EQ(list[0].filename(), "f1.tif");
  EXPECT_EQ(list[1].filename(), "f2.JPG");
  EXPECT_EQ(list[2].filename(), "f3.pgm");
  EXPECT_EQ(list[3].filename(), "f10.png");
}

TEST(ImageIo, ModesAndErrors) {
  test::TempDir tmp;
  cv::Mat bgra(10, 12, CV_8UC4, cv::Scalar(10, 20, 30, 128));
  ASSERT_TRUE(cv::imwrite((tmp / "a.png").string(), bgra));
  EXPECT_EQ(readImage(tmp / "a.png", ImageMode::kUnchanged).type(), CV_8UC4);
  EXPECT_EQ(readImage(tmp / "a.png", ImageMode::kColor).type(), CV_8UC3);
  const cv::Mat g = readImage(tmp / "a.png");
  EXPECT_EQ(g.type(), CV_8UC1);
  EXPECT_EQ(g.size(), cv::Size(12, 10));
  cv::Mat g16(10, 12, CV_16UC1, cv::Scalar(40000));
  ASSERT_TRUE(cv::imwrite((tmp / "d.png").string(), g16));
  EXPECT_EQ(readImage(tmp / "d.png", ImageMode::kUnchanged).type(), CV_16UC1);
  const cv::Mat g8 = readImage(tmp / "d.png", ImageMode::kGray);
  EXPECT_EQ(g8.type(), CV_8UC1);
  EXPECT_EQ(g8.at<uchar>(3, 4), 40000 / 256);

  auto expectError = [](const fs::path& p, const std::string& what) {
    try {
      readImage(p);
      ADD_FAILURE() << "no error for " << p;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(p.string()), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
    }
  };
  expectError(tmp / "missing.png", "not found");
  spit(tmp / "text.png", "this is not an image");
  expectError(tmp / "text.png", "not a readable image");
  spit(tmp / "empty.png", "");
  expectError(tmp / "empty.png", "empty");
  // Truncated PNG and JPEG (OpenCV alone would return a partly decoded image for the JPEG).
  cv::Mat noise(200, 200, CV_8UC3);
  cv::randu(noise, 0, 255);
  ASSERT_TRUE(cv::imwrite((tmp / "n.png").string(), noise));
  ASSERT_TRUE(cv::imwrite((tmp / "n.jpg").string(), noise));
  const std::string png = slurp(tmp / "n.png"), jpg = slurp(tmp / "n.jpg");
  spit(tmp / "half.png", png.substr(0, png.size() / 2));
  spit(tmp / "half.jpg", jpg.substr(0, jpg.size() / 2));
  expectError(tmp / "half.png", "truncated PNG");
  expectError(tmp / "half.jpg", "truncated JPEG");
  // JPEG data under a .png name decodes by content.
  spit(tmp / "jpeg_named.png", jpg);
  EXPECT_EQ(readImage(tmp / "jpeg_named.png", ImageMode::kColor).size(), cv::Size(200, 200));
}

}  // namespace
}  // namespace nerfslam
