#pragma once
// All tracking options as one YAML section ("tracking": features, initializer, tracker, keyframes,
// relocalizer) for the system's option tree.
#include "nerfslam/core/options.h"
#include "nerfslam/tracking/frame.h"
#include "nerfslam/tracking/initializer.h"
#include "nerfslam/tracking/relocalizer.h"
#include "nerfslam/tracking/tracker.h"

namespace nerfslam {

struct TrackingOptions {
  FeatureOptions features;
  InitializerOptions initializer;
  TrackerOptions tracker;
  KeyframePolicyOptions keyframes;
  RelocalizerOptions relocalizer;
  template <class V>
  void visit(V& v) {
    v("features", features, "FAST corners and steered-BRIEF descriptors");
    v("initializer", initializer, "Two-view map initialisation");
    v("tracker", tracker, "Frame-to-map pose tracking");
    v("keyframes", keyframes, "Keyframe decision");
    v("relocalizer", relocalizer, "Relocalisation when lost");
  }
};

}  // namespace nerfslam
