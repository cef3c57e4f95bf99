// The fallback motion detector (motion_tracker.hpp): a node without motion reports, carried and put
// down again, seen moving and seen still from its ranges alone (issue 19: within 1 s of the truth);
// and in a room where nothing moves, with NLOS links and outliers, no node called moving.
//
// The ranges come from a small simulation of the demo scenario's room (tools/cdro_tools/scenarios/
// demo.yaml): every pair ranged in turn, ~14 ranges a second, the carried node's pairs twice as
// often while it moves (the firmware's moving boost), Gaussian noise, links that read long, and
// NLOS outliers (long by an exponential excess). Seeded; CDRO_TEST_SEED replays one draw.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <optional>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "cdro/engine/engine.hpp"
#include "support.hpp"

namespace cdro::enginetest {
namespace {

using engine::Engine;
using engine::EngineParams;
using engine::Vector3;

constexpr double kRangesPerS = 14.0; // the firmware's rate in the demo scenario (docs/results.md)

struct Room {
    std::vector<NodeId> ids;
    std::vector<Vector3> at_m;                         // m, where each node stands at t = 0
    std::vector<std::pair<size_t, size_t>> nlos_links; // indices into ids: these read long ...
    std::vector<double> nlos_excess_m;                 // ... by this much (m)
    double outlier_probability = 0.01;                 // of every range: NLOS, long by Exp(mean)
    double outlier_mean_m = 0.6;                       // m
    std::optional<size_t> carried;                     // index of the node carried
    double start_s = 0.0;                              // s, when it is picked up
    double speed_mps = 1.3;                            // m/s
    std::vector<Vector2> waypoints_m;                  // m, its path from where it stands
    double duration_s = 60.0;                          // s
};

// The demo scenario: 7 nodes in a 12 m x 9 m room, 0x6006 carried 5.2 m at 1.3 m/s from 28 s.
Room demoRoom()
{
    Room room;
    room.ids = {0x6001, 0x6002, 0x6003, 0x6004, 0x6005, 0x6006, 0x6007};
    room.at_m = {{1.0, 1.0, 0.8}, {11.5, 0.5, 2.4}, {11.0, 8.5, 1.8}, {0.5, 8.0, 2.2},
                 {6.0, 4.5, 0.3}, {3.0, 6.0, 1.2},  {8.5, 2.5, 1.0}};
    room.nlos_links = {{1, 3}, {2, 4}};
    room.nlos_excess_m = {0.9, 0.5};
    room.carried = 5;
    room.start_s = 28.0;
    room.waypoints_m = {{5.5, 7.0}, {8.0, 6.5}};
    return room;
}

// scripts/scenarios/still-room.yaml: 10 nodes, nothing moves, four NLOS links, 5 % outliers.
Room stillRoom()
{
    Room room;
    room.ids = {0x6101, 0x6102, 0x6103, 0x6104, 0x6105, 0x6106, 0x6107, 0x6108, 0x6109, 0x610A};
    room.at_m = {{1.0, 1.0, 0.8}, {13.5, 0.5, 2.4}, {13.0, 9.5, 1.8}, {0.5, 9.0, 2.2},  {7.0, 5.0, 0.3},
                 {3.5, 6.5, 1.2}, {9.5, 2.5, 1.0},  {7.5, 0.5, 2.0},  {10.5, 7.5, 1.1}, {4.0, 3.0, 0.9}};
    room.nlos_links = {{1, 3}, {2, 4}, {5, 6}, {7, 8}};
    room.nlos_excess_m = {0.9, 0.5, 0.6, 0.4};
    room.outlier_probability = 0.05;
    room.outlier_mean_m = 0.8;
    room.duration_s = 90.0;
    return room;
}

// When the carried node arrives at its last waypoint (s).
double stopTime(const Room &room)
{
    double length_m = 0.0;
    Vector2 from = room.at_m[*room.carried].head<2>();
    for (const Vector2 &to : room.waypoints_m) {
        length_m += (to - from).norm();
        from = to;
    }
    return room.start_s + length_m / room.speed_mps;
}

Vector3 positionAt(const Room &room, size_t node, double t_s)
{
    Vector3 at = room.at_m[node];
    if (!room.carried || node != *room.carried || t_s <= room.start_s) {
        return at;
    }
    double left_m = (t_s - room.start_s) * room.speed_mps;
    Vector2 from = at.head<2>();
    for (const Vector2 &to : room.waypoints_m) {
        const double leg_m = (to - from).norm();
        if (left_m <= leg_m) {
            at.head<2>() = from + (to - from) * (left_m / leg_m);
            return at;
        }
        left_m -= leg_m;
        from = to;
    }
    at.head<2>() = from;
    return at;
}

struct Seen {
    std::optional<double> start_after_s; // first range at which the carried node is moving, after its start
    std::optional<double> stop_after_s;  // first range at which it is no longer moving, after its stop
    std::vector<std::pair<NodeId, double>> false_starts; // a node moving that is not being carried (id, t_s)
    std::optional<double> early_stop_s;                  // s, when it was called still while still carried
};

// Runs the room's ranges through the engine (heights known, no motion reports) and watches the
// nodes' lifecycles after every range.
Seen run(const Room &room, uint64_t seed)
{
    Random random(seed);
    Engine engine{EngineParams{}};
    for (size_t i = 0; i < room.ids.size(); ++i) {
        engine.setHeight(room.ids[i], room.at_m[i].z());
    }
    const double stop_s = room.carried ? stopTime(room) : room.duration_s;
    Seen seen;
    std::vector<bool> moving(room.ids.size(), false);
    bool seen_moving = false;
    // The firmware's schedule: every pair in turn, in one order (drawn once); while the node is
    // carried (its accelerometer says so) its pairs come twice a sweep, spread evenly between the
    // others'.
    std::vector<std::pair<size_t, size_t>> pairs;
    for (size_t a = 0; a < room.ids.size(); ++a) {
        for (size_t b = a + 1; b < room.ids.size(); ++b) {
            pairs.emplace_back(a, b);
        }
    }
    random.shuffle(pairs);
    std::vector<std::pair<size_t, size_t>> sweep;
    size_t next = 0;
    bool sweep_boosted = false;
    double t_s = 0.5;
    while (t_s < room.duration_s) {
        // The accelerometer is polled every 0.2 s: the schedule changes that long after the node does.
        const bool boosted = room.carried && t_s >= room.start_s + 0.2 && t_s < stop_s + 0.2;
        if (next == sweep.size() || boosted != sweep_boosted) {
            sweep.clear();
            next = 0;
            sweep_boosted = boosted;
            std::vector<std::pair<size_t, size_t>> carried_pairs;
            for (const auto &pair : pairs) {
                const bool carried_pair = room.carried && (pair.first == *room.carried || pair.second == *room.carried);
                (boosted && carried_pair ? carried_pairs : sweep).push_back(pair);
            }
            if (boosted) {
                const std::vector<std::pair<size_t, size_t>> others = sweep;
                const size_t extra = 2 * carried_pairs.size();
                sweep.clear();
                for (size_t i = 0, k = 0; i < others.size(); ++i) {
                    sweep.push_back(others[i]);
                    for (; k < extra && k * others.size() < (i + 1) * extra; ++k) {
                        sweep.push_back(carried_pairs[k % carried_pairs.size()]);
                    }
                }
            }
        }
        const auto [a, b] = sweep[next++];
        if (random.chance(0.02)) { // a dropout: the slot passes without a range
            t_s += 1.0 / kRangesPerS;
            continue;
        }
        double range_m = (positionAt(room, a, t_s) - positionAt(room, b, t_s)).norm() + 0.10 * random.normal();
        for (size_t k = 0; k < room.nlos_links.size(); ++k) {
            if (room.nlos_links[k] == std::make_pair(a, b)) {
                range_m += room.nlos_excess_m[k];
            }
        }
        if (random.chance(room.outlier_probability)) {
            range_m += random.exponential(room.outlier_mean_m);
        }
        engine.addRange(room.ids[a], room.ids[b], range_m, t_s);
        for (size_t i = 0; i < room.ids.size(); ++i) {
            const std::optional<engine::NodeOutput> node = engine.estimate(room.ids[i]);
            const bool now = node && node->moving();
            const bool carried_now = room.carried && i == *room.carried;
            if (now && !moving[i] && (!carried_now || t_s < room.start_s)) {
                seen.false_starts.emplace_back(room.ids[i], t_s);
            }
            if (carried_now && t_s >= room.start_s) {
                if (now && t_s <= stop_s && !seen.start_after_s) {
                    seen.start_after_s = t_s - room.start_s;
                }
                seen_moving = seen_moving || now;
                if (!now && seen_moving && t_s > stop_s && !seen.stop_after_s) {
                    seen.stop_after_s = t_s - stop_s;
                }
                if (!now && seen_moving && t_s <= stop_s && !seen.early_stop_s) {
                    seen.early_stop_s = t_s;
                }
            }
            moving[i] = now;
        }
        t_s += 1.0 / kRangesPerS;
    }
    return seen;
}

// The demo room's carry, each seed simulated once for the tests that read it.
const std::vector<std::pair<uint64_t, Seen>> &demoRoomRuns()
{
    static const std::vector<std::pair<uint64_t, Seen>> runs = [] {
        std::vector<std::pair<uint64_t, Seen>> out;
        for (const uint64_t seed : testSeeds({1, 2, 3, 4, 5, 6})) {
            out.emplace_back(seed, run(demoRoom(), seed));
        }
        return out;
    }();
    return runs;
}

std::string shown(const std::optional<double> &s) { return s ? std::to_string(*s) : std::string("never"); }

TEST(MotionDetector, ACarriedNodeIsSeenMovingWithinASecondOfItsStart)
{
    CDRO_SKIP_WHEN_SANITIZED();
    const auto &runs = demoRoomRuns();
    size_t within = 0;
    for (const auto &[seed, seen] : runs) {
        SCOPED_TRACE(seedTrace(seed));
        std::printf("seed %llu: start seen after %s s, stop after %s s\n", static_cast<unsigned long long>(seed),
                    shown(seen.start_after_s).c_str(), shown(seen.stop_after_s).c_str());
        EXPECT_TRUE(seen.false_starts.empty())
            << "node " << seen.false_starts.front().first << " at " << seen.false_starts.front().second << " s";
        ASSERT_TRUE(seen.start_after_s.has_value());
        EXPECT_LE(*seen.start_after_s, 1.5); // never much later
        within += *seen.start_after_s <= 1.0 ? 1U : 0U;
    }
    // The goal in (nearly) every draw: the detector needs a handful of ranges, and a draw whose
    // first ranges after the start run along the path may need one more.
    EXPECT_GE(within + 1, runs.size());
}

TEST(MotionDetector, ACarriedNodeIsSeenStillAgainSoonAfterItIsPutDownAndNotBefore)
{
    CDRO_SKIP_WHEN_SANITIZED();
    const auto &runs = demoRoomRuns();
    size_t within = 0;
    for (const auto &[seed, seen] : runs) {
        SCOPED_TRACE(seedTrace(seed));
        EXPECT_FALSE(seen.early_stop_s.has_value()) << "called still at " << *seen.early_stop_s << " s, still carried";
        ASSERT_TRUE(seen.stop_after_s.has_value());
        within += *seen.stop_after_s <= 1.0 ? 1U : 0U;
    }
    // About 6 ranges come in the first second after the stop; a draw whose first ones are to
    // anchors that the map places less well waits for more (docs/results.md: 6 of 10 demo draws).
    EXPECT_GE(2 * within, runs.size());
}

TEST(MotionDetector, NothingMovesInARoomWithNlosLinksAndOutliers)
{
    CDRO_SKIP_WHEN_SANITIZED();
    for (const uint64_t seed : testSeeds({1, 2, 3})) {
        SCOPED_TRACE(seedTrace(seed));
        const Seen seen = run(stillRoom(), seed);
        for (const auto &[id, t_s] : seen.false_starts) {
            ADD_FAILURE() << "node " << id << " called moving at " << t_s << " s";
        }
    }
}

} // namespace
} // namespace cdro::enginetest
