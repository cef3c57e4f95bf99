// DeviceSession: the handshake, retries, NACKs, keepalive, resets and incompatible devices,
// driven by frames and a ManualClock (no sleeping).
#include <gtest/gtest.h>

#include "cdro/service/session.hpp"
#include "support.hpp"

using namespace cdro::service;

namespace {

struct Sink final : CommandSink {
    std::vector<cdro_frame_t> sent;
    uint16_t next = 100;
    bool sendCommand(cdro_frame_t &frame) override
    {
        frame.sequence = next++;
        sent.push_back(frame);
        return true;
    }
};

struct Listener final : SessionListener {
    std::vector<LinkState> states;
    std::vector<std::string> reopens;
    void onSessionState(LinkState state, const std::string &) override { states.push_back(state); }
    void onReopenRequested(const std::string &reason) override { reopens.push_back(reason); }
};

struct Fixture {
    Fixture()
    {
        config.nodes.ids = {0x6069, 0x6A11};
        config.serial.hello_timeout_s = 1.0;
        config.serial.hello_retries = 3;
        config.serial.command_timeout_s = 0.5;
        config.serial.command_retries = 2;
        config.serial.keepalive_period_s = 2.0;
        config.serial.keepalive_misses = 2;
        session = std::make_unique<DeviceSession>(config, clock, sink, listener, counters);
    }
    void frame(const cdro_frame_t &f) { session->onDeviceFrame(f, 0); }
    void ack(const cdro_frame_t &command) { frame(cdro::test::ackFrame(0, command.type, command.sequence)); }
    // Advances to the session's deadline and ticks it.
    void timeout()
    {
        const int64_t deadline = session->nextDeadlineUs();
        ASSERT_NE(deadline, INT64_MAX);
        clock.advanceUs(deadline - clock.monotonicUs());
        session->onTick();
    }
    // Brings the session to running, answering each command.
    void handshake()
    {
        session->onLinkUp();
        frame(cdro::test::helloFrame(0, 10));
        for (int i = 0; i < 3; ++i) {
            ack(sink.sent.back());
        }
    }
    ServiceConfig config;
    ManualClock clock;
    Sink sink;
    Listener listener;
    ServiceCounters counters;
    std::unique_ptr<DeviceSession> session;
};

} // namespace

TEST(Session, HelloThenSetNodesSetScheduleStartThenRunning)
{
    Fixture f;
    f.session->onLinkUp();
    EXPECT_EQ(f.session->linkState(), LinkState::Handshaking);
    EXPECT_TRUE(f.sink.sent.empty()); // the device may say HELLO by itself first
    f.frame(cdro::test::helloFrame(0, 10));
    ASSERT_EQ(f.sink.sent.size(), 1U);
    EXPECT_EQ(f.sink.sent[0].type, CDRO_FRAME_SET_NODES);
    EXPECT_EQ(f.sink.sent[0].as.set_nodes.node_ids_count, 2);
    EXPECT_EQ(f.sink.sent[0].as.set_nodes.node_ids[1], 0x6A11);
    f.ack(f.sink.sent[0]);
    ASSERT_EQ(f.sink.sent.size(), 2U);
    EXPECT_EQ(f.sink.sent[1].type, CDRO_FRAME_SET_SCHEDULE);
    EXPECT_EQ(f.sink.sent[1].as.set_schedule.status_period_ms, 1000);
    f.frame(cdro::test::ackFrame(0, CDRO_FRAME_SET_SCHEDULE, 9999)); // wrong sequence: ignored
    EXPECT_EQ(f.sink.sent.size(), 2U);
    f.ack(f.sink.sent[1]);
    ASSERT_EQ(f.sink.sent.size(), 3U);
    EXPECT_EQ(f.sink.sent[2].type, CDRO_FRAME_START);
    f.ack(f.sink.sent[2]);
    EXPECT_EQ(f.session->linkState(), LinkState::Connected);
    EXPECT_EQ(f.counters.handshakes, 1U);
}

TEST(Session, WithoutNodeIdsTheDiscoveredListIsKept)
{
    Fixture f;
    f.config.nodes.ids.clear();
    f.session = std::make_unique<DeviceSession>(f.config, f.clock, f.sink, f.listener, f.counters);
    f.session->onLinkUp();
    f.frame(cdro::test::helloFrame(0, 10));
    ASSERT_EQ(f.sink.sent.size(), 1U);
    EXPECT_EQ(f.sink.sent[0].type, CDRO_FRAME_SET_SCHEDULE);
}

