// Parsing helpers shared by the dataset readers.
#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdlib>
#include <sstream>

#include "dataset_internal.h"
#include "nerfslam/core/error.h"
#include "nerfslam/core/input_file.h"
#include "nerfslam/core/options_yaml.h"
#include "nerfslam/io/image_io.h"
#include "nerfslam/io/trajectory.h"

namespace nerfslam::io_detail {

std::vector<Line> readDataLines(const fs::path& file) {
  InputFile f = openInputFile(file);
  std::istream& in = f.stream;
  std::vector<Line> out;
  std::string s;
  size_t n = 0;
  while (std::getline(in, s)) {
    ++n;
    // Blank means what splitTokens splits on (std::isspace: also \r, \f, \v), so that every data
    // line returned holds at least one token.
    const auto blank = [](char c) { return std::isspace(static_cast<unsigned char>(c)) != 0; };
    const auto b = std::find_if_not(s.begin(), s.end(), blank);
    if (b == s.end() || *b == '#') continue;
    const auto e = std::find_if_not(s.rbegin(), s.rend(), blank).base();
    out.push_back({n, std::string(b, e)});
  }
  checkReadable(in, file);
  return out;
}

std::vector<std::string> splitTokens(const std::string& s, bool commas) {
  std::vector<std::string> out;
  std::string cur;
  for (char c : s) {
    if (std::isspace(static_cast<unsigned char>(c)) || (commas && c == ',')) {
      if (!cur.empty()) out.push_back(std::move(cur));
      cur.clear();
    } else {
      cur.push_back(c);
    }
  }
  if (!cur.empty()) out.push_back(std::move(cur));
  return out;
}

double parseNumber(const std::string& tok, const fs::path& file, size_t line, const std::string& what) {
  const char* b = tok.c_str();
  char* e = nullptr;
  const double v = std::strtod(b, &e);
  if (tok.empty() || e != b + tok.size() || !std::isfinite(v))
    fail("{}:{}: {} '{}' is not a finite number", file.string(), line, what, cutForMessage(tok));
  return v;
}

std::vector<double> parseNumbers(const Line& line, const fs::path& file, size_t min_count, const std::string& what,
                                 bool commas) {
  const auto toks = splitTokens(line.text, commas);
  if (toks.size() < min_count)
    fail("{}:{}: expected {} numbers ({}), found {}", file.string(), line.number, min_count, what, toks.size());
  std::vector<double> v;
  v.reserve(toks.size());
  for (const auto& t : toks) v.push_back(parseNumber(t, file, line.number, what));
  return v;
}

void checkIncreasing(double prev, double t, const fs::path& file, size_t line) {
  if (!(t > prev))
    fail("{}:{}: timestamp {} is not after the previous one ({}); timestamps must increase", file.string(), line,
         numberForMessage(t, 9), numberForMessage(prev, 9));
}

std::vector<TimedPose> checkedTimes(const Trajectory& traj, const fs::path& file) {
  std::vector<TimedPose> out;
  out.reserve(traj.size());
  for (size_t i = 0; i < traj.size(); ++i) {
    if (i > 0 && !(traj[i].timestamp > traj[i - 1].timestamp))
      fail("{}: data line {}: timestamp {} is not after the previous one ({}); timestamps must increase", file.string(),
           i + 1, numberForMessage(traj[i].timestamp, 9), numberForMessage(traj[i - 1].timestamp, 9));
    out.push_back({traj[i].timestamp, traj[i].pose});
  }
  return out;
}

std::optional<SE3> nearestPose(const std::vector<TimedPose>& traj, double t, double tol) {
  if (traj.empty()) return std::nullopt;
  auto it = std::lower_bound(traj.begin(), traj.end(), t, [](const TimedPose& p, double x) { return p.t < x; });
  const TimedPose* best = nullptr;
  if (it != traj.end()) best = &*it;
  if (it != traj.begin()) {
    const TimedPose* prev = &*(it - 1);
    if (!best || std::abs(prev->t - t) <= std::abs(best->t - t)) best = prev;
  }
  if (best && std::abs(best->t - t) <= tol) return best->pose;
  return std::nullopt;
}

std::optional<SE3> interpolatePose(const std::vector<TimedPose>& traj, double t, double tol) {
  auto it = std::lower_bound(traj.begin(), traj.end(), t, [](const TimedPose& p, double x) { return p.t < x; });
  if (it != traj.end() && it != traj.begin()) {
    const TimedPose& a = *(it - 1);
    const TimedPose& b = *it;
    if (b.t - a.t <= 2 * tol) return SE3::interpolate(a.pose, b.pose, (t - a.t) / (b.t - a.t));
  }
  return nearestPose(traj, t, tol);
}

std::optional<fs::path> resolveImage(const fs::path& path) {
  std::error_code ec;
  if (fs::is_directory(path, ec)) fail("{}: is a directory, not an image file", path.string());
  if (fs::exists(path, ec)) return path;
  if (isImageExtension(path)) return std::nullopt;
  for (const char* ext : {".png", ".jpg", ".jpeg", ".PNG", ".JPG", ".bmp", ".tif", ".tiff", ".pgm", ".ppm"}) {
    fs::path p = path;
    p += ext;
    if (fs::is_directory(p, ec)) fail("{}: is a directory, not an image file", p.string());
    if (fs::exists(p, ec)) return p;
  }
  return std::nullopt;
}

void checkListedImage(const fs::path& image, const fs::path& index, size_t line) {
  std::error_code ec;
  const fs::file_type type = fs::status(image, ec).type();
  if (type == fs::file_type::not_found) fail("{}:{}: image {} not found", index.string(), line, image.string());
  if (type == fs::file_type::directory)
    fail("{}:{}: image {} is a directory, not an image file", index.string(), line, image.string());
}

std::string readYamlText(const fs::path& file) {
  std::istringstream in(readInputFile(file, "YAML file", kMaxYamlFileBytes));
  std::ostringstream os;
  std::string s;
  bool first = true;
  while (std::getline(in, s)) {
    // OpenCV FileStorage writes "%YAML:1.0", which is not a valid YAML directive.
    if (first && s.rfind("%YAML", 0) == 0) s = "# " + s;
    first = false;
    os << s << '\n';
  }
  return os.str();
}

int imageDimension(double value, const std::string& where, const std::string& field) {
  if (!std::isfinite(value) || value < 1 || value > 65535 || value != std::floor(value))
    throw fieldError(where, field, fmt::format("image size {} is not a whole number in [1, 65535]", value));
  return static_cast<int>(value);
}

}  // namespace nerfslam::io_detail
