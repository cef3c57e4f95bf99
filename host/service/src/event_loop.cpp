#include "cdro/service/event_loop.hpp"

#include <cerrno>
#include <csignal>
#include <cstring>
#include <system_error>

#include <fcntl.h>
#include <poll.h>
#include <unistd.h>

#include "cdro/service/log.hpp"

namespace cdro::service {

namespace {
// The signal handler can only reach the pipe through a global; one loop owns it at a time.
std::atomic<int> g_signal_pipe{-1};

constexpr uint8_t kWakeByte = 0; // any other byte in the pipe is a signal number

extern "C" void onSignal(int signo)
{
    const int saved_errno = errno;
    const int fd = g_signal_pipe.load();
    if (fd >= 0) {
        const auto byte = static_cast<uint8_t>(signo);
        // A full pipe already holds a wake-up; losing this byte loses nothing that matters.
        [[maybe_unused]] const ssize_t written = ::write(fd, &byte, 1);
    }
    errno = saved_errno;
}
} // namespace

EventLoop::EventLoop(const Clock &clock) : clock_(clock)
{
    int fds[2];
    if (::pipe2(fds, O_NONBLOCK | O_CLOEXEC) != 0) {
        throw std::system_error(errno, std::generic_category(), "event loop self-pipe");
    }
    pipe_read_ = fds[0];
    pipe_write_ = fds[1];
}

EventLoop::~EventLoop()
{
    if (!handled_signals_.empty()) {
        for (const int signo : handled_signals_) {
            std::signal(signo, SIG_DFL);
        }
        g_signal_pipe.store(-1);
    }
    ::close(pipe_read_);
    ::close(pipe_write_);
}

void EventLoop::watchFd(int fd, short events, FdCallback callback)
{
    Watch &watch = fds_[fd];
    watch.events = events;
    watch.registration = next_registration_++;
    watch.callback = std::move(callback);
}

void EventLoop::setFdEvents(int fd, short events)
{
    const auto it = fds_.find(fd);
    if (it != fds_.end()) {
        it->second.events = events;
    }
}

void EventLoop::unwatchFd(int fd) { fds_.erase(fd); }

EventLoop::TimerId EventLoop::addTimerAt(int64_t deadline_monotonic_us, TimerCallback callback)
{
    const TimerId id = next_timer_++;
    timers_.emplace(std::make_pair(deadline_monotonic_us, id), std::move(callback));
    timer_deadlines_.emplace(id, deadline_monotonic_us);
    return id;
}

EventLoop::TimerId EventLoop::addTimerAfter(int64_t delay_us, TimerCallback callback)
{
    return addTimerAt(clock_.monotonicUs() + delay_us, std::move(callback));
}

void EventLoop::cancelTimer(TimerId id)
{
    const auto it = timer_deadlines_.find(id);
    if (it == timer_deadlines_.end()) {
        return;
    }
    timers_.erase(std::make_pair(it->second, id));
    timer_deadlines_.erase(it);
}

void EventLoop::post(std::function<void()> task)
{
    {
        std::lock_guard<std::mutex> lock(posted_mutex_);
        posted_.push_back(std::move(task));
    }
    const uint8_t byte = kWakeByte;
    [[maybe_unused]] const ssize_t written = ::write(pipe_write_, &byte, 1);
}

void EventLoop::stop()
{
    stop_requested_.store(true);
    const uint8_t byte = kWakeByte;
    [[maybe_unused]] const ssize_t written = ::write(pipe_write_, &byte, 1);
}

void EventLoop::handleSignals(const std::vector<int> &signals, std::function<void(int)> handler)
{
    signal_handler_ = std::move(handler);
    g_signal_pipe.store(pipe_write_);
    std::signal(SIGPIPE, SIG_IGN);
    for (const int signo : signals) {
        struct sigaction action {};
        action.sa_handler = onSignal;
        sigemptyset(&action.sa_mask);
        action.sa_flags = SA_RESTART;
        sigaction(signo, &action, nullptr);
        handled_signals_.push_back(signo);
    }
}

void EventLoop::drainPipe()
{
    uint8_t bytes[256];
    for (;;) {
        const ssize_t n = ::read(pipe_read_, bytes, sizeof bytes);
        if (n <= 0) {
            break;
        }
        for (ssize_t i = 0; i < n; ++i) {
            if (bytes[i] != kWakeByte && signal_handler_) {
                signal_handler_(bytes[i]);
            }
        }
    }
}

void EventLoop::runPosted()
{
    std::vector<std::function<void()>> tasks;
    {
        std::lock_guard<std::mutex> lock(posted_mutex_);
        tasks.swap(posted_);
    }
    for (auto &task : tasks) {
        task();
    }
}

void EventLoop::runDueTimers()
{
    const int64_t now_us = clock_.monotonicUs();
    // Timers added by a callback for "now" run in the next iteration, so a timer that
    // re-arms itself at zero delay cannot starve the descriptors.
    std::vector<TimerId> due;
    for (const auto &entry : timers_) {
        if (entry.first.first > now_us) {
            break;
        }
        due.push_back(entry.first.second);
    }
    for (const TimerId id : due) {
        const auto deadline = timer_deadlines_.find(id);
        if (deadline == timer_deadlines_.end()) {
            continue; // cancelled by an earlier callback
        }
        const auto it = timers_.find(std::make_pair(deadline->second, id));
        TimerCallback callback = std::move(it->second);
        timers_.erase(it);
        timer_deadlines_.erase(deadline);
        callback();
    }
}

void EventLoop::runOnce(int64_t max_wait_us)
{
    int64_t wait_us = max_wait_us;
    if (!timers_.empty()) {
        wait_us = std::min(wait_us, timers_.begin()->first.first - clock_.monotonicUs());
    }
    {
        std::lock_guard<std::mutex> lock(posted_mutex_);
        if (!posted_.empty()) {
            wait_us = 0;
        }
    }
    if (stop_requested_.load()) {
        wait_us = 0;
    }
    wait_us = std::max<int64_t>(0, wait_us);

    std::vector<pollfd> pollfds;
    std::vector<uint64_t> registrations;
    pollfds.reserve(fds_.size() + 1);
    pollfds.push_back({pipe_read_, POLLIN, 0});
    registrations.push_back(0);
    for (const auto &[fd, watch] : fds_) {
        pollfds.push_back({fd, watch.events, 0});
        registrations.push_back(watch.registration);
    }
    timespec timeout{};
    timeout.tv_sec = static_cast<time_t>(wait_us / 1'000'000);
    timeout.tv_nsec = static_cast<long>((wait_us % 1'000'000) * 1000);
    const int ready = ::ppoll(pollfds.data(), static_cast<nfds_t>(pollfds.size()), &timeout, nullptr);
    if (ready < 0 && errno != EINTR) {
        log()->error("event loop: poll failed: {}", std::strerror(errno));
    }
    if (ready > 0) {
        if (pollfds[0].revents != 0) {
            drainPipe();
        }
        for (size_t i = 1; i < pollfds.size(); ++i) {
            if (pollfds[i].revents == 0) {
                continue;
            }
            // The registration may have been removed or replaced by an earlier callback in
            // this iteration (a closed and reopened descriptor can reuse the number).
            const auto it = fds_.find(pollfds[i].fd);
            if (it == fds_.end() || it->second.registration != registrations[i]) {
                continue;
            }
            FdCallback callback = it->second.callback; // a copy: the callback may unwatch itself
            callback(pollfds[i].revents);
        }
    }
    runPosted();
    runDueTimers();
}

void EventLoop::run()
{
    while (!stop_requested_.load()) {
        runOnce(60'000'000);
    }
}

} // namespace cdro::service
