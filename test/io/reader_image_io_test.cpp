#include "nerfslam/io/image_io.h"

#include <fstream>
#include <random>

#include <zlib.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "io/image_header.h"
#include "nerfslam/core/crc32.h"
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

std::string be32(uint32_t v) { return {char(v >> 24), char((v >> 16) & 0xff), char((v >> 8) & 0xff), char(v & 0xff)}; }
uint32_t readBe32(const std::string& s, size_t at) {
  return uint32_t(uint8_t(s[at])) << 24 | uint32_t(uint8_t(s[at + 1])) << 16 | uint32_t(uint8_t(s[at + 2])) << 8 |
         uint8_t(s[at + 3]);
}
// A PNG chunk with its length and CRC.
std::string pngChunk(const std::string& type, const std::string& data) {
  const std::string body = type + data;
  return be32(uint32_t(data.size())) + body + be32(crc32(body));
}
std::string zlibCompress(const std::string& raw) {
  uLongf n = compressBound(uLong(raw.size()));
  std::string out(n, '\0');
  EXPECT_EQ(
      compress(reinterpret_cast<Bytef*>(out.data()), &n, reinterpret_cast<const Bytef*>(raw.data()), uLong(raw.size())),
      Z_OK);
  out.resize(n);
  return out;
}

void expectImageError(const fs::path& p, const std::string& what) {
  const std::string e = test::errorOf([&] { readImage(p, ImageMode::kColor); });
  EXPECT_NE(e.find(p.string() + ": " + what), std::string::npos) << "expected '" << what << "', got: " << e;
}

// Corrupt copies of real frames (issue 22). OpenCV decodes a JPEG whose entropy data is damaged, or
// that was cut short and re-terminated with FF D9, into a partly grey or garbled image with only
// libjpeg's warning on stderr; libpng reports a PNG whose pixel data ends early (its chunks intact)
// only on stderr too. Each is now an Error naming the file, which a run treats as any unreadable
// frame. A JPEG has no checksum: a flipped byte that leaves the Huffman stream in step is decoded
// without a warning by libjpeg itself, and cannot be told from image content.
TEST(ImageIo, CorruptCopiesOfRealJpegAndPngFramesAreRefused) {
  NERFSLAM_REQUIRE_DATA(jpg_file, "strecha_fountain-P11/images/0000.jpg");
  NERFSLAM_REQUIRE_DATA(png_file, "kitti06_first51/image_l/000000.png");
  test::TempDir tmp;
  const std::string jpg = slurp(jpg_file), png = slurp(png_file);
  ASSERT_NO_THROW(readImage(jpg_file, ImageMode::kColor));
  // The entropy-coded data: after the start-of-scan marker and its header.
  const size_t sos = jpg.find("\xff\xda");
  ASSERT_NE(sos, std::string::npos);
  const size_t data = sos + 2 + (size_t(uint8_t(jpg[sos + 2])) << 8 | uint8_t(jpg[sos + 3]));
  spit(tmp / "cut.jpg", jpg.substr(0, data + (jpg.size() - data) / 2) + "\xff\xd9");
  expectImageError(tmp / "cut.jpg", "corrupt JPEG image: Corrupt JPEG data: premature end of data segment");
  std::string flipped = jpg;
  flipped[data + jpg.size() / 3] ^= 0x10;
  spit(tmp / "flipped.jpg", flipped);
  expectImageError(tmp / "flipped.jpg",
                   "corrupt JPEG image: Corrupt JPEG data: 42 extraneous bytes before marker 0xd9");
  // Random single-byte changes in the entropy data: those that put the decoder out of step are
  // found (15 of these 40; the rest decode without a warning from libjpeg either).
  std::mt19937 rng(1);
  int found = 0;
  for (int k = 0; k < 40; ++k) {
    std::string c = jpg;
    c[data + rng() % (jpg.size() - data - 2)] ^= char(1 + rng() % 255);
    spit(tmp / "r.jpg", c);
    found += test::errorOf([&] { readImage(tmp / "r.jpg"); }).find("corrupt JPEG image") != std::string::npos;
  }
  std::printf("random single-byte changes in the entropy data found: %d of 40\n", found);
  EXPECT_GE(found, 12);

  // PNG: a flipped byte fails its chunk's CRC; pixel data cut short in a file whose chunks are all
  // valid (the first IDAT halved, the others dropped, IEND after it).
  ASSERT_EQ(png.substr(12, 4), "IHDR");
  const size_t idat = 8 + 12 + 13;
  ASSERT_EQ(png.substr(idat + 4, 4), "IDAT");
  std::string crc = png;
  crc[idat + 8 + 100] ^= 0x01;
  spit(tmp / "crc.png", crc);
  expectImageError(tmp / "crc.png", "corrupt PNG image: chunk 'IDAT' at byte 33 fails its CRC check");
  const uint32_t n = readBe32(png, idat);
  const std::string cut = png.substr(0, idat) + pngChunk("IDAT", png.substr(idat + 8, n / 2)) + pngChunk("IEND", "");
  spit(tmp / "cut.png", cut);
  expectImageError(tmp / "cut.png",
                   "truncated PNG image: its pixel data holds 7613 of the 453990 bytes of rows its header declares");
  // Data that does not inflate, its CRC made right.
  std::string bad = png.substr(idat + 8, n);
  for (size_t i = 2; i < 40; ++i) bad[i] = char(0xff);
  spit(tmp / "zlib.png", png.substr(0, idat) + pngChunk("IDAT", bad) + png.substr(idat + 12 + n));
  expectImageError(tmp / "zlib.png", "corrupt PNG image: its pixel data does not decompress (zlib: ");
}

