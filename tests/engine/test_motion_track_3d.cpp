// Nodes that never stop, tracked in 3D (motion_track_3d.hpp, Engine::trackMoving3D): a seeded
// simulated flight of two tags among six nearly coplanar anchors (MiLUV's geometry: a 4 m x 4 m
// room, anchors at 1.6-1.9 m, tags at 0.3-1.3 m), tracked from the known anchors, converges; the
// tag-to-tag ranges move both ends; the same input gives the same output bit for bit; and the
// static map is not touched by a tracked node; the tracks' state saved mid-flight and restored
// into another engine continues bit for bit as the uninterrupted run.
#include <Eigen/Cholesky>
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <stdexcept>
#include <string>
#include <vector>

#include "cdro/engine/engine.hpp"
#include "simulated_flight.hpp"
#include "support.hpp"

namespace cdro::enginetest {
namespace {

using namespace cdro::engine; // NOLINT(google-build-using-namespace): the engine's types throughout

constexpr std::array<NodeId, 2> kTags = {10, 20};
const FlightSchedule kSchedule; // one range every 0.1 s for 60 s, one slot in five between the tags; noise 0.1 m

std::vector<FlightRange> simulate(uint64_t seed, bool tag_tag)
{
    FlightSchedule schedule = kSchedule;
    schedule.tag_to_tag = tag_tag;
    return simulateFlight(seed, {kTags.begin(), kTags.end()}, schedule);
}

Engine anchoredEngine()
{
    Engine engine;
    fixFlightAnchors(engine);
    for (NodeId tag : kTags) {
        engine.trackMoving3D(tag);
    }
    return engine;
}

struct FlightScore {
    double rmse_3d_m = 0.0;
    double rmse_h_m = 0.0;
    double inside_95 = 0.0; // share of errors inside the 95 % ellipsoid (chi2 3 dof: 7.815)
    size_t rows = 0;
    std::vector<double> outputs; // every estimate, for the determinism check
};

// Runs the flight; scores each tag's estimate after each of its ranges from t >= from_s.
FlightScore fly(const std::vector<FlightRange> &ranges, double from_s)
{
    Engine engine = anchoredEngine();
    FlightScore score;
    double sum_3d = 0.0;
    double sum_h = 0.0;
    size_t inside = 0;
    for (const FlightRange &r : ranges) {
        EXPECT_EQ(engine.addRange(r.from, r.to, r.range_m, r.t_s), RangeVerdict::Used);
        for (size_t k = 0; k < kTags.size(); ++k) {
            if (r.from != kTags[k] && r.to != kTags[k]) {
                continue;
            }
            const std::optional<FlightEstimate> e = engine.flightEstimate(kTags[k]);
            if (!e || e->status != FlightStatus::Tracking) {
                continue;
            }
            score.outputs.insert(score.outputs.end(), e->position_m.data(), e->position_m.data() + 3);
            score.outputs.insert(score.outputs.end(), e->covariance_m2.data(), e->covariance_m2.data() + 9);
            if (r.t_s < from_s) {
                continue;
            }
            const Vector3 error = e->position_m - flightTagPositionM(k, r.t_s);
            sum_3d += error.squaredNorm();
            sum_h += error.head<2>().squaredNorm();
            inside += error.dot(e->covariance_m2.ldlt().solve(error)) <= 7.815 ? 1U : 0U;
            ++score.rows;
        }
    }
    if (score.rows > 0) {
        const double n = static_cast<double>(score.rows);
        score.rmse_3d_m = std::sqrt(sum_3d / n);
        score.rmse_h_m = std::sqrt(sum_h / n);
        score.inside_95 = static_cast<double>(inside) / n;
    }
    return score;
}

TEST(MotionTrack3D, SimulatedFlightFromKnownAnchorsConverges)
{
    // Stated bounds, from 10 s on (the start is a prior over the whole room): 3D RMSE <= 0.30 m,
    // horizontal <= 0.20 m, at least 80 % of the errors inside the 95 % ellipsoid. Observed on
    // seeds 1-3: 0.230-0.238 m 3D (height is the weak axis under nearly coplanar anchors),
    // 0.169-0.173 m horizontal, 100 % inside (printed).
    for (uint64_t seed : testSeeds({1, 2, 3})) {
        SCOPED_TRACE(seedTrace(seed));
        const FlightScore score = fly(simulate(seed, true), 10.0);
        std::printf("3D flight, %s: %zu rows, RMSE 3D %.3f m, horizontal %.3f m, %.0f %% inside the 95 %% region\n",
                    seedTrace(seed).c_str(), score.rows, score.rmse_3d_m, score.rmse_h_m, 100.0 * score.inside_95);
        ASSERT_GT(score.rows, 400U);
        EXPECT_LE(score.rmse_3d_m, 0.30);
        EXPECT_LE(score.rmse_h_m, 0.20);
        EXPECT_GE(score.inside_95, 0.80);
    }
}

TEST(MotionTrack3D, TheSameInputGivesTheSameOutputBitForBit)
{
    const uint64_t seed = testSeed(4);
    SCOPED_TRACE(seedTrace(seed));
    const std::vector<FlightRange> ranges = simulate(seed, true);
    const FlightScore a = fly(ranges, 0.0);
    const FlightScore b = fly(ranges, 0.0);
    ASSERT_EQ(a.outputs.size(), b.outputs.size());
    ASSERT_FALSE(a.outputs.empty());
    EXPECT_EQ(0, std::memcmp(a.outputs.data(), b.outputs.data(), a.outputs.size() * sizeof(double)));
}

TEST(MotionTrack3D, ATagToTagRangeMovesBothEnds)
{
    const uint64_t seed = testSeed(5);
    SCOPED_TRACE(seedTrace(seed));
    Engine engine = anchoredEngine();
    const std::vector<FlightRange> ranges = simulate(seed, false);
    for (const FlightRange &r : ranges) {
        if (r.t_s > 20.0) {
            break;
        }
        engine.addRange(r.from, r.to, r.range_m, r.t_s);
    }
    const FlightEstimate a0 = *engine.flightEstimate(kTags[0]);
    const FlightEstimate b0 = *engine.flightEstimate(kTags[1]);
    ASSERT_EQ(a0.status, FlightStatus::Tracking);
    ASSERT_EQ(b0.status, FlightStatus::Tracking);
    // A range 0.5 m shorter than the estimates' distance, 0.05 s after the last range.
    const double d = (a0.position_m - b0.position_m).norm();
    EXPECT_EQ(engine.addRange(kTags[0], kTags[1], d - 0.5, 19.95), RangeVerdict::Used);
    const FlightEstimate a1 = *engine.flightEstimate(kTags[0]);
    const FlightEstimate b1 = *engine.flightEstimate(kTags[1]);
    EXPECT_GT((a1.position_m - a0.position_m).norm(), 0.01);
    EXPECT_GT((b1.position_m - b0.position_m).norm(), 0.01);
    EXPECT_LT((a1.position_m - b1.position_m).norm(), d);
    EXPECT_EQ(engine.flightCounters().tag_ranges, 1U);
}

TEST(MotionTrack3D, CooperationHelpsOnTheSimulatedFlight)
{
    // The same flights with and without the tag-to-tag slots' ranges (the tag-anchor ranges are
    // the same: the schedule keeps their slots), seeds 1-3, RMSE 3D summed: cooperation must not
    // make it worse by more than 2 cm (observed: 0.702 m with, 0.733 m without).
    double with = 0.0;
    double without = 0.0;
    for (uint64_t seed : testSeeds({1, 2, 3})) {
        SCOPED_TRACE(seedTrace(seed));
        with += fly(simulate(seed, true), 10.0).rmse_3d_m;
        std::vector<FlightRange> anchors_only;
        for (const FlightRange &r : simulate(seed, true)) {
            if (r.to != kTags[1]) {
                anchors_only.push_back(r);
            }
        }
        without += fly(anchors_only, 10.0).rmse_3d_m;
    }
    std::printf("3D flight, RMSE 3D summed over the seeds: %.3f m with tag-to-tag ranges, %.3f m without\n", with,
                without);
    EXPECT_LE(with, without + 0.02);
}

TEST(MotionTrack3D, ATrackedNodeLeavesTheStaticMapAsItWas)
{
    // Four static nodes with unknown positions and heights known, ranged among themselves; the
    // same with a tracked node's ranges interleaved: the static estimates are identical.
    const std::array<Vector2, 4> positions = {Vector2(0.0, 0.0), Vector2(6.0, 0.0), Vector2(6.0, 5.0),
                                              Vector2(0.0, 5.0)};
    Random random(testSeed(6));
    std::vector<FlightRange> ranges;
    for (int round = 0; round < 40; ++round) {
        for (size_t i = 0; i < positions.size(); ++i) {
            for (size_t j = i + 1; j < positions.size(); ++j) {
                ranges.push_back({round * 1.0, static_cast<NodeId>(30 + i), static_cast<NodeId>(30 + j),
                                  (positions[i] - positions[j]).norm() + 0.05 * random.normal()});
            }
        }
    }
    auto run = [&](bool with_tag) {
        Engine engine;
        for (size_t i = 0; i < positions.size(); ++i) {
            engine.setHeight(static_cast<NodeId>(30 + i), 1.0);
        }
        if (with_tag) {
            engine.trackMoving3D(kTags[0]);
        }
        for (const FlightRange &r : ranges) {
            engine.addRange(r.from, r.to, r.range_m, r.t_s);
            if (with_tag) {
                EXPECT_EQ(engine.addRange(kTags[0], r.from, 3.0, r.t_s), RangeVerdict::Stored); // no anchor there
            }
        }
        engine.settle(10000);
        return engine.estimates();
    };
    const std::vector<NodeOutput> plain = run(false);
    const std::vector<NodeOutput> with_tag = run(true);
    ASSERT_EQ(plain.size(), with_tag.size());
    for (size_t i = 0; i < plain.size(); ++i) {
        EXPECT_EQ(plain[i].id, with_tag[i].id);
        EXPECT_EQ(plain[i].position_m, with_tag[i].position_m);
        EXPECT_EQ(plain[i].covariance_m2, with_tag[i].covariance_m2);
        EXPECT_EQ(plain[i].lifecycle, with_tag[i].lifecycle);
    }
}

// Two tags on one body (0.45 m apart, the body turning at 0.3 rad/s): tag A ranges an anchor in 4
// of 5 slots, tag B in the fifth. Returns B's 3D RMSE from 10 s on, with or without the body.
double bodyFlightRmseOfB(uint64_t seed, bool body)
{
    const Vector3 arm_a(0.15, -0.165, -0.05);
    const Vector3 arm_b(-0.155, 0.16, -0.05);
    auto position = [&](const Vector3 &arm, double t_s) {
        const double yaw = 0.3 * t_s;
        const Vector3 turned(std::cos(yaw) * arm.x() - std::sin(yaw) * arm.y(),
                             std::sin(yaw) * arm.x() + std::cos(yaw) * arm.y(), arm.z());
        return Vector3(flightTagPositionM(0, t_s) + turned);
    };
    Random random(seed);
    Engine engine = anchoredEngine();
    if (body) {
        engine.trackOnOneBody(kTags[0], kTags[1], (arm_a - arm_b).norm());
    }
    double sum = 0.0;
    size_t rows = 0;
    for (size_t slot = 0; static_cast<double>(slot) * kSchedule.slot_s < kSchedule.duration_s; ++slot) {
        const double t_s = static_cast<double>(slot) * kSchedule.slot_s;
        const bool is_b = slot % 5 == 4;
        const size_t a = (slot / 5 + (is_b ? 3 : slot % 5)) % kFlightAnchors.size();
        const Vector3 tag = position(is_b ? arm_b : arm_a, t_s);
        const NodeId id = kTags[is_b ? 1 : 0];
        engine.addRange(id, kFlightAnchors[a],
                        (tag - kFlightAnchorPositionsM[a]).norm() + kSchedule.noise_m * random.normal(), t_s);
        const std::optional<FlightEstimate> b = engine.flightEstimate(kTags[1]);
        if (t_s >= 10.0 && b && b->status == FlightStatus::Tracking) {
            sum += (b->position_m - position(arm_b, t_s)).squaredNorm();
            ++rows;
        }
    }
    EXPECT_GT(rows, 400U);
    return std::sqrt(sum / static_cast<double>(std::max<size_t>(rows, 1)));
}

TEST(MotionTrack3D, TwoTagsOnOneBodyHelpTheOneThatRangesLess)
{
    // Observed on seeds 1-3: B's RMSE 3D 0.282-0.300 m with the body, 0.400-0.414 m without
    // (printed); stated: with the body at most 0.8 times without. (A tie applied at full weight at
    // every prediction failed this: 0.39 and 0.41 m on seeds 2 and 3, the tags pulled together.)
    for (uint64_t seed : testSeeds({1, 2, 3})) {
        SCOPED_TRACE(seedTrace(seed));
        const double with = bodyFlightRmseOfB(seed, true);
        const double without = bodyFlightRmseOfB(seed, false);
        std::printf("one body, %s: tag B's RMSE 3D %.3f m with the body, %.3f m without\n", seedTrace(seed).c_str(),
                    with, without);
        EXPECT_LE(with, 0.8 * without);
    }
    Engine engine = anchoredEngine();
    EXPECT_THROW(engine.trackOnOneBody(kTags[0], 99, 0.4), std::invalid_argument); // 99 is not tracked
    EXPECT_THROW(engine.trackOnOneBody(kTags[0], kTags[1], 0.0), std::invalid_argument);
    engine.trackOnOneBody(kTags[0], kTags[1], 0.45);
    EXPECT_THROW(engine.trackOnOneBody(kTags[1], kTags[0], 0.45), std::invalid_argument); // already on a body
}

TEST(MotionTrack3D, TheNlosCountsNameTheBiasedAnchor)
{
    // The simulated flight with every range to one anchor (id 3) read long by 0.6 m plus |N(0,
    // 0.5 m)| (a wall in the way): that anchor's ranges must be the ones down-weighted or refused.
    // Stated: at least half of the biased anchor's ranges, at most 15 % of any other's, at most
    // 15 % of the tag-to-tag ranges; and every decided range counted once. Observed on seeds 1-3:
    // 0.72-0.85 of the biased anchor's, at most 0.04 of any other's, none of the tag-to-tag ranges.
    constexpr size_t kBiased = 2;
    for (uint64_t seed : testSeeds({1, 2, 3})) {
        SCOPED_TRACE(seedTrace(seed));
        Random bias(seed + 1000);
        std::vector<FlightRange> ranges = simulate(seed, true);
        std::array<uint64_t, kFlightAnchors.size()> per_anchor{};
        uint64_t tag_tag = 0;
        for (FlightRange &r : ranges) {
            for (size_t a = 0; a < kFlightAnchors.size(); ++a) {
                per_anchor[a] += r.to == kFlightAnchors[a] ? 1U : 0U;
            }
            tag_tag += r.to == kTags[1] ? 1U : 0U;
            if (r.to == kFlightAnchors[kBiased]) {
                r.range_m += 0.6 + 0.5 * std::abs(bias.normal());
            }
        }
        Engine engine = anchoredEngine();
        for (const FlightRange &r : ranges) {
            engine.addRange(r.from, r.to, r.range_m, r.t_s);
        }
        const std::vector<FlightNlosCount> &counts = engine.flightNlosCounts();
        ASSERT_EQ(counts.size(), kFlightAnchors.size() + 1);
        EXPECT_EQ(counts.back().anchor, 0U);
        EXPECT_EQ(counts.back().taken + counts.back().refused, tag_tag);
        for (size_t a = 0; a < kFlightAnchors.size(); ++a) {
            const FlightNlosCount &c = counts[a];
            EXPECT_EQ(c.anchor, kFlightAnchors[a]);
            EXPECT_EQ(c.taken + c.refused, per_anchor[a]);
            const double flagged =
                static_cast<double>(c.down_weighted + c.refused) / static_cast<double>(per_anchor[a]);
            std::printf("NLOS counts, %s: anchor %u%s: %llu taken, %llu down-weighted, %llu refused (%.2f)\n",
                        seedTrace(seed).c_str(), static_cast<unsigned>(c.anchor), a == kBiased ? " (biased)" : "",
                        static_cast<unsigned long long>(c.taken), static_cast<unsigned long long>(c.down_weighted),
                        static_cast<unsigned long long>(c.refused), flagged);
            if (a == kBiased) {
                EXPECT_GE(flagged, 0.5);
            } else {
                EXPECT_LE(flagged, 0.15);
            }
        }
        const FlightNlosCount &t = counts.back();
        std::printf("NLOS counts, %s: tag-to-tag: %llu taken, %llu down-weighted, %llu refused\n",
                    seedTrace(seed).c_str(), static_cast<unsigned long long>(t.taken),
                    static_cast<unsigned long long>(t.down_weighted), static_cast<unsigned long long>(t.refused));
        EXPECT_LE(static_cast<double>(t.down_weighted + t.refused), 0.15 * static_cast<double>(tag_tag));
    }
}

// Every estimate of both tags after each range (status, anchors heard, position, velocity,
// covariance as their bits), then the counters and NLOS counts at the end.
struct FlightRecord {
    std::vector<double> values;
    std::vector<uint64_t> counts;
};

void record(const Engine &engine, FlightRecord &out)
{
    for (NodeId tag : kTags) {
        const std::optional<FlightEstimate> e = engine.flightEstimate(tag);
        ASSERT_TRUE(e.has_value());
        out.counts.push_back(static_cast<uint64_t>(e->status));
        out.counts.push_back(e->anchors_heard);
        out.values.insert(out.values.end(), e->position_m.data(), e->position_m.data() + 3);
        out.values.insert(out.values.end(), e->velocity_mps.data(), e->velocity_mps.data() + 3);
        out.values.insert(out.values.end(), e->covariance_m2.data(), e->covariance_m2.data() + 9);
    }
}

void recordTotals(const Engine &engine, FlightRecord &out)
{
    const FlightCounters &c = engine.flightCounters();
    out.counts.insert(out.counts.end(), {c.anchor_ranges, c.tag_ranges, c.down_weighted, c.refused, c.resets, c.waiting,
                                         c.no_anchor, c.mirrored, c.truncated, c.body_updates});
    for (const FlightNlosCount &n : engine.flightNlosCounts()) {
        out.counts.insert(out.counts.end(), {n.anchor, n.taken, n.down_weighted, n.refused});
    }
}

Engine bodyEngine()
{
    Engine engine = anchoredEngine();
    engine.trackOnOneBody(kTags[0], kTags[1], 1.5);
    return engine;
}

constexpr double kBurstStartS = 20.0; // s: from then, for 2 s, every anchor range of tag 10 reads 3 m long
constexpr double kBurstS = 2.0;       // s

// The flight with one anchor reading long now and then (the NLOS model refuses and down-weights)
// and a burst of long ranges to one tag (refused in a row until its covariance is reset), so that
// every part of the state is exercised.
std::vector<FlightRange> nlosFlight(uint64_t seed)
{
    std::vector<FlightRange> ranges = simulate(seed, true);
    Random bias(seed + 2000);
    for (FlightRange &r : ranges) {
        if ((r.from == kFlightAnchors[2] || r.to == kFlightAnchors[2]) && bias.uniform() < 0.3) {
            r.range_m += 1.0 + 3.0 * bias.uniform(); // m
        }
        const bool tag_to_tag = r.from == kTags[1] || r.to == kTags[1];
        if (r.from == kTags[0] && !tag_to_tag && r.t_s >= kBurstStartS && r.t_s < kBurstStartS + kBurstS) {
            r.range_m += 3.0; // m
        }
    }
    return ranges;
}

// Runs `ranges` from `first` on, recording after each.
void flyOn(Engine &engine, const std::vector<FlightRange> &ranges, size_t first, FlightRecord &out)
{
    for (size_t k = first; k < ranges.size(); ++k) {
        engine.addRange(ranges[k].from, ranges[k].to, ranges[k].range_m, ranges[k].t_s);
        record(engine, out);
    }
    recordTotals(engine, out);
}

TEST(MotionTrack3D, SavedAndRestoredMidFlightTheTracksContinueBitForBit)
{
    const uint64_t seed = testSeed(8);
    SCOPED_TRACE(seedTrace(seed));
    const std::vector<FlightRange> ranges = nlosFlight(seed);
    // Within the burst: tag 10 has ranges refused in a row.
    const size_t in_burst = static_cast<size_t>(
        std::find_if(ranges.begin(), ranges.end(), [](const FlightRange &r) { return r.t_s >= kBurstStartS + 0.5; }) -
        ranges.begin());
    // Before any range (no anchors taken), while starting, early, in the burst, and late.
    for (const size_t split :
         {size_t{0}, size_t{3}, size_t{40}, in_burst, size_t{ranges.size() / 2}, ranges.size() - 1}) {
        SCOPED_TRACE("split after " + std::to_string(split) + " ranges");
        Engine whole = bodyEngine();
        Engine head = bodyEngine();
        FlightRecord uninterrupted;
        FlightRecord resumed;
        for (size_t k = 0; k < split; ++k) {
            whole.addRange(ranges[k].from, ranges[k].to, ranges[k].range_m, ranges[k].t_s);
            head.addRange(ranges[k].from, ranges[k].to, ranges[k].range_m, ranges[k].t_s);
        }
        Engine tail = bodyEngine();
        const FlightTracks::RestoreReport report = tail.restoreFlights(head.flightSaved());
        EXPECT_TRUE(report.dropped.empty() && report.restarted.empty() && !report.bodies_differ);
        flyOn(whole, ranges, split, uninterrupted);
        flyOn(tail, ranges, split, resumed);
        ASSERT_EQ(uninterrupted.values.size(), resumed.values.size());
        ASSERT_FALSE(uninterrupted.values.empty());
        EXPECT_EQ(0, std::memcmp(uninterrupted.values.data(), resumed.values.data(),
                                 uninterrupted.values.size() * sizeof(double)));
        EXPECT_EQ(uninterrupted.counts, resumed.counts);
    }
    // The flight did exercise the state: refusals, resets, tag-to-tag ranges and the body.
    Engine engine = bodyEngine();
    for (const FlightRange &r : ranges) {
        engine.addRange(r.from, r.to, r.range_m, r.t_s);
    }
    const FlightCounters &c = engine.flightCounters();
    std::printf("saved and restored flight, %s: %llu refused, %llu resets, %llu down-weighted, %llu body updates\n",
                seedTrace(seed).c_str(), static_cast<unsigned long long>(c.refused),
                static_cast<unsigned long long>(c.resets), static_cast<unsigned long long>(c.down_weighted),
                static_cast<unsigned long long>(c.body_updates));
    EXPECT_GT(c.refused, 0U);
    EXPECT_GT(c.resets, 0U);
    EXPECT_GT(c.tag_ranges, 0U);
    EXPECT_GT(c.body_updates, 0U);
}

TEST(MotionTrack3D, ARestoreTellsWhichNodesItDroppedAndWhichRestart)
{
    const uint64_t seed = testSeed(9);
    SCOPED_TRACE(seedTrace(seed));
    const std::vector<FlightRange> ranges = simulate(seed, true);
    Engine head = bodyEngine();
    for (size_t k = 0; k < 200; ++k) {
        head.addRange(ranges[k].from, ranges[k].to, ranges[k].range_m, ranges[k].t_s);
    }
    const FlightTracks::Saved saved = head.flightSaved();
    Engine other; // declares tags 10 and 30: 20 is not declared, 30 was not saved; no body
    for (size_t a = 0; a < kFlightAnchors.size(); ++a) {
        other.setFixed(kFlightAnchors[a], kFlightAnchorPositionsM[a].head<2>());
        other.setHeight(kFlightAnchors[a], kFlightAnchorPositionsM[a].z());
    }
    other.trackMoving3D(10);
    other.trackMoving3D(30);
    const FlightTracks::RestoreReport report = other.restoreFlights(saved);
    EXPECT_EQ(report.dropped, std::vector<NodeId>{20});
    EXPECT_EQ(report.restarted, std::vector<NodeId>{30});
    EXPECT_TRUE(report.bodies_differ);
    EXPECT_FALSE(report.anchors_differ);
    const std::optional<FlightEstimate> kept = other.flightEstimate(10);
    const std::optional<FlightEstimate> was = head.flightEstimate(10);
    ASSERT_TRUE(kept && was);
    EXPECT_EQ(kept->status, FlightStatus::Tracking);
    EXPECT_EQ(kept->position_m, was->position_m);
    EXPECT_EQ(kept->covariance_m2, was->covariance_m2);
    EXPECT_EQ(other.flightEstimate(30)->status, FlightStatus::Waiting);
    EXPECT_EQ(other.flightEstimate(20), std::nullopt);

    // Anchors given otherwise now (one moved 2 mm): said; the saved ones are kept.
    Engine moved;
    for (size_t a = 0; a < kFlightAnchors.size(); ++a) {
        moved.setFixed(kFlightAnchors[a], kFlightAnchorPositionsM[a].head<2>() + Vector2(a == 3 ? 0.002 : 0.0, 0.0));
        moved.setHeight(kFlightAnchors[a], kFlightAnchorPositionsM[a].z());
    }
    moved.trackMoving3D(10);
    moved.trackMoving3D(20);
    moved.trackOnOneBody(10, 20, 1.5);
    const FlightTracks::RestoreReport anchors = moved.restoreFlights(saved);
    EXPECT_TRUE(anchors.anchors_differ);
    EXPECT_FALSE(anchors.bodies_differ);
    EXPECT_TRUE(anchors.dropped.empty() && anchors.restarted.empty());
    EXPECT_EQ(moved.flightSaved().anchors, saved.anchors);

    // A state that does not fit together is refused, naming what is wrong, and changes nothing.
    FlightTracks::Saved cut = saved;
    cut.state.conservativeResize(cut.state.size() - 1);
    Engine fresh = bodyEngine();
    try {
        fresh.restoreFlights(cut);
        ADD_FAILURE() << "a state one value short was taken";
    } catch (const std::invalid_argument &error) {
        EXPECT_NE(std::string(error.what()).find("11 state values"), std::string::npos) << error.what();
    }
    FlightTracks::Saved deaf = saved;
    deaf.nodes[0].heard.push_back(99);
    EXPECT_THROW(fresh.restoreFlights(deaf), std::invalid_argument);
    EXPECT_EQ(fresh.flightEstimate(10)->status, FlightStatus::Waiting);
    EXPECT_FALSE(fresh.flightSaved().anchors_set);
}

TEST(MotionTrack3D, AFixedOrHeightKnownNodeCannotBeTracked)
{
    Engine engine;
    engine.setFixed(1, Vector2(0.0, 0.0));
    engine.setHeight(2, 1.0);
    EXPECT_THROW(engine.trackMoving3D(1), std::logic_error);
    EXPECT_THROW(engine.trackMoving3D(2), std::logic_error);
    engine.trackMoving3D(10);
    EXPECT_THROW(engine.setHeight(10, 1.0), std::logic_error);
    EXPECT_THROW(engine.setFixed(10, Vector2(1.0, 1.0)), std::logic_error);
    EXPECT_EQ(engine.addRange(10, 1, 2.0), RangeVerdict::RejectedValue); // no time: no track
    EXPECT_EQ(engine.addRange(10, 10, 2.0, 0.0), RangeVerdict::RejectedSelf);
}

} // namespace
} // namespace cdro::enginetest
