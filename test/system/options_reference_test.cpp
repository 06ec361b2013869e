#include "nerfslam/system/options_reference.h"

#include <fstream>
#include <sstream>

#include "nerfslam/core/error.h"
#include "nerfslam/core/options_yaml.h"
#include "nerfslam/system/slam_system.h"
#include "test_support.h"

namespace nerfslam {
namespace {
namespace fs = std::filesystem;

TEST(OptionsReference, DocsEmbedTheGeneratedReference) {
  std::ifstream is(test::sourceDir() / "docs" / "options.md");
  ASSERT_TRUE(is) << "docs/options.md missing";
  std::stringstream ss;
  ss << is.rdbuf();
  const std::string generated = optionReferenceMarkdown();
  const std::string doc = ss.str();
  // The generated part is everything after the marker line: exactly the reference, once.
  const std::string marker = "do not edit below -->\n";
  const size_t m = doc.find(marker);
  ASSERT_NE(m, std::string::npos) << "docs/options.md has no generated section";
  std::string tail = doc.substr(m + marker.size());
  while (!tail.empty() && tail.front() == '\n') tail.erase(0, 1);
  std::string expect = generated;
  while (!expect.empty() && expect.front() == '\n') expect.erase(0, 1);
  EXPECT_EQ(tail, expect)
      << "docs/options.md is out of date: run scripts/update_options_doc.sh (`nerfslam options --markdown`)";
}

// The example at the top of docs/options.md is a `run --config` file: it loads into SystemOptions,
// validates, and the error messages the page quotes are the ones the loader gives.
TEST(OptionsReference, DocsExampleIsARunConfiguration) {
  std::ifstream is(test::sourceDir() / "docs" / "options.md");
  ASSERT_TRUE(is);
  std::stringstream ss;
  ss << is.rdbuf();
  const std::string doc = ss.str();
  const size_t a = doc.find("```yaml\n");
  ASSERT_NE(a, std::string::npos);
  const size_t b = doc.find("```", a + 8);
  ASSERT_NE(b, std::string::npos);
  SystemOptions o;
  ASSERT_NO_THROW(loadOptions(YAML::Load(doc.substr(a + 8, b - a - 8)), o, "run.yaml"));
  EXPECT_NO_THROW(validateOptions(o, "run.yaml"));
  EXPECT_EQ(o.tracking.features.max_features, 1500);
  EXPECT_EQ(o.nerf.holdout_every, 5);
  auto quoted = [&](const std::string& yaml, bool validate) {
    SystemOptions x;
    const std::string e = test::errorOf([&] {
      loadOptions(YAML::Load(yaml), x, "run.yaml");
      if (validate) validateOptions(x, "run.yaml");
    });
    EXPECT_FALSE(e.empty()) << yaml;
    EXPECT_NE(doc.find("`" + e + "`"), std::string::npos) << "docs/options.md does not quote: " << e;
  };
  quoted("tracking: {features: {max_featres: 1}}", false);
  quoted("tracking: {features: {max_features: many}}", false);
  quoted("tracking: {features: {max_features: 10}}", true);
}

// Turns `a.b.c = value  # doc` lines (printOptions) into a nested YAML document.
YAML::Node yamlFromPrinted(const std::string& printed) {
  YAML::Node root(YAML::NodeType::Map);
  std::istringstream is(printed);
  std::string line;
  while (std::getline(is, line)) {
    const size_t eq = line.find(" = ");
    if (line.empty() || line[0] == '#' || eq == std::string::npos) continue;
    std::string path = line.substr(0, eq);
    std::string value = line.substr(eq + 3);
    if (size_t hash = value.find("  # "); hash != std::string::npos) value = value.substr(0, hash);
    std::vector<std::string> keys;
    for (size_t p = 0;;) {
      size_t dot = path.find('.', p);
      keys.push_back(path.substr(p, dot - p));
      if (dot == std::string::npos) break;
      p = dot + 1;
    }
    std::vector<YAML::Node> chain{root};
    for (size_t i = 0; i + 1 < keys.size(); ++i) chain.push_back(chain.back()[keys[i]]);
    chain.back()[keys.back()] = YAML::Load(value);
  }
  return root;
}

TEST(OptionsReference, PrintedDefaultsLoadBackExactly) {
  const SystemOptions defaults;
  const std::string printed = printOptions(defaults);
  SystemOptions changed;
  changed.local_map_keyframes = 7;
  changed.lockstep = !changed.lockstep;
  changed.tracking.features.max_features += 1;
  changed.mapping.ba.huber_px *= 2;
  ASSERT_NE(printOptions(changed), printed);
  loadOptions(yamlFromPrinted(printed), changed, "printed");
  EXPECT_EQ(printOptions(changed), printed);
}

TEST(OptionsReference, UnknownSystemKeyIsAnErrorWithHint) {
  YAML::Node root = YAML::Load("local_map_keyframe: 7\n");
  SystemOptions o;
  try {
    loadOptions(root, o, "run.yaml");
    FAIL() << "expected an error";
  } catch (const Error& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("run.yaml"), std::string::npos) << msg;
    EXPECT_NE(msg.find("local_map_keyframes"), std::string::npos) << msg;
  }
}

TEST(OptionsReference, CliPrintsReferenceAndDefaults) {
  auto r = test::runCli("options --markdown");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("local_map_keyframes"), std::string::npos);
  auto d = test::runCli("options --defaults");
  ASSERT_EQ(d.exit_code, 0) << d.output;
  EXPECT_NE(d.output.find("local_map_keyframes = 10"), std::string::npos) << d.output;
}

}  // namespace
}  // namespace nerfslam
