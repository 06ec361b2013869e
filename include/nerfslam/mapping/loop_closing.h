#pragma once
// Loop closing (ORB-SLAM's LoopClosing, with our keyframe database, Sim(3) solver and essential
// graph): a thread of its own that takes every keyframe the mapping thread has processed (submit(),
// a bounded queue that drops the newest when full, like the mapping queue) and
//   1. detection: the keyframe's bag of words goes into the keyframe database (tracking/
//      keyframe_database.h); candidates are the keyframes scoring above the lowest score of the
//      keyframe's covisible neighbours (min_shared_points or more shared), the neighbours excluded;
//      a candidate is accepted when it (or a keyframe covisible with it) was a candidate for
//      `consistency` consecutive keyframes;
//   2. geometry: map points matched through the vocabulary's direct index (bow_matcher.h) give a
//      Sim(3) between the two keyframes (sim3_solver.h, RANSAC then Ceres); the loop side's points
//      projected into the keyframe by it must match at least min_projection_matches keypoints;
//   3. correction, with the mapping thread held (MappingThread::hold: the local mapper pauses only
//      here): the Sim(3) is propagated to the keyframe's covisible neighbourhood, the loop side's
//      points replace the duplicates the neighbourhood made (fusion by projection), the essential
//      graph (consecutive keyframes, strong covisibility, loop edges) is optimised over Sim(3)
//      (pose_graph.h, the loop keyframe fixed), and every keyframe and point moves with it (a point
//      with the keyframe of its first observation). Keyframes made while the loop was being found
//      are in the map when the hold is taken, so they are corrected with the rest;
//   4. a global bundle adjustment in the background (global_ba, on by default; ORB-SLAM3's RunGlobalBundleAdjustment)
//      on a thread of its own: it copies the map and solves without holding anything, is stopped by
//      the next closure (which then starts a new one) and at stop(), and writes its result with the
//      mapping thread held: keyframes and points it adjusted get its poses and positions, keyframes
//      made meanwhile move with their parent (the adjusted keyframe they share the most points with,
//      else the newest older one) as ORB-SLAM3 propagates through its spanning tree, and points made
//      meanwhile with their reference keyframe (their first observation). idle() is false while it
//      runs, so offline (lockstep) runs wait for it and stay reproducible.
// The tracking thread never waits for it: it asks correctionsSince() at its next frame and moves its
// own pose, motion model and the frames' relative poses by the correction (SlamSystem).
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <unordered_map>
#include <utility>
#include <vector>

#include "nerfslam/core/bounded_queue.h"
#include "nerfslam/core/options.h"
#include "nerfslam/core/pose.h"
#include "nerfslam/mapping/map.h"
#include "nerfslam/mapping/place_recognition.h"
#include "nerfslam/mapping/pose_graph.h"
#include "nerfslam/tracking/keyframe_database.h"
#include "nerfslam/tracking/sim3_solver.h"
#include "nerfslam/tracking/vocabulary.h"

namespace nerfslam {

class MappingThread;
class LocalMapper;

struct LoopClosingOptions {
  bool enabled = true;
  std::string vocabulary;  // empty: the shipped config/vocabulary/brief_k12_L4.voc
  int queue = 5;
  int min_keyframes = 12;      // no detection before the map has this many keyframes
  int min_keyframe_gap = 10;   // keyframes after a closure before the next detection
  int min_shared_points = 15;  // a covisible neighbour, for the minimum score (and excluded)
  int consistency = 3;         // consecutive keyframes that must find the same place
  int max_candidates = 5;      // best database candidates examined per keyframe
  int direct_index_level = 1;  // vocabulary level of the guided matching (bow_matcher.h)
  int min_bow_matches = 20;    // matched map-point pairs needed to try a Sim(3)
  // The Sim(3) solver's inliers. 30, not ORB-SLAM's 20: the true closures of our synthetic loops
  // have 40-58, a false one in the 600-frame room (perceptual aliasing of its textures: frame 500
  // with frame 286, truly 50 degrees apart) 23, and the orbit's 21 corrected only 0.018.
  int min_sim3_inliers = 30;
  int min_projection_matches = 40;    // keypoints the loop side's points match by projection
  double projection_radius_px = 7.5;  // search radius by projection (x the keypoint's level scale)
  int max_descriptor_distance = 50;   // Hamming distance of a projection match
  int loop_group_keyframes = 10;      // the loop keyframe and its best covisibles: the points projected
  int essential_min_shared = 100;     // covisibility edges of the essential graph
  int pose_graph_iterations = 20;
  // A global BA in the background after each closure: on since the pyramid's keypoints sit at their
  // true scale (it had raised the room loops' ATE by fitting their bias; docs/benchmarks.md).
  bool global_ba = true;
  int global_ba_iterations = 10;  // its iterations (ORB-SLAM3: 10)

