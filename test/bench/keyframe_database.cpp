// Keyframe-database query time as the map grows: 50, 500 and 5,000 keyframes, one core (CPU time
// of the calling thread). Keyframes carry real bags of words: our features of the shared data's
// image sequences (KITTI 06, New Tsukuba, EuRoC, the temple ring, the fountain) with the shipped
// vocabulary, keyframe n drawing image n modulo their number and a random 70 % of its features
// (so that no two keyframes are alike). Queries: a different 70 % of each image. Printed: median and
// p99 query time, postings walked and candidates scored per query. Google Benchmark timings follow
// (queries, and the bag of words of one image). Then relocalisation's candidate query
// (PlaceRecognition::relocalizationCandidates: the database query, the covisibility of the keyframes
// sharing the most words, the groups) on a map of 50, 500 and 5,000 keyframes with those bags, each
// keyframe covisible with the next (30 shared points).
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cstdio>
#include <random>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "nerfslam/core/timing.h"
#include "nerfslam/mapping/place_recognition.h"
#include "nerfslam/tracking/frame.h"
#include "nerfslam/tracking/keyframe_database.h"
#include "test_support.h"

namespace nerfslam {
namespace {

struct Data {
  Vocabulary voc;
  std::vector<cv::Mat> descriptors;  // per image
};

const Data& data() {
  static const Data d = [] {
    Data x;
    x.voc = loadVocabulary(test::sourceDir() / "config/vocabulary/brief_k12_L4.voc");
    const auto root = test::dataDir();
    for (const char* dir : {"kitti06_first51/image_l", "new_tsukuba_150/images", "euroc_V1_01_piece/mav0/cam0/data",
                            "middlebury_templeRing", "strecha_fountain-P11/images"}) {
      std::vector<std::filesystem::path> files;
      if (!std::filesystem::exists(root / dir)) continue;
      for (const auto& e : std::filesystem::directory_iterator(root / dir))
        if (e.path().extension() == ".png" || e.path().extension() == ".jpg") files.push_back(e.path());
      std::sort(files.begin(), files.end());
      for (const auto& f : files) {
        const cv::Mat img = cv::imread(f.string(), cv::IMREAD_GRAYSCALE);
        if (img.empty()) continue;
        const Camera cam = Camera::pinhole(img.cols, img.rows, img.cols, img.cols, img.cols / 2.0, img.rows / 2.0);
        x.descriptors.push_back(extractFrame(img, cam, FeatureOptions{}).descriptors);
      }
    }
    return x;
  }();
  return d;
}

BowVector subsetBow(const Data& d, size_t image, std::mt19937& rng) {
  const cv::Mat& all = d.descriptors[image];
  cv::Mat sub;
  for (int r = 0; r < all.rows; ++r)
    if (rng() % 10 < 7) sub.push_back(all.row(r));
  BowVector b;
  d.voc.transform(sub, &b);
  return b;
}

KeyframeDatabase makeDatabase(const Data& d, size_t n) {
  KeyframeDatabase db(d.voc.wordCount());
  std::mt19937 rng{static_cast<uint32_t>(n)};
  for (size_t k = 0; k < n; ++k) db.add(k, subsetBow(d, k % d.descriptors.size(), rng));
  return db;
}

void printTable() {
  const Data& d = data();
  if (d.descriptors.empty()) {
    std::printf("no images found under %s\n", test::dataDir().string().c_str());
    return;
  }
  std::mt19937 rng(99);
  std::vector<BowVector> queries;
  for (size_t i = 0; i < d.descriptors.size(); ++i) queries.push_back(subsetBow(d, i, rng));
  std::printf("%zu images, %zu words; query: min score 0, 10 results\n", d.descriptors.size(), d.voc.wordCount());
  std::printf("%10s %10s %12s %12s %14s %12s\n", "keyframes", "postings", "median ms", "p99 ms", "postings/query",
              "candidates");
  for (size_t n : {50, 500, 5000}) {
    const KeyframeDatabase db = makeDatabase(d, n);
    std::vector<double> ms;
    double walked = 0, candidates = 0;
    PlaceQuery q;
    for (int rep = 0; rep < 3; ++rep)
      for (const BowVector& b : queries) {
        const double t0 = threadCpuMs();
        const auto r = db.query(b, q);
        ms.push_back(threadCpuMs() - t0);
        benchmark::DoNotOptimize(r.data());
        if (rep == 0) {
          PlaceQuery all;
          all.max_results = 0;
          candidates += double(db.query(b, all).size());
          for (const auto& e : b) walked += double(db.postingCount(e.first));
        }
      }
    std::sort(ms.begin(), ms.end());
    std::printf("%10zu %10zu %12.3f %12.3f %14.0f %12.0f\n", n, db.postingCount(), ms[ms.size() / 2],
                ms[size_t(0.99 * double(ms.size()))], walked / double(queries.size()),
                candidates / double(queries.size()));
  }
}

// The map's keyframes: 200 keypoints with random descriptors (the map needs a frame per keyframe;
// the bags come from the images), consecutive keyframes sharing 30 points.
void printRelocalizationTable() {
  const Data& d = data();
  if (d.descriptors.empty()) return;
  auto voc = std::make_shared<const Vocabulary>(d.voc);
  std::mt19937 qrng(99);
  std::vector<BowVector> queries;
  for (size_t i = 0; i < d.descriptors.size(); ++i) queries.push_back(subsetBow(d, i, qrng));
  std::printf("\nrelocalisation candidates (PlaceRecognition::relocalizationCandidates, 5 kept)\n");
  std::printf("%10s %12s %12s %12s\n", "keyframes", "median ms", "p99 ms", "candidates");
  for (size_t n : {50, 500, 5000}) {
    Map map;
    PlaceRecognition places(voc);
    std::mt19937 rng{static_cast<uint32_t>(n)};
    std::vector<KeyframeId> ids;
    for (size_t k = 0; k < n; ++k) {
      auto f = std::make_shared<Frame>();
      f->descriptors = cv::Mat(200, 32, CV_8U);
      cv::randu(f->descriptors, 0, 256);
      for (int i = 0; i < 200; ++i) {
        f->keypoints.emplace_back(cv::Point2f(float(i), float(i)), 7.f);
        f->undistorted.emplace_back(i, i);
      }
      Keyframe kf;
      kf.frame = f;
      ids.push_back(map.addKeyframe(kf));
      places.add(ids.back(), subsetBow(d, k % d.descriptors.size(), rng));
      if (k > 0)
        for (int j = 0; j < 30; ++j)
          map.addPoint(Eigen::Vector3d(double(k), double(j), 5.0), {{ids[k - 1], 100 + j}, {ids[k], j}});
    }
    std::vector<double> ms;
    double kept = 0;
    for (int rep = 0; rep < 3; ++rep)
      for (const BowVector& b : queries) {
        const double t0 = threadCpuMs();
        const auto r = places.relocalizationCandidates(map, b);
        ms.push_back(threadCpuMs() - t0);
        if (rep == 0) kept += double(r.size());
      }
    std::sort(ms.begin(), ms.end());
    std::printf("%10zu %12.3f %12.3f %12.1f\n", n, ms[ms.size() / 2], ms[size_t(0.99 * double(ms.size()))],
                kept / double(queries.size()));
  }
}

void BM_Query(benchmark::State& state) {
  const Data& d = data();
  if (d.descriptors.empty()) {
    state.SkipWithError("no shared data");
    return;
  }
  const KeyframeDatabase db = makeDatabase(d, size_t(state.range(0)));
  std::mt19937 rng(7);
  std::vector<BowVector> queries;
  for (size_t i = 0; i < d.descriptors.size(); ++i) queries.push_back(subsetBow(d, i, rng));
  size_t i = 0;
  for (auto _ : state) {
    auto r = db.query(queries[i++ % queries.size()]);
    benchmark::DoNotOptimize(r.data());
  }
}
BENCHMARK(BM_Query)->Arg(50)->Arg(500)->Arg(5000)->Unit(benchmark::kMicrosecond);

// Bag of words and direct index (level 1) of one image's descriptors (about 1,000 features).
void BM_Transform(benchmark::State& state) {
  const Data& d = data();
  if (d.descriptors.empty()) {
    state.SkipWithError("no shared data");
    return;
  }
  size_t i = 0;
  BowVector bow;
  FeatureVector direct;
  for (auto _ : state) {
    d.voc.transform(d.descriptors[i++ % d.descriptors.size()], &bow, &direct, 1);
    benchmark::DoNotOptimize(bow.data());
  }
}
BENCHMARK(BM_Transform)->Unit(benchmark::kMicrosecond);

}  // namespace
}  // namespace nerfslam

int main(int argc, char** argv) {
  nerfslam::printTable();
  nerfslam::printRelocalizationTable();
  benchmark::Initialize(&argc, argv);
  benchmark::RunSpecifiedBenchmarks();
  return 0;
}
