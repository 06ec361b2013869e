#include <gtest/gtest.h>

#include <algorithm>
#include <fstream>
#include <sstream>

#include "nerfslam/core/error.h"
#include "nerfslam/core/options_yaml.h"
#include "test_support.h"

namespace nerfslam {
namespace {

struct SampleTracker {
  int fast_threshold = 20;
  double min_parallax_deg = 1.0;
  std::string matcher = "patch";
  bool use_pyramid = true;
  std::vector<double> scales = {1.0, 0.5};
  template <class V>
  void visit(V& v) {
    v("fast_threshold", fast_threshold, "FAST corner threshold on 8-bit intensities", check::range(1, 255));
    v("min_parallax_deg", min_parallax_deg, "Smallest median parallax accepted by initialisation",
      check::positive<double>());
    v("matcher", matcher, "Map-point matcher", check::oneOf({"patch", "orb"}));
    v("use_pyramid", use_pyramid, "Track on an image pyramid");
    v("scales", scales, "Pyramid scales");
  }
};

// A section of three leaves (threads, log level, seed), as a process-wide section would be.
struct SampleCore {
  int threads = 0;
  std::string log_level = "info";
  int64_t seed = 0;
  template <class V>
  void visit(V& v) {
    v("threads", threads, "Worker threads for parallel stages; 0 = all cores", check::range(0, 1024));
    v("log_level", log_level, "spdlog level for console output",
      check::oneOf({"trace", "debug", "info", "warn", "error", "off"}));
    v("seed", seed, "Seed of every random number generator", check::nonNegative<int64_t>());
  }
};

struct SampleSystem {
  int64_t max_frames = 1000;
  float fps = 30.f;
  std::vector<int> levels = {0, 1};
  std::string name = "run";
  SampleTracker tracker;
  SampleCore core;
  template <class V>
  void visit(V& v) {
    v("max_frames", max_frames, "Stop after this many frames", check::nonNegative<int64_t>());
    v("fps", fps, "Frame rate | pipes are escaped", check::positive<float>());
    v("levels", levels, "Levels to use");
    v("name", name, "Run name");
    v("tracker", tracker, "Tracking front end");
    v("core", core, "Threads, logging, seed");
  }
};

std::string loadError(const std::string& yaml, SampleSystem& o) {
  try {
    loadOptions(YAML::Load(yaml), o, "run.yaml");
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

void expectMentions(const std::string& msg, const std::vector<std::string>& parts) {
  EXPECT_FALSE(msg.empty()) << "expected an error";
  for (const auto& p : parts) EXPECT_NE(msg.find(p), std::string::npos) << "'" << p << "' not in: " << msg;
}

TEST(Options, EditDistanceAndHint) {
  EXPECT_EQ(editDistance("", ""), 0u);
  EXPECT_EQ(editDistance("abc", ""), 3u);
  EXPECT_EQ(editDistance("kitten", "sitting"), 3u);
  EXPECT_EQ(editDistance("fast_threshold", "fast_threshlod"), 1u);  // transposition
  EXPECT_EQ(editDistance("fx", "fxx"), 1u);
  EXPECT_EQ(didYouMean("fast_treshold", {"matcher", "fast_threshold"}), " (did you mean 'fast_threshold'?)");
  EXPECT_EQ(didYouMean("zzzzzz", {"matcher", "fast_threshold"}), "");
}

TEST(Options, LoadsNestedYaml) {
  SampleSystem o;
  loadOptions(YAML::Load(R"(
max_frames: 5000000000
fps: 15.5
levels: [2, 3, 4]
name: kitchen
tracker:
  fast_threshold: 35
  matcher: orb
  use_pyramid: false
  scales: [1, 0.5, 0.25]
core:
  threads: 2
  log_level: debug
)"),
              o, "run.yaml");
  EXPECT_EQ(o.max_frames, 5000000000LL);
  EXPECT_FLOAT_EQ(o.fps, 15.5f);
  EXPECT_EQ(o.levels, (std::vector<int>{2, 3, 4}));
  EXPECT_EQ(o.name, "kitchen");
  EXPECT_EQ(o.tracker.fast_threshold, 35);
  EXPECT_EQ(o.tracker.matcher, "orb");
  EXPECT_FALSE(o.tracker.use_pyramid);
  EXPECT_EQ(o.tracker.scales, (std::vector<double>{1, 0.5, 0.25}));
  EXPECT_EQ(o.tracker.min_parallax_deg, 1.0);  // absent: default kept
  EXPECT_EQ(o.core.threads, 2);
  EXPECT_EQ(o.core.log_level, "debug");
  EXPECT_EQ(o.core.seed, 0);
  EXPECT_NO_THROW(validateOptions(o, "run.yaml"));
}

TEST(Options, EmptyDocumentAndEmptySectionKeepDefaults) {
  SampleSystem o;
  loadOptions(YAML::Load(""), o, "empty.yaml");
  loadOptions(YAML::Load("tracker:\n"), o, "empty.yaml");
  EXPECT_EQ(o.tracker.fast_threshold, 20);
  EXPECT_EQ(o.name, "run");
}

TEST(Options, UnknownKeyNamesSourceKeyAndHint) {
  SampleSystem o;
  expectMentions(loadError("tracker:\n  fast_treshold: 30\n", o),
                 {"run.yaml", "'tracker.fast_treshold'", "unknown option", "did you mean 'fast_threshold'?"});
  expectMentions(loadError("nmae: x\n", o), {"run.yaml", "'nmae'", "did you mean 'name'?"});
  // No hint when nothing is close.
  const std::string msg = loadError("completely_different: 1\n", o);
  expectMentions(msg, {"run.yaml", "'completely_different'", "unknown option"});
  EXPECT_EQ(msg.find("did you mean"), std::string::npos) << msg;
}

TEST(Options, WrongTypeNamesKeyAndExpectedType) {
  SampleSystem o;
  expectMentions(loadError("tracker:\n  fast_threshold: fast\n", o),
                 {"run.yaml", "'tracker.fast_threshold'", "expected int", "'fast'"});
  expectMentions(loadError("tracker:\n  fast_threshold: 2.5\n", o), {"'tracker.fast_threshold'", "expected int"});
  expectMentions(loadError("tracker:\n  fast_threshold: 99999999999\n", o), {"'tracker.fast_threshold'", "int"});
  expectMentions(loadError("tracker:\n  use_pyramid: maybe\n", o), {"'tracker.use_pyramid'", "expected bool"});
  expectMentions(loadError("tracker:\n  scales: 0.5\n", o), {"'tracker.scales'", "expected list of double"});
  expectMentions(loadError("tracker:\n  scales: [1, x]\n", o), {"'tracker.scales'", "expected list of double"});
  expectMentions(loadError("levels: [1, 2.5]\n", o), {"'levels'", "expected list of int"});
  expectMentions(loadError("fps: [30]\n", o), {"'fps'", "expected float", "a list"});
  expectMentions(loadError("name: {a: 1}\n", o), {"'name'", "expected string"});
  expectMentions(loadError("tracker: 5\n", o), {"'tracker'", "expected a section"});
  expectMentions(loadError("max_frames: 1e3\n", o), {"'max_frames'", "expected int64"});
  // Several problems are reported together.
  const std::string both = loadError("fps: x\ntracker:\n  matcherr: orb\n", o);
  expectMentions(both, {"'fps'", "'tracker.matcherr'", "did you mean 'matcher'"});
}

TEST(Options, ValidationReportsEveryViolation) {
  SampleSystem o;
  o.tracker.fast_threshold = 300;
  o.tracker.min_parallax_deg = -1;
  o.tracker.matcher = "sift";
  o.fps = std::numeric_limits<float>::quiet_NaN();
  o.core.threads = -2;
  o.core.log_level = "verbose";
  try {
    validateOptions(o, "run.yaml");
    FAIL() << "invalid options accepted";
  } catch (const Error& e) {
    expectMentions(e.what(),
                   {"run.yaml: field 'tracker.fast_threshold': must be in [1, 255] (got 300)",
                    "'tracker.min_parallax_deg': must be > 0 (got -1)",
                    "'tracker.matcher': must be one of: patch, orb (got \"sift\")", "'fps': must be a finite number",
                    "'core.threads': must be in [0, 1024] (got -2)", "'core.log_level'"});
  }
  EXPECT_NO_THROW(validateOptions(SampleSystem{}, "defaults"));
  EXPECT_NO_THROW(validateOptions(SampleCore{}, "defaults"));
}

TEST(Options, PrintsOneLinePerLeaf) {
  SampleSystem o;
  o.tracker.fast_threshold = 42;
  const std::string s = printOptions(o);
  EXPECT_NE(s.find("tracker.fast_threshold = 42  # FAST corner threshold on 8-bit intensities\n"), std::string::npos)
      << s;
  EXPECT_NE(s.find("tracker.matcher = \"patch\"  # Map-point matcher\n"), std::string::npos) << s;
  EXPECT_NE(s.find("tracker.scales = [1, 0.5]  # Pyramid scales\n"), std::string::npos) << s;
  EXPECT_NE(s.find("tracker.use_pyramid = true  #"), std::string::npos) << s;
  EXPECT_NE(s.find("fps = 30  #"), std::string::npos) << s;
  EXPECT_NE(s.find("core.threads = 0  # Worker threads"), std::string::npos) << s;
  // 4 + 5 (tracker) + 3 (core) leaves.
  EXPECT_EQ(std::count(s.begin(), s.end(), '\n'), 12);
}

TEST(Options, PrintedValuesLoadBack) {
  SampleSystem o;
  o.tracker.min_parallax_deg = 0.1 + 0.2;  // needs all 17 digits
  o.fps = 29.97f;
  o.name = "a \"b\" \\c";
  // Turn "a.b = v  # doc" lines into nested YAML and load it into fresh defaults.
  YAML::Node root;
  std::istringstream in(printOptions(o));
  std::string line;
  while (std::getline(in, line)) {
    const std::string path = line.substr(0, line.find(" = "));
    const std::string value = line.substr(line.find(" = ") + 3, line.find("  # ") - line.find(" = ") - 3);
    const size_t dot = path.find('.');
    if (dot == std::string::npos)
      root[path] = YAML::Load(value);
    else
      root[path.substr(0, dot)][path.substr(dot + 1)] = YAML::Load(value);
  }
  SampleSystem back;
  loadOptions(root, back, "printed");
  EXPECT_EQ(back.tracker.min_parallax_deg, o.tracker.min_parallax_deg);
  EXPECT_EQ(back.fps, o.fps);
  EXPECT_EQ(back.name, o.name);
  EXPECT_EQ(printOptions(back), printOptions(o));
}

TEST(Options, YamlOfOptionsLoadsBackExactly) {
  SampleSystem o;
  o.tracker.min_parallax_deg = 0.1 + 0.2;  // needs all 17 digits
  o.fps = 29.97f;
  o.name = "a \"b\" \\c";
  o.levels = {};
  o.core.seed = -3;
  const std::string yaml = optionsYaml(o, "sample options");
  EXPECT_EQ(yaml.rfind("# sample options\nmax_frames: 1000  # Stop after this many frames\n", 0), 0u) << yaml;
  EXPECT_NE(yaml.find("\ntracker:  # Tracking front end\n  fast_threshold: 20  # FAST corner threshold on 8-bit "
                      "intensities\n"),
            std::string::npos)
      << yaml;
  EXPECT_NE(yaml.find("\n  scales: [1, 0.5]  # Pyramid scales\ncore:  # Threads, logging, seed\n  threads: 0"),
            std::string::npos)
      << yaml;
  EXPECT_NE(yaml.find("\nlevels: []  # Levels to use\n"), std::string::npos) << yaml;
  EXPECT_EQ(optionsYaml(o).rfind("max_frames: 1000", 0), 0u) << "no title, no title line";
  SampleSystem back;
  back.tracker.fast_threshold = 99;
  back.levels = {4};
  loadOptions(YAML::Load(yaml), back, "written");
  EXPECT_EQ(back.tracker.min_parallax_deg, o.tracker.min_parallax_deg);
  EXPECT_EQ(back.name, o.name);
  EXPECT_EQ(printOptions(back), printOptions(o));
  EXPECT_EQ(optionsYaml(back, "sample options"), yaml);
}

TEST(Options, DocumentsEveryOption) {
  const std::string md = documentOptions<SampleSystem>();
  EXPECT_EQ(md.rfind("| Option | Type | Default | Constraint | Description |\n|---|---|---|---|---|\n", 0), 0u) << md;
  EXPECT_NE(md.find("| `tracker.fast_threshold` | int | `20` | in [1, 255] | FAST corner threshold on 8-bit "
                    "intensities |"),
            std::string::npos)
      << md;
  EXPECT_NE(md.find("| `tracker.min_parallax_deg` | double | `1` | > 0 |"), std::string::npos) << md;
  EXPECT_NE(md.find("| `tracker.matcher` | string | `\"patch\"` | one of: patch, orb | Map-point matcher |"),
            std::string::npos)
      << md;
  EXPECT_NE(md.find("| `max_frames` | int64 | `1000` | >= 0 |"), std::string::npos) << md;
  EXPECT_NE(md.find("| `tracker.use_pyramid` | bool | `true` |  | Track on an image pyramid |"), std::string::npos)
      << md;
  EXPECT_NE(md.find("| `tracker` | section |"), std::string::npos) << md;
  EXPECT_NE(md.find("Frame rate \\| pipes are escaped"), std::string::npos) << md;
  EXPECT_NE(md.find("| `levels` | list of int | `[0, 1]` |"), std::string::npos) << md;
}

TEST(Options, LoadOptionsFileNamesTheFile) {
  test::TempDir dir;
  std::ofstream(dir / "good.yaml") << "tracker:\n  fast_threshold: 12\n";
  SampleSystem o;
  loadOptionsFile(dir / "good.yaml", o);
  EXPECT_EQ(o.tracker.fast_threshold, 12);

  std::ofstream(dir / "typo.yaml") << "tracker:\n  fast_threshol: 12\n";
  try {
    loadOptionsFile(dir / "typo.yaml", o);
    FAIL() << "unknown key accepted";
  } catch (const Error& e) {
    expectMentions(e.what(), {(dir / "typo.yaml").string(), "tracker.fast_threshol", "did you mean"});
  }
  std::ofstream(dir / "broken.yaml") << "tracker:\n  fast_threshold: [12\n";
  try {
    loadOptionsFile(dir / "broken.yaml", o);
    FAIL() << "broken YAML accepted";
  } catch (const Error& e) {
    expectMentions(e.what(), {(dir / "broken.yaml").string(), "invalid YAML", "line"});
  }
  try {
    loadOptionsFile(dir / "missing.yaml", o);
    FAIL() << "missing file accepted";
  } catch (const Error& e) {
    expectMentions(e.what(), {(dir / "missing.yaml").string(), "not found"});
  }
}

// Size and echo (issue 22): a 10 MB YAML list took 2.45 GB in yaml-cpp, so a YAML file over
// kMaxYamlFileBytes is refused before it is parsed, naming the file and its size; a long value in a
// file under the cap is quoted cut to 80 characters, not whole; a key far longer than any option is
// not compared letter by letter with each (the "did you mean" search was quadratic in its length).
TEST(Options, RefusesHugeFilesAndCutsLongValues) {
  test::TempDir dir;
  SampleSystem o;
  {
    std::ofstream out(dir / "list.yaml");
    out << "tracker:\n  scales: [";
    for (int i = 0; i < 600000; ++i) out << "1, ";
    out << "1]\n";
  }
  const std::string big = test::errorOf([&] { loadOptionsFile(dir / "list.yaml", o); });
  EXPECT_EQ(big, (dir / "list.yaml").string() + ": 1.80 MB, more than the 1.00 MB a YAML file may have");
  std::ofstream(dir / "scalar.yaml") << "tracker:\n  matcher: " << std::string(900000, 'x') << "\n";
  const std::string scalar = test::errorOf([&] {
    SampleSystem s;
    loadOptionsFile(dir / "scalar.yaml", s);
    validateOptions(s, (dir / "scalar.yaml").string());
  });
  expectMentions(scalar, {(dir / "scalar.yaml").string(), "tracker.matcher", "must be one of: patch, orb",
                          "(got \"" + std::string(76, 'x') + "...)"});
  EXPECT_LT(scalar.size(), 300u) << scalar;
  std::ofstream(dir / "type.yaml") << "tracker:\n  fast_threshold: " << std::string(900000, '7') << "\n";
  const std::string type = test::errorOf([&] { loadOptionsFile(dir / "type.yaml", o); });
  expectMentions(type, {"tracker.fast_threshold", "expected int, got '" + std::string(77, '7') + "...'"});
  EXPECT_LT(type.size(), 300u) << type;
  std::ofstream(dir / "key.yaml") << "tracker:\n  ? " << std::string(900000, 'k') << "\n  : 1\n";
  const std::string key = test::errorOf([&] { loadOptionsFile(dir / "key.yaml", o); });
  expectMentions(key, {"field 'tracker." + std::string(77, 'k') + "...': unknown option"});
  EXPECT_LT(key.size(), 300u) << key;
}

// Two holes a user fell into (issue 22): a directory given as the file was ignored (all defaults,
// exit 0), and a key given twice kept its first value silently.
TEST(Options, RefusesADirectoryAndAKeyGivenTwice) {
  test::TempDir dir;
  SampleSystem o;
  try {
    loadOptionsFile(dir.path(), o);
    FAIL() << "a directory accepted as a YAML file";
  } catch (const Error& e) {
    expectMentions(e.what(), {dir.path().string(), "is a directory"});
  }
  std::ofstream(dir / "twice.yaml") << "tracker:\n  fast_threshold: 12\n  fast_threshold: 30\n";
  try {
    loadOptionsFile(dir / "twice.yaml", o);
    FAIL() << "a key given twice accepted";
  } catch (const Error& e) {
    expectMentions(e.what(), {(dir / "twice.yaml").string(), "line 3", "'fast_threshold' given twice", "line 2"});
  }
  // Top-level sections too, and the same key in two different sections is fine.
  std::ofstream(dir / "sections.yaml") << "tracker:\n  fast_threshold: 12\ntracker:\n  fast_threshold: 13\n";
  EXPECT_THROW(loadOptionsFile(dir / "sections.yaml", o), Error);
  std::ofstream(dir / "ok.yaml") << "tracker:\n  fast_threshold: 12\n";
  SampleSystem p;
  loadOptionsFile(dir / "ok.yaml", p);
  EXPECT_EQ(p.tracker.fast_threshold, 12);
}

TEST(Options, SectionOfScalarsLoadsAndValidates) {
  SampleCore c;
  loadOptions(YAML::Load("threads: 4\nseed: 7\nlog_level: warn\n"), c, "core.yaml");
  EXPECT_EQ(c.threads, 4);
  EXPECT_EQ(c.seed, 7);
  EXPECT_EQ(c.log_level, "warn");
  c.seed = -1;
  EXPECT_THROW(validateOptions(c, "core.yaml"), Error);
}

}  // namespace
}  // namespace nerfslam