  template <class V>
  void visit(V& v) {
    v("enabled", enabled, "Detect and correct loops on a thread of their own");
    v("vocabulary", vocabulary,
      "Vocabulary file (nerfslam_learn_vocabulary) of the keyframe database (loop closing and relocalisation; "
      "read also when loop closing is off); empty: the shipped config/vocabulary/brief_k12_L4.voc");
    v("queue", queue, "Keyframes queued for loop detection before new ones are dropped", check::range(1, 1000));
    v("min_keyframes", min_keyframes, "Keyframes in the map before loops are looked for", check::range(2, 100000));
    v("min_keyframe_gap", min_keyframe_gap, "Keyframes after a closure before the next detection",
      check::range(0, 100000));
    v("min_shared_points", min_shared_points,
      "Shared points that make a keyframe a covisible neighbour (its score is a candidate's minimum; it is "
      "never a candidate)",
      check::range(1, 100000));
    v("consistency", consistency, "Consecutive keyframes that must find the same place (or a covisible one)",
      check::range(1, 100));
    v("max_candidates", max_candidates, "Best place candidates examined per keyframe", check::range(1, 1000));
    v("direct_index_level", direct_index_level, "Vocabulary level of the guided matching between two keyframes",
      check::range(1, 8));
    v("min_bow_matches", min_bow_matches, "Matched map-point pairs needed to try a Sim(3)", check::range(3, 100000));
    v("min_sim3_inliers", min_sim3_inliers, "Inliers of the Sim(3) (RANSAC, then refined)", check::range(3, 100000));
    v("min_projection_matches", min_projection_matches,
      "Keypoints of the keyframe the loop side's points must match by projection to accept the loop",
      check::range(1, 100000));
    v("projection_radius_px", projection_radius_px, "Search radius of the matching by projection (x level scale)",
      check::positive<double>());
    v("max_descriptor_distance", max_descriptor_distance, "Hamming distance of a match by projection",
      check::range(1, 256));
    v("loop_group_keyframes", loop_group_keyframes,
      "The loop keyframe and its best covisible keyframes whose points are projected", check::range(1, 1000));
    v("essential_min_shared", essential_min_shared, "Shared points of a covisibility edge of the essential graph",
      check::range(1, 100000));
    v("pose_graph_iterations", pose_graph_iterations, "Iterations of the essential-graph optimisation",
      check::range(1, 1000));
    v("global_ba", global_ba,
      "After each closure, a global bundle adjustment in the background (stopped by the next closure and at the "
      "end; the mapping thread pauses only while its result is written)");
    v("global_ba_iterations", global_ba_iterations, "Iterations of the background global BA", check::range(1, 1000));
  }
};

// One closed loop.
struct LoopClosureRecord {
  uint64_t frame = 0;  // the current keyframe's frame
  KeyframeId current = -1, loop = -1;
  uint64_t loop_frame = 0;
  double sim3_scale = 1;      // of S(current <- loop) found by the solver
  double correction_m = 0;    // the current keyframe's centre moved by (map units)
  double correction_deg = 0;  // its rotation changed by
  int sim3_inliers = 0, projection_matches = 0, fused_points = 0, corrected_keyframes = 0;
  double detection_ms = 0;   // from the keyframe's arrival to the accepted Sim(3)
  double correction_ms = 0;  // with the mapping thread held
};

// One background global BA (after closure `closure`, 0-based).
struct GlobalBaRecord {
  int closure = 0;
  int keyframes = 0, points = 0;     // adjusted
  int iterations = 0, outliers = 0;  // observations removed
  double rmse_before_px = 0, rmse_after_px = 0;
  int propagated_keyframes = 0, propagated_points = 0;  // made meanwhile, moved with their parent / keyframe
  bool stopped = false;                                 // by a new closure or stop(): nothing written
  double solve_ms = 0;                                  // copying the map and solving, nothing held
  double write_ms = 0;                                  // with the mapping thread held
};

// One applied correction: per keyframe the similarity its pose moved by (S_world_kf after = delta *
// before; points move with their keyframe), and Map::version() just before the map was written (a
// copy of the map read at a later version already has it).
struct LoopCorrection {
  std::map<KeyframeId, Sim3> delta;
  uint64_t map_version_before = 0;
};

// A loop found and checked, to be corrected (detect()).
struct LoopCandidate {
  KeyframeId current = -1, loop = -1;
  Sim3 S_cur_loop;                               // p_current_cam = S * p_loop_cam
  Sim3 S_world_cur;                              // the current keyframe's corrected pose as a similarity
  std::vector<std::pair<int, PointId>> matches;  // current keypoint -> loop-side point (by projection)
  int sim3_inliers = 0;
  double detection_ms = 0;
};

// Keypoints of `frame` posed at S_world_cam (a similarity) that the points match by projection:
// (keypoint, point), one point per keypoint (the closest descriptor), points behind the camera or
// outside the image skipped.
std::vector<std::pair<int, PointId>> matchPointsByProjection(const Frame& frame, const Sim3& S_world_cam,
                                                             const std::vector<MapPoint>& points, double radius_px,
                                                             int max_distance);

class LoopClosing {
 public:
  // `mapping` (may be null: tests) is held while the map is corrected. `places`: the database
  // shared with relocalisation (SlamSystem); null: one of its own over `vocabulary`.
  LoopClosing(Map& map, MappingThread* mapping, std::shared_ptr<const Vocabulary> vocabulary,
              LoopClosingOptions options, std::shared_ptr<PlaceRecognition> places = nullptr);
  ~LoopClosing();
  LoopClosing(const LoopClosing&) = delete;
  LoopClosing& operator=(const LoopClosing&) = delete;