TEST(Session, SilentDeviceGetsHelloRequestsThenAReopen)
{
    Fixture f;
    f.session->onLinkUp();
    for (int i = 0; i < 3; ++i) {
        f.timeout();
        ASSERT_EQ(f.sink.sent.size(), static_cast<size_t>(i + 1));
        EXPECT_EQ(f.sink.sent.back().type, CDRO_FRAME_HELLO_REQUEST);
    }
    EXPECT_TRUE(f.listener.reopens.empty());
    f.timeout();
    ASSERT_EQ(f.listener.reopens.size(), 1U);
    EXPECT_NE(f.listener.reopens[0].find("no HELLO after 3"), std::string::npos);
    EXPECT_EQ(f.counters.hello_requests, 3U);
}

TEST(Session, CommandTimeoutsAreRetriedThenTheHandshakeStartsOver)
{
    Fixture f;
    f.session->onLinkUp();
    f.frame(cdro::test::helloFrame(0, 10));
    f.timeout(); // SET_NODES again
    f.timeout(); // and again
    ASSERT_EQ(f.sink.sent.size(), 3U);
    for (const auto &sent : f.sink.sent) {
        EXPECT_EQ(sent.type, CDRO_FRAME_SET_NODES);
    }
    EXPECT_NE(f.sink.sent[0].sequence, f.sink.sent[1].sequence); // a resend is a new frame
    f.timeout();                                                 // retries exhausted
    EXPECT_EQ(f.sink.sent.back().type, CDRO_FRAME_HELLO_REQUEST);
    EXPECT_EQ(f.counters.command_timeouts, 3U);
    EXPECT_EQ(f.session->linkState(), LinkState::Handshaking);
}

TEST(Session, NackedConfigurationGoesOnNackedStartIsRetried)
{
    Fixture f;
    f.session->onLinkUp();
    f.frame(cdro::test::helloFrame(0, 10));
    cdro_frame_t nack{};
    nack.type = CDRO_FRAME_NACK;
    nack.as.nack = {CDRO_FRAME_SET_NODES, f.sink.sent[0].sequence, CDRO_NACK_TOO_MANY_NODES};
    f.frame(nack);
    EXPECT_EQ(f.sink.sent.back().type, CDRO_FRAME_SET_SCHEDULE);
    f.ack(f.sink.sent.back());
    EXPECT_EQ(f.sink.sent.back().type, CDRO_FRAME_START);
    nack.as.nack = {CDRO_FRAME_START, f.sink.sent.back().sequence, CDRO_NACK_WRONG_STATE};
    f.frame(nack);
    EXPECT_EQ(f.sink.sent.back().type, CDRO_FRAME_START); // resent
    EXPECT_EQ(f.counters.nacks, 2U);
    f.ack(f.sink.sent.back());
    EXPECT_EQ(f.session->linkState(), LinkState::Connected);
}

TEST(Session, KeepalivePingsAndMissedPingsRestartTheHandshake)
{
    Fixture f;
    f.handshake();
    const size_t before = f.sink.sent.size();
    f.timeout(); // keepalive period
    ASSERT_EQ(f.sink.sent.size(), before + 1);
    const cdro_frame_t ping = f.sink.sent.back();
    ASSERT_EQ(ping.type, CDRO_FRAME_PING);
    f.frame(cdro::test::ackFrame(0, CDRO_FRAME_PING, ping.sequence, ping.as.ping.nonce));
    f.timeout(); // next PING
    f.timeout(); // unanswered: miss 1, PING again
    EXPECT_EQ(f.counters.pings_missed, 1U);
    EXPECT_EQ(f.session->linkState(), LinkState::Connected);
    f.timeout(); // miss 2: handshake over
    EXPECT_EQ(f.counters.pings_missed, 2U);
    EXPECT_EQ(f.sink.sent.back().type, CDRO_FRAME_HELLO_REQUEST);
    EXPECT_EQ(f.session->linkState(), LinkState::Handshaking);
}

TEST(Session, ResetReHandshakesAndStoppedDeviceIsConfiguredAgain)
{
    Fixture f;
    f.handshake();
    f.session->onDeviceReset(DeviceResetReason::SequenceRestart, 0);
    EXPECT_EQ(f.session->linkState(), LinkState::Handshaking);
    f.frame(cdro::test::helloFrame(0, 10)); // the boot HELLO
    EXPECT_EQ(f.sink.sent.back().type, CDRO_FRAME_SET_NODES);
    for (int i = 0; i < 3; ++i) {
        f.ack(f.sink.sent.back());
    }
    EXPECT_EQ(f.counters.handshakes, 2U);
    cdro_frame_t status{};
    status.type = CDRO_FRAME_STATUS;
    status.as.status.running = 0;
    f.frame(status);
    EXPECT_EQ(f.session->linkState(), LinkState::Handshaking);
    EXPECT_EQ(f.sink.sent.back().type, CDRO_FRAME_SET_NODES);
}