// The row count of an interlaced (Adam7) PNG, which OpenCV never writes: a 13x7 grey image made by
// hand reads; the same with its last row missing is refused.
TEST(ImageIo, InterlacedPngIsCheckedByItsSevenPasses) {
  test::TempDir tmp;
  const int w = 13, h = 7;
  const int pass[7][4] = {{0, 0, 8, 8}, {4, 0, 8, 8}, {0, 4, 4, 8}, {2, 0, 4, 4},
                          {0, 2, 2, 4}, {1, 0, 2, 2}, {0, 1, 1, 2}};
  std::string raw;
  for (const auto& p : pass)
    for (int y = p[1]; y < h; y += p[3]) {
      if (p[0] >= w) continue;
      raw.push_back('\0');  // filter: none
      for (int x = p[0]; x < w; x += p[2]) raw.push_back(char(10 * x + y));
    }
  std::string ihdr = be32(w) + be32(h);
  ihdr += std::string{char(8), char(0), char(0), char(0), char(1)};  // 8-bit grey, Adam7
  const std::string head = "\x89PNG\r\n\x1a\n" + pngChunk("IHDR", ihdr);
  spit(tmp / "adam7.png", head + pngChunk("IDAT", zlibCompress(raw)) + pngChunk("IEND", ""));
  const cv::Mat img = readImage(tmp / "adam7.png", ImageMode::kGray);
  ASSERT_EQ(img.size(), cv::Size(w, h));
  EXPECT_EQ(img.at<uchar>(6, 12), 126);
  EXPECT_EQ(img.at<uchar>(3, 5), 53);
  spit(tmp / "short.png", head + pngChunk("IDAT", zlibCompress(raw.substr(0, raw.size() - 7))) + pngChunk("IEND", ""));
  expectImageError(tmp / "short.png", "truncated PNG image: its pixel data holds 98 of the 105 bytes");
}

// No false alarm: every image of the shared data (at most 30 a folder) reads.
TEST(ImageIo, EveryRealImageOfTheSharedDataReads) {
  NERFSLAM_REQUIRE_DATA(data, "kitti06_first51");
  size_t n = 0;
  for (const char* dir :
       {"kitti06_first51/image_l", "new_tsukuba_150/images", "strecha_fountain-P11/images", "opencv_chessboard",
        "euroc_V1_01_piece/mav0/cam0/data", "middlebury_dino", "middlebury_templeRing", "lego_train/train"}) {
    const auto files = listImages(test::dataDir() / dir);
    EXPECT_FALSE(files.empty()) << dir;
    for (size_t i = 0; i < files.size() && i < 30; ++i, ++n)
      EXPECT_NO_THROW(readImage(files[i], ImageMode::kColor)) << files[i];
  }
  EXPECT_EQ(n, 193u);
}

}  // namespace
}  // namespace nerfslam
