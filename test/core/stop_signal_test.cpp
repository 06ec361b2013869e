// The stop handler (core/stop_signal.h): it counts SIGINT and SIGTERM, and the third exits at once.
#include <gtest/gtest.h>

#include <signal.h>

#include "nerfslam/core/stop_signal.h"

namespace nerfslam {
namespace {

TEST(StopSignal, CountsSigintAndSigtermAndRemembersTheLast) {
  resetStopRequests();
  EXPECT_EQ(stopRequests(), 0);
  EXPECT_EQ(lastStopSignal(), 0);
  installStopHandlers();
  ASSERT_EQ(::raise(SIGINT), 0);  // handled: the process goes on
  EXPECT_EQ(stopRequests(), 1);
  EXPECT_EQ(lastStopSignal(), SIGINT);
  EXPECT_EQ(interruptedExitCode(), 130);
  ASSERT_EQ(::raise(SIGTERM), 0);
  EXPECT_EQ(stopRequests(), 2);
  EXPECT_EQ(lastStopSignal(), SIGTERM);
  EXPECT_EQ(interruptedExitCode(), 128 + SIGTERM);
  resetStopRequests();
  EXPECT_EQ(stopRequests(), 0);
  ::signal(SIGINT, SIG_DFL);
  ::signal(SIGTERM, SIG_DFL);
}

TEST(StopSignal, TheThirdSignalExitsAtOnceWith128PlusTheSignal) {
  GTEST_FLAG_SET(death_test_style, "threadsafe");
  EXPECT_EXIT(
      {
        resetStopRequests();
        installStopHandlers();
        ::raise(SIGINT);
        ::raise(SIGINT);
        ::raise(SIGINT);
        std::abort();  // not reached
      },
      ::testing::ExitedWithCode(130), "stopped at once");
  EXPECT_EXIT(
      {
        resetStopRequests();
        installStopHandlers();
        ::raise(SIGTERM);
        ::raise(SIGINT);
        ::raise(SIGTERM);
        std::abort();
      },
      ::testing::ExitedWithCode(128 + SIGTERM), "stopped at once");
}

TEST(StopSignal, RequestStopCountsWithoutExiting) {
  resetStopRequests();
  for (int i = 0; i < 5; ++i) requestStop(SIGINT);
  EXPECT_EQ(stopRequests(), 5);
  EXPECT_EQ(interruptedExitCode(), 130);
  resetStopRequests();
}

}  // namespace
}  // namespace nerfslam
