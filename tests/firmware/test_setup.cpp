// The firmware's Pozyx set-up: identification retried with backoff, the Pozyx
// firmware check, every node's settings read and compared (NODE_INFO), SET_UWB, the stuck-bus
// recoveries in STATUS, and the bench diagnostics (DIAGNOSE). The real device's behaviour.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "cdro_fw/pozyx_regs.h"
#include "support.hpp"

namespace {

using fwtest::Bench;
using fwtest::NodeSpec;

constexpr uint16_t kOwn = 0x6000;
const std::vector<NodeSpec> kNodes = {
    {0x6A01, false, 4.0, 0.0, 0.0},
    {0x6A02, false, 0.0, 5.0, 0.0},
    {0x7001, true, 2.0, 2.0, 1.0},
};

std::vector<cdro_frame_t> errorsOf(const Bench &bench, uint8_t code)
{
    std::vector<cdro_frame_t> out;
    for (const cdro_frame_t &e : bench.serial.ofType(CDRO_FRAME_ERROR)) {
        if (e.as.error.code == code) {
            out.push_back(e);
        }
    }
    return out;
}

// ---- identification ----------------------------------------------------------------------------

// A Pozyx that boots in 1.2 s instead of the 250 ms the firmware first waits: tried at 250 ms,
// then 500 ms and 1 s later; each failed try is an ERROR; found at the third, it says HELLO again
// (node id, capabilities, three tries), discovers, and ranges after START.
TEST(Setup, ASlowPozyxIsTriedAgainWithBackoffAndFound)
{
    Bench bench(fwtest::testSeed(81), kNodes);
    bench.sim()->nodes[0].ready_at_us = 1200000;
    bench.runForMs(2500);
    const auto hellos = bench.serial.ofType(CDRO_FRAME_HELLO);
    ASSERT_EQ(hellos.size(), 2U);
    EXPECT_EQ(hellos[0].sequence, 0);
    EXPECT_EQ(hellos[0].as.hello.node_id, CDRO_FW_NODE_ID_UNKNOWN);
    EXPECT_EQ(hellos[0].as.hello.pozyx_tries, 1);
    EXPECT_EQ(hellos[1].as.hello.node_id, kOwn);
    EXPECT_EQ(hellos[1].as.hello.pozyx_tries, 3);
    EXPECT_NE(hellos[1].as.hello.capabilities & CDRO_CAP_REMOTE_RANGING, 0);
    const auto absent = errorsOf(bench, CDRO_DEVICE_ERROR_POZYX_ABSENT);
    ASSERT_EQ(absent.size(), 2U) << "each failed try reported";
    EXPECT_NEAR(absent[0].as.error.device_time_ms, 250.0, 5.0);
    EXPECT_NEAR(absent[1].as.error.device_time_ms, 750.0, 5.0) << "500 ms later";
    EXPECT_NEAR(hellos[1].as.hello.device_time_ms, 1750.0, 5.0) << "1 s later";
    EXPECT_EQ(bench.sim()->stats.boot_refusals, 2U);
    ASSERT_EQ(bench.serial.count(CDRO_FRAME_NODE_LIST), 1U) << "discovered once found";
    bench.command(fwtest::makeFrame(CDRO_FRAME_START));
    bench.runForMs(1000);
    EXPECT_GT(bench.serial.count(CDRO_FRAME_RANGE), 5U);
}

// The backoff doubles up to 8 s and the tries go on for ever: a Pozyx powered 40 s late is
// found within 8 s of booting.
TEST(Setup, IdentificationBackoffIsCappedAndNeverGivesUp)
{
    Bench bench(fwtest::testSeed(82), kNodes);
    pozyx_sim_node_t *own = &bench.sim()->nodes[0];
    own->config.powered = 0;
    bench.runForMs(40000);
    std::vector<uint32_t> tries;
    for (const cdro_frame_t &e : errorsOf(bench, CDRO_DEVICE_ERROR_POZYX_ABSENT)) {
        tries.push_back(e.as.error.device_time_ms);
    }
    ASSERT_EQ(tries.size(), 9U); // 0.25, 0.75, 1.75, 3.75, 7.75, 15.75, 23.75, 31.75, 39.75 s
    for (size_t i = 1; i < tries.size(); ++i) {
        const double gap_ms = tries[i] - tries[i - 1];
        EXPECT_NEAR(gap_ms, std::min(500.0 * std::pow(2.0, static_cast<double>(i - 1)), 8000.0), 10.0) << i;
    }
    own->config.powered = 1;
    const uint32_t on_ms = bench.bus.nowMs();
    bench.runForMs(8000 + 250 + 500);
    const auto hellos = bench.serial.ofType(CDRO_FRAME_HELLO);
    ASSERT_EQ(hellos.size(), 2U);
    EXPECT_EQ(hellos[1].as.hello.node_id, kOwn);
    EXPECT_LE(hellos[1].as.hello.device_time_ms - on_ms, 8000U + 250U + 10U);
    EXPECT_EQ(hellos[1].as.hello.pozyx_tries, 10);
}

// Pozyx firmware before 1.0 (another function map) or from 1.3 (remote results handled
// differently) is refused: HELLO carries the version, capabilities 0, ERROR POZYX_FIRMWARE,
// START NACKed, no discovery, no retry. 1.0 to 1.2 are driven.
TEST(Setup, PozyxFirmwareOutsideOneZeroToOneTwoIsRefused)
{
    for (const uint8_t version : std::vector<uint8_t>{0x09, 0x10, 0x11, 0x12, 0x13, 0x21}) {
        SCOPED_TRACE(version);
        Bench bench(fwtest::testSeed(83), kNodes);
        bench.sim()->config.firmware_version = version;
        bench.boot();
        bench.runForMs(2000);
        const auto hellos = bench.serial.ofType(CDRO_FRAME_HELLO);
        ASSERT_EQ(hellos.size(), 1U);
        EXPECT_EQ(hellos[0].as.hello.pozyx_firmware, version);
        const bool supported = version >= 0x10 && version <= 0x12;
        const auto refused = errorsOf(bench, CDRO_DEVICE_ERROR_POZYX_FIRMWARE);
        if (supported) {
            EXPECT_TRUE(refused.empty());
            EXPECT_NE(hellos[0].as.hello.capabilities, 0);
            EXPECT_EQ(bench.fw.pozyx_state, CDRO_FW_POZYX_OK);
            continue;
        }
        ASSERT_EQ(refused.size(), 1U);
        EXPECT_EQ(refused[0].as.error.detail, version);
        EXPECT_EQ(hellos[0].as.hello.capabilities, 0);
        EXPECT_EQ(hellos[0].as.hello.node_id, kOwn) << "it answered: its id is known";
        EXPECT_EQ(bench.fw.pozyx_state, CDRO_FW_POZYX_FIRMWARE);
        EXPECT_EQ(bench.serial.count(CDRO_FRAME_NODE_LIST), 0U);
        bench.command(fwtest::setNodes({0x6A01}));
        const size_t from = bench.serial.frames.size();
        bench.command(fwtest::makeFrame(CDRO_FRAME_START));
        const auto nacks = bench.serial.ofType(CDRO_FRAME_NACK, from);
        ASSERT_EQ(nacks.size(), 1U);
        EXPECT_EQ(nacks[0].as.nack.reason, CDRO_NACK_WRONG_STATE);
    }
}

// ---- the nodes' settings ------------------------------------------------------------------------

// At start every node is read: the own node first, then each discovered one; a node whose gain
// or protocol differs is flagged; a host-set node on another channel does not answer.
TEST(Setup, EveryNodesSettingsAreReadAndMismatchesFlagged)
{
    Bench bench(fwtest::testSeed(84), kNodes);
    pozyx_sim_find(bench.sim(), 0x6A02)->regs[POZYX_REG_UWB_GAIN] = 30;
    pozyx_sim_find(bench.sim(), 0x7001)->regs[POZYX_REG_RANGE_PROTOCOL] = 1;
    bench.boot();
    auto infos = bench.serial.ofType(CDRO_FRAME_NODE_INFO);
    ASSERT_EQ(infos.size(), 4U);
    const uint16_t order[4] = {kOwn, 0x6A01, 0x6A02, 0x7001};
    const uint8_t mismatch[4] = {0, 0, CDRO_MISMATCH_GAIN, CDRO_MISMATCH_PROTOCOL};
    for (size_t i = 0; i < 4; ++i) {
        const cdro_node_info_t &n = infos[i].as.node_info;
        EXPECT_EQ(n.node_id, order[i]);
        EXPECT_EQ(n.result, CDRO_NODE_INFO_READ);
        EXPECT_EQ(n.pozyx_firmware, 0x11);
        EXPECT_EQ(n.uwb_channel, 5);
        EXPECT_EQ(n.uwb_rates, 0x80);
        EXPECT_EQ(n.uwb_plen, 0x08);
        EXPECT_EQ(n.mismatch, mismatch[i]) << std::hex << n.node_id;
    }
    EXPECT_EQ(infos[2].as.node_info.uwb_gain, 30);
    EXPECT_NE(bench.fw.nodes[3].flags & CDRO_FW_NODE_TAG, 0) << "the tag's kind learnt on the way";

    // A node on channel 2 cannot be discovered, nor read: NO_ANSWER once the host lists it.
    Bench other(fwtest::testSeed(85), kNodes);
    pozyx_sim_find(other.sim(), 0x6A02)->regs[POZYX_REG_UWB_CHANNEL] = 2;
    other.boot();
    ASSERT_EQ(other.fw.node_count, 2U);
    const size_t from = other.serial.frames.size();
    other.command(fwtest::setNodes({0x6A01, 0x6A02}));
    other.runForMs(1500);
    infos = other.serial.ofType(CDRO_FRAME_NODE_INFO, from);
    ASSERT_EQ(infos.size(), 3U);
    EXPECT_EQ(infos[2].as.node_info.node_id, 0x6A02);
    EXPECT_EQ(infos[2].as.node_info.result, CDRO_NODE_INFO_NO_ANSWER);
}

// SET_UWB moves every node and the own node to other settings (remote nodes first: they go
// silent on the old ones), then reports each node as it is now; ranging works on the new ones.
TEST(Setup, SetUwbMovesEveryNodeAndReportsThem)
{
    Bench bench(fwtest::testSeed(86), kNodes);
    bench.boot();
    cdro_frame_t set = fwtest::makeFrame(CDRO_FRAME_SET_UWB);
    set.as.set_uwb = {2, (1U << 6) | 2U, 0x24, 40, 1}; // channel 2, 6.8 Mbit/s at 16 MHz, 256 symbols
    bench.command(fwtest::makeFrame(CDRO_FRAME_START));
    const size_t running_from = bench.serial.frames.size();
    bench.command(set);
    EXPECT_EQ(bench.serial.ofType(CDRO_FRAME_NACK, running_from).size(), 1U) << "not while ranging";
    bench.command(fwtest::makeFrame(CDRO_FRAME_STOP));
    const size_t from = bench.serial.frames.size();
    bench.command(set);
    ASSERT_EQ(bench.serial.ofType(CDRO_FRAME_ACK, from).size(), 1U);
    bench.runForMs(3000);
    const auto infos = bench.serial.ofType(CDRO_FRAME_NODE_INFO, from);
    ASSERT_EQ(infos.size(), 4U);
    for (const cdro_frame_t &f : infos) {
        const cdro_node_info_t &n = f.as.node_info;
        EXPECT_EQ(n.result, CDRO_NODE_INFO_READ) << std::hex << n.node_id;
        EXPECT_EQ(n.uwb_channel, 2);
        EXPECT_EQ(n.uwb_rates, (1U << 6) | 2U);
        EXPECT_EQ(n.uwb_plen, 0x24);
        EXPECT_EQ(n.uwb_gain, 40);
        EXPECT_EQ(n.range_protocol, 1);
        EXPECT_EQ(n.mismatch, 0);
    }
    const size_t ranging_from = bench.serial.frames.size();
    bench.command(fwtest::makeFrame(CDRO_FRAME_START));
    bench.runForMs(2000);
    EXPECT_GT(bench.serial.ofType(CDRO_FRAME_RANGE, ranging_from).size(), 10U);
    // Invalid settings are refused by the decoder's check (channel 6 does not exist).
    const size_t bad_from = bench.serial.frames.size();
    bench.command(fwtest::makeFrame(CDRO_FRAME_STOP));
    set.as.set_uwb.uwb_channel = 6;
    bench.command(set);
    const auto nacks = bench.serial.ofType(CDRO_FRAME_NACK, bad_from);
    ASSERT_EQ(nacks.size(), 1U);
    EXPECT_EQ(nacks[0].as.nack.reason, CDRO_NACK_BAD_VALUE);
}

// ---- the bus ------------------------------------------------------------------------------------

TEST(Setup, StuckBusRecoveriesAreCountedInStatus)
{
    Bench bench(fwtest::testSeed(87), kNodes);
    bench.boot();
    bench.command(fwtest::makeFrame(CDRO_FRAME_START));
    bench.sim()->faults.hang = 3;
    bench.runForMs(3000);
    const auto status = bench.serial.ofType(CDRO_FRAME_STATUS).back().as.status;
    EXPECT_EQ(status.bus_recoveries, 3U);
    EXPECT_EQ(bench.bus.recoveries, 3U);
    EXPECT_GE(status.bus_errors, 3U);
    EXPECT_GT(bench.serial.count(CDRO_FRAME_RANGE), 10U) << "and ranging goes on";
}

// ---- DIAGNOSE: the bench checklist ----------------------------------------------------------------

TEST(Setup, DiagnoseReportsEveryItemOfTheBenchChecklist)
{
    Bench bench(fwtest::testSeed(88), kNodes);
    bench.boot();
    const size_t from = bench.serial.frames.size();
    bench.command(fwtest::makeFrame(CDRO_FRAME_DIAGNOSE));
    bench.runForMs(2000);
    const auto diags = bench.serial.ofType(CDRO_FRAME_DIAG, from);
    ASSERT_EQ(diags.size(), 8U) << "items 1-6 and one accelerometer item per tag (own node, 0x7001)";
    const pozyx_sim_config_t &model = bench.sim()->config;
    for (const cdro_frame_t &f : diags) {
        const cdro_diag_t &d = f.as.diag;
        SCOPED_TRACE(static_cast<int>(d.item));
        EXPECT_EQ(d.status, CDRO_POZYX_OK);
        switch (d.item) {
        case CDRO_DIAG_REMOTE_FLAGS:
            EXPECT_EQ(d.node_id, 0x6A01);
            EXPECT_EQ(d.value_a & (POZYX_INT_FUNC | POZYX_INT_RX_DATA), POZYX_INT_FUNC | POZYX_INT_RX_DATA)
                << "the acknowledgement raised both (the real device's behaviour as modelled)";
            EXPECT_EQ(d.value_b & POZYX_INT_RX_DATA, POZYX_INT_RX_DATA);
            EXPECT_NEAR(d.value_c, (model.ranging_duration_us + model.uwb_message_us) / 1000.0, 4.0);
            break;
        case CDRO_DIAG_RESULT_MESSAGE: {
            EXPECT_EQ(d.value_a, 4U);
            EXPECT_EQ(d.value_b, d.value_c) << "the message carries the distance GETRANGEINFO returns";
            const double truth_mm = 1000.0 * pozyx_sim_true_distance_m(bench.sim(), 0x6A01, 0x6A02);
            EXPECT_NEAR(d.value_c, truth_mm, 150.0);
            break;
        }
        case CDRO_DIAG_REMOTE_TIME:
            EXPECT_EQ(d.node_id, 0x6A02);
            EXPECT_GT(d.value_a, d.value_b + d.value_c);
            // Two messages and the remote's handling, plus TX_DATA, the clear and TX_SEND on the
            // bus (~2.5 ms at 100 kHz) and the polling.
            EXPECT_GE(d.value_b, (2 * model.uwb_message_us + model.remote_processing_us) / 1000U);
            EXPECT_LE(d.value_b, (2 * model.uwb_message_us + model.remote_processing_us) / 1000U + 5U);
            break;
        case CDRO_DIAG_LOCAL_TIME:
            EXPECT_NEAR(d.value_a, model.ranging_duration_us / 1000.0, 3.0);
            EXPECT_NEAR(d.value_b, 4000.0, 150.0);
            break;
        case CDRO_DIAG_GETIDS_OFFSET:
            EXPECT_EQ(d.value_a, 3U);
            EXPECT_EQ(d.value_b, 0x6A02U);
            EXPECT_EQ(d.value_c, d.value_b) << "the offset is honoured (the model's default)";
            break;
        case CDRO_DIAG_I2C_TIMING:
            EXPECT_GT(d.value_b, d.value_c) << "clock stretching and Wire's overhead on top of the wire time";
            EXPECT_LT(d.value_b, d.value_c + model.stretch_function_us + 200U);
            EXPECT_GE(d.value_a, model.stretch_register_us);
            break;
        case CDRO_DIAG_ACCEL: EXPECT_NEAR(d.value_a, 1000.0, 30.0); break;
        default: ADD_FAILURE() << "unexpected item";
        }
    }
    // While ranging it is refused: it would take the Pozyx over for seconds.
    bench.command(fwtest::makeFrame(CDRO_FRAME_START));
    const size_t refused_from = bench.serial.frames.size();
    bench.command(fwtest::makeFrame(CDRO_FRAME_DIAGNOSE));
    const auto nacks = bench.serial.ofType(CDRO_FRAME_NACK, refused_from);
    ASSERT_EQ(nacks.size(), 1U);
    EXPECT_EQ(nacks[0].as.nack.reason, CDRO_NACK_WRONG_STATE);
}

// Every round step stays within one operation's bound (the watchdog's half), also when nodes
// do not answer and every remote request runs to its timeout.
TEST(Setup, RoundsKeepEveryStepWithinTheBoundWhenNodesAreSilent)
{
    const std::vector<NodeSpec> nodes = {
        {0x6A01, false, 4.0, 0.0, 0.0},
        {0x6A02, false, 0.0, 5.0, 0.0},
        {0x7001, true, 2.0, 2.0, 1.0},
        {0x7002, true, 3.0, 1.0, 1.0},
    };
    Bench bench(fwtest::testSeed(89), nodes);
    bench.boot();
    pozyx_sim_find(bench.sim(), 0x6A02)->config.powered = 0;
    pozyx_sim_find(bench.sim(), 0x7002)->config.powered = 0;
    const size_t from = bench.serial.frames.size();
    bench.longestStepUs = 0;
    bench.command(fwtest::makeFrame(CDRO_FRAME_DIAGNOSE));
    bench.runForMs(6000);
    cdro_frame_t set = fwtest::makeFrame(CDRO_FRAME_SET_UWB);
    set.as.set_uwb = {5, 0x80, 0x08, 30, 0};
    bench.command(set);
    bench.runForMs(8000);
    EXPECT_LE(bench.longestStepUs, (CDRO_FW_LONGEST_OPERATION_MS + 20U) * 1000U);
    const auto diags = bench.serial.ofType(CDRO_FRAME_DIAG, from);
    bool silent_tag_failed = false;
    for (const cdro_frame_t &f : diags) {
        if (f.as.diag.item == CDRO_DIAG_ACCEL && f.as.diag.node_id == 0x7002) {
            silent_tag_failed = f.as.diag.status == CDRO_POZYX_ERR_TIMEOUT;
        }
    }
    EXPECT_TRUE(silent_tag_failed) << "the silent tag's accelerometer item says it timed out";
    const auto infos = bench.serial.ofType(CDRO_FRAME_NODE_INFO, from);
    ASSERT_EQ(infos.size(), 5U);
    EXPECT_EQ(infos[2].as.node_info.result, CDRO_NODE_INFO_NO_ANSWER);
    EXPECT_EQ(infos[4].as.node_info.result, CDRO_NODE_INFO_NO_ANSWER);
    EXPECT_EQ(infos[1].as.node_info.uwb_gain, 30);
}

} // namespace
