// event_loop.hpp: the one poll()-based loop of the service. The serial descriptor, the MQTT
// socket, a self-pipe (signals and wake-ups from other threads) and timers all go through it:
// nothing busy-waits, and everything except the HTTP server's own threads runs here.
//
// Threading: watch/unwatch/timers/run are for the loop thread only. post() and stop() may be
// called from any thread (they write to the self-pipe). The signal handler installed by
// handleSignals() only writes the signal number to the self-pipe; the handler callback then
// runs on the loop thread, where anything may be done.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <map>
#include <mutex>
#include <vector>

#include "cdro/service/clock.hpp"

namespace cdro::service {

class EventLoop {
public:
    using FdCallback = std::function<void(short revents)>;
    using TimerCallback = std::function<void()>;
    using TimerId = uint64_t;

    explicit EventLoop(const Clock &clock); // throws std::system_error if the pipe fails
    ~EventLoop();
    EventLoop(const EventLoop &) = delete;
    EventLoop &operator=(const EventLoop &) = delete;

    const Clock &clock() const { return clock_; }

    // Watches fd for events (POLLIN, POLLOUT); replaces an earlier registration of fd.
    // POLLHUP/POLLERR/POLLNVAL are always reported.
    void watchFd(int fd, short events, FdCallback callback);
    void setFdEvents(int fd, short events);
    void unwatchFd(int fd);

    TimerId addTimerAt(int64_t deadline_monotonic_us, TimerCallback callback);
    TimerId addTimerAfter(int64_t delay_us, TimerCallback callback);
    void cancelTimer(TimerId id); // no-op for a timer that ran or was cancelled

    // Runs task on the loop thread soon. Thread-safe.
    void post(std::function<void()> task);
    // Makes run() return after the current iteration. Thread-safe.
    void stop();
    bool stopping() const { return stop_requested_.load(); }

    // Routes the given signals through the self-pipe to handler (on the loop thread) and
    // ignores SIGPIPE. Only one loop per process may do this; the destructor restores SIG_DFL.
    void handleSignals(const std::vector<int> &signals, std::function<void(int)> handler);

    // Polls once (waiting at most max_wait_us, or until the next timer) and dispatches.
    void runOnce(int64_t max_wait_us);
    // Until stop().
    void run();

    size_t watchedFdCount() const { return fds_.size(); }
    size_t pendingTimerCount() const { return timers_.size(); }

private:
    struct Watch {
        short events = 0;
        uint64_t registration = 0;
        FdCallback callback;
    };
    void drainPipe();
    void runDueTimers();
    void runPosted();

    const Clock &clock_;
    int pipe_read_ = -1;
    int pipe_write_ = -1;
    std::map<int, Watch> fds_;
    uint64_t next_registration_ = 1;
    std::map<std::pair<int64_t, TimerId>, TimerCallback> timers_;
    std::map<TimerId, int64_t> timer_deadlines_;
    TimerId next_timer_ = 1;
    std::mutex posted_mutex_;
    std::vector<std::function<void()>> posted_;
    std::atomic<bool> stop_requested_{false};
    std::function<void(int)> signal_handler_;
    std::vector<int> handled_signals_;
};

} // namespace cdro::service