  void start();
  // Finishes the queued keyframes, then joins; a running global BA is stopped (nothing written).
  // Idempotent.
  void stop();
  // Non-blocking; false when the queue is full (counted) or stopped.
  bool submit(KeyframeId id);
  bool idle() const { return pending_.load() == 0 && !gba_running_.load(); }
  void waitIdle() const;
  uint64_t droppedKeyframes() const { return queue_.dropped(); }

  // The steps, in the calling thread (the thread runs process()): detect() adds the keyframe to the
  // database and returns a checked loop; correct() applies it.
  std::optional<LoopCandidate> detect(KeyframeId id);
  bool correct(const LoopCandidate& loop, LoopClosureRecord* record = nullptr);
  void process(KeyframeId id);
  // The background global BA: startGlobalBa() stops a running one and starts a new one on its own
  // thread; runGlobalBa() is its body (solve, then write with the mapping thread held), callable
  // directly (tests); stopGlobalBa() stops and joins it. writeGlobalBa(): the write step alone
  // (LocalMapper::solveGlobalBundleAdjustment's solution of the map as it was).
  void startGlobalBa();
  bool runGlobalBa(GlobalBaRecord* record = nullptr);
  void stopGlobalBa();
  void writeGlobalBa(const MapUpdate& solution, GlobalBaRecord* record = nullptr);
  std::vector<GlobalBaRecord> globalBas() const;
  // Forgets every keyframe (the map was cleared); only while idle().
  void clear();

  // Corrections applied so far. correctionsSince(&seen, &delta): the composed per-keyframe
  // correction (S_world_kf after = delta * before) of the corrections after `seen`, which it then
  // sets to the current count; false when there is none.
  uint64_t corrections() const { return corrections_.load(std::memory_order_acquire); }
  bool correctionsSince(uint64_t* seen, std::map<KeyframeId, Sim3>* delta) const;
  // The same, each correction on its own, in order.
  bool correctionsSince(uint64_t* seen, std::vector<LoopCorrection>* corrections) const;
  std::vector<LoopClosureRecord> closures() const;
  // Time of each keyframe's detection step (ms), in order.
  std::vector<double> detectionTimes() const;
  const PlaceRecognition& database() const { return *places_; }
  const LoopClosingOptions& options() const { return opt_; }

 private:
  void run();
  struct Bow {
    BowVector bow;
    FeatureVector direct;
  };
  const Bow* bowOf(KeyframeId id, const Keyframe* kf);
  std::optional<LoopCandidate> checkGeometry(const Keyframe& cur, const Bow& cur_bow, KeyframeId loop);

  Map& map_;
  MappingThread* mapping_;
  std::shared_ptr<const Vocabulary> voc_;
  LoopClosingOptions opt_;
  std::shared_ptr<PlaceRecognition> places_;
  std::unordered_map<KeyframeId, Bow> bows_;
  // Consistency groups of the previous keyframe: (keyframes of the group, consecutive count).
  std::vector<std::pair<std::vector<KeyframeId>, int>> groups_;
  KeyframeId last_loop_kf_ = -1;

  BoundedQueue<KeyframeId> queue_;
  std::thread thread_;
  std::atomic<int> pending_{0};
  mutable std::mutex mutex_;  // closures_, deltas_, detection_ms_
  mutable std::condition_variable idle_cv_;
  std::vector<LoopClosureRecord> closures_;
  std::vector<LoopCorrection> deltas_;  // per correction
  std::vector<double> detection_ms_;
  std::atomic<uint64_t> corrections_{0};
  bool started_ = false;
  // The background global BA.
  std::unique_ptr<LocalMapper> own_mapper_;  // when there is no mapping thread (tests)
  std::thread gba_thread_;
  std::atomic<bool> gba_stop_{false}, gba_running_{false};
  std::vector<GlobalBaRecord> gbas_;  // under mutex_
};

// The shipped vocabulary's path (NERFSLAM_SOURCE_DIR/config/vocabulary/brief_k12_L4.voc), or
// `given` when not empty.
std::string vocabularyPath(const std::string& given);

}  // namespace nerfslam
