#include "nerfslam/render/trajectory_plot.h"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>
#include <opencv2/imgproc.hpp>

#include "nerfslam/core/error.h"

namespace nerfslam {
namespace {

const cv::Scalar kInk(30, 30, 30), kGrid(225, 225, 225), kPaper(255, 255, 255);
constexpr int kFont = cv::FONT_HERSHEY_SIMPLEX;
constexpr int kShift = 4;  // sub-pixel bits of the polylines

double tickStep(double range, int count) {
  const double raw = range / std::max(1, count);
  const double p = std::pow(10.0, std::floor(std::log10(raw)));
  for (double m : {1.0, 2.0, 5.0})
    if (raw <= m * p * (1 + 1e-9)) return m * p;
  return 10 * p;
}

std::string tickLabel(double v, double step) {
  const int decimals = std::max(0, int(-std::floor(std::log10(step) + 1e-9)));
  if (std::abs(v) < 0.5 * step) v = 0;  // no "-0"
  return fmt::format("{:.{}f}", v, decimals);
}

void text(cv::Mat& img, const std::string& s, cv::Point at, double scale, int thickness = 1,
          const cv::Scalar& color = kInk) {
  cv::putText(img, s, at, kFont, scale, color, thickness, cv::LINE_AA);
}

cv::Size textSize(const std::string& s, double scale, int thickness = 1) {
  int base = 0;
  return cv::getTextSize(s, kFont, scale, thickness, &base);
}

}  // namespace

cv::Point2d TrajectoryPlot::toPixel(const Eigen::Vector3d& p) const {
  const double u = frame.x + (p[axis_h] - h_lo) / (h_hi - h_lo) * frame.width;
  const double v = frame.y + (v_hi - p[axis_v]) / (v_hi - v_lo) * frame.height;
  return {u, v};
}

TrajectoryPlot plotTrajectories(const std::vector<PlotSeries>& series, const TrajectoryPlotOptions& o) {
  if (o.width < 200 || o.height < 200 || o.width > 8192 || o.height > 8192)
    fail("trajectory plot size {}x{} invalid: width and height must be in 200..8192", o.width, o.height);
  const PlotSeries* ref = nullptr;
  for (const auto& s : series)
    if (!s.positions.empty()) {
      ref = &s;
      break;
    }
  if (!ref) fail("trajectory plot: no positions to draw");
  TrajectoryPlot pl;
  // The plane of largest motion: the two axes along which the reference spreads most.
  Eigen::Vector3d rlo = ref->positions[0], rhi = rlo;
  for (const auto& p : ref->positions) rlo = rlo.cwiseMin(p), rhi = rhi.cwiseMax(p);
  const Eigen::Vector3d spread = rhi - rlo;
  int drop = 0;
  if (o.up && o.up->allFinite() && o.up->norm() > 0) {
    o.up->cwiseAbs().maxCoeff(&drop);
  } else {
    for (int k = 1; k < 3; ++k)
      if (spread[k] < spread[drop]) drop = k;
  }
  pl.axis_h = drop == 0 ? 1 : 0;
  pl.axis_v = drop == 2 ? 1 : 2;
  const char* names = "xyz";
  pl.plane = fmt::format("{}-{} plane", names[pl.axis_h], names[pl.axis_v]);

  // Data extent of every series on the two axes.
  double hl = 1e300, hh = -1e300, vl = 1e300, vh = -1e300;
  for (const auto& s : series)
    for (const auto& p : s.positions) {
      hl = std::min(hl, p[pl.axis_h]), hh = std::max(hh, p[pl.axis_h]);
      vl = std::min(vl, p[pl.axis_v]), vh = std::max(vh, p[pl.axis_v]);
    }
  const double pad = 0.04 * std::max({hh - hl, vh - vl, 1e-6});
  hl -= pad, hh += pad, vl -= pad, vh += pad;

  // Layout: title and subtitle above, tick labels left and below.
  const int left = 100, right = 30, top = 96, bottom = 70;
  const int fw = o.width - left - right, fh = o.height - top - bottom;
  // One tick step for both axes (equal scale: grid squares), the axes' ends on ticks, then the
  // shorter side widened (centred) to fill the frame at that scale.
  const double step = std::max(tickStep(hh - hl, std::max(2, fw / 160)), tickStep(vh - vl, std::max(2, fh / 160)));
  hl = std::floor(hl / step) * step, hh = std::ceil(hh / step) * step;
  vl = std::floor(vl / step) * step, vh = std::ceil(vh / step) * step;
  const double scale = std::min(fw / (hh - hl), fh / (vh - vl));  // pixels per unit
  const double hc = 0.5 * (hl + hh), vc = 0.5 * (vl + vh);
  pl.h_lo = hc - 0.5 * fw / scale, pl.h_hi = hc + 0.5 * fw / scale;
  pl.v_lo = vc - 0.5 * fh / scale, pl.v_hi = vc + 0.5 * fh / scale;
  pl.frame = cv::Rect(left, top, fw, fh);
  for (double k = std::ceil(pl.h_lo / step - 1e-9); k * step <= pl.h_hi + 1e-9 * step; ++k)
    pl.h_ticks.push_back(k * step);
  for (double k = std::ceil(pl.v_lo / step - 1e-9); k * step <= pl.v_hi + 1e-9 * step; ++k)
    pl.v_ticks.push_back(k * step);

  cv::Mat img(o.height, o.width, CV_8UC3, kPaper);
  // Grid and tick labels.
  const double ts = 0.5;
  for (double t : pl.h_ticks) {
    const int u = int(std::lround(pl.toPixel(Eigen::Vector3d::Constant(t)).x));
    cv::line(img, {u, pl.frame.y}, {u, pl.frame.br().y}, kGrid, 1);
    cv::line(img, {u, pl.frame.br().y}, {u, pl.frame.br().y + 6}, kInk, 1);
    const std::string s = tickLabel(t, step);
    text(img, s, {u - textSize(s, ts).width / 2, pl.frame.br().y + 24}, ts);
  }
  for (double t : pl.v_ticks) {
    const int v = int(std::lround(pl.toPixel(Eigen::Vector3d::Constant(t)).y));
    cv::line(img, {pl.frame.x, v}, {pl.frame.br().x, v}, kGrid, 1);
    cv::line(img, {pl.frame.x - 6, v}, {pl.frame.x, v}, kInk, 1);
    const std::string s = tickLabel(t, step);
    text(img, s, {pl.frame.x - 10 - textSize(s, ts).width, v + 6}, ts);
  }
  cv::rectangle(img, pl.frame, kInk, 1);
  const std::string hlabel = fmt::format("{} [{}]", names[pl.axis_h], o.unit);
  const std::string vlabel = fmt::format("{} [{}]", names[pl.axis_v], o.unit);
  text(img, hlabel, {pl.frame.x + fw / 2 - textSize(hlabel, 0.6).width / 2, o.height - 16}, 0.6);
  text(img, vlabel, {8, pl.frame.y - 18}, 0.6);
  if (!o.title.empty()) text(img, o.title, {left, 34}, 0.7, 2);
  text(img, fmt::format("top view onto the {}; grid {} {}", pl.plane, tickLabel(step, step), o.unit), {left, 62}, 0.55);

  // The series (the first underneath, thicker), each with a dot at its start.
  cv::Mat plot = img(pl.frame);
  std::vector<cv::Point> corners_hits(4, cv::Point(0, 0));
  for (size_t i = 0; i < series.size(); ++i) {
    const auto& s = series[i];
    if (s.positions.empty()) continue;
    std::vector<cv::Point> pts;
    for (const auto& p : s.positions) {
      const cv::Point2d q = pl.toPixel(p) - cv::Point2d(pl.frame.x, pl.frame.y);
      pts.emplace_back(int(std::lround(q.x * (1 << kShift))), int(std::lround(q.y * (1 << kShift))));
      corners_hits[(q.x > fw / 2 ? 1 : 0) + (q.y > fh / 2 ? 2 : 0)].x++;
    }
    const cv::Scalar c(s.color[0], s.color[1], s.color[2]);
    cv::polylines(plot, pts, false, c, i == 0 && series.size() > 1 ? 4 : 2, cv::LINE_AA, kShift);
    cv::circle(plot, pts.front(), 7 << kShift, c, 2, cv::LINE_AA, kShift);
  }
  // Legend in the quadrant the trajectories use least.
  std::vector<std::pair<std::string, cv::Scalar>> entries;
  for (const auto& s : series)
    if (!s.label.empty()) entries.emplace_back(s.label, cv::Scalar(s.color[0], s.color[1], s.color[2]));
  if (!entries.empty()) {
    int q = 0;
    for (int k = 1; k < 4; ++k)
      if (corners_hits[k].x < corners_hits[q].x) q = k;
    int w = textSize("o  start", 0.55).width;
    for (const auto& e : entries) w = std::max(w, textSize(e.first, 0.55).width);
    const cv::Size box(w + 64, 26 * int(entries.size() + 1) + 10);
    const cv::Point at(q & 1 ? fw - box.width - 12 : 12, q & 2 ? fh - box.height - 12 : 12);
    cv::rectangle(plot, cv::Rect(at, box), kPaper, cv::FILLED);
    cv::rectangle(plot, cv::Rect(at, box), cv::Scalar(190, 190, 190), 1);
    int y = at.y + 24;
    for (const auto& [label, color] : entries) {
      cv::line(plot, {at.x + 10, y - 6}, {at.x + 44, y - 6}, color, 3, cv::LINE_AA);
      text(plot, label, {at.x + 54, y}, 0.55);
      y += 26;
    }
    cv::circle(plot, {at.x + 27, y - 6}, 7, kInk, 2, cv::LINE_AA);
    text(plot, "start", {at.x + 54, y}, 0.55);
  }
  pl.image = img;
  return pl;
}

}  // namespace nerfslam
