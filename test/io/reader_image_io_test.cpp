#include "nerfslam/io/image_io.h"

#include <fstream>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "io/image_header.h"
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

// The header sniffer reads the size every format we accept declares, as OpenCV writes it, and
// recognises nothing else.
TEST(ImageIo, HeaderSizesOfEveryFormat) {
  cv::Mat img(23, 37, CV_8UC3);
  cv::randu(img, 0, 255);
  cv::Mat gray;
  cv::cvtColor(img, gray, cv::COLOR_BGR2GRAY);
  const std::vector<std::pair<std::string, std::string>> formats = {
      {".png", "PNG"}, {".jpg", "JPEG"}, {".bmp", "BMP"}, {".tif", "TIFF"}, {".ppm", "PNM"}, {".pgm", "PNM"}};
  for (const auto& [ext, name] : formats) {
    SCOPED_TRACE(ext);
    std::vector<uchar> bytes;
    ASSERT_TRUE(cv::imencode(ext, ext == ".pgm" ? gray : img, bytes));
    const auto h = io_detail::sniffImageHeader(bytes);
    ASSERT_TRUE(h.has_value());
    EXPECT_EQ(std::string(io_detail::imageFormatName(h->format)), name);
    EXPECT_EQ(h->width, 37);
    EXPECT_EQ(h->height, 23);
  }
  std::vector<uchar> bytes;
  ASSERT_TRUE(cv::imencode(".ppm", img, bytes, {cv::IMWRITE_PXM_BINARY, 0}));  // ASCII P3
  EXPECT_EQ(io_detail::sniffImageHeader(bytes)->width, 37);
  const std::string pnm_comment = "P5\n# made by hand\n37 # width\n23\n255\n";
  EXPECT_EQ(io_detail::sniffImageHeader(std::vector<uchar>(pnm_comment.begin(), pnm_comment.end()))->height, 23);
  for (const std::string other : {"RIFF\x10\0\0\0WEBPVP8 ", "#?RADIANCE\n", "P7\nWIDTH 4\n", "GIF89a", "text"})
    EXPECT_FALSE(io_detail::sniffImageHeader(std::vector<uchar>(other.begin(), other.end())).has_value()) << other;
}

// A header that declares a huge image is refused before decoding: OpenCV would allocate the whole
// image first (2.7 GB for 30000x30000 colour) and only then find the data short.
TEST(ImageIo, RefusesHeadersDeclaringHugeImages) {
  test::TempDir tmp;
  cv::Mat img(23, 37, CV_8UC3, cv::Scalar(1, 2, 3));
  auto be16 = [](std::vector<uchar>& b, size_t at, uint32_t v) {
    b[at] = static_cast<uchar>(v >> 8);
    b[at + 1] = static_cast<uchar>(v);
  };
  std::vector<uchar> png, jpg, bmp;
  ASSERT_TRUE(cv::imencode(".png", img, png));
  ASSERT_TRUE(cv::imencode(".jpg", img, jpg));
  ASSERT_TRUE(cv::imencode(".bmp", img, bmp));
  be16(png, 18, 30000);  // IHDR width and height (big-endian 32-bit at 16 and 20)
  be16(png, 22, 30000);
  size_t sof = 2;  // the SOF0 marker OpenCV writes
  while (sof + 1 < jpg.size() && !(jpg[sof] == 0xff && jpg[sof + 1] == 0xc0)) ++sof;
  ASSERT_LT(sof + 9, jpg.size());
  be16(jpg, sof + 5, 30000);
  be16(jpg, sof + 7, 30000);
  bmp[19] = 0x75, bmp[18] = 0x30, bmp[23] = 0x75, bmp[22] = 0x30;  // little-endian 30000
  const std::string pnm = "P6\n30000 30000\n255\n" + std::string(16, 'x');
  const std::vector<std::pair<std::string, std::string>> files = {{"png", std::string(png.begin(), png.end())},
                                                                  {"jpg", std::string(jpg.begin(), jpg.end())},
                                                                  {"bmp", std::string(bmp.begin(), bmp.end())},
                                                                  {"ppm", pnm}};
  for (const auto& [ext, content] : files) {
    SCOPED_TRACE(ext);
    const fs::path p = tmp / ("huge." + ext);
    spit(p, content);
    try {
      readImage(p, ImageMode::kColor);
      ADD_FAILURE() << "no error";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("huge." + ext + ": "), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("header declares 30000x30000 pixels"), std::string::npos) << e.what();
    }
  }
  // Formats OpenCV would decode but we do not accept.
  std::vector<uchar> webp;
  if (cv::imencode(".webp", img, webp)) {
    spit(tmp / "w.png", std::string(webp.begin(), webp.end()));
    try {
      readImage(tmp / "w.png");
      ADD_FAILURE() << "no error for WebP";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("unknown format"), std::string::npos) << e.what();
    }
  }
}

}  // namespace
}  // namespace nerfslam
