// clock.hpp: the clock seam. Nothing in cdro_service reads the system clock directly; the
// event loop, the serial link and every state machine take time from a Clock (or are handed
// a time), so that tests drive them with a ManualClock and never sleep.
//
// Two time bases, never mixed:
//   monotonic_us  steady, for timers, timeouts, backoff and pacing;
//   unix_us       wall clock (us since the Unix epoch), only for capture timestamps and for
//                 the "event time" of live frames. On the replay path, event time comes from
//                 the capture records instead, so replay never depends on wall time.
#pragma once

#include <atomic>
#include <cstdint>

namespace cdro::service {

class Clock {
public:
    virtual ~Clock() = default;
    virtual int64_t monotonicUs() const = 0; // us, steady, arbitrary origin
    virtual int64_t unixUs() const = 0;      // us since the Unix epoch (UTC)
};

// The real clocks: CLOCK_MONOTONIC and CLOCK_REALTIME.
class SystemClock final : public Clock {
public:
    int64_t monotonicUs() const override;
    int64_t unixUs() const override;
};

// A clock that moves only when told to. Thread-safe reads (atomics), for tests.
class ManualClock final : public Clock {
public:
    explicit ManualClock(int64_t monotonic_us = 1'000'000, int64_t unix_us = 1'700'000'000'000'000)
        : monotonic_us_(monotonic_us), unix_us_(unix_us)
    {
    }
    int64_t monotonicUs() const override { return monotonic_us_.load(); }
    int64_t unixUs() const override { return unix_us_.load(); }
    void advanceUs(int64_t delta_us)
    {
        monotonic_us_ += delta_us;
        unix_us_ += delta_us;
    }
    void setUnixUs(int64_t unix_us) { unix_us_ = unix_us; }

private:
    std::atomic<int64_t> monotonic_us_;
    std::atomic<int64_t> unix_us_;
};

// Seconds (config values) to microseconds, rounded; negative values give 0.
int64_t secondsToUs(double seconds);

} // namespace cdro::service
