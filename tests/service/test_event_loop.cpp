// The event loop: timers in deadline order, descriptors, wake-ups from other threads, signals
// through the self-pipe, and no stale events for a descriptor replaced in the same iteration.
#include <chrono>
#include <csignal>
#include <thread>

#include <gtest/gtest.h>
#include <poll.h>
#include <unistd.h>

#include "cdro/service/event_loop.hpp"

using namespace cdro::service;

TEST(EventLoop, TimersRunInDeadlineOrderAndCanBeCancelled)
{
    SystemClock clock;
    EventLoop loop(clock);
    std::vector<int> order;
    const int64_t now = clock.monotonicUs();
    loop.addTimerAt(now + 3000, [&] {
        order.push_back(3);
        loop.stop();
    });
    loop.addTimerAt(now + 1000, [&] { order.push_back(1); });
    const auto cancelled = loop.addTimerAt(now + 2000, [&] { order.push_back(99); });
    loop.addTimerAt(now + 2000, [&] { order.push_back(2); });
    loop.cancelTimer(cancelled);
    loop.run();
    EXPECT_EQ(order, (std::vector<int>{1, 2, 3}));
    EXPECT_EQ(loop.pendingTimerCount(), 0U);
}

TEST(EventLoop, PostFromAnotherThreadWakesTheLoop)
{
    SystemClock clock;
    EventLoop loop(clock);
    const auto start = std::chrono::steady_clock::now();
    std::thread other([&] { loop.post([&] { loop.stop(); }); });
    loop.run();
    other.join();
    // Without the wake-up the loop sleeps its 60 s poll timeout before it sees the post: half of
    // that tells the two apart on any machine, however loaded.
    EXPECT_LT(std::chrono::steady_clock::now() - start, std::chrono::seconds(30));
}

TEST(EventLoop, DescriptorsAreWatched)
{
    SystemClock clock;
    EventLoop loop(clock);
    int fds[2];
    ASSERT_EQ(::pipe(fds), 0);
    std::string got;
    loop.watchFd(fds[0], POLLIN, [&](short) {
        char buffer[16];
        const ssize_t n = ::read(fds[0], buffer, sizeof buffer);
        got.append(buffer, static_cast<size_t>(n));
        loop.stop();
    });
    ASSERT_EQ(::write(fds[1], "abc", 3), 3);
    loop.run();
    EXPECT_EQ(got, "abc");
    ::close(fds[0]);
    ::close(fds[1]);
}

TEST(EventLoop, AReplacedRegistrationGetsNoStaleEvents)
{
    SystemClock clock;
    EventLoop loop(clock);
    int a[2], b[2];
    ASSERT_EQ(::pipe(a), 0);
    ASSERT_EQ(::pipe(b), 0);
    int stale = 0, first = 0;
    // Both readable; the first callback re-registers the other descriptor with a new callback,
    // which must not receive the events polled for the old registration.
    loop.watchFd(a[0], POLLIN, [&](short) {
        ++first;
        char c;
        [[maybe_unused]] auto n = ::read(a[0], &c, 1);
        loop.watchFd(b[0], POLLIN, [&](short) { ++stale; });
        loop.stop();
    });
    loop.watchFd(b[0], POLLIN, [&](short) { ++stale; });
    ASSERT_EQ(::write(a[1], "x", 1), 1);
    ASSERT_EQ(::write(b[1], "y", 1), 1);
    loop.runOnce(0);
    EXPECT_EQ(first + stale, first == 1 ? 1 + stale : stale);
    if (first == 1) {
        EXPECT_EQ(stale, 0);
    }
    for (int fd : {a[0], a[1], b[0], b[1]}) {
        ::close(fd);
    }
}

TEST(EventLoop, SignalsArriveOnTheLoopThroughTheSelfPipe)
{
    SystemClock clock;
    EventLoop loop(clock);
    int received = 0;
    loop.handleSignals({SIGUSR1}, [&](int signo) {
        received = signo;
        loop.stop();
    });
    std::thread other([] { ::kill(::getpid(), SIGUSR1); });
    loop.run();
    other.join();
    EXPECT_EQ(received, SIGUSR1);
}
