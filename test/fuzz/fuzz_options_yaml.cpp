// libFuzzer target for core/options_yaml.h: loadYamlFile + loadOptions + validateOptions on an
// options struct with every leaf type the loader supports (bool, int, int64, float, double, string,
// lists of double and int), nested sections, constraints, and two real option structs.
#include <cstdint>
#include <string>
#include <vector>

#include "fuzz_common.h"
#include "nerfslam/core/options_yaml.h"
#include "nerfslam/eval/trajectory_metrics.h"

using namespace nerfslam;

namespace {

struct LeafOptions {
  bool flag = false;
  int count = 3;
  int64_t big = 1;
  float ratio = 0.5f;
  double scale = 1.0;
  std::string mode = "a";
  std::vector<double> weights = {1.0, 2.0};
  std::vector<int> sizes = {4};
  template <class V>
  void visit(V& v) {
    v("flag", flag, "a bool");
    v("count", count, "an int", check::range(0, 100));
    v("big", big, "an int64", check::nonNegative<int64_t>());
    v("ratio", ratio, "a float", check::range(0.0f, 1.0f));
    v("scale", scale, "a double", check::positive<double>());
    v("mode", mode, "a string", check::oneOf({"a", "b"}));
    v("weights", weights, "a list of double");
    v("sizes", sizes, "a list of int");
  }
};

struct CoreLike {
  int threads = 0;
  std::string log_level = "info";
  int64_t seed = 0;
  template <class V>
  void visit(V& v) {
    v("threads", threads, "an int in a range", check::range(0, 1024));
    v("log_level", log_level, "a string of a set", check::oneOf({"trace", "debug", "info", "warn", "error", "off"}));
    v("seed", seed, "a non-negative int64", check::nonNegative<int64_t>());
  }
};

struct FuzzOptions {
  CoreLike core;
  TrajectoryEvalOptions eval;
  LeafOptions leaf;
  struct Outer {
    LeafOptions inner;
    double x = 0;
    template <class V>
    void visit(V& v) {
      v("inner", inner, "nested section");
      v("x", x, "a double");
    }
  } outer;
  template <class V>
  void visit(V& v) {
    v("core", core, "three checked scalars");
    v("eval", eval, "TrajectoryEvalOptions");
    v("leaf", leaf, "every leaf type");
    v("outer", outer, "two levels of nesting");
  }
};

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  fuzz::quietLogs();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const auto path = fuzz::scratchDir() / "options.yaml";
  fuzz::writeBytes(path, std::string_view(reinterpret_cast<const char*>(data), size));
  fuzz::expectOnlyError([&] {
    FuzzOptions o;
    loadOptionsFile(path, o);
    volatile size_t sink = printOptions(o).size();
    (void)sink;
    validateOptions(o, path.string());
  });
  return 0;
}
