#pragma once
// Thread settings shared by the library and the ROS layer.

namespace nerfslam {

// The thread count `threads` stands for: itself when > 0, otherwise the number of cores (>= 1).
int resolveThreads(int threads);

// Adds `increment` (> 0) to the calling thread's niceness (Linux: per thread; threads it starts
// afterwards inherit it), so that it yields the CPU to the tracking thread. False when the system
// refused (the thread then runs at its old priority); true for increment <= 0, which changes nothing.
bool lowerThreadPriority(int increment);

}  // namespace nerfslam
