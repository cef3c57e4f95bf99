#include "cdro/engine/worker_priority.hpp"

#include <algorithm>

#ifdef __linux__
#include <cerrno>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>
#endif

namespace cdro::engine {

#ifdef __linux__
namespace {

// setpriority(PRIO_PROCESS, tid) changes one thread on Linux (man 2 setpriority, "BUGS": threads do
// not share a nice value); the process id would change the main thread only.
id_t thisThreadsId() { return static_cast<id_t>(syscall(SYS_gettid)); }

constexpr int kLowestNice = 19;

} // namespace

int thisThreadsNice()
{
    errno = 0;
    const int nice = getpriority(PRIO_PROCESS, thisThreadsId());
    return errno == 0 ? nice : 0;
}

bool lowerThisThreadsPriority()
{
    const int lowered = std::min(thisThreadsNice() + kWorkerNiceSteps, kLowestNice);
    return setpriority(PRIO_PROCESS, thisThreadsId(), lowered) == 0;
}
#else
int thisThreadsNice() { return 0; }

bool lowerThisThreadsPriority() { return false; }
#endif

} // namespace cdro::engine
