// The firmware's boot and host commands (docs/protocol.md, "Device behaviour"), end to end:
// the core over the simulated Pozyx, frames decoded by common/'s decoder on the host side.
#include <gtest/gtest.h>

#include <cstring>
#include <string>
#include <vector>

#include "cdro/cobs.h"
#include "cdro/crc.h"
#include "cdro_fw/pozyx_regs.h"
#include "golden.hpp"
#include "support.hpp"

namespace {

using fwtest::Bench;
using fwtest::NodeSpec;

const std::vector<NodeSpec> kNodes = {
    {0x6A01, false, 4.0, 0.0, 0.0},
    {0x6A02, false, 0.0, 5.0, 0.0},
    {0x6A03, false, 4.0, 5.0, 0.0},
    {0x7001, true, 2.0, 2.0, 1.0},
};

// A raw frame with any header values, CRC'd and COBS-encoded with its delimiter.
std::vector<uint8_t> rawFrame(uint8_t version, uint8_t type, uint16_t sequence, const std::vector<uint8_t> &payload)
{
    std::vector<uint8_t> raw = {version, type, static_cast<uint8_t>(sequence & 0xFF),
                                static_cast<uint8_t>(sequence >> 8), static_cast<uint8_t>(payload.size())};
    raw.insert(raw.end(), payload.begin(), payload.end());
    const uint16_t crc = cdro_crc16(raw.data(), raw.size());
    raw.push_back(static_cast<uint8_t>(crc & 0xFF));
    raw.push_back(static_cast<uint8_t>(crc >> 8));
    std::vector<uint8_t> out(raw.size() + 4);
    const size_t n = cdro_cobs_encode(raw.data(), raw.size(), out.data(), out.size());
    out.resize(n);
    out.push_back(0);
    return out;
}

// What a command may change, to check that a refused one changed nothing.
struct Snapshot {
    uint8_t node_count, running, mode, boost, retries;
    uint16_t slot_ms, poll_ms, status_ms;
    std::vector<uint16_t> ids;
    bool operator==(const Snapshot &o) const
    {
        return node_count == o.node_count && running == o.running && mode == o.mode && boost == o.boost &&
               retries == o.retries && slot_ms == o.slot_ms && poll_ms == o.poll_ms && status_ms == o.status_ms &&
               ids == o.ids;
    }
};

Snapshot snapshot(const cdro_fw_t &fw)
{
    Snapshot s{fw.node_count,     fw.running,           fw.sched.mode,
               fw.sched.boost,    fw.sched.max_retries, fw.slot_period_ms,
               fw.motion_poll_ms, fw.status_period_ms,  {}};
    for (uint8_t i = 1; i <= fw.node_count; ++i) {
        s.ids.push_back(fw.nodes[i].id);
    }
    return s;
}

class Commands : public ::testing::Test {
protected:
    Commands() : bench(fwtest::testSeed(51), kNodes) {}
    void SetUp() override { bench.boot(); }

    // The answer to the last command: the first ACK/NACK after `from`.
    cdro_frame_t answer(size_t from)
    {
        for (size_t i = from; i < bench.serial.frames.size(); ++i) {
            const cdro_frame_t &f = bench.serial.frames[i].frame;
            if (f.type == CDRO_FRAME_ACK || f.type == CDRO_FRAME_NACK) {
                return f;
            }
        }
        ADD_FAILURE() << "no answer";
        return fwtest::makeFrame(0);
    }
    void expectNack(const cdro_frame_t &command, uint8_t reason)
    {
        const Snapshot before = snapshot(bench.fw);
        const size_t from = bench.serial.frames.size();
        const uint16_t sequence = bench.serial.hostSequence;
        bench.command(command);
        const cdro_frame_t a = answer(from);
        ASSERT_EQ(a.type, CDRO_FRAME_NACK);
        EXPECT_EQ(a.as.nack.nacked_type, command.type);
        EXPECT_EQ(a.as.nack.nacked_sequence, sequence);
        EXPECT_EQ(a.as.nack.reason, reason);
        EXPECT_TRUE(snapshot(bench.fw) == before) << "a NACKed command changed nothing";
    }
    void expectAck(const cdro_frame_t &command, uint32_t value = 0)
    {
        const size_t from = bench.serial.frames.size();
        const uint16_t sequence = bench.serial.hostSequence;
        bench.command(command);
        const cdro_frame_t a = answer(from);
        ASSERT_EQ(a.type, CDRO_FRAME_ACK);
        EXPECT_EQ(a.as.ack.acked_type, command.type);
        EXPECT_EQ(a.as.ack.acked_sequence, sequence);
        EXPECT_EQ(a.as.ack.value, value);
    }

