#include "nerfslam/core/thread.h"

#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <thread>

namespace nerfslam {
namespace {

int ownNiceness() { return getpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid))); }

TEST(Thread, ResolveThreads) {
  EXPECT_EQ(resolveThreads(3), 3);
  EXPECT_EQ(resolveThreads(0), std::max(1, static_cast<int>(std::thread::hardware_concurrency())));
  EXPECT_GE(resolveThreads(-1), 1);
}

TEST(Thread, LowerThreadPriorityRaisesOnlyTheCallingThreadsNiceness) {
  const int before = ownNiceness();
  int in_thread = 0, after_in_thread = 0;
  bool ok = false;
  std::thread t([&] {
    in_thread = ownNiceness();
    ok = lowerThreadPriority(3);
    after_in_thread = ownNiceness();
  });
  t.join();
  ASSERT_TRUE(ok);
  EXPECT_EQ(after_in_thread, std::min(19, in_thread + 3));
  EXPECT_EQ(ownNiceness(), before);  // this thread is untouched
  EXPECT_TRUE(lowerThreadPriority(0));
  EXPECT_EQ(ownNiceness(), before);
}

}  // namespace
}  // namespace nerfslam