TEST(Session, IncompatibleDeviceIsLeftAloneUntilACompatibleHello)
{
    Fixture f;
    f.session->onLinkUp();
    f.session->onIncompatible("device speaks protocol version 2");
    EXPECT_EQ(f.session->linkState(), LinkState::Incompatible);
    EXPECT_EQ(f.session->nextDeadlineUs(), f.clock.monotonicUs() + 1'000'000); // asked again later
    cdro_frame_t hello = cdro::test::helloFrame(0, 10);
    hello.as.hello.protocol_version = CDRO_PROTOCOL_VERSION + 1;
    f.frame(hello);
    EXPECT_TRUE(f.sink.sent.empty());
    f.frame(cdro::test::helloFrame(0, 10));
    EXPECT_EQ(f.session->linkState(), LinkState::Handshaking);
    EXPECT_EQ(f.sink.sent.size(), 1U);
}

// An incompatible device is asked again: otherwise a HELLO that only looked incompatible (or a
// device reflashed without a reset) would lock the service out until the device rebooted by
// itself. HELLO_REQUEST keeps going out, with a doubling delay.
TEST(Session, IncompatibleDeviceIsAskedAgainWithBackoff)
{
    Fixture f;
    f.config.serial.reconnect_max_s = 4.0;
    f.session = std::make_unique<DeviceSession>(f.config, f.clock, f.sink, f.listener, f.counters);
    f.session->onLinkUp();
    f.session->onIncompatible("device speaks protocol version 2");
    std::vector<int64_t> delays_us;
    for (int i = 0; i < 5; ++i) {
        const int64_t before_us = f.clock.monotonicUs();
        f.timeout();
        delays_us.push_back(f.clock.monotonicUs() - before_us);
        EXPECT_EQ(f.sink.sent.back().type, CDRO_FRAME_HELLO_REQUEST);
        EXPECT_EQ(f.session->linkState(), LinkState::Incompatible);
    }
    EXPECT_EQ(f.sink.sent.size(), 5U);
    // hello_timeout_s (1 s) doubling, up to serial.reconnect_max_s (4 s).
    EXPECT_EQ(delays_us, (std::vector<int64_t>{1'000'000, 2'000'000, 4'000'000, 4'000'000, 4'000'000}));
    f.frame(cdro::test::helloFrame(7, 10)); // the answer is compatible after all
    EXPECT_EQ(f.session->linkState(), LinkState::Handshaking);
    EXPECT_EQ(f.sink.sent.back().type, CDRO_FRAME_SET_NODES);
}

// The late answer to an earlier HELLO_REQUEST is not a reason to configure again.
TEST(Session, ALateHelloWhileRunningOrConfiguringChangesNothing)
{
    Fixture f;
    f.handshake();
    const size_t sent = f.sink.sent.size();
    f.frame(cdro::test::helloFrame(40, 5000));
    EXPECT_EQ(f.session->linkState(), LinkState::Connected);
    EXPECT_EQ(f.sink.sent.size(), sent);
    EXPECT_EQ(f.counters.handshakes, 1U);

    Fixture g;
    g.session->onLinkUp();
    g.frame(cdro::test::helloFrame(3, 10));
    ASSERT_EQ(g.sink.sent.back().type, CDRO_FRAME_SET_NODES);
    g.frame(cdro::test::helloFrame(4, 20)); // the answer to a second request
    ASSERT_EQ(g.sink.sent.size(), 1U);      // SET_NODES is not sent again
    for (int i = 0; i < 3; ++i) {
        g.ack(g.sink.sent.back());
    }
    EXPECT_EQ(g.session->linkState(), LinkState::Connected);
    EXPECT_EQ(g.counters.command_timeouts, 0U);
}

TEST(Session, LinkDownIsDisconnectedAndSilent)
{
    Fixture f;
    f.handshake();
    f.session->onLinkDown();
    EXPECT_EQ(f.session->linkState(), LinkState::Disconnected);
    EXPECT_EQ(f.session->nextDeadlineUs(), INT64_MAX);
    const size_t sent = f.sink.sent.size();
    f.frame(cdro::test::helloFrame(0, 10));
    EXPECT_EQ(f.sink.sent.size(), sent);
}