    Bench bench;
};

TEST_F(Commands, BootSendsZeroHelloAndTheDiscoveredNodesThenWaitsStopped)
{
    ASSERT_FALSE(bench.serial.wire.empty());
    EXPECT_EQ(bench.serial.wire[0], 0x00) << "a delimiter first";
    ASSERT_GE(bench.serial.frames.size(), 2U);
    const cdro_frame_t &hello = bench.serial.frames[0].frame;
    ASSERT_EQ(hello.type, CDRO_FRAME_HELLO);
    EXPECT_EQ(hello.sequence, 0);
    // Every field, through the golden vectors' JSON view of a frame.
    nlohmann::json fields = golden::fieldsToJson(hello);
    EXPECT_EQ(fields["device_time_ms"], CDRO_FW_POZYX_BOOT_MS);
    EXPECT_EQ(fields["firmware_version"], 0x0100);
    EXPECT_EQ(fields["protocol_version"], CDRO_PROTOCOL_VERSION);
    EXPECT_EQ(fields["layout_hash"], CDRO_LAYOUT_HASH);
    EXPECT_EQ(fields["node_id"], 0x6000);
    EXPECT_EQ(fields["capabilities"], CDRO_CAP_DIRECT_RANGING | CDRO_CAP_REMOTE_RANGING | CDRO_CAP_LOCAL_ACCEL |
                                          CDRO_CAP_REMOTE_ACCEL | CDRO_CAP_DISCOVERY | CDRO_CAP_POZYX_SETUP);
    EXPECT_EQ(fields["pozyx_tries"], 1) << "the Pozyx answered at once";
    EXPECT_EQ(fields["pozyx_firmware"], 0x11);
    EXPECT_EQ(fields["max_nodes"], CDRO_FW_MAX_REMOTE_NODES);
    EXPECT_EQ(fields["reset_cause"], CDRO_RESET_POWER_ON);

    const cdro_frame_t &list = bench.serial.frames[1].frame;
    ASSERT_EQ(list.type, CDRO_FRAME_NODE_LIST);
    EXPECT_EQ(list.sequence, 1);
    EXPECT_EQ(list.as.node_list.source, CDRO_NODE_SOURCE_DISCOVERY);
    ASSERT_EQ(list.as.node_list.node_ids_count, 4);
    for (size_t i = 0; i < 4; ++i) {
        EXPECT_EQ(list.as.node_list.node_ids[i], kNodes[i].id);
    }
    // Stopped: STATUS every second, no ranging, no motion.
    bench.runForMs(3500);
    EXPECT_EQ(bench.serial.count(CDRO_FRAME_RANGE), 0U);
    EXPECT_EQ(bench.serial.count(CDRO_FRAME_MOTION), 0U);
    const auto statuses = bench.serial.ofType(CDRO_FRAME_STATUS);
    ASSERT_GE(statuses.size(), 3U);
    EXPECT_EQ(statuses.back().as.status.running, 0);
    EXPECT_EQ(statuses.back().as.status.node_count, 4);
    EXPECT_EQ(statuses.back().as.status.free_ram_bytes, 777) << "the platform's figure";
    EXPECT_EQ(bench.sim()->stats.rangings, 0U);
    EXPECT_EQ(bench.serial.decoder.counters.frames_ok, bench.serial.frames.size());
}

TEST_F(Commands, SetNodesAcksThenListsAndRestartsTheSchedule)
{
    const size_t from = bench.serial.frames.size();
    expectAck(fwtest::setNodes({0x6A03, 0x6A01}));
    const auto lists = bench.serial.ofType(CDRO_FRAME_NODE_LIST, from);
    ASSERT_EQ(lists.size(), 1U);
    EXPECT_EQ(lists[0].as.node_list.source, CDRO_NODE_SOURCE_HOST);
    ASSERT_EQ(lists[0].as.node_list.node_ids_count, 2);
    EXPECT_EQ(lists[0].as.node_list.node_ids[0], 0x6A03);
    EXPECT_EQ(lists[0].as.node_list.node_ids[1], 0x6A01);
    // ACK first, then NODE_LIST.
    EXPECT_EQ(bench.serial.frames[from].frame.type, CDRO_FRAME_ACK);
    EXPECT_EQ(bench.fw.node_count, 2);
    EXPECT_EQ(bench.fw.sched.cursor, 0);
    // An empty list is a valid list.
    expectAck(fwtest::setNodes({}));
    EXPECT_EQ(bench.fw.node_count, 0);
}

TEST_F(Commands, SetNodesRefusals)
{
    std::vector<uint16_t> too_many;
    for (uint16_t i = 0; i <= CDRO_FW_MAX_REMOTE_NODES; ++i) {
        too_many.push_back(static_cast<uint16_t>(0x6100 + i));
    }
    expectNack(fwtest::setNodes(too_many), CDRO_NACK_TOO_MANY_NODES);
    expectNack(fwtest::setNodes({0x6A01, 0x6A01}), CDRO_NACK_BAD_VALUE); // duplicate
    expectNack(fwtest::setNodes({0x6A01, 0x0000}), CDRO_NACK_BAD_VALUE); // zero id
    expectNack(fwtest::setNodes({0x6A01, 0x6000}), CDRO_NACK_BAD_VALUE); // the own node
    // More ids than the protocol's 20 cannot even be a valid SET_NODES payload.
    std::vector<uint8_t> payload = {21};
    for (int i = 0; i < 21; ++i) {
        payload.push_back(static_cast<uint8_t>(i + 1));
        payload.push_back(0x61);
    }
    const Snapshot before = snapshot(bench.fw);
    const size_t from = bench.serial.frames.size();
    bench.serial.hostSendBytes(rawFrame(CDRO_PROTOCOL_VERSION, CDRO_FRAME_SET_NODES, 900, payload));
    bench.runForMs(50);
    const cdro_frame_t a = answer(from);
    ASSERT_EQ(a.type, CDRO_FRAME_NACK);
    EXPECT_EQ(a.as.nack.nacked_sequence, 900);
    EXPECT_EQ(a.as.nack.reason, CDRO_NACK_MALFORMED);
    EXPECT_TRUE(snapshot(bench.fw) == before);
}

TEST_F(Commands, SetScheduleTakesEffectAndOutOfRangeValuesAreRefused)
{
    expectAck(fwtest::setSchedule(50, CDRO_SCHEDULE_DIRECT_ONLY, 0, 3, 500, 2));
    EXPECT_EQ(bench.fw.slot_period_ms, 50);
    EXPECT_EQ(bench.fw.motion_poll_ms, 0);
    EXPECT_EQ(bench.fw.status_period_ms, 500);
    EXPECT_EQ(bench.fw.sched.mode, CDRO_SCHEDULE_DIRECT_ONLY);
    EXPECT_EQ(bench.fw.sched.boost, 3);
    EXPECT_EQ(bench.fw.sched.max_retries, 2);
    expectNack(fwtest::setSchedule(50, 2, 0, 3, 500, 2), CDRO_NACK_BAD_VALUE);    // mode
    expectNack(fwtest::setSchedule(50, 1, 0, 0, 500, 2), CDRO_NACK_BAD_VALUE);    // boost 0
    expectNack(fwtest::setSchedule(50, 1, 0, 9, 500, 2), CDRO_NACK_BAD_VALUE);    // boost 9
    expectNack(fwtest::setSchedule(50, 1, 0, 2, 99, 2), CDRO_NACK_BAD_VALUE);     // status period
    expectNack(fwtest::setSchedule(50, 1, 0, 2, 500, 11), CDRO_NACK_BAD_VALUE);   // retries
    expectNack(fwtest::setSchedule(60001, 1, 0, 2, 500, 1), CDRO_NACK_BAD_VALUE); // slot period
    // STATUS now comes every 500 ms.
    const size_t from = bench.serial.frames.size();
    bench.runForMs(2600);
    const size_t statuses = bench.serial.count(CDRO_FRAME_STATUS, from);
    EXPECT_GE(statuses, 5U);
    EXPECT_LE(statuses, 6U);
}

TEST_F(Commands, StartStopPing)
{
    expectAck(fwtest::makeFrame(CDRO_FRAME_START));
    EXPECT_EQ(bench.fw.running, 1);
    expectAck(fwtest::makeFrame(CDRO_FRAME_START)); // also when already running
    bench.runForMs(500);
    EXPECT_GT(bench.serial.count(CDRO_FRAME_RANGE), 0U);
    expectAck(fwtest::makeFrame(CDRO_FRAME_STOP));
    EXPECT_EQ(bench.fw.running, 0);
    const uint32_t rangings = bench.sim()->stats.rangings;
    const size_t from = bench.serial.frames.size();
    bench.runForMs(2100);
    EXPECT_EQ(bench.sim()->stats.rangings, rangings) << "no ranging after STOP";
    EXPECT_EQ(bench.serial.count(CDRO_FRAME_RANGE, from), 0U);
    EXPECT_GE(bench.serial.count(CDRO_FRAME_STATUS, from), 2U) << "STATUS continues";
    cdro_frame_t ping = fwtest::makeFrame(CDRO_FRAME_PING);
    ping.as.ping.nonce = 0xDEADBEEF;
    expectAck(ping, 0xDEADBEEF);
}

TEST_F(Commands, StartWithoutNodesIsWrongState)
{
    expectAck(fwtest::setNodes({}));
    expectNack(fwtest::makeFrame(CDRO_FRAME_START), CDRO_NACK_WRONG_STATE);
}

// A host that opens the link of a device already running (the host restarted, the device did
// not) asks for HELLO; it has not seen the boot's node list either, so that follows, with the
// list's own source; no ACK (HELLO is the answer).
TEST_F(Commands, HelloRequestIsAnsweredWithHelloThenTheNodeList)
{
    size_t from = bench.serial.frames.size();
    bench.command(fwtest::makeFrame(CDRO_FRAME_HELLO_REQUEST));
    const auto hellos = bench.serial.ofType(CDRO_FRAME_HELLO, from);
    ASSERT_EQ(hellos.size(), 1U);
    EXPECT_NE(hellos[0].sequence, 0) << "the sequence goes on: not a reset";
    EXPECT_EQ(bench.serial.count(CDRO_FRAME_ACK, from), 0U);
    EXPECT_EQ(bench.serial.count(CDRO_FRAME_NACK, from), 0U);
    auto lists = bench.serial.ofType(CDRO_FRAME_NODE_LIST, from);
    ASSERT_EQ(lists.size(), 1U);
    EXPECT_EQ(lists[0].as.node_list.source, CDRO_NODE_SOURCE_DISCOVERY);
    EXPECT_EQ(lists[0].as.node_list.node_ids_count, bench.fw.node_count);
    EXPECT_EQ(bench.serial.frames[from].frame.type, CDRO_FRAME_HELLO) << "HELLO first, then NODE_LIST";

    expectAck(fwtest::setNodes({0x6A03}));
    from = bench.serial.frames.size();
    bench.command(fwtest::makeFrame(CDRO_FRAME_HELLO_REQUEST));
    lists = bench.serial.ofType(CDRO_FRAME_NODE_LIST, from);
    ASSERT_EQ(lists.size(), 1U);
    EXPECT_EQ(lists[0].as.node_list.source, CDRO_NODE_SOURCE_HOST);
    ASSERT_EQ(lists[0].as.node_list.node_ids_count, 1);
    EXPECT_EQ(lists[0].as.node_list.node_ids[0], 0x6A03);

    expectAck(fwtest::setNodes({}));
    bench.runUntilUs(bench.bus.nowUs() + 100000U); // the UART drains (else HELLO is dropped, counted)
    from = bench.serial.frames.size();
    bench.command(fwtest::makeFrame(CDRO_FRAME_HELLO_REQUEST));
    EXPECT_EQ(bench.serial.count(CDRO_FRAME_HELLO, from), 1U);
    EXPECT_EQ(bench.serial.count(CDRO_FRAME_NODE_LIST, from), 0U) << "no nodes, no list";
}

TEST_F(Commands, MalformedFramesAreNackedWithTheirReason)
{
    struct Case {
        const char *what;
        std::vector<uint8_t> bytes;
        uint16_t sequence;
        uint8_t reason;
    };
    const std::vector<Case> cases = {
        {"other version", rawFrame(CDRO_PROTOCOL_VERSION + 1, CDRO_FRAME_START, 501, {}), 501, CDRO_NACK_MALFORMED},
        {"START with a payload", rawFrame(CDRO_PROTOCOL_VERSION, CDRO_FRAME_START, 502, {1}), 502, CDRO_NACK_MALFORMED},
        {"PING too short", rawFrame(CDRO_PROTOCOL_VERSION, CDRO_FRAME_PING, 503, {1, 2}), 503, CDRO_NACK_MALFORMED},
        {"unknown type", rawFrame(CDRO_PROTOCOL_VERSION, 0x4F, 504, {}), 504, CDRO_NACK_UNKNOWN_TYPE},
        {"device-to-host type", rawFrame(CDRO_PROTOCOL_VERSION, CDRO_FRAME_ACK, 505, {0x43, 1, 0, 0, 0, 0, 0}), 505,
         CDRO_NACK_UNKNOWN_TYPE},
        {"device-to-host type with a bad value",
         rawFrame(CDRO_PROTOCOL_VERSION, CDRO_FRAME_ERROR, 506, {0, 0, 0, 0, 0, 0, 0, 0, 0}), 506,
         CDRO_NACK_UNKNOWN_TYPE},
    };
    uint32_t rejected = 0;
    for (const Case &c : cases) {
        SCOPED_TRACE(c.what);
        const Snapshot before = snapshot(bench.fw);
        const size_t from = bench.serial.frames.size();
        bench.serial.hostSendBytes(c.bytes);
        bench.runForMs(20);
        const cdro_frame_t a = answer(from);
        ASSERT_EQ(a.type, CDRO_FRAME_NACK);
        EXPECT_EQ(a.as.nack.nacked_sequence, c.sequence);
        EXPECT_EQ(a.as.nack.reason, c.reason);
        EXPECT_TRUE(snapshot(bench.fw) == before);
        ++rejected;
    }
    EXPECT_EQ(bench.fw.counters.commands_rejected, rejected);
}

TEST_F(Commands, UndecodableChunksAreCountedAndReportedNotAnswered)
{
    const size_t from = bench.serial.frames.size();
    std::vector<uint8_t> bad_crc = rawFrame(CDRO_PROTOCOL_VERSION, CDRO_FRAME_PING, 601, {1, 2, 3, 4});
    bad_crc[3] ^= 0x40;
    bench.serial.hostSendBytes(bad_crc);
    bench.serial.hostSendBytes({0x05, 0x01, 0x00});              // COBS says 4 more bytes, gets 1
    bench.serial.hostSendBytes({0x02, 0x01, 0x00});              // too short for a header
    bench.serial.hostSendBytes(std::vector<uint8_t>(200, 0x33)); // no delimiter within 73 bytes
    bench.serial.hostSendBytes({0x00});
    cdro_frame_t ping = fwtest::makeFrame(CDRO_FRAME_PING);
    ping.as.ping.nonce = 7;
    bench.serial.hostSend(ping); // the link resynchronises: this one is answered
    bench.runForMs(1500);
    EXPECT_EQ(bench.serial.count(CDRO_FRAME_NACK, from), 0U);
    const auto acks = bench.serial.ofType(CDRO_FRAME_ACK, from);
    ASSERT_EQ(acks.size(), 1U);
    EXPECT_EQ(acks[0].as.ack.value, 7U);
    EXPECT_EQ(bench.fw.counters.commands_rejected, 4U);
    // At most one ERROR COMMAND per status period, naming the last rejection's cdro_result_t:
    // the first step's 80 bytes hold three bad chunks, the overlong one ends in the next step.
    const auto errors = bench.serial.ofType(CDRO_FRAME_ERROR, from);
    ASSERT_EQ(errors.size(), 2U);
    EXPECT_EQ(errors[0].as.error.code, CDRO_DEVICE_ERROR_COMMAND);
    EXPECT_EQ(static_cast<int16_t>(errors[0].as.error.detail), CDRO_ERR_SHORT);
    EXPECT_EQ(errors[1].as.error.code, CDRO_DEVICE_ERROR_COMMAND);
    EXPECT_EQ(static_cast<int16_t>(errors[1].as.error.detail), CDRO_ERR_TOO_LONG);
    EXPECT_GE(errors[1].as.error.device_time_ms - errors[0].as.error.device_time_ms, 1000U);
    const auto statuses = bench.serial.ofType(CDRO_FRAME_STATUS, from);
    ASSERT_FALSE(statuses.empty());
    EXPECT_EQ(statuses.back().as.status.commands_rejected, 4U);
}

// The report is driven by a pending flag, not by comparing a wrapping 8-bit count: exactly
// 256 bad chunks between two reports (which a wrapping count would alias to "none") are
// reported too.
TEST_F(Commands, ExactlyTwoHundredFiftySixBadChunksBetweenReportsAreStillReported)
{
    const size_t from = bench.serial.frames.size();
    const uint32_t rejected_before = bench.fw.counters.commands_rejected;
    bench.serial.hostSendBytes({0x01, 0x00}); // decodes to nothing: too short
    bench.runForMs(50);
    ASSERT_EQ(bench.serial.count(CDRO_FRAME_ERROR, from), 1U);
    for (int batch = 0; batch < 16; ++batch) { // 256 more, well inside one status period
        for (int i = 0; i < 16; ++i) {
            bench.serial.hostSendBytes({0x01, 0x00});
        }
        bench.runForMs(20);
    }
    bench.runForMs(2000);
    const auto errors = bench.serial.ofType(CDRO_FRAME_ERROR, from);
    ASSERT_EQ(errors.size(), 2U);
    EXPECT_EQ(errors[1].as.error.code, CDRO_DEVICE_ERROR_COMMAND);
    EXPECT_EQ(static_cast<int16_t>(errors[1].as.error.detail), CDRO_ERR_SHORT);
    EXPECT_EQ(bench.fw.counters.commands_rejected - rejected_before, 257U);
}

TEST(CommandsAtBoot, AbsentPozyxSaysSoAndRefusesStart)
{
    Bench bench(fwtest::testSeed(52), kNodes);
    pozyx_sim_find(bench.sim(), 0x6000)->config.powered = 0;
    bench.boot();
    ASSERT_GE(bench.serial.frames.size(), 2U);
    const cdro_frame_t &hello = bench.serial.frames[0].frame;
    ASSERT_EQ(hello.type, CDRO_FRAME_HELLO);
    EXPECT_EQ(hello.as.hello.node_id, CDRO_FW_NODE_ID_UNKNOWN);
    EXPECT_EQ(hello.as.hello.pozyx_firmware, 0);
    EXPECT_EQ(hello.as.hello.capabilities, 0);
    const cdro_frame_t &error = bench.serial.frames[1].frame;
    ASSERT_EQ(error.type, CDRO_FRAME_ERROR);
    EXPECT_EQ(error.as.error.code, CDRO_DEVICE_ERROR_POZYX_ABSENT);
    // Commands are still answered; START is refused even with nodes.
    bench.command(fwtest::setNodes({0x6A01}));
    const size_t from = bench.serial.frames.size();
    bench.command(fwtest::makeFrame(CDRO_FRAME_START));
    const auto nacks = bench.serial.ofType(CDRO_FRAME_NACK, from);
    ASSERT_EQ(nacks.size(), 1U);
    EXPECT_EQ(nacks[0].as.nack.reason, CDRO_NACK_WRONG_STATE);
}

TEST(CommandsAtBoot, WrongWhoAmIIsReportedWithTheValueRead)
{
    Bench bench(fwtest::testSeed(53), kNodes);
    bench.sim()->config.who_am_i = 0x00;
    bench.boot();
    const cdro_frame_t &error = bench.serial.frames[1].frame;
    ASSERT_EQ(error.type, CDRO_FRAME_ERROR);
    EXPECT_EQ(error.as.error.code, CDRO_DEVICE_ERROR_POZYX_ABSENT);
    EXPECT_EQ(error.as.error.detail, 0x00);
    EXPECT_EQ(bench.fw.pozyx_state, CDRO_FW_POZYX_ABSENT);
}

TEST(CommandsAtBoot, FailedSelfTestIsReportedAndStartRefused)
{
    Bench bench(fwtest::testSeed(54), kNodes);
    pozyx_sim_find(bench.sim(), 0x6000)->config.self_test = 0x3E; // accelerometer failed
    bench.boot();
    ASSERT_EQ(bench.serial.frames[0].frame.type, CDRO_FRAME_HELLO);
    EXPECT_EQ(bench.serial.frames[0].frame.as.hello.node_id, 0x6000) << "the id is still known";
    const cdro_frame_t &error = bench.serial.frames[1].frame;
    ASSERT_EQ(error.type, CDRO_FRAME_ERROR);
    EXPECT_EQ(error.as.error.code, CDRO_DEVICE_ERROR_SELF_TEST);
    EXPECT_EQ(error.as.error.detail, 0x3E);
    const size_t from = bench.serial.frames.size();
    bench.command(fwtest::makeFrame(CDRO_FRAME_START));
    ASSERT_EQ(bench.serial.count(CDRO_FRAME_NACK, from), 1U);
}

TEST(CommandsAtBoot, AnchorAsOwnNodeHasNoLocalAccel)
{
    Bench bench(fwtest::testSeed(55), kNodes, /*local_tag=*/false);
    bench.boot();
    EXPECT_EQ(bench.serial.frames[0].frame.as.hello.capabilities & CDRO_CAP_LOCAL_ACCEL, 0);
    EXPECT_EQ(bench.fw.pozyx_state, CDRO_FW_POZYX_OK);
}

TEST(CommandsAtBoot, DiscoveryFailureIsRetriedThenReported)
{
    Bench once(fwtest::testSeed(56), kNodes);
    once.sim()->faults.no_completion = 1; // the first discovery times out, the retry works
    once.boot();
    // The timed-out attempt is counted and reported as a timeout; the discovery did not fail.
    const auto errors_once = once.serial.ofType(CDRO_FRAME_ERROR);
    ASSERT_EQ(errors_once.size(), 1U);
    EXPECT_EQ(errors_once[0].as.error.code, CDRO_DEVICE_ERROR_TIMEOUT);
    EXPECT_EQ(errors_once[0].as.error.detail, POZYX_FN_DEVICES_DISCOVER);
    ASSERT_EQ(once.serial.count(CDRO_FRAME_NODE_LIST), 1U);

    Bench twice(fwtest::testSeed(57), kNodes);
    twice.sim()->faults.error_completion = 2;
    twice.sim()->faults.error_code = 0x0B;
    twice.boot();
    const auto errors = twice.serial.ofType(CDRO_FRAME_ERROR);
    ASSERT_EQ(errors.size(), 1U);
    EXPECT_EQ(errors[0].as.error.code, CDRO_DEVICE_ERROR_DISCOVERY);
    EXPECT_EQ(errors[0].as.error.detail, 0x0B);
    EXPECT_EQ(twice.serial.count(CDRO_FRAME_NODE_LIST), 0U);
    EXPECT_EQ(twice.fw.node_count, 0);
}

TEST(CommandsAtBoot, DiscoveryKeepsAtMostMaxNodes)
{
    std::vector<NodeSpec> many;
    for (uint16_t i = 0; i < 14; ++i) {
        many.push_back({static_cast<uint16_t>(0x6100 + i), false, 1.0 + i, 0.0, 0.0});
    }
    Bench bench(fwtest::testSeed(58), many);
    bench.boot();
    const auto lists = bench.serial.ofType(CDRO_FRAME_NODE_LIST);
    ASSERT_EQ(lists.size(), 1U);
    EXPECT_EQ(lists[0].as.node_list.node_ids_count, CDRO_FW_MAX_REMOTE_NODES);
}

} // namespace
