#include "nerfslam/core/parse.h"

#include <gtest/gtest.h>

#include "nerfslam/core/error.h"
#include "test_support.h"

namespace nerfslam {
namespace {

TEST(Parse, NumberListsOfFiniteNumbers) {
  EXPECT_EQ(parseNumberList("1,2.5,-3e2", "--x"), (std::vector<double>{1, 2.5, -300}));
  EXPECT_EQ(parseNumberList(" 0 , 0,\t1 ", "--up"), (std::vector<double>{0, 0, 1}));
  EXPECT_TRUE(parseNumberList("", "--x").empty());
  EXPECT_TRUE(parseNumberList("  ", "--x").empty());
  for (const char* bad : {"nan,0,1", "1,inf", "1,,2", "1,", "1x", "1,2,three", "-nan"}) {
    SCOPED_TRACE(bad);
    const std::string e = test::errorOf([&] { parseNumberList(bad, "--up"); });
    EXPECT_NE(e.find(std::string("--up '") + bad + "'"), std::string::npos) << e;
    EXPECT_NE(e.find("is not a finite number"), std::string::npos) << e;
  }
}

TEST(Parse, ImageSizes) {
  int w = 0, h = 0;
  parseImageSize("640x480", "--size", 1, &w, &h);
  EXPECT_EQ(w, 640);
  EXPECT_EQ(h, 480);
  parseImageSize("16X8192", "--size", 16, &w, &h);
  EXPECT_EQ(w, 16);
  EXPECT_EQ(h, 8192);
  for (const char* bad :
       {"640", "x480", "640x", "-5x10", "6.5x10", "640x480x3", " 640x480", "99999999999999999999x1"}) {
    SCOPED_TRACE(bad);
    const std::string e = test::errorOf([&] { parseImageSize(bad, "--size", 1, &w, &h); });
    EXPECT_NE(e.find("expected WIDTHxHEIGHT"), std::string::npos) << e;
  }
  for (const char* bad : {"0x480", "640x0", "9000x480", "15x100"}) {
    SCOPED_TRACE(bad);
    const std::string e = test::errorOf([&] { parseImageSize(bad, "--size", 16, &w, &h); });
    EXPECT_NE(e.find("must be in 16..8192"), std::string::npos) << e;
  }
}

}  // namespace
}  // namespace nerfslam
