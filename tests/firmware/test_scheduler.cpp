// The ranging scheduler (firmware/core/src/scheduler.c): pair order, moving boost, retries,
// backoff, fairness.
#include <gtest/gtest.h>

#include <algorithm>
#include <map>
#include <random>
#include <set>
#include <utility>
#include <vector>

#include "cdro_fw/scheduler.h"
#include "support.hpp"

namespace {

using Pair = std::pair<int, int>;

cdro_sched_t make(uint8_t nodes, uint8_t mode, uint8_t boost, uint8_t retries)
{
    cdro_sched_t s;
    cdro_sched_init(&s);
    cdro_sched_configure(&s, mode, boost, retries);
    cdro_sched_set_nodes(&s, nodes);
    return s;
}

TEST(Scheduler, DefaultsAreThoseOfTheProtocol)
{
    cdro_sched_t s;
    cdro_sched_init(&s);
    EXPECT_EQ(s.mode, CDRO_SCHEDULE_ALL_PAIRS);
    EXPECT_EQ(s.boost, 2);
    EXPECT_EQ(s.max_retries, 1);
    cdro_sched_slot_t slot;
    EXPECT_EQ(cdro_sched_next(&s, 0, &slot), 0) << "no nodes, nothing to range";
}

TEST(Scheduler, PairListOrder)
{
    cdro_sched_t s = make(4, CDRO_SCHEDULE_ALL_PAIRS, 1, 0);
    ASSERT_EQ(cdro_sched_pair_count(&s), 10);
    const std::vector<Pair> expected = {{0, 1}, {0, 2}, {0, 3}, {0, 4}, {1, 2}, {1, 3}, {1, 4}, {2, 3}, {2, 4}, {3, 4}};
    for (uint8_t p = 0; p < 10; ++p) {
        uint8_t from = 0;
        uint8_t to = 0;
        cdro_sched_pair_nodes(&s, p, &from, &to);
        EXPECT_EQ(Pair(from, to), expected[p]) << "pair " << int(p);
    }
    cdro_sched_configure(&s, CDRO_SCHEDULE_DIRECT_ONLY, 1, 0);
    EXPECT_EQ(cdro_sched_pair_count(&s), 4);
    cdro_sched_t max = make(CDRO_FW_MAX_REMOTE_NODES, CDRO_SCHEDULE_ALL_PAIRS, 1, 0);
    EXPECT_EQ(cdro_sched_pair_count(&max), CDRO_FW_MAX_PAIRS);
    uint8_t from = 0;
    uint8_t to = 0;
    cdro_sched_pair_nodes(&max, CDRO_FW_MAX_PAIRS - 1, &from, &to);
    EXPECT_EQ(Pair(from, to), Pair(CDRO_FW_MAX_REMOTE_NODES - 1, CDRO_FW_MAX_REMOTE_NODES));
}

TEST(Scheduler, RoundRobinVisitsEveryPairOncePerRound)
{
    cdro_sched_t s = make(4, CDRO_SCHEDULE_ALL_PAIRS, 3, 1);
    std::vector<int> visits;
    for (int i = 0; i < 30; ++i) {
        cdro_sched_slot_t slot;
        ASSERT_EQ(cdro_sched_next(&s, 0, &slot), 1);
        EXPECT_EQ(slot.is_retry, 0);
        visits.push_back(slot.pair);
        EXPECT_EQ(cdro_sched_report(&s, 1), 0);
    }
    // Still pairs are spread over the 3 passes (p mod 3 == pass), in pair order within a pass.
    const std::vector<int> round = {0, 3, 6, 9, 1, 4, 7, 2, 5, 8};
    for (int r = 0; r < 3; ++r) {
        EXPECT_EQ(std::vector<int>(visits.begin() + r * 10, visits.begin() + r * 10 + 10), round);
    }
    EXPECT_EQ(s.rounds, 2U);
}

TEST(Scheduler, PairsWithAMovingNodeAreVisitedBoostTimesPerRoundAndSpread)
{
    const uint8_t boost = 4;
    cdro_sched_t s = make(5, CDRO_SCHEDULE_ALL_PAIRS, boost, 0);
    const uint32_t moving = 1U << 3;           // remote node R3
    std::map<int, std::vector<int>> positions; // pair -> slot indices within the round
    const uint8_t pairs = cdro_sched_pair_count(&s);
    int slot_index = 0;
    int pair_moving = 0;
    for (uint8_t p = 0; p < pairs; ++p) {
        uint8_t from = 0;
        uint8_t to = 0;
        cdro_sched_pair_nodes(&s, p, &from, &to);
        pair_moving += (from == 3 || to == 3) ? 1 : 0;
    }
    const int round_length = (pairs - pair_moving) + boost * pair_moving;
    for (int i = 0; i < round_length; ++i) {
        cdro_sched_slot_t slot;
        ASSERT_EQ(cdro_sched_next(&s, moving, &slot), 1);
        positions[slot.pair].push_back(slot_index++);
        (void)cdro_sched_report(&s, 1);
    }
    EXPECT_EQ(s.rounds, 0U) << "exactly one round";
    for (uint8_t p = 0; p < pairs; ++p) {
        uint8_t from = 0;
        uint8_t to = 0;
        cdro_sched_pair_nodes(&s, p, &from, &to);
        const bool is_moving = from == 3 || to == 3;
        ASSERT_EQ(positions[p].size(), is_moving ? boost : 1U) << "pair " << int(p);
        if (is_moving) {
            // Spread: consecutive visits of a moving pair are at most two passes apart.
            for (size_t k = 1; k < positions[p].size(); ++k) {
                EXPECT_LE(positions[p][k] - positions[p][k - 1], 2 * round_length / boost + 1);
            }
        }
    }
}

TEST(Scheduler, FailedAttemptIsRetriedImmediatelyUpToMaxRetries)
{
    cdro_sched_t s = make(3, CDRO_SCHEDULE_DIRECT_ONLY, 1, 2);
    cdro_sched_slot_t slot;
    ASSERT_EQ(cdro_sched_next(&s, 0, &slot), 1);
    EXPECT_EQ(slot.pair, 0);
    EXPECT_EQ(cdro_sched_report(&s, 0), CDRO_SCHED_RETRY);
    ASSERT_EQ(cdro_sched_next(&s, 0, &slot), 1);
    EXPECT_EQ(slot.pair, 0);
    EXPECT_EQ(slot.is_retry, 1);
    EXPECT_EQ(cdro_sched_report(&s, 0), CDRO_SCHED_RETRY);
    ASSERT_EQ(cdro_sched_next(&s, 0, &slot), 1);
    EXPECT_EQ(slot.is_retry, 1);
    EXPECT_EQ(cdro_sched_report(&s, 0), 0) << "third failure: max_retries 2 used up";
    ASSERT_EQ(cdro_sched_next(&s, 0, &slot), 1);
    EXPECT_EQ(slot.pair, 1) << "the schedule moved on";
    EXPECT_EQ(slot.is_retry, 0);
    // A success on a retry ends the slot.
    EXPECT_EQ(cdro_sched_report(&s, 0), CDRO_SCHED_RETRY);
    ASSERT_EQ(cdro_sched_next(&s, 0, &slot), 1);
    EXPECT_EQ(slot.is_retry, 1);
    EXPECT_EQ(cdro_sched_report(&s, 1), 0);
    ASSERT_EQ(cdro_sched_next(&s, 0, &slot), 1);
    EXPECT_EQ(slot.pair, 2);
}

TEST(Scheduler, StreakErrorOnceAfterFiveConsecutiveFailedAttempts)
{
    cdro_sched_t s = make(1, CDRO_SCHEDULE_DIRECT_ONLY, 1, 10);
    std::vector<int> streak_at;
    for (int attempt = 1; attempt <= 11; ++attempt) {
        cdro_sched_slot_t slot;
        ASSERT_EQ(cdro_sched_next(&s, 0, &slot), 1);
        if (cdro_sched_report(&s, 0) & CDRO_SCHED_STREAK_ERROR) {
            streak_at.push_back(attempt);
        }
    }
    EXPECT_EQ(streak_at, std::vector<int>{5});
    // After a success, a new streak reports again.
    cdro_sched_slot_t slot;
    ASSERT_EQ(cdro_sched_next(&s, 0, &slot), 1);
    (void)cdro_sched_report(&s, 1);
    for (int attempt = 1; attempt <= 5; ++attempt) {
        ASSERT_EQ(cdro_sched_next(&s, 0, &slot), 1);
        const uint8_t actions = cdro_sched_report(&s, 0);
        EXPECT_EQ((actions & CDRO_SCHED_STREAK_ERROR) != 0, attempt == 5);
    }
}

TEST(Scheduler, AlwaysFailingPairBacksOffExponentiallyUpToTheCap)
{
    cdro_sched_t s = make(2, CDRO_SCHEDULE_DIRECT_ONLY, 1, 0);
    // Pair 0 always fails, pair 1 always succeeds: record the rounds in which pair 0 runs.
    std::vector<uint32_t> rounds_attempted;
    while (s.rounds < 40) {
        cdro_sched_slot_t slot;
        ASSERT_EQ(cdro_sched_next(&s, 0, &slot), 1);
        if (slot.pair == 0) {
            rounds_attempted.push_back(s.rounds);
        }
        (void)cdro_sched_report(&s, slot.pair == 0 ? 0 : 1);
    }
    // Sitting out 0, 1, 3, then 4 rounds (the cap) between attempts.
    const std::vector<uint32_t> expected = {0, 1, 3, 7, 12, 17, 22, 27, 32, 37};
    EXPECT_EQ(rounds_attempted, expected);
}

TEST(Scheduler, SuccessEndsTheBackoff)
{
    cdro_sched_t s = make(2, CDRO_SCHEDULE_DIRECT_ONLY, 1, 0);
    bool fail = true;
    std::vector<uint32_t> rounds_attempted;
    while (s.rounds < 12) {
        cdro_sched_slot_t slot;
        ASSERT_EQ(cdro_sched_next(&s, 0, &slot), 1);
        if (slot.pair == 0) {
            rounds_attempted.push_back(s.rounds);
            (void)cdro_sched_report(&s, fail ? 0 : 1);
            if (s.rounds >= 3) {
                fail = false; // the node came back
            }
        } else {
            (void)cdro_sched_report(&s, 1);
        }
    }
    const std::vector<uint32_t> expected = {0, 1, 3, 7, 8, 9, 10, 11, 12};
    EXPECT_EQ(rounds_attempted, expected);
}

TEST(Scheduler, EveryPairGetsAttemptsUnderRandomMotionAndFailures)
{
    const uint64_t seed = fwtest::testSeed(41);
    std::mt19937_64 rng(seed);
    for (int trial = 0; trial < 20; ++trial) {
        const uint8_t nodes = static_cast<uint8_t>(1 + rng() % CDRO_FW_MAX_REMOTE_NODES);
        const uint8_t boost = static_cast<uint8_t>(1 + rng() % 8);
        const uint8_t retries = static_cast<uint8_t>(rng() % 3);
        const uint8_t mode = static_cast<uint8_t>(rng() % 2);
        cdro_sched_t s = make(nodes, mode, boost, retries);
        const uint8_t pairs = cdro_sched_pair_count(&s);
        const double fail_probability = static_cast<double>(rng() % 4) * 0.25; // 0, 25, 50 or 75 % of attempts
        std::vector<uint32_t> last_round(pairs, 0);
        std::vector<uint32_t> attempts(pairs, 0);
        uint32_t moving = 0;
        std::uniform_real_distribution<double> u(0.0, 1.0);
        while (s.rounds < 60) {
            if (u(rng) < 0.05) {
                moving = static_cast<uint32_t>(rng()) & ((1U << (nodes + 1)) - 1U);
            }
            cdro_sched_slot_t slot;
            const uint32_t before = s.rounds;
            if (cdro_sched_next(&s, moving, &slot) == 0U) {
                ASSERT_GT(s.rounds, before) << "an empty call still moves the rounds on";
                continue;
            }
            ASSERT_LT(slot.pair, pairs);
            // No pair sits out more than CDRO_FW_BACKOFF_MAX_ROUNDS whole rounds.
            ASSERT_LE(s.rounds - last_round[slot.pair], CDRO_FW_BACKOFF_MAX_ROUNDS + 1U)
                << "trial " << trial << " pair " << int(slot.pair);
            last_round[slot.pair] = s.rounds;
            ++attempts[slot.pair];
            (void)cdro_sched_report(&s, u(rng) >= fail_probability ? 1 : 0);
        }
        for (uint8_t p = 0; p < pairs; ++p) {
            EXPECT_LE(last_round[p], s.rounds);
            EXPECT_LE(s.rounds - last_round[p], CDRO_FW_BACKOFF_MAX_ROUNDS + 1U) << "trial " << trial;
            if (fail_probability == 0.0) {
                EXPECT_GE(attempts[p], 60U) << "without failures, every pair every round";
            }
        }
    }
}

TEST(Scheduler, NewNodeListRestartsFromTheFirstPairAndForgetsBackoff)
{
    cdro_sched_t s = make(3, CDRO_SCHEDULE_DIRECT_ONLY, 1, 0);
    cdro_sched_slot_t slot;
    ASSERT_EQ(cdro_sched_next(&s, 0, &slot), 1);
    (void)cdro_sched_report(&s, 0);
    ASSERT_EQ(cdro_sched_next(&s, 0, &slot), 1);
    (void)cdro_sched_report(&s, 0);
    cdro_sched_set_nodes(&s, 3);
    ASSERT_EQ(cdro_sched_next(&s, 0, &slot), 1);
    EXPECT_EQ(slot.pair, 0);
    EXPECT_EQ(s.pairs[1].backoff, 0);
}

TEST(Scheduler, ModeChangeKeepsPerPairStateAndDropsARetryOfARemovedPair)
{
    cdro_sched_t s = make(3, CDRO_SCHEDULE_ALL_PAIRS, 1, 3);
    cdro_sched_slot_t slot;
    for (int i = 0; i < 4; ++i) { // pairs 0, 1, 2 succeed; pair 3 (R1, R2) fails once
        ASSERT_EQ(cdro_sched_next(&s, 0, &slot), 1);
        (void)cdro_sched_report(&s, slot.pair == 3 ? 0 : 1);
    }
    EXPECT_EQ(s.current, 3) << "retry pending";
    cdro_sched_configure(&s, CDRO_SCHEDULE_DIRECT_ONLY, 1, 3);
    ASSERT_EQ(cdro_sched_next(&s, 0, &slot), 1);
    EXPECT_LT(slot.pair, 3) << "the remote pair left the list";
    EXPECT_EQ(slot.is_retry, 0);
    EXPECT_EQ(s.pairs[3].failed_attempts, 1) << "kept for when ALL_PAIRS returns";
}

} // namespace
