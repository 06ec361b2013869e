#include "nerfslam/core/stop_signal.h"

#include <signal.h>
#include <unistd.h>

#include <atomic>
#include <cstring>

namespace nerfslam {
namespace {

std::atomic<int> g_requests{0};
std::atomic<int> g_signal{0};
static_assert(std::atomic<int>::is_always_lock_free, "the signal handler needs a lock-free counter");

void say(const char* text) {
  // write(2) is async-signal-safe; its result does not matter here.
  const ssize_t n = ::write(STDERR_FILENO, text, std::strlen(text));
  (void)n;
}

extern "C" void onStopSignal(int sig) {
  g_signal.store(sig);
  const int n = g_requests.fetch_add(1) + 1;
  if (n == 1)
    say("\nstopping: finishing the frame in hand and writing the outputs (signal again to skip global BA and the "
        "final NeRF training, a third time to exit at once)\n");
  else if (n == 2)
    say("\nstopping: skipping global BA and the final NeRF training; writing the outputs (signal again to exit at "
        "once)\n");
  else {
    say("\nstopped at once: outputs on disk are the last complete ones\n");
    ::_exit(128 + sig);
  }
}

}  // namespace

void installStopHandlers() {
  struct sigaction sa;
  std::memset(&sa, 0, sizeof sa);
  sa.sa_handler = onStopSignal;
  sigemptyset(&sa.sa_mask);
  sa.sa_flags = SA_RESTART;  // blocking reads and writes continue; the code polls stopRequests()
  sigaction(SIGINT, &sa, nullptr);
  sigaction(SIGTERM, &sa, nullptr);
}

int stopRequests() { return g_requests.load(); }

int lastStopSignal() { return g_signal.load(); }

void requestStop(int signal) {
  g_signal.store(signal);
  g_requests.fetch_add(1);
}

void resetStopRequests() {
  g_requests.store(0);
  g_signal.store(0);
}

int interruptedExitCode() {
  const int s = g_signal.load();
  return 128 + (s > 0 ? s : SIGINT);
}

}  // namespace nerfslam
