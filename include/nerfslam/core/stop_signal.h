#pragma once
// Graceful stop on SIGINT and SIGTERM for the long-running commands (`run`, `train`). The handler
// only counts: the code that runs checks stopRequests() at its own safe points and winds down, so a
// stopped run keeps what it has done.
//   1st signal: stop taking new work (`run` reads no more frames; `train` takes no more steps) and
//               finish what is needed for complete outputs (`run`: global BA, the final NeRF
//               training cut to kShortenedFinalSeconds at most, every output file).
//   2nd signal: skip what is left that only improves the result (the global BA, or the rest of a
//               running one after its current iteration, the
//               final NeRF training, the NeRF's held-out renders, mesh and cloud); the trajectory,
//               keyframes, map folder, NeRF model and report are still written.
//   3rd signal: exit at once with 128 + the signal (outputs are written atomically, so what is on
//               disk is complete: the previous checkpoint of a file or its final version).
// Without installStopHandlers() the signals keep their default action and stopRequests() stays 0
// (a library user, or a test, calls requestStop() instead).
namespace nerfslam {

// Seconds the final NeRF training may still take after the first signal.
inline constexpr double kShortenedFinalSeconds = 10.0;

// Installs the counting handler for SIGINT and SIGTERM (idempotent, for the process's lifetime).
void installStopHandlers();
// Signals received so far (or requestStop() calls).
int stopRequests();
// The last signal received (SIGINT or SIGTERM), 0 when none; requestStop() records its argument.
int lastStopSignal();
// As if `signal` had arrived, without the third signal's immediate exit (tests, embedding code).
void requestStop(int signal);
// Back to no request (tests).
void resetStopRequests();
// The exit status of a command interrupted by lastStopSignal(): 128 + the signal (130 for SIGINT).
int interruptedExitCode();

}  // namespace nerfslam
