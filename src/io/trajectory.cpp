#include "nerfslam/io/trajectory.h"

#include <fmt/format.h>

#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <optional>

#include "nerfslam/core/atomic_file.h"
#include "nerfslam/core/error.h"
#include "nerfslam/core/input_file.h"

namespace nerfslam {
namespace fs = std::filesystem;
namespace {

constexpr double kUnitTolerance = 1e-3;

struct DataLine {
  size_t line_no = 0;
  std::vector<std::string> tokens;
  bool has_comma = false;
};

std::string pathString(const fs::path& p) { return p.string(); }

[[noreturn]] void lineError(const fs::path& path, size_t line_no, const std::string& what) {
  throw Error(fmt::format("{}:{}: {}", pathString(path), line_no, what));
}

// Splits every non-blank, non-comment line into tokens separated by spaces, tabs and commas.
std::vector<DataLine> readDataLines(const fs::path& path) {
  InputFile f = openInputFile(path, "trajectory file");
  std::istream& is = f.stream;
  std::vector<DataLine> lines;
  std::string line;
  size_t line_no = 0;
  while (std::getline(is, line)) {
    ++line_no;
    size_t start = line.find_first_not_of(" \t\r");
    if (start == std::string::npos || line[start] == '#') continue;
    // The UTF-8 byte-order mark some editors write.
    if (line_no == 1 && line.compare(0, 3, "\xEF\xBB\xBF") == 0) {
      line = line.substr(3);
      start = line.find_first_not_of(" \t\r");
      if (start == std::string::npos || line[start] == '#') continue;
    }
    DataLine dl;
    dl.line_no = line_no;
    std::string cur;
    for (char c : line) {
      if (c == ' ' || c == '\t' || c == ',' || c == '\r') {
        if (c == ',') dl.has_comma = true;
        if (!cur.empty()) dl.tokens.push_back(std::move(cur));
        cur.clear();
      } else {
        cur.push_back(c);
      }
    }
    if (!cur.empty()) dl.tokens.push_back(std::move(cur));
    lines.push_back(std::move(dl));
  }
  checkReadable(is, path);
  return lines;
}

std::optional<double> toDouble(const std::string& s) {
  errno = 0;
  char* end = nullptr;
  const double v = std::strtod(s.c_str(), &end);
  if (end == s.c_str() || *end != '\0') return std::nullopt;
  return v;
}

std::vector<double> parseNumbers(const fs::path& path, const DataLine& dl, size_t expected_min, size_t expected_max,
                                 const char* layout) {
  if (dl.tokens.size() < expected_min || dl.tokens.size() > expected_max) {
    const std::string expected =
        expected_min == expected_max ? std::to_string(expected_min) : fmt::format("at least {}", expected_min);
    lineError(path, dl.line_no, fmt::format("expected {} columns ({}), found {}", expected, layout, dl.tokens.size()));
  }
  std::vector<double> v(dl.tokens.size());
  for (size_t i = 0; i < dl.tokens.size(); ++i) {
    const auto d = toDouble(dl.tokens[i]);
    if (!d)
      lineError(path, dl.line_no, fmt::format("column {}: '{}' is not a number", i + 1, cutForMessage(dl.tokens[i])));
    if (!std::isfinite(*d))
      lineError(path, dl.line_no, fmt::format("column {}: '{}' is not finite", i + 1, cutForMessage(dl.tokens[i])));
    v[i] = *d;
  }
  return v;
}

Eigen::Quaterniond checkedQuaternion(const fs::path& path, size_t line_no, double w, double x, double y, double z) {
  const double n = std::sqrt(w * w + x * x + y * y + z * z);
  if (n == 0.0) lineError(path, line_no, "quaternion is zero");
  if (std::abs(n - 1.0) > kUnitTolerance)
    lineError(path, line_no, fmt::format("quaternion is not a unit quaternion (norm {:.6g})", n));
  return Eigen::Quaterniond(w / n, x / n, y / n, z / n);
}

void requireData(const fs::path& path, const std::vector<DataLine>& lines) {
  if (lines.empty()) throw Error(fmt::format("{}: trajectory file has no poses", pathString(path)));
}

std::string formatDouble(double v) { return fmt::format("{}", v); }

}  // namespace

TrajectoryFormat parseTrajectoryFormat(const std::string& name) {
  if (name == "auto") return TrajectoryFormat::kAuto;
  if (name == "tum") return TrajectoryFormat::kTum;
  if (name == "kitti") return TrajectoryFormat::kKitti;
  if (name == "euroc") return TrajectoryFormat::kEuroc;
  fail("unknown trajectory format '{}': must be one of auto, tum, kitti, euroc", name);
}

std::string trajectoryFormatName(TrajectoryFormat format) {
  switch (format) {
    case TrajectoryFormat::kAuto:
      return "auto";
    case TrajectoryFormat::kTum:
      return "tum";
    case TrajectoryFormat::kKitti:
      return "kitti";
    case TrajectoryFormat::kEuroc:
      return "euroc";
  }
  return "unknown";
}

TrajectoryFormat detectTrajectoryFormat(const fs::path& path) {
  const auto lines = readDataLines(path);
  requireData(path, lines);
  const DataLine& first = lines.front();
  const size_t n = first.tokens.size();
  if (n == 12) return TrajectoryFormat::kKitti;
  if (n >= 8 && first.has_comma) {
    const auto t = toDouble(first.tokens[0]);
    if (t && *t > 1e12 && first.tokens[0].find_first_not_of("0123456789") == std::string::npos)
      return TrajectoryFormat::kEuroc;
  }
  if (n == 8) return TrajectoryFormat::kTum;
  lineError(path, first.line_no,
            fmt::format("cannot detect the trajectory format from {} columns (TUM has 8, KITTI 12, EuRoC CSV "
                        "at least 8 with nanosecond timestamps)",
                        n));
}

Trajectory readTumTrajectory(const fs::path& path) {
  const auto lines = readDataLines(path);
  requireData(path, lines);
  Trajectory traj;
  traj.reserve(lines.size());
  for (const auto& dl : lines) {
    const auto v = parseNumbers(path, dl, 8, 8, "timestamp tx ty tz qx qy qz qw");
    const Eigen::Quaterniond q = checkedQuaternion(path, dl.line_no, v[7], v[4], v[5], v[6]);
    traj.push_back({v[0], SE3(q, Eigen::Vector3d(v[1], v[2], v[3]))});
  }
  return traj;
}

Trajectory readKittiTrajectory(const fs::path& path, const fs::path& times_path) {
  const auto lines = readDataLines(path);
  requireData(path, lines);
  std::vector<double> times;
  if (!times_path.empty()) {
    for (const auto& dl : readDataLines(times_path))
      times.push_back(parseNumbers(times_path, dl, 1, 1, "timestamp")[0]);
    if (times.size() != lines.size())
      throw Error(fmt::format("{}: has {} timestamps but {} has {} poses", pathString(times_path), times.size(),
                              pathString(path), lines.size()));
  }
  Trajectory traj;
  traj.reserve(lines.size());
  for (size_t i = 0; i < lines.size(); ++i) {
    const auto v = parseNumbers(path, lines[i], 12, 12, "r11 r12 r13 tx r21 r22 r23 ty r31 r32 r33 tz");
    Eigen::Matrix<double, 3, 4> M;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 4; ++c) M(r, c) = v[4 * r + c];
    const Eigen::Matrix3d R = M.leftCols<3>();
    const double orth = (R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
    if (orth > kUnitTolerance || R.determinant() <= 0)
      lineError(path, lines[i].line_no,
                fmt::format("the 3x3 part is not a rotation matrix (max |R^T R - I| = {:.3g}, det = {:.6g})", orth,
                            R.determinant()));
    traj.push_back({times.empty() ? static_cast<double>(i) : times[i], SE3::fromMatrix3x4(M)});
  }
  return traj;
}

Trajectory readEurocTrajectory(const fs::path& path) {
  const auto lines = readDataLines(path);
  requireData(path, lines);
  Trajectory traj;
  traj.reserve(lines.size());
  for (const auto& dl : lines) {
    const auto v = parseNumbers(path, dl, 8, 1000, "timestamp[ns] px py pz qw qx qy qz ...");
    // Integer nanoseconds split into seconds and remainder keep full precision (a double holds a
    // 19-digit stamp only to ~256 ns). Longer digit strings overflow 64 bits: they keep the double.
    double t = v[0] * 1e-9;
    const std::string& s = dl.tokens[0];
    if (s.size() > 9 && s.size() <= 19 && s.find_first_not_of("0123456789") == std::string::npos) {
      long long sec = 0, nsec = 0;
      const char* split = s.data() + s.size() - 9;
      if (std::from_chars(s.data(), split, sec).ec == std::errc() &&
          std::from_chars(split, s.data() + s.size(), nsec).ec == std::errc())
        t = static_cast<double>(sec) + static_cast<double>(nsec) * 1e-9;
    }
    const Eigen::Quaterniond q = checkedQuaternion(path, dl.line_no, v[4], v[5], v[6], v[7]);
    traj.push_back({t, SE3(q, Eigen::Vector3d(v[1], v[2], v[3]))});
  }
  return traj;
}

Trajectory readTrajectory(const fs::path& path, TrajectoryFormat format, const fs::path& kitti_times) {
  if (format == TrajectoryFormat::kAuto) format = detectTrajectoryFormat(path);
  switch (format) {
    case TrajectoryFormat::kTum:
      return readTumTrajectory(path);
    case TrajectoryFormat::kKitti:
      return readKittiTrajectory(path, kitti_times);
    case TrajectoryFormat::kEuroc:
      return readEurocTrajectory(path);
    case TrajectoryFormat::kAuto:
      break;
  }
  fail("{}: unsupported trajectory format", pathString(path));
}

void writeTumTrajectory(const fs::path& path, const Trajectory& trajectory) {
  writeFileAtomic(path, [&](std::ostream& os) {
    os << "# timestamp tx ty tz qx qy qz qw\n";
    for (const auto& e : trajectory) {
      const auto& t = e.pose.translation();
      const auto& q = e.pose.rotation();
      os << fmt::format("{:.9f} {} {} {} {} {} {} {}\n", e.timestamp, formatDouble(t.x()), formatDouble(t.y()),
                        formatDouble(t.z()), formatDouble(q.x()), formatDouble(q.y()), formatDouble(q.z()),
                        formatDouble(q.w()));
    }
  });
}

void writeKittiTrajectory(const fs::path& path, const Trajectory& trajectory, const fs::path& times_path) {
  writeFileAtomic(path, [&](std::ostream& os) {
    for (const auto& e : trajectory) {
      const Eigen::Matrix<double, 3, 4> M = e.pose.matrix3x4();
      std::string line;
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 4; ++c) line += (line.empty() ? "" : " ") + formatDouble(M(r, c));
      os << line << '\n';
    }
  });
  if (!times_path.empty()) {
    writeFileAtomic(times_path, [&](std::ostream& os) {
      for (const auto& e : trajectory) os << fmt::format("{:.9f}\n", e.timestamp);
    });
  }
}

}  // namespace nerfslam
