// The firmware streaming: ranging over the simulated network, motion, status, overflow and
// faults, all decoded on the host side by common/'s decoder and checked against the geometry.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <random>
#include <set>
#include <utility>
#include <vector>

#include "cdro_fw/pozyx_regs.h"
#include "support.hpp"

namespace {

using fwtest::Bench;
using fwtest::NodeSpec;

constexpr uint16_t kOwn = 0x6000;
constexpr uint16_t kTag = 0x7001;
const std::vector<NodeSpec> kNodes = {
    {0x6A01, false, 6.0, 0.0, 0.0},
    {0x6A02, false, 0.0, 8.0, 0.0},
    {0x6A03, false, 6.0, 8.0, 0.5},
    {kTag, true, 2.0, 3.0, 1.0},
};
constexpr double kNoiseMm = 30.0;             // the simulator's default
constexpr double kTolerance = 5.0 * kNoiseMm; // mm

// Longest step the firmware may take: one Pozyx operation with its timeouts (and polling),
// plus the bookkeeping of a step (a few frames, 80 host bytes), generously 20 ms in simulation.
constexpr uint64_t kStepBoundUs = (CDRO_FW_LONGEST_OPERATION_MS + 20U) * 1000U;

std::pair<uint16_t, uint16_t> key(const cdro_frame_t &f) { return {f.as.range.from_id, f.as.range.to_id}; }

void startRanging(Bench &bench, uint8_t mode = CDRO_SCHEDULE_ALL_PAIRS, uint8_t boost = 2, uint8_t retries = 1,
                  uint16_t motion_poll_ms = 200)
{
    bench.boot();
    bench.command(fwtest::setSchedule(0, mode, motion_poll_ms, boost, 1000, retries));
    bench.command(fwtest::makeFrame(CDRO_FRAME_START));
    ASSERT_EQ(bench.fw.running, 1);
}

// Sequence numbers are per sender, +1 per frame, spent by dropped frames too: the gaps are the
// frames the firmware dropped.
uint32_t sequenceGaps(const Bench &bench)
{
    uint32_t gaps = 0;
    for (size_t i = 1; i < bench.serial.frames.size(); ++i) {
        gaps += static_cast<uint16_t>(bench.serial.frames[i].frame.sequence -
                                      bench.serial.frames[i - 1].frame.sequence - 1U);
    }
    return gaps;
}

TEST(Stream, RangesAllPairsWithTheGeometricDistances)
{
    Bench bench(fwtest::testSeed(61), kNodes);
    startRanging(bench);
    bench.runForMs(10000);

    const auto ranges = bench.serial.ofType(CDRO_FRAME_RANGE);
    std::map<std::pair<uint16_t, uint16_t>, int> per_pair;
    for (const cdro_frame_t &f : ranges) {
        const cdro_range_t &r = f.as.range;
        const double truth_mm = 1000.0 * pozyx_sim_true_distance_m(bench.sim(), r.from_id, r.to_id);
        EXPECT_NEAR(r.distance_mm, truth_mm, kTolerance) << std::hex << r.from_id << "-" << r.to_id;
        EXPECT_EQ((r.flags & CDRO_RANGE_FLAG_REMOTE) != 0, r.from_id != kOwn);
        EXPECT_EQ(r.flags & CDRO_RANGE_FLAG_RETRY, 0) << "no faults, no retries";
        EXPECT_EQ(r.flags & CDRO_RANGE_FLAG_MOVING, 0);
        ++per_pair[key(f)];
    }
    // Every pair of ALL_PAIRS, in the order of NODE_LIST: (O, Ri) and (Ri, Rj), i < j.
    ASSERT_EQ(per_pair.size(), 10U);
    for (size_t i = 0; i < kNodes.size(); ++i) {
        EXPECT_GT((per_pair[{kOwn, kNodes[i].id}]), 0);
        for (size_t j = i + 1; j < kNodes.size(); ++j) {
            EXPECT_GT((per_pair[{kNodes[i].id, kNodes[j].id}]), 0);
        }
    }
    // Round robin without motion: every pair once per round, so the counts differ by at most 1.
    int lo = 1 << 30;
    int hi = 0;
    for (const auto &kv : per_pair) {
        lo = std::min(lo, kv.second);
        hi = std::max(hi, kv.second);
    }
    EXPECT_LE(hi - lo, 1);
    std::printf("%zu ranges in 10 s (%.1f /s) over 10 pairs, longest step %.1f ms\n", ranges.size(),
                static_cast<double>(ranges.size()) / 10.0, static_cast<double>(bench.longestStepUs) / 1000.0);

    // Nothing lost, nothing the host could not decode.
    EXPECT_EQ(sequenceGaps(bench), 0U);
    EXPECT_EQ(bench.serial.decoder.counters.frames_ok, bench.serial.frames.size());
    EXPECT_EQ(bench.serial.decoder.counters.bytes_discarded, 0U);

    // The last STATUS agrees with what the host received before it.
    const auto statuses = bench.serial.ofType(CDRO_FRAME_STATUS);
    ASSERT_GE(statuses.size(), 10U);
    const cdro_frame_t &last = statuses.back();
    size_t ranges_before = 0;
    for (const auto &rf : bench.serial.frames) {
        if (rf.frame.sequence < last.sequence && rf.frame.type == CDRO_FRAME_RANGE) {
            ++ranges_before;
        }
    }
    EXPECT_EQ(last.as.status.ranges_ok_direct + last.as.status.ranges_ok_remote, ranges_before);
    EXPECT_EQ(last.as.status.frames_sent, last.sequence) << "frames before this one";
    EXPECT_EQ(last.as.status.frames_dropped, 0U);
    EXPECT_EQ(last.as.status.ranges_failed_direct + last.as.status.ranges_failed_remote, 0U);
    EXPECT_EQ(last.as.status.running, 1);
    EXPECT_EQ(last.as.status.node_count, 4);
    EXPECT_GT(last.as.status.longest_loop_us, 0U);
    EXPECT_LE(last.as.status.longest_loop_us, kStepBoundUs);
    EXPECT_LE(bench.longestStepUs, kStepBoundUs);
}

TEST(Stream, DirectOnlyRangesOnlyFromTheOwnNode)
{
    Bench bench(fwtest::testSeed(62), kNodes);
    startRanging(bench, CDRO_SCHEDULE_DIRECT_ONLY);
    bench.runForMs(3000);
    const auto ranges = bench.serial.ofType(CDRO_FRAME_RANGE);
    ASSERT_GT(ranges.size(), 20U);
    for (const cdro_frame_t &f : ranges) {
        EXPECT_EQ(f.as.range.from_id, kOwn);
        EXPECT_EQ(f.as.range.flags & CDRO_RANGE_FLAG_REMOTE, 0);
    }
}

TEST(Stream, SlotPeriodSpacesTheSlots)
{
    Bench bench(fwtest::testSeed(63), kNodes);
    startRanging(bench, CDRO_SCHEDULE_DIRECT_ONLY);
    bench.command(fwtest::setSchedule(100, CDRO_SCHEDULE_DIRECT_ONLY, 0, 1, 1000, 1));
    const size_t from = bench.serial.frames.size();
    bench.runForMs(5000);
    const size_t ranges = bench.serial.count(CDRO_FRAME_RANGE, from);
    EXPECT_GE(ranges, 48U); // one slot per 100 ms
    EXPECT_LE(ranges, 51U);
}

TEST(Stream, MotionIsReportedAtStartPeriodicallyAndNeverForAnchors)
{
    Bench bench(fwtest::testSeed(64), kNodes);
    startRanging(bench);
    bench.runForMs(11000);
    const auto motion = bench.serial.ofType(CDRO_FRAME_MOTION);
    std::map<uint16_t, std::vector<cdro_motion_t>> per_node;
    for (const cdro_frame_t &f : motion) {
        per_node[f.as.motion.node_id].push_back(f.as.motion);
    }
    ASSERT_EQ(per_node.size(), 2U) << "the own node and the remote tag; anchors have no accelerometer";
    for (uint16_t id : {kOwn, kTag}) {
        const auto &m = per_node[id];
        ASSERT_GE(m.size(), 3U) << std::hex << id; // at start, ~5 s, ~10 s
        EXPECT_LE(m.size(), 4U);
        for (const cdro_motion_t &x : m) {
            EXPECT_EQ(x.reason, CDRO_MOTION_REASON_PERIODIC);
            EXPECT_EQ(x.moving, 0);
            EXPECT_NEAR(x.accel_norm_mg, 1000, 30);
            EXPECT_LT(x.deviation_mg, 40);
        }
        for (size_t k = 1; k < m.size(); ++k) {
            const uint32_t gap_ms = m[k].device_time_ms - m[k - 1].device_time_ms;
            // Every 5 s, at the next poll; a node's place in its poll round moves by up to two
            // steps (polls alternate with ranging steps of up to ~60 ms with the real timings).
            EXPECT_GE(gap_ms, 4800U);
            EXPECT_LE(gap_ms, 5400U) << "every 5 s, at the next poll";
        }
    }
    // The anchors were asked what they are once, and not polled again.
    const uint32_t remote_before = bench.sim()->stats.remote_requests;
    bench.command(fwtest::setSchedule(0, CDRO_SCHEDULE_DIRECT_ONLY, 200, 1, 1000, 0));
    bench.runForMs(1000);
    // Direct ranging uses no remote requests: what remains are the tag's accelerometer polls.
    const uint32_t polls = bench.sim()->stats.remote_requests - remote_before;
    EXPECT_GE(polls, 4U);
    EXPECT_LE(polls, 6U);
}

// A tag picked up and carried for 5 s: it moves 1 m/s along x and its accelerometer shows a walk.
struct Walk {
    static constexpr double start_s = 3.0;
    static constexpr double stop_s = 8.0;
    static pozyx_sim_vec3_t position(void *, double t)
    {
        const double moved = std::clamp(t - start_s, 0.0, stop_s - start_s);
        return {2.0 + moved, 3.0, 1.0};
    }
    static pozyx_sim_vec3_t accel(void *, double t)
    {
        if (t < start_s || t >= stop_s) {
            return {0.0, 0.0, 1000.0};
        }
        return {80.0 * std::sin(11.3 * t + 1.0), 40.0 * std::sin(5.6 * t), 1000.0 + 230.0 * std::sin(11.3 * t)};
    }
};

TEST(Stream, MovingTagIsReportedAndRangedMoreOften)
{
    Bench bench(fwtest::testSeed(65), kNodes);
    pozyx_sim_node_t *tag = pozyx_sim_find(bench.sim(), kTag);
    tag->config.position_fn = &Walk::position;
    tag->config.accel_fn = &Walk::accel;
    const uint8_t boost = 3;
    startRanging(bench, CDRO_SCHEDULE_ALL_PAIRS, boost);
    bench.runUntilUs(16000000);

    std::vector<std::pair<uint32_t, uint8_t>> changes; // (time, moving) of the tag
    for (const cdro_frame_t &f : bench.serial.ofType(CDRO_FRAME_MOTION)) {
        if (f.as.motion.node_id == kTag && f.as.motion.reason == CDRO_MOTION_REASON_CHANGE) {
            changes.emplace_back(f.as.motion.device_time_ms, f.as.motion.moving);
        } else if (f.as.motion.node_id == kOwn) {
            EXPECT_EQ(f.as.motion.moving, 0) << "the own node never moved";
        }
    }
    ASSERT_EQ(changes.size(), 2U);
    EXPECT_EQ(changes[0].second, 1);
    EXPECT_GE(changes[0].first, 3000U);
    EXPECT_LE(changes[0].first, 3700U);
    EXPECT_EQ(changes[1].second, 0);
    EXPECT_GE(changes[1].first, 8000U + 22U * 200U) << "8 samples to clear the window, 16 quiet";
    EXPECT_LE(changes[1].first, 8000U + 30U * 210U);

    // While it moves: its pairs carry MOVING, are ranged `boost` times as often per pair, and
    // their distances follow it.
    int moving_pairs = 0;
    int still_pairs = 0;
    for (const cdro_frame_t &f : bench.serial.ofType(CDRO_FRAME_RANGE)) {
        const cdro_range_t &r = f.as.range;
        const bool with_tag = r.from_id == kTag || r.to_id == kTag;
        const bool inside = r.device_time_ms > changes[0].first + 100U && r.device_time_ms < changes[1].first;
        if (inside) {
            EXPECT_EQ((r.flags & CDRO_RANGE_FLAG_MOVING) != 0, with_tag);
            (with_tag ? moving_pairs : still_pairs)++;
        }
        if (with_tag && r.device_time_ms > changes[1].first + 100U) {
            EXPECT_EQ(r.flags & CDRO_RANGE_FLAG_MOVING, 0);
        }
    }
    // 4 pairs with the tag, 6 without.
    const double ratio = (moving_pairs / 4.0) / (still_pairs / 6.0);
    std::printf("moving pairs ranged %.2f times as often as still ones (boost %u)\n", ratio, boost);
    EXPECT_GT(ratio, boost - 0.4);
    EXPECT_LT(ratio, boost + 0.4);
}

TEST(Stream, FullTransmitBufferDropsFramesCountsThemAndKeepsRanging)
{
    Bench bench(fwtest::testSeed(66), kNodes);
    startRanging(bench);
    bench.runForMs(1000);
    const uint32_t rangings_before = bench.sim()->stats.rangings;
    bench.serial.setDraining(false); // the host stops reading, the buffer fills
    bench.runForMs(2000);
    // A round of 4 direct (~45 ms) and 6 remote pairs (~60 ms each) with the real timings: ~18
    // rangings a second when nothing waits.
    EXPECT_GT(bench.sim()->stats.rangings - rangings_before, 30U) << "ranging never waited for the UART";
    const uint32_t dropped = static_cast<uint32_t>(bench.fw.link.frames_dropped);
    EXPECT_GT(dropped, 28U);
    bench.serial.setDraining(true);
    bench.runForMs(2000);

    const auto errors = bench.serial.ofType(CDRO_FRAME_ERROR);
    uint32_t reported = 0;
    for (const cdro_frame_t &e : errors) {
        ASSERT_EQ(e.as.error.code, CDRO_DEVICE_ERROR_TX_OVERFLOW);
        reported += e.as.error.detail;
    }
    EXPECT_GE(errors.size(), 1U);
    const auto statuses = bench.serial.ofType(CDRO_FRAME_STATUS);
    const uint32_t total_dropped = statuses.back().as.status.frames_dropped;
    EXPECT_GE(total_dropped, dropped);
    EXPECT_EQ(reported, total_dropped) << "every drop reported once, once there was room";
    EXPECT_EQ(sequenceGaps(bench), total_dropped) << "the host sees the drops as sequence gaps";
    EXPECT_EQ(bench.serial.decoder.counters.frames_ok, bench.serial.frames.size()) << "no torn frame";
}

TEST(Stream, NodeOffThenBackReportsOnceAndRecoversWithinTheBackoffBound)
{
    Bench bench(fwtest::testSeed(67), kNodes);
    startRanging(bench);
    bench.runForMs(2000);
    pozyx_sim_node_t *off = pozyx_sim_find(bench.sim(), 0x6A02);
    off->config.powered = 0;
    const uint32_t off_ms = bench.bus.nowMs();
    bench.runForMs(6000);
    off->config.powered = 1;
    const uint32_t on_ms = bench.bus.nowMs();
    bench.runForMs(4000);

    std::map<std::pair<uint16_t, uint16_t>, int> streak_errors;
    int timeout_errors = 0;
    uint32_t last_timeout_ms = 0;
    for (const cdro_frame_t &e : bench.serial.ofType(CDRO_FRAME_ERROR)) {
        if (e.as.error.code == CDRO_DEVICE_ERROR_RANGING) {
            ++streak_errors[{e.as.error.node_id, e.as.error.detail}];
        } else if (e.as.error.code == CDRO_DEVICE_ERROR_TIMEOUT) {
            if (timeout_errors++ > 0) {
                EXPECT_GE(e.as.error.device_time_ms - last_timeout_ms, 1000U) << "rate-limited";
            }
            last_timeout_ms = e.as.error.device_time_ms;
        } else {
            ADD_FAILURE() << "unexpected ERROR code " << int(e.as.error.code);
        }
    }
    // Each of the 4 pairs with 0x6A02 failed 5 times in a row once: one ERROR RANGING each.
    // node_id is the pair's responding node: 0x6A02 for (O, R2), (R1, R2); R3 / the tag for
    // (R2, R3), (R2, tag). The direct pair fails with ERR (ranging timeout on the device).
    int total = 0;
    for (const auto &kv : streak_errors) {
        total += kv.second;
    }
    EXPECT_EQ(total, 4);
    EXPECT_EQ((streak_errors[{0x6A02, POZYX_ERROR_RTIMEOUT1}]), 1);
    EXPECT_GT(timeout_errors, 2);

    // While off: no range with it; after it is back: every one of its pairs ranges again soon.
    std::map<std::pair<uint16_t, uint16_t>, uint32_t> first_after;
    for (const cdro_frame_t &f : bench.serial.ofType(CDRO_FRAME_RANGE)) {
        const cdro_range_t &r = f.as.range;
        const bool with_it = r.from_id == 0x6A02 || r.to_id == 0x6A02;
        if (!with_it) {
            continue;
        }
        EXPECT_FALSE(r.device_time_ms > off_ms + 100U && r.device_time_ms < on_ms) << "ranged while off";
        if (r.device_time_ms >= on_ms && first_after.count(key(f)) == 0U) {
            first_after[key(f)] = r.device_time_ms - on_ms;
        }
    }
    ASSERT_EQ(first_after.size(), 4U) << "all four pairs came back";
    for (const auto &kv : first_after) {
        EXPECT_LT(kv.second, 2500U) << "within the backoff bound (4 rounds sitting out)";
    }
    const auto status = bench.serial.ofType(CDRO_FRAME_STATUS).back().as.status;
    EXPECT_GT(status.ranges_failed_direct, 0U);
    EXPECT_GT(status.ranges_failed_remote, 0U);
    EXPECT_GT(status.retries, 0U);
    EXPECT_GT(status.timeouts, 0U);
    EXPECT_LE(bench.longestStepUs, kStepBoundUs);
}

TEST(Stream, StaleResultIsRejectedAndTheRetryReportsIt)
{
    Bench bench(fwtest::testSeed(68), kNodes);
    startRanging(bench, CDRO_SCHEDULE_ALL_PAIRS, 1, 1);
    bench.runForMs(2000); // every pair has a stored result now
    const size_t from = bench.serial.frames.size();
    const uint32_t failed_before = bench.fw.counters.ranges_failed_direct + bench.fw.counters.ranges_failed_remote;
    bench.sim()->faults.stale_range = 1;
    bench.runForMs(500);
    EXPECT_EQ(bench.fw.counters.stale_results, 1U);
    EXPECT_EQ(bench.fw.counters.ranges_failed_direct + bench.fw.counters.ranges_failed_remote, failed_before + 1U);
    const auto ranges = bench.serial.ofType(CDRO_FRAME_RANGE, from);
    const auto retried = std::count_if(ranges.begin(), ranges.end(), [](const cdro_frame_t &f) {
        return (f.as.range.flags & CDRO_RANGE_FLAG_RETRY) != 0;
    });
    EXPECT_EQ(retried, 1) << "the stale attempt was retried at once and succeeded";
}

TEST(Stream, RandomFaultSoakKeepsEveryInvariant)
{
    const uint64_t seed = fwtest::testSeed(69);
    Bench bench(seed, kNodes);
    std::mt19937_64 rng(seed);
    startRanging(bench, CDRO_SCHEDULE_ALL_PAIRS, 2, 2);
    for (int tick = 0; tick < 300; ++tick) { // 30 s
        pozyx_sim_faults_t &f = bench.sim()->faults;
        switch (rng() % 13) {
        case 0: f.nack_address += 1; break;
        case 1: f.nack_write += 1; break;
        case 2: f.hang += 1; break;
        case 3: f.no_completion += 1; break;
        case 4:
            f.error_completion += 1;
            f.error_code = static_cast<uint8_t>(0x11 + rng() % 7);
            break;
        case 5: f.garbage_range += 1; break;
        case 6: f.stale_range += 1; break;
        case 7: f.drop_remote_reply += 1; break;
        case 8: f.refuse_function += 1; break;
        case 10: f.late_reply += 1; break;
        case 9: {
            const uint8_t junk[5] = {1, 2, 3, 4, 5};
            (void)pozyx_sim_inject_message(bench.sim(), 0x6A03, junk, 5, bench.bus.nowUs() + rng() % 50000);
            break;
        }
        default: break;
        }
        if (rng() % 50 == 0) { // now and then a host command in the middle of it all
            cdro_frame_t ping = fwtest::makeFrame(CDRO_FRAME_PING);
            ping.as.ping.nonce = static_cast<uint32_t>(tick);
            bench.serial.hostSend(ping);
        }
        bench.runForMs(100);
    }
    bench.runForMs(1500);
    // Every reported range is a true one: garbage and stale results never reach the host.
    const auto ranges = bench.serial.ofType(CDRO_FRAME_RANGE);
    ASSERT_GT(ranges.size(), 300U); // ~18 a second with the real timings, fewer under faults
    for (const cdro_frame_t &f : ranges) {
        const double truth_mm = 1000.0 * pozyx_sim_true_distance_m(bench.sim(), f.as.range.from_id, f.as.range.to_id);
        ASSERT_NEAR(f.as.range.distance_mm, truth_mm, kTolerance);
    }
    EXPECT_EQ(bench.serial.decoder.counters.frames_ok, bench.serial.frames.size());
    EXPECT_EQ(sequenceGaps(bench), bench.fw.link.frames_dropped);
    const auto status = bench.serial.ofType(CDRO_FRAME_STATUS).back().as.status;
    EXPECT_GT(status.bus_errors, 0U);
    EXPECT_GT(status.timeouts, 0U);
    EXPECT_GT(status.retries, 0U);
    EXPECT_EQ(bench.fw.pozyx.sticky_flags & POZYX_INT_ERR, 0);
    EXPECT_LE(bench.longestStepUs, kStepBoundUs);
    std::printf("soak: %zu ranges, %u bus errors, %u timeouts, %u retries, %llu stale, longest step %.1f ms\n",
                ranges.size(), status.bus_errors, status.timeouts, status.retries,
                static_cast<unsigned long long>(bench.fw.counters.stale_results),
                static_cast<double>(bench.longestStepUs) / 1000.0);
}

// The remote-ranging race at the level of the device: a node carried at 2 m/s while replies and result messages
// now and then arrive late (into the next attempt), with the real device's behaviour (replies
// raise RX_DATA with FUNC, busy nodes, collisions). Every RANGE is where the nodes were when it
// was ranged, never where they were at an earlier attempt (0.3 s earlier is 0.6 m away).
struct Carried {
    static pozyx_sim_vec3_t position(void *, double t_s)
    {
        const double moved_m = 2.0 * std::clamp(t_s - 2.0, 0.0, 5.0); // 2 m/s from 2 s to 7 s
        return {2.0 + moved_m, 3.0, 1.0};
    }
};

TEST(Stream, ACarriedNodeIsNeverReportedWhereItWas)
{
    const uint64_t seed = fwtest::testSeed(71);
    Bench bench(seed, kNodes);
    std::mt19937_64 rng(seed);
    pozyx_sim_find(bench.sim(), kTag)->config.position_fn = &Carried::position;
    startRanging(bench, CDRO_SCHEDULE_ALL_PAIRS, 1, 1, 0);
    for (int tick = 0; tick < 80; ++tick) { // 8 s
        if (rng() % 3 == 0) {
            bench.sim()->faults.late_reply += 1;
        }
        bench.runForMs(100);
    }
    EXPECT_GT(bench.sim()->stats.faults_injected, 10U);
    size_t with_tag = 0;
    for (const cdro_frame_t &f : bench.serial.ofType(CDRO_FRAME_RANGE)) {
        const cdro_range_t &r = f.as.range;
        // The truth when the range was reported; it was ranged at most ~20 ms before (0.04 m).
        const pozyx_sim_vec3_t tag = Carried::position(nullptr, r.device_time_ms / 1000.0);
        const uint16_t other = r.from_id == kTag ? r.to_id : r.from_id;
        if (r.to_id != kTag && r.from_id != kTag) {
            continue;
        }
        ++with_tag;
        pozyx_sim_vec3_t at{0, 0, 0};
        for (const NodeSpec &n : kNodes) {
            if (n.id == other) {
                at = {n.x, n.y, n.z};
            }
        }
        const double truth_mm = 1000.0 * std::sqrt((tag.x - at.x) * (tag.x - at.x) + (tag.y - at.y) * (tag.y - at.y) +
                                                   (tag.z - at.z) * (tag.z - at.z));
        EXPECT_NEAR(r.distance_mm, truth_mm, kTolerance + 60.0)
            << std::hex << r.from_id << "-" << r.to_id << std::dec << " at " << r.device_time_ms << " ms";
    }
    EXPECT_GT(with_tag, 40U);
    std::printf("carried: %zu ranges with the tag, %u late replies, %u collisions, %u requests lost to busy nodes\n",
                with_tag, bench.sim()->stats.faults_injected, bench.sim()->stats.collisions,
                bench.sim()->stats.busy_losses);
}

TEST(Stream, NoProtocolViolationsAndTheWireBufferIsRespected)
{
    Bench bench(fwtest::testSeed(70), kNodes);
    startRanging(bench);
    bench.runForMs(5000);
    EXPECT_EQ(bench.sim()->stats.protocol_violations, 0U);
    EXPECT_LE(bench.bus.longestWrite, 32U);
    EXPECT_LE(bench.bus.longestRead, 32U);
    // I2C traffic per range, for docs/firmware.md.
    std::printf("I2C: %u writes, %u reads, %u bytes out, %u bytes in, %u polls (delays), %u rangings\n",
                bench.bus.writes, bench.bus.reads, bench.sim()->stats.bytes_written, bench.sim()->stats.bytes_read,
                bench.bus.delays, bench.sim()->stats.rangings);
}

} // namespace
