#pragma once
// Image reading with errors that name the file, and natural-order file listing.
#include <filesystem>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "nerfslam/io/dataset.h"

namespace nerfslam {

// Decodes a PNG, JPEG, BMP, TIFF or PNM image (by content, whatever the extension). Throws
// nerfslam::Error naming the file when it is missing, in another format, declares more than 16384
// pixels a side or 64 megapixels (checked before decoding), is larger than 1 GiB, or is truncated or
// corrupt. OpenCV decodes a damaged PNG or JPEG partially with only a libpng/libjpeg warning on
// stderr, so the PNG's chunks are walked to IEND with their CRCs checked and its pixel data inflated
// to check it holds every row, and the JPEG's end-of-image marker is looked for and its entropy data
// decoded with libjpeg's "Corrupt JPEG data" warnings as errors (io/image_header.h).
// kGray/kColor always give 8-bit images (16-bit data is scaled down by 1/256).
cv::Mat readImage(const std::filesystem::path& path, ImageMode mode = ImageMode::kGray);
// The same checks and decoding for an image file's bytes held in memory (a bag's CompressedImage);
// `name` says where they came from in errors.
cv::Mat decodeImage(const std::vector<unsigned char>& bytes, ImageMode mode, const std::string& name);

// Encodes `image` in the format of `path`'s extension (cv::imencode: .png, .jpg, ...) and writes it
// atomically (core/atomic_file.h) with every write checked: an Error naming the file when the
// format is unknown, encoding fails or the disk is full; never a cut-off image in its place.
void writeImageAtomic(const std::filesystem::path& path, const cv::Mat& image, const std::vector<int>& params = {});

// True for the extensions the image-folder reader accepts: png jpg jpeg bmp tif tiff pgm ppm
// (case-insensitive).
bool isImageExtension(const std::filesystem::path& path);

// "img2" < "img10": digit runs compare by value, the rest byte-wise.
bool naturalLess(const std::string& a, const std::string& b);

// Image files directly in `dir` (not recursive), natural order.
std::vector<std::filesystem::path> listImages(const std::filesystem::path& dir);

}  // namespace nerfslam
