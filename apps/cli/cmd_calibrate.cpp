// `nerfslam calibrate`: intrinsic calibration from chessboard photos, written as our camera YAML.
#include <cstdio>
#include <memory>

#include <fmt/format.h>

#include "command.h"
#include "nerfslam/core/calibration.h"
#include "nerfslam/core/camera.h"
#include "nerfslam/core/error.h"
#include "nerfslam/core/input_file.h"
#include "nerfslam/io/image_io.h"

namespace {

struct CalibrateArgs {
  std::string images;
  std::string board;
  double square = 0.0;
  std::string out;
  std::string model = "radtan";
};

nerfslam::cli::Registrar reg(
    "calibrate", "Calibrate camera intrinsics from chessboard photos (Zhang's method)",
    [](CLI::App& sub) -> nerfslam::cli::Runner {
      auto a = std::make_shared<CalibrateArgs>();
      sub.add_option("--images", a->images, "Directory of chessboard photos from one camera")->required();
      sub.add_option("--board", a->board, "Inner corners COLSxROWS, e.g. 9x6 for a board of 10x7 squares")->required();
      sub.add_option("--square", a->square, "Side of one chessboard square in metres")->required();
      sub.add_option("--out", a->out, "Camera YAML to write")->required();
      sub.add_option("--model", a->model, "Distortion model")
          ->check(CLI::IsMember({"radtan", "equidistant"}))
          ->capture_default_str();
      return [a]() -> int {
        using namespace nerfslam;
        const ChessboardSpec board = parseBoardSize(a->board, a->square);
        const DistortionModel model =
            a->model == "equidistant" ? DistortionModel::kEquidistant : DistortionModel::kRadTan;
        // Before anything is read: --out must not be one of the photos it would overwrite.
        std::error_code ec;
        if (std::filesystem::is_directory(a->images, ec))
          for (const auto& photo : listImageFiles(a->images))
            if (sameFile(a->out, photo))
              fail("calibrate: --out {} is one of the photos in --images; choose another output file", a->out);
        // readImage refuses truncated and corrupt PNG/JPEG photos (OpenCV would decode them in part).
        const CalibrationResult r = calibrateFromImages(
            a->images, board, model, [](const std::filesystem::path& p) { return readImage(p, ImageMode::kGray); });
        for (const auto& im : r.images) {
          if (im.board_found)
            fmt::print("{:<32} RMS {:.4f} px\n", im.path.filename().string(), im.rms);
          else
            fmt::print("{:<32} skipped: {}\n", im.path.filename().string(), im.problem);
        }
        fmt::print("board found in {} of {} images\n", r.images_used, r.images.size());
        fmt::print("overall RMS reprojection error {:.4f} px\n", r.rms);
        fmt::print("camera: {}\n", r.camera.describe());
        saveCameraYaml(r.camera, a->out);
        fmt::print("wrote {}\n", a->out);
        return 0;
      };
    });

}  // namespace
