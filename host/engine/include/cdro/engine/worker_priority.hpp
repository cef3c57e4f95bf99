// worker_priority.hpp: the global solve's worker runs behind the range path.
//
// The engine's solve runs on a worker thread (global_step.hpp) beside the thread that feeds it
// ranges; in the service that thread is also the one that reads frames and writes the outputs.
// On a computer with few cores the worker and its helpers (the starts refined side by side,
// global_solve.hpp) would share the feeding thread's core as equals, and a range that arrives
// while a solve runs would wait for the scheduler's next turn: milliseconds, the service's
// latency tail. The worker lowers its own priority when it starts, so the feeding thread takes a
// core at once and the solve uses what is left. Only when the solve runs, never what it computes:
// a solve's result and the range it is adopted at do not depend on how fast it ran.
#pragma once

namespace cdro::engine {

// nice steps the worker runs below the thread that started it (Linux nice values: 0 the default,
// 19 the lowest; at 10 a busy worker gets about a tenth of a core that a nice-0 thread also wants).
inline constexpr int kWorkerNiceSteps = 10;

// Lowers the calling thread's priority by kWorkerNiceSteps (up to the lowest), on Linux, where each
// thread has its own nice value and the threads it starts inherit it. Whether it did; elsewhere, or
// if the system refuses, nothing changes and it returns false (only how fast the worker runs depends
// on it).
bool lowerThisThreadsPriority();

// The calling thread's nice value (Linux; 0 elsewhere).
int thisThreadsNice();

} // namespace cdro::engine
