// Writes fuzz_image's small seeds: 24x16 crops of real images from the shared data, encoded in every
// format readImage accepts (8- and 16-bit, gray, colour, RGBA), each prefixed with the selector byte
// fuzz_image.cpp reads (extension index + 6 * mode index).
//   make_image_seeds OUT_DIR IMAGE...
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr, "usage: %s OUT_DIR IMAGE...\n", argv[0]);
    return 2;
  }
  const std::filesystem::path out = argv[1];
  std::filesystem::create_directories(out);
  const char* const kExt[] = {".png", ".jpg", ".bmp", ".tif", ".pgm", ".ppm"};
  int written = 0;
  for (int a = 2; a < argc; ++a) {
    const cv::Mat full = cv::imread(argv[a], cv::IMREAD_UNCHANGED);
    if (full.empty()) {
      std::fprintf(stderr, "cannot read %s\n", argv[a]);
      return 1;
    }
    const cv::Mat crop = full(cv::Rect(full.cols / 2, full.rows / 2, 24, 16)).clone();
    std::vector<cv::Mat> variants = {crop};
    cv::Mat gray, color, wide;
    if (crop.channels() == 1) {
      cv::cvtColor(crop, color, cv::COLOR_GRAY2BGR);
      variants.push_back(color);
    } else {
      cv::cvtColor(crop, gray, crop.channels() == 4 ? cv::COLOR_BGRA2GRAY : cv::COLOR_BGR2GRAY);
      variants.push_back(gray);
    }
    variants.front().convertTo(wide, CV_16U, 257.0);
    variants.push_back(wide);
    for (size_t v = 0; v < variants.size(); ++v) {
      for (int e = 0; e < 6; ++e) {
        const cv::Mat& img = variants[v];
        const int ch = img.channels();
        if ((e == 4 && ch != 1) || (e == 5 && ch != 3)) continue;   // pgm gray, ppm colour
        if (img.depth() == CV_16U && (e == 1 || e == 2)) continue;  // jpg, bmp: 8-bit only
        if (ch == 4 && (e == 1 || e == 4 || e == 5)) continue;      // no alpha there
        std::vector<uchar> buf;
        if (!cv::imencode(kExt[e], img, buf)) continue;
        const int mode = (written + e) % 3;
        const std::string name = std::filesystem::path(argv[a]).stem().string() + "_" + std::to_string(v) + kExt[e];
        std::ofstream f(out / name, std::ios::binary);
        const char selector = static_cast<char>(e + 6 * mode);
        f.write(&selector, 1);
        f.write(reinterpret_cast<const char*>(buf.data()), static_cast<std::streamsize>(buf.size()));
        ++written;
      }
    }
  }
  std::printf("%d image seeds in %s\n", written, out.c_str());
  return written > 0 ? 0 : 1;
}
