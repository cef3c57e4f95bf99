#include "cdro/service/clock.hpp"

#include <cmath>
#include <ctime>

namespace cdro::service {

namespace {
int64_t readClockUs(clockid_t id)
{
    timespec ts{};
    clock_gettime(id, &ts);
    return static_cast<int64_t>(ts.tv_sec) * 1'000'000 + static_cast<int64_t>(ts.tv_nsec / 1000);
}
} // namespace

int64_t SystemClock::monotonicUs() const { return readClockUs(CLOCK_MONOTONIC); }
int64_t SystemClock::unixUs() const { return readClockUs(CLOCK_REALTIME); }

int64_t secondsToUs(double seconds)
{
    if (!(seconds > 0.0)) {
        return 0;
    }
    return static_cast<int64_t>(std::llround(seconds * 1e6));
}

} // namespace cdro::service
