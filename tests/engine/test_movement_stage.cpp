// MovementStage end to end (docs/engine.md, "Stage 2") on small seeded worlds of netgen's robot
// world (cdro/netgen/robot_world.hpp): a robot with noisy odometry (2 % of each step, 3 mrad a
// step, a 5 mrad/s heading drift) ranging to nodes (0.1 m noise, 3 % long, known heights), the
// nodes ranging each other where they can.
//   (a) no map: 4 beacons that never range each other, the robot drives two loops;
//   (b) joining a map: 6 nodes ranging each other, the robot drives an L;
//   (c) a corridor: a node with only two map neighbours, the robot driving a straight line;
//   (d) a node carried away and put down again;
//   the learnt range noise, an NLOS link left out, the robot output before the EKF runs;
//   (e) determinism.
// Every bound was set from a measured figure (in the comment next to it) with margin, and the
// main ones are checked to be able to fail: dead reckoning, the rings before the robot moved,
// the map before it, or the engine before the bug fix they guard against does not meet them.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <optional>
#include <vector>

#include <gtest/gtest.h>

#include "cdro/engine/alignment.hpp"
#include "cdro/engine/engine.hpp"
#include "cdro/engine/movement.hpp"
#include "cdro/netgen/robot_world.hpp"
#include "support.hpp"

namespace cdro::enginetest {
namespace {

using engine::Engine;
using engine::EngineParams;
using engine::MovementParams;
using engine::MovementStage;
using engine::NodeOutput;
using engine::OdometryStep;
using engine::Pose2;
using engine::predictOdometry;
using engine::RobotFrame;
using engine::RobotOutput;
using netgen::Carry;
using netgen::kOdometryTickS;
using netgen::RobotEvent;
using netgen::RobotWorld;
using netgen::RobotWorldSpec;
using netgen::simulateRobot;

constexpr double kPi = 3.14159265358979323846;

// What a run gives: the robot after each odometry step, the estimates at chosen moments.
struct StageRun {
    std::vector<RobotOutput> robot;                 // after each odometry event (robot() always has a value)
    std::vector<std::vector<NodeOutput>> snapshots; // estimates after the odometry events in `snapshot_at`
    std::vector<NodeOutput> final_estimates;
    engine::MovementCounters counters;
    size_t decided_at = std::numeric_limits<size_t>::max(); // first odometry index with one hypothesis left
    size_t started_at = std::numeric_limits<size_t>::max(); // first odometry index with the EKF running
};

StageRun runStage(const RobotWorld &world, const std::vector<size_t> &snapshot_at = {},
                  const MovementParams &movement = MovementParams{}, const EngineParams &params = EngineParams{})
{
    Engine engine(params);
    engine.setHeight(world.spec.robot_id, world.spec.robot_height_m);
    for (size_t i = 0; i < world.spec.ids.size(); ++i) {
        engine.setHeight(world.spec.ids[i], world.spec.height_m[i]);
    }
    MovementParams stage_params = movement;
    stage_params.robot_id = world.spec.robot_id;
    MovementStage stage(engine, stage_params);
    StageRun run;
    for (const RobotEvent &event : world.events) {
        switch (event.kind) {
        case RobotEvent::Kind::Odometry: {
            stage.addOdometry(event.t_s, event.step);
            const std::optional<RobotOutput> robot = stage.robot();
            run.robot.push_back(*robot);
            const size_t index = run.robot.size() - 1;
            if (robot->localized && run.started_at == std::numeric_limits<size_t>::max()) {
                run.started_at = index;
            }
            if (robot->localized && robot->hypotheses == 1 && run.decided_at == std::numeric_limits<size_t>::max()) {
                run.decided_at = index;
            }
            if (std::find(snapshot_at.begin(), snapshot_at.end(), index) != snapshot_at.end()) {
                run.snapshots.push_back(stage.estimates());
            }
            break;
        }
        case RobotEvent::Kind::Range: stage.addRange(event.from, event.to, event.range_m, event.t_s); break;
        case RobotEvent::Kind::Motion: stage.setMoving(event.id, event.moving, event.t_s); break;
        }
    }
    run.final_estimates = stage.estimates();
    run.counters = stage.counters();
    return run;
}

// Aligned RMSE (rigid fit, reflection allowed) of a path segment against the truth.
double pathError(const std::vector<Vector2> &estimate_m, const std::vector<Vector2> &truth_m)
{
    return engine::fitRigid(estimate_m, truth_m, true).rms_error_m;
}

Pose2 poseOf(const RobotOutput &robot) { return robot.pose; }
Pose2 poseOf(const Pose2 &pose) { return pose; }

std::vector<Vector2> positions(const std::vector<RobotOutput> &robot, size_t from, size_t to)
{
    std::vector<Vector2> out;
    for (size_t i = from; i < to; ++i) {
        out.emplace_back(robot[i].pose.x_m, robot[i].pose.y_m);
    }
    return out;
}

std::vector<Vector2> positions(const std::vector<Pose2> &poses, size_t from, size_t to)
{
    std::vector<Vector2> out;
    for (size_t i = from; i < to; ++i) {
        out.emplace_back(poses[i].x_m, poses[i].y_m);
    }
    return out;
}

// The rigid fit (reflection allowed) of the placed estimates of `ids` onto their truth.
engine::RigidTransform mapFit(const std::vector<NodeOutput> &estimates, const std::vector<NodeId> &ids,
                              const std::vector<Vector2> &truth_m)
{
    std::vector<Vector2> source;
    std::vector<Vector2> target;
    for (size_t i = 0; i < ids.size(); ++i) {
        for (const NodeOutput &node : estimates) {
            if (node.id == ids[i] && node.placed()) {
                source.push_back(node.position_m);
                target.push_back(truth_m[i]);
            }
        }
    }
    return engine::fitRigid(source, target, true);
}

// RMS of |fit(estimate) - truth| over [from, to) (no fit of its own).
template <typename Poses>
double errorThroughFit(const engine::RigidTransform &fit, const Poses &estimate, const std::vector<Pose2> &truth,
                       size_t from, size_t to)
{
    double sum_m2 = 0.0;
    for (size_t i = from; i < to; ++i) {
        const Pose2 pose = poseOf(estimate[i]);
        sum_m2 += (fit.apply(Vector2(pose.x_m, pose.y_m)) - Vector2(truth[i].x_m, truth[i].y_m)).squaredNorm();
    }
    return to > from ? std::sqrt(sum_m2 / static_cast<double>(to - from)) : 0.0;
}

const NodeOutput *findNode(const std::vector<NodeOutput> &estimates, NodeId id)
{
    for (const NodeOutput &node : estimates) {
        if (node.id == id) {
            return &node;
        }
    }
    return nullptr;
}

size_t indexAt(double t_s)
{
    return static_cast<size_t>(std::lround(t_s / kOdometryTickS)) - 1;
} // odometry index ending at t

// ---------------------------------------------------------------------------------------------
// (a) No map: beacons that never range each other

RobotWorldSpec loopAmongBeacons()
{
    RobotWorldSpec spec;
    spec.ids = {1, 2, 3, 4};
    spec.truth_m = {{-6.0, 9.0}, {15.0, 12.0}, {17.0, -6.0}, {-4.0, -8.0}};
    spec.height_m = {2.0, 1.5, 2.5, 1.8};
    spec.stand_s = 5.0;
    // Two laps of a rounded 9 m square, counter-clockwise: 16 s at 0.5 m/s, a quarter turn.
    for (int lap = 0; lap < 2; ++lap) {
        for (int side = 0; side < 4; ++side) {
            spec.drive.push_back({16.0, 0.5, 0.0});
            spec.drive.push_back({kPi, 0.3, 0.5});
        }
    }
    return spec;
}

TEST(MovementStage, WithoutAMapBeaconsAroundTheRobotEnterTheEkfAndEndNearTheTruth)
{
    const uint64_t seed = testSeed(5101);
    SCOPED_TRACE(seedTrace(seed));
    const RobotWorld world = simulateRobot(loopAmongBeacons(), seed);
    const size_t early = indexAt(7.0); // 2 s after the robot started: every beacon still a ring
    const StageRun run = runStage(world, {early});
    ASSERT_EQ(run.snapshots.size(), 1U);

    const AlignedError before = alignedError(run.snapshots[0], world.spec.ids, world.final_truth_m);
    const AlignedError after = alignedError(run.final_estimates, world.spec.ids, world.final_truth_m);
    const size_t end = run.robot.size();
    const std::vector<Vector2> truth_m = positions(world.robot_truth, run.started_at, end);
    const double path_m = pathError(positions(run.robot, run.started_at, end), truth_m);
    const double dead_m = pathError(positions(world.dead_reckoning, run.started_at, end), truth_m);
    std::printf("no map: beacons %.3f m (max %.3f) after 2 s of driving %.3f m; path %.3f m, dead reckoning %.3f m; "
                "%llu beacon SoGs, %llu nodes into the EKF; scale %.4f\n",
                after.rmse_m, after.max_m, before.rmse_m, path_m, dead_m,
                static_cast<unsigned long long>(run.counters.beacon_sogs),
                static_cast<unsigned long long>(run.counters.nodes_inserted), run.robot.back().range_scale);

    EXPECT_EQ(run.counters.beacon_sogs, 4U);
    EXPECT_EQ(run.counters.nodes_inserted, 4U);
    EXPECT_EQ(after.placed, 4U);
    for (NodeId id : world.spec.ids) {
        const NodeOutput *beacon = findNode(run.final_estimates, id);
        ASSERT_NE(beacon, nullptr);
        EXPECT_TRUE(beacon->converged()) << "beacon " << id; // the EKF holds it
    }
    // Measured (seed 5101): beacons 0.186 m (max 0.196), 13.3 m while still rings; path 0.121 m,
    // dead reckoning 1.154 m; scale 1.0255 (true 1.03). Over seeds 1-20: beacons 0.07-0.21 m
    // (max 0.22), path 0.07-0.18 m, dead reckoning 0.68-1.61 m, scale 1.024-1.028.
    EXPECT_LT(after.rmse_m, 0.5);
    EXPECT_LT(after.max_m, 0.6);
    EXPECT_GT(before.rmse_m, 0.5); // the bound is not met by the rings alone
    EXPECT_LT(path_m, 0.5);
    EXPECT_GT(dead_m, 0.5); // nor by dead reckoning
    EXPECT_NEAR(run.robot.back().range_scale, 1.03, 0.01);
    EXPECT_TRUE(run.robot.back().localized);
    EXPECT_EQ(run.robot.back().hypotheses, 1U); // the odometry frame: one heading from the start
}

// ---------------------------------------------------------------------------------------------
// (b) Joining a map: six nodes that range each other, a robot that stands, then drives an L

RobotWorldSpec lShapeInAMap()
{
    RobotWorldSpec spec;
    spec.ids = {11, 12, 13, 14, 15, 16};
    spec.truth_m = {{0.0, 0.0}, {12.0, 1.0}, {20.0, 8.0}, {14.0, 17.0}, {3.0, 14.0}, {9.0, 7.0}};
    spec.height_m = {2.0, 2.4, 1.6, 2.2, 1.9, 2.6};
    for (size_t a = 0; a < spec.ids.size(); ++a) {
        for (size_t b = a + 1; b < spec.ids.size(); ++b) {
            spec.links.emplace_back(a, b);
        }
    }
    // The robot stands 20 s (stage 1 places it with the others), heading 0.7 rad (unknown to
    // the engine), then 10 m straight, a left quarter turn, 14 m straight, and stands 5 s.
    spec.robot_start = Pose2{4.0, 3.0, 0.7};
    spec.stand_s = 20.0;
    spec.drive = {{20.0, 0.5, 0.0}, {kPi, 0.2, 0.5}, {28.0, 0.5, 0.0}};
    spec.end_stand_s = 5.0;
    return spec;
}

TEST(MovementStage, JoiningAMapTheHeadingBankDecidesAndTheRobotFollowsItsPath)
{
    const uint64_t seed = testSeed(5102);
    SCOPED_TRACE(seedTrace(seed));
    const RobotWorld world = simulateRobot(lShapeInAMap(), seed);
    const size_t start = indexAt(world.spec.stand_s); // the last step standing
    const StageRun run = runStage(world, {start});
    ASSERT_EQ(run.snapshots.size(), 1U);
    ASSERT_LT(run.started_at, run.robot.size()) << "the EKF never started";
    ASSERT_LT(run.decided_at, run.robot.size()) << "the heading was never decided";

    const AlignedError map_before = alignedError(run.snapshots[0], world.spec.ids, world.final_truth_m);
    const AlignedError map_after = alignedError(run.final_estimates, world.spec.ids, world.final_truth_m);
    // The robot in the map's frame: seen through the fit of the final map onto the truth (so
    // where it is relative to the nodes counts, not only the shape of its path).
    const engine::RigidTransform fit = mapFit(run.final_estimates, world.spec.ids, world.final_truth_m);
    const size_t end = run.robot.size();
    const double path_m = errorThroughFit(fit, run.robot, world.robot_truth, run.decided_at, end);
    const double undecided_m = errorThroughFit(fit, run.robot, world.robot_truth, run.started_at, run.decided_at);
    const double dead_m =
        errorThroughFit(engine::RigidTransform{}, world.dead_reckoning, world.robot_truth, run.decided_at, end);
    const double decided_after_m = std::hypot(world.robot_truth[run.decided_at].x_m - world.spec.robot_start.x_m,
                                              world.robot_truth[run.decided_at].y_m - world.spec.robot_start.y_m);
    std::printf("map: EKF from t %.1f s, heading decided at t %.1f s (%.2f m from the start); map %.3f m before the "
                "robot moved, %.3f m at the end; path after the decision %.3f m (before it %.3f m), dead reckoning "
                "from the true start %.3f m; %llu nodes in the EKF; scale %.4f\n",
                static_cast<double>(run.started_at + 1) * kOdometryTickS,
                static_cast<double>(run.decided_at + 1) * kOdometryTickS, decided_after_m, map_before.rmse_m,
                map_after.rmse_m, path_m, undecided_m, dead_m,
                static_cast<unsigned long long>(run.counters.nodes_inserted), run.robot.back().range_scale);

    // Measured (seed 5102): decided at t 44.4 s (the turn is at 40-43.1 s); map 0.271 m before
    // (stage 1 cannot know the ranges read 3 % long) and 0.021 m after; path after the decision
    // 0.231 m, dead reckoning 1.760 m. Seeds 1-20: decided at 43.8-44.7 s, map 0.26-0.29 m ->
    // 0.014-0.076 m, path 0.06-0.21 m, dead reckoning 0.46-2.91 m.
    EXPECT_EQ(map_before.placed, 6U);
    EXPECT_EQ(run.counters.nodes_inserted, 6U);
    EXPECT_EQ(run.robot.back().hypotheses, 1U);
    // A straight line cannot tell the map from its mirror image (mirrored odometry only differs
    // in turns): the bank decides after the turn begins, and soon after it.
    const double decided_s = static_cast<double>(run.decided_at + 1) * kOdometryTickS;
    EXPECT_GT(decided_s, 40.0);
    EXPECT_LT(decided_s, 50.0);
    EXPECT_LT(path_m, 0.4);
    EXPECT_GT(dead_m, 0.4); // dead reckoning, even from the true start pose, does not meet it
    EXPECT_LT(map_after.rmse_m, 0.5 * map_before.rmse_m); // the map improves ...
    EXPECT_LT(map_after.rmse_m, 0.1);
    EXPECT_NEAR(run.robot.back().range_scale, 1.03, 0.01); // ... as the scale is learnt
}

// ---------------------------------------------------------------------------------------------
// (c) A corridor: a node with two map neighbours only, the robot driving a straight line

RobotWorldSpec corridor()
{
    RobotWorldSpec spec;
    // Four nodes that range each other, and node 25 that only 23 and 24 reach: stage 1 sees two
    // places for it (mirror images across the line 23-24), at (24, 0) and near (1.6, 11.2).
    spec.ids = {21, 22, 23, 24, 25};
    spec.truth_m = {{0.0, 0.0}, {4.0, 8.0}, {10.0, 0.0}, {14.0, 8.0}, {24.0, 0.0}};
    spec.height_m = {2.0, 2.4, 1.6, 2.2, 1.9};
    spec.links = {{0, 1}, {0, 2}, {0, 3}, {1, 2}, {1, 3}, {2, 3}, {2, 4}, {3, 4}};
    // The robot stands at (2, 1.5), out of 25's reach (14 m), drives 3 m north and turns right
    // (the turn decides its heading: mirrored odometry only differs in turns), then drives
    // straight along y = 5.1 to x = 33: its own ranges leave 25 two places too (mirror images
    // across that line).
    spec.robot_max_range_m = 14.0;
    spec.robot_start = Pose2{2.0, 1.5, kPi / 2.0};
    spec.stand_s = 20.0;
    spec.drive = {{6.0, 0.5, 0.0}, {kPi, 0.3, -0.5}, {60.0, 0.5, 0.0}};
    spec.end_stand_s = 5.0;
    return spec;
}

TEST(MovementStage, ANodeWithTwoMapNeighboursEndsOnTheCorrectSideOfTheRobotsLine)
{
    // Regression: before "movement: a node's SoG around the robot is also weighted by the ranges
    // from map nodes the EKF holds", the ring around the robot kept both mirror modes and the
    // node stayed out of the map (as the last anchor of robot-corridor, 2.2 m RMSE).
    const uint64_t seed = testSeed(5103);
    SCOPED_TRACE(seedTrace(seed));
    const RobotWorld world = simulateRobot(corridor(), seed);
    const StageRun run = runStage(world, {indexAt(world.spec.stand_s)});
    ASSERT_EQ(run.snapshots.size(), 1U);
    ASSERT_LT(run.started_at, run.robot.size()) << "the EKF never started";

    const std::vector<NodeId> map_ids = {21, 22, 23, 24};
    const std::vector<Vector2> map_truth_m(world.final_truth_m.begin(), world.final_truth_m.begin() + 4);
    const engine::RigidTransform fit = mapFit(run.final_estimates, map_ids, map_truth_m);
    const NodeOutput *node = findNode(run.final_estimates, 25);
    ASSERT_NE(node, nullptr);
    const NodeOutput *before = findNode(run.snapshots[0], 25);
    const Vector2 truth_m = world.final_truth_m[4];
    const Vector2 estimate_m = fit.apply(node->position_m);
    const double error_m = (estimate_m - truth_m).norm();
    const AlignedError all = alignedError(run.final_estimates, world.spec.ids, world.final_truth_m);
    std::printf("corridor: node 25 %s before the robot moved; at the end %s at (%.2f, %.2f), %.3f m from the truth "
                "(24, 0), converged %d; all nodes %.3f m; %llu beacon SoGs, %llu nodes into the EKF; hypotheses %u\n",
                before != nullptr && before->placed()
                    ? ((before->doubt == engine::NodeDoubt::Ambiguous) ? "placed, ambiguous" : "placed")
                    : "not placed",
                node->placed() ? "placed" : "not placed", estimate_m.x(), estimate_m.y(), error_m,
                node->converged() ? 1 : 0, all.rmse_m, static_cast<unsigned long long>(run.counters.beacon_sogs),
                static_cast<unsigned long long>(run.counters.nodes_inserted), run.robot.back().hypotheses);
    // Measured (seed 5103): node 25 at (24.07, -0.03), 0.079 m off; all nodes 0.037 m. Seeds
    // 1-20: 0.02-0.17 m, all nodes at most 0.088 m. With the engine before that commit this test
    // failed (on the draws of the tests' former stream): node 25 ended 4.6-10.7 m off (seeds
    // 5103, 1-3), between the two modes or on the mirror side.
    EXPECT_TRUE(node->placed());
    EXPECT_TRUE(node->converged());
    EXPECT_EQ(run.counters.beacon_sogs, 1U);
    EXPECT_LT(estimate_m.y(), 5.1) << "on the wrong side of the robot's line y = 5.1";
    EXPECT_LT(error_m, 0.5);
    EXPECT_LT(all.rmse_m, 0.3);
}

// ---------------------------------------------------------------------------------------------
// (d) A node carried away leaves the EKF, and rejoins once it has stopped and converged again

TEST(MovementStage, ACarriedNodeLeavesTheEkfAndRejoinsAfterItStops)
{
    const uint64_t seed = testSeed(5104);
    SCOPED_TRACE(seedTrace(seed));
    RobotWorldSpec spec = lShapeInAMap();
    // Node 16 is carried 4.1 m from (9, 7) to (10, 11) while the robot drives (its heading is
    // decided by then), reported moving at 50 s and still at 55 s; the robot then stands 30 s.
    spec.carry = Carry{16, 50.0, 55.0, Vector2(10.0, 11.0)};
    spec.end_stand_s = 30.0;
    const RobotWorld world = simulateRobot(spec, seed);
    std::vector<size_t> every_second;
    for (double t_s = 45.0; t_s < 100.0; t_s += 1.0) {
        every_second.push_back(indexAt(t_s));
    }
    const StageRun run = runStage(world, every_second);
    ASSERT_LT(run.decided_at, indexAt(50.0)) << "the heading should be decided before the carry";

    const std::vector<NodeId> others = {11, 12, 13, 14, 15};
    const std::vector<Vector2> others_truth_m(world.final_truth_m.begin(), world.final_truth_m.begin() + 5);
    const engine::RigidTransform fit = mapFit(run.final_estimates, others, others_truth_m);
    std::optional<double> rejoined_after_s;
    double rejoined_error_m = 0.0;
    bool out_while_carried = true;
    for (size_t k = 0; k < run.snapshots.size(); ++k) {
        const double t_s = 45.0 + static_cast<double>(k);
        const NodeOutput *node = findNode(run.snapshots[k], 16);
        ASSERT_NE(node, nullptr);
        if (t_s > 50.0 && t_s < 55.0) {
            out_while_carried = out_while_carried && node->moving() && !node->converged();
        }
        if (t_s > 55.0 && !rejoined_after_s && node->converged()) {
            rejoined_after_s = t_s - 55.0;
            rejoined_error_m = (fit.apply(node->position_m) - spec.carry->to_m).norm();
        }
    }
    const NodeOutput *node = findNode(run.final_estimates, 16);
    ASSERT_NE(node, nullptr);
    const double error_m = (fit.apply(node->position_m) - spec.carry->to_m).norm();
    const AlignedError map = alignedError(run.final_estimates, world.spec.ids, world.final_truth_m);
    std::printf("carried: out of the EKF while carried %d; converged again %.0f s after it stopped (%.3f m off); at "
                "the end %.3f m from where it was put; map %.3f m; %llu nodes into the EKF, %llu out\n",
                out_while_carried ? 1 : 0, rejoined_after_s ? *rejoined_after_s : -1.0, rejoined_error_m, error_m,
                map.rmse_m, static_cast<unsigned long long>(run.counters.nodes_inserted),
                static_cast<unsigned long long>(run.counters.nodes_removed));
    // Measured (seed 5104): out of the EKF while carried, converged (back in the EKF) 2 s after
    // the stop 0.030 m off, 0.004 m off at the end; map 0.018 m. Seeds 1-20: always 2 s, at most
    // 0.24 m off when it rejoined, 0.028 m at the end, map at most 0.061 m.
    EXPECT_TRUE(out_while_carried);
    EXPECT_EQ(run.counters.nodes_removed, 1U);
    EXPECT_EQ(run.counters.nodes_inserted, 7U); // six, and 16 again
    ASSERT_TRUE(rejoined_after_s.has_value()) << "node 16 never converged again";
    EXPECT_LT(*rejoined_after_s, 10.0);
    EXPECT_TRUE(node->converged());
    EXPECT_FALSE(node->moving());
    EXPECT_LT(error_m, 0.2); // 4.1 m if it had stayed where it was
    EXPECT_LT(map.rmse_m, 0.15);
}

// ---------------------------------------------------------------------------------------------
// The range noise is learnt; an NLOS link is left out; the robot output before the EKF runs

// Feeds the world's odometry and ranges to the stage; the range noise it uses, once a second
// over the second half of the run, sorted.
std::vector<double> noiseInUseOverTheSecondHalf(MovementStage &stage, const RobotWorld &world)
{
    std::vector<double> in_use_m;
    double next_sample_s = world.events.back().t_s / 2.0;
    for (const RobotEvent &event : world.events) {
        if (event.kind == RobotEvent::Kind::Odometry) {
            stage.addOdometry(event.t_s, event.step);
            if (event.t_s >= next_sample_s) {
                in_use_m.push_back(stage.rangeSigmaInUse());
                next_sample_s += 1.0;
            }
        } else if (event.kind == RobotEvent::Kind::Range) {
            stage.addRange(event.from, event.to, event.range_m, event.t_s);
        }
    }
    std::sort(in_use_m.begin(), in_use_m.end());
    return in_use_m;
}

TEST(MovementStage, TheRangeNoiseIsLearntFromTheInnovations)
{
    const uint64_t seed = testSeed(5106);
    SCOPED_TRACE(seedTrace(seed));
    RobotWorldSpec spec = loopAmongBeacons();
    spec.range_noise_m = 0.4; // above the engine's floor (range.sigma_m = 0.1 m)
    const RobotWorld world = simulateRobot(spec, seed);
    Engine engine;
    MovementParams params;
    params.robot_id = spec.robot_id;
    MovementStage stage(engine, params);
    EXPECT_EQ(stage.rangeSigmaInUse(), params.adaptive_initial_sigma_m); // 1 m until learnt
    // The learnt value follows the last 60 innovations: it wanders.
    const std::vector<double> learnt_m = noiseInUseOverTheSecondHalf(stage, world);
    const double median_m = learnt_m[learnt_m.size() / 2];
    std::printf("noise: learnt %.3f m (median over the second half; %.3f-%.3f m; true 0.4 m)\n", median_m,
                learnt_m.front(), learnt_m.back());
    // Measured (seed 5106): median 0.427 m (0.275-0.519 m). Seeds 1-20: medians 0.38-0.46 m,
    // every sample within 0.21-0.67 m.
    EXPECT_NEAR(median_m, 0.4, 0.15);
    EXPECT_GT(learnt_m.front(), 0.15); // never down at the floor (0.1 m) ...
    EXPECT_LT(learnt_m.back(), 0.9);   // ... nor back at the initial 1 m
    // A fixed noise is used as given.
    MovementParams fixed = params;
    fixed.range_sigma_m = 0.25;
    Engine other;
    EXPECT_EQ(MovementStage(other, fixed).rangeSigmaInUse(), 0.25);
}

TEST(MovementStage, ARangeNoiseBelowTheFloorIsLearntAsTheFloorNotAsTheInitialGuess)
{
    // Fixture: ranges far more exact than the engine's floor (range.sigma_m = 0.1 m), so that what
    // the state still does not know explains the innovations' whole spread and the learnt value
    // is 0. Before the fix a learnt 0 read as "not learnt" and the EKF ran on the initial 1 m
    // (cdro-sim robot-corridor seed 4 reported "range noise 1.000 m").
    const uint64_t seed = testSeed(5110);
    SCOPED_TRACE(seedTrace(seed));
    RobotWorldSpec spec = loopAmongBeacons();
    spec.range_noise_m = 0.005;
    const RobotWorld world = simulateRobot(spec, seed);
    Engine engine;
    MovementParams params;
    params.robot_id = spec.robot_id;
    MovementStage stage(engine, params);

    // Test
    const std::vector<double> in_use_m = noiseInUseOverTheSecondHalf(stage, world);

    // Assert: at the floor or a little above it, never the initial 1 m.
    ASSERT_FALSE(in_use_m.empty());
    std::printf("noise in use: %.3f-%.3f m (floor 0.1 m, true 0.005 m)\n", in_use_m.front(), in_use_m.back());
    EXPECT_EQ(in_use_m.front(), engine.params().range.sigma_m);
    EXPECT_LT(in_use_m.back(), 0.3);
}

TEST(MovementStage, ALinkThatReadsLongPersistentlyIsLeftOutOfTheEkf)
{
    const uint64_t seed = testSeed(5107);
    SCOPED_TRACE(seedTrace(seed));
    const RobotWorld clean = simulateRobot(lShapeInAMap(), seed);
    RobotWorld world = clean;
    // The link 11-13 (21 m long, past node 16) reads 1 m long every time: NLOS.
    for (RobotEvent &event : world.events) {
        if (event.kind == RobotEvent::Kind::Range && event.from == 11 && event.to == 13) {
            event.range_m += 1.0;
        }
    }
    const StageRun run = runStage(world);
    const StageRun reference = runStage(clean);
    MovementParams no_exclusion;
    no_exclusion.nlos_min_m = 1e9; // never excluded
    const StageRun kept = runStage(world, {}, no_exclusion);
    const AlignedError map = alignedError(run.final_estimates, world.spec.ids, world.final_truth_m);
    const AlignedError map_kept = alignedError(kept.final_estimates, world.spec.ids, world.final_truth_m);
    const AlignedError map_clean = alignedError(reference.final_estimates, world.spec.ids, world.final_truth_m);
    std::printf("nlos: %llu of its ranges left out, map %.3f m (with them %.3f m; without the NLOS link %.3f m, %llu "
                "ranges left out)\n",
                static_cast<unsigned long long>(run.counters.nlos_link_ranges_skipped), map.rmse_m, map_kept.rmse_m,
                map_clean.rmse_m, static_cast<unsigned long long>(reference.counters.nlos_link_ranges_skipped));
    // Measured (seed 5107): 17 ranges left out, map 0.047 m (0.048 m with them, 0.046 m without
    // the NLOS); no range of the clean data left out. Seeds 1-20: 14-18 left out, map 0.014-0.076 m.
    EXPECT_GT(run.counters.nlos_link_ranges_skipped, 0U);
    EXPECT_EQ(kept.counters.nlos_link_ranges_skipped, 0U);
    EXPECT_EQ(reference.counters.nlos_link_ranges_skipped, 0U);
    EXPECT_LT(map.rmse_m, 0.1);
}

TEST(MovementStage, BeforeTheRobotMovesItsOutputIsDeadReckoningOrItsStageOneEstimate)
{
    // No robot: no output.
    Engine none;
    EXPECT_FALSE(MovementStage(none, MovementParams{}).robot().has_value());

    // No map: the odometry frame, placed at its dead reckoning, not localized.
    Engine engine;
    MovementParams params;
    params.robot_id = 100;
    MovementStage stage(engine, params);
    stage.addOdometry(0.1, OdometryStep{0.02, 0.1}); // 2 cm: below motion_start_m (5 cm)
    ASSERT_TRUE(stage.robot().has_value());
    const Pose2 expected = predictOdometry(Pose2{}, OdometryStep{0.02, 0.1}).pose;
    EXPECT_FALSE(stage.started());
    EXPECT_FALSE(stage.robot()->localized);
    EXPECT_TRUE(stage.robot()->placed);
    EXPECT_EQ(stage.robot()->frame, RobotFrame::Odometry);
    EXPECT_EQ(stage.robot()->pose.x_m, expected.x_m);
    EXPECT_EQ(stage.robot()->pose.y_m, expected.y_m);
    EXPECT_EQ(stage.robot()->pose.heading_rad, expected.heading_rad);
    EXPECT_EQ(stage.robot()->t_s, 0.1);
    stage.addOdometry(0.2, OdometryStep{0.04, 0.0}); // 6 cm in all: the EKF starts, same frame
    EXPECT_TRUE(stage.started());
    EXPECT_TRUE(stage.robot()->localized);
    EXPECT_EQ(stage.robot()->hypotheses, 1U);
    EXPECT_EQ(stage.robot()->frame, RobotFrame::Odometry); // no map appeared: the odometry's frame stays
    EXPECT_NEAR(stage.robot()->pose.x_m, expected.x_m + 0.04 * std::cos(0.1), 1e-12);

    // A map: standing, the robot is a node of stage 1, placed with an unknown heading.
    const RobotWorld world = simulateRobot(lShapeInAMap(), testSeed(5108));
    Engine mapped;
    for (size_t i = 0; i < world.spec.ids.size(); ++i) {
        mapped.setHeight(world.spec.ids[i], world.spec.height_m[i]);
    }
    mapped.setHeight(world.spec.robot_id, world.spec.robot_height_m);
    MovementParams map_params;
    map_params.robot_id = world.spec.robot_id;
    MovementStage standing(mapped, map_params);
    std::vector<RobotFrame> frames; // after each odometry step, while the map appears
    for (const RobotEvent &event : world.events) {
        if (event.t_s > world.spec.stand_s) {
            break;
        }
        if (event.kind == RobotEvent::Kind::Odometry) {
            standing.addOdometry(event.t_s, event.step);
            const std::optional<RobotOutput> now = standing.robot();
            if (now && now->placed) {
                frames.push_back(now->frame);
            }
        } else if (event.kind == RobotEvent::Kind::Range) {
            standing.addRange(event.from, event.to, event.range_m, event.t_s);
        }
    }
    const std::optional<RobotOutput> robot = standing.robot();
    ASSERT_TRUE(robot.has_value());
    EXPECT_FALSE(standing.started());
    EXPECT_FALSE(robot->localized);
    EXPECT_TRUE(robot->placed);
    EXPECT_NEAR(robot->covariance(2, 2), 4.0 * kPi * kPi / 12.0, 1e-12); // uniform over the circle
    EXPECT_EQ(robot->frame, RobotFrame::Map);
    // Before stage 1 placed any node the pose was dead reckoning in the odometry's frame; once,
    // and for good, it switched to the map's (the rows before are not comparable with the rest).
    ASSERT_FALSE(frames.empty());
    EXPECT_EQ(frames.front(), RobotFrame::Odometry);
    const auto first_map = std::find(frames.begin(), frames.end(), RobotFrame::Map);
    ASSERT_NE(first_map, frames.end());
    EXPECT_TRUE(std::all_of(first_map, frames.end(), [](RobotFrame f) { return f == RobotFrame::Map; }));
    const std::optional<NodeOutput> node = mapped.estimate(world.spec.robot_id);
    ASSERT_TRUE(node.has_value());
    EXPECT_EQ(robot->pose.x_m, node->position_m.x());
    EXPECT_EQ(robot->pose.y_m, node->position_m.y());
}

TEST(MovementStage, AStandingRobotWhoseStageOnePositionIsAmbiguousHasNoPositionYet)
{
    // Fixture: six nodes that all range each other (with four, one link error too small to be
    // noticed could move them beyond the metre, and too few are converged for the robot to lean
    // on); the robot (standing) ranges two of them, so its mirror image across their line fits as
    // well, until it ranges a third.
    const std::vector<Vector2> truth_m = {{0.0, 0.0}, {10.0, 0.0}, {10.0, 8.0}, {0.0, 8.0}, {-3.0, 4.0}, {13.0, 4.0}};
    const Vector2 robot_m(3.0, 3.0);
    const NodeId robot_id = 100;
    Engine engine;
    MovementParams params;
    params.robot_id = robot_id;
    MovementStage stage(engine, params);
    double t_s = 0.0;
    auto round = [&](size_t robot_links) {
        for (size_t a = 0; a < truth_m.size(); ++a) {
            for (size_t b = a + 1; b < truth_m.size(); ++b) {
                stage.addRange(static_cast<NodeId>(a + 1), static_cast<NodeId>(b + 1), (truth_m[a] - truth_m[b]).norm(),
                               t_s += 0.01);
            }
        }
        for (size_t a = 0; a < robot_links; ++a) {
            stage.addRange(robot_id, static_cast<NodeId>(a + 1), (truth_m[a] - robot_m).norm(), t_s += 0.01);
        }
        stage.addOdometry(t_s += 0.01, OdometryStep{0.0, 0.0});
    };

    // Test and assert: with two links, once stage 1 has placed the robot's node (ambiguous).
    for (int k = 0; k < 200 && !(engine.estimate(robot_id) && engine.estimate(robot_id)->placed()); ++k) {
        round(2);
    }
    const std::optional<NodeOutput> two = engine.estimate(robot_id);
    ASSERT_TRUE(two.has_value() && two->placed());
    EXPECT_EQ(two->doubt, engine::NodeDoubt::TooFewLinks);
    ASSERT_TRUE(stage.robot().has_value());
    EXPECT_FALSE(stage.robot()->placed); // no trajectory row, no position to publish
    EXPECT_FALSE(stage.started());

    // With a third link the position is one: placed, in the map's frame, where it is.
    for (int k = 0; k < 50; ++k) {
        round(3);
    }
    const std::optional<NodeOutput> three = engine.estimate(robot_id);
    ASSERT_TRUE(three.has_value() && three->placed());
    EXPECT_NE(three->doubt, engine::NodeDoubt::Ambiguous);
    EXPECT_NE(three->doubt, engine::NodeDoubt::TooFewLinks);
    const std::optional<RobotOutput> robot = stage.robot();
    ASSERT_TRUE(robot.has_value());
    EXPECT_TRUE(robot->placed);
    EXPECT_EQ(robot->frame, RobotFrame::Map);
    for (size_t a = 0; a < 3; ++a) {
        const std::optional<NodeOutput> node = engine.estimate(static_cast<NodeId>(a + 1));
        ASSERT_TRUE(node.has_value());
        EXPECT_NEAR((Vector2(robot->pose.x_m, robot->pose.y_m) - node->position_m).norm(),
                    (truth_m[a] - robot_m).norm(), 0.05);
    }
}

// A regression test (the robot corridor of docs/results.md, seed 4: its first 10 ranges, heights
// and times as simulated): the standing robot's tag was the hub of a map of doubtful nodes, the
// only node of its main part (covariance zero: the gauge on it), called flexible, and the
// trajectory's rows put it ~50 m from the truth. A stage-1 position that ranges fewer than three
// converged nodes is no position yet.
TEST(MovementStage, AStandingRobotThatRangesNoConvergedNodeHasNoPositionYet)
{
    const NodeId robot_id = 0x6001;
    const std::vector<std::pair<NodeId, double>> heights_m = {{0x6001, 0.5}, {0x6021, 2.5}, {0x6022, 2.0},
                                                              {0x6023, 2.8}, {0x6024, 1.5}, {0x6025, 2.2},
                                                              {0x6027, 1.8}};
    struct Range {
        double t_s;
        NodeId from;
        NodeId to;
        double range_m;
    };
    const std::vector<Range> ranges = {{0.603, 0x6001, 0x6021, 26.169}, {0.647, 0x6001, 0x6023, 12.626},
                                       {0.690, 0x6001, 0x6025, 6.313},  {0.734, 0x6001, 0x6027, 18.380},
                                       {0.802, 0x6021, 0x6022, 12.436}, {0.872, 0x6021, 0x6024, 24.107},
                                       {1.395, 0x6022, 0x6024, 14.293}, {1.918, 0x6023, 0x6025, 14.591},
                                       {2.214, 0x6024, 0x6025, 12.781}, {2.282, 0x6024, 0x6027, 23.973}};
    Engine engine;
    for (const auto &[id, z_m] : heights_m) {
        engine.setHeight(id, z_m);
    }
    MovementParams params;
    params.robot_id = robot_id;
    MovementStage stage(engine, params);
    for (const Range &range : ranges) {
        stage.addRange(range.from, range.to, range.range_m, range.t_s);
    }
    stage.addOdometry(2.3, OdometryStep{0.0, 0.0});

    const std::optional<NodeOutput> node = engine.estimate(robot_id);
    ASSERT_TRUE(node.has_value() && node->placed());
    EXPECT_EQ(node->doubt, engine::NodeDoubt::Flexible);
    ASSERT_TRUE(stage.robot().has_value());
    EXPECT_FALSE(stage.robot()->placed); // no trajectory row, no position to publish
}

// A regression test: a beacon whose SoG around the robot has become one mode when the EKF is
// full (RobotFilter::kMaxNodes = 120) stays a SoG. Before the fix it was counted in
// nodes_inserted, pinned in stage 1 at its SoG's mean and its SoG dropped although the EKF did not
// hold it; the next robot range started a ring again, and so on. With 124 beacons (seed 5109, on
// the draws of the tests' own stream then): 124 pinned for 120 in the EKF, nodes_inserted 129,
// beacon_sogs 133, the 4 left out up to 2.61 m off (the EKF's at most 0.44 m).
TEST(MovementStage, ABeaconThatFindsTheEkfFullIsNotPinnedOutsideIt)
{
    CDRO_SKIP_WHEN_SANITIZED(); // an EKF over kMaxNodes beacons: ~2 min in the sanitized build
    const uint64_t seed = testSeed(5109);
    SCOPED_TRACE(seedTrace(seed));
    const size_t beacons = engine::RobotFilter::kMaxNodes + 4;
    RobotWorldSpec spec;
    spec.robot_id = 1000;
    spec.robot_height_m = 0.0; // all at one height: the ranges are planar, and the engine is given no heights
    for (size_t i = 0; i < beacons; ++i) { // a 13 x 10 grid, 6 m apart, around the robot's path
        const size_t column = i % 13;
        const size_t row = i / 13;
        spec.ids.push_back(static_cast<NodeId>(1 + i));
        spec.truth_m.emplace_back(-27.0 + 6.0 * static_cast<double>(column), -27.0 + 6.0 * static_cast<double>(row));
        spec.height_m.push_back(0.0);
    }
    // 150 s at 1 m/s from the origin: 10 s straight, 30 s turning left (a wobbly loop), ...
    spec.stand_s = 0.0;
    for (int lap = 0; lap < 4; ++lap) {
        spec.drive.push_back({10.0, 1.0, 0.0});
        spec.drive.push_back({lap < 3 ? 30.0 : 20.0, 1.0, 0.157});
    }
    spec.robot_ranges_per_tick = 8; // round robin over the beacons, none beyond reach
    spec.range_scale = 1.0;
    spec.range_noise_m = 0.1;
    spec.distance_noise_fraction = 0.0; // exact odometry: its frame is the world's
    spec.heading_noise_rad = 0.0;
    spec.heading_drift_rad_s = 0.0;
    const RobotWorld world = simulateRobot(spec, seed);
    ASSERT_EQ(world.robot_truth.size(), 1500U);
    const std::vector<Vector2> &truth_m = spec.truth_m;
    Engine engine;
    MovementParams params;
    params.robot_id = spec.robot_id;
    MovementStage stage(engine, params);
    for (const RobotEvent &event : world.events) {
        if (event.kind == RobotEvent::Kind::Odometry) {
            stage.addOdometry(event.t_s, event.step);
        } else if (event.kind == RobotEvent::Kind::Range) {
            stage.addRange(event.from, event.to, event.range_m, event.t_s);
        }
    }
    size_t pinned = 0;
    for (const engine::NodeState &node : engine.map().nodes) {
        pinned += node.pinned() ? 1U : 0U;
    }
    double worst_held_m = 0.0;  // beacons the EKF holds (reported converged)
    double worst_other_m = 0.0; // the others
    size_t others = 0;
    for (const NodeOutput &node : stage.estimates()) {
        if (node.id == params.robot_id) {
            continue;
        }
        const double error_m = (node.position_m - truth_m[node.id - 1U]).norm(); // the odometry frame is the world's
        if (node.converged()) {
            worst_held_m = std::max(worst_held_m, error_m);
        } else {
            worst_other_m = std::max(worst_other_m, error_m);
            ++others;
        }
    }
    std::printf("capacity: %zu beacons, %llu inserted, %llu beacon SoGs, %zu pinned in stage 1; the EKF's at most "
                "%.2f m off, the %zu others at most %.2f m\n",
                beacons, static_cast<unsigned long long>(stage.counters().nodes_inserted),
                static_cast<unsigned long long>(stage.counters().beacon_sogs), pinned, worst_held_m, others,
                worst_other_m);
    // Measured (seed 5109): 120 inserted, 124 beacon SoGs, 120 pinned; the EKF's at most 0.54 m
    // off, the 4 others 0.51 m. Seeds 1-20: the same counts, 0.29-0.68 m and 0.24-0.66 m.
    EXPECT_LE(stage.counters().nodes_inserted, engine::RobotFilter::kMaxNodes);
    EXPECT_LE(pinned, engine::RobotFilter::kMaxNodes); // stage 1 pins what the EKF holds, no more
    EXPECT_EQ(stage.counters().beacon_sogs, beacons);  // each beacon's ring starts once
}

// ---------------------------------------------------------------------------------------------
// (e) Determinism: the same inputs give the same outputs, bit for bit

bool sameBits(double a, double b) { return std::memcmp(&a, &b, sizeof a) == 0; }

bool sameRobot(const RobotOutput &a, const RobotOutput &b)
{
    bool same = a.id == b.id && a.localized == b.localized && a.placed == b.placed && a.frame == b.frame &&
                a.hypotheses == b.hypotheses && sameBits(a.t_s, b.t_s) && sameBits(a.pose.x_m, b.pose.x_m) &&
                sameBits(a.pose.y_m, b.pose.y_m) && sameBits(a.pose.heading_rad, b.pose.heading_rad) &&
                sameBits(a.range_scale, b.range_scale) && sameBits(a.range_scale_sigma, b.range_scale_sigma) &&
                sameBits(a.range_offset_m, b.range_offset_m) &&
                sameBits(a.range_offset_sigma_m, b.range_offset_sigma_m);
    for (Eigen::Index i = 0; i < 9; ++i) {
        same = same && sameBits(a.covariance(i), b.covariance(i));
    }
    return same;
}

// The first odometry index where two runs' robot outputs differ; the size when none does.
size_t firstDifference(const StageRun &a, const StageRun &b)
{
    for (size_t i = 0; i < std::min(a.robot.size(), b.robot.size()); ++i) {
        if (!sameRobot(a.robot[i], b.robot[i])) {
            return i;
        }
    }
    return a.robot.size() == b.robot.size() ? a.robot.size() : std::min(a.robot.size(), b.robot.size());
}

TEST(MovementStage, AStageRestoredFromItsSavedStateGoesOnAsTheOriginal)
{
    const uint64_t seed = testSeed(5106);
    SCOPED_TRACE(seedTrace(seed));
    // Saved while the robot drives (the EKF and its heading bank running) and a node is carried.
    RobotWorldSpec spec = lShapeInAMap();
    spec.carry = Carry{16, 30.0, 36.0, Vector2(10.0, 11.0)};
    const RobotWorld world = simulateRobot(spec, seed);
    MovementParams params;
    params.robot_id = spec.robot_id;
    Engine engine;
    engine.setHeight(spec.robot_id, spec.robot_height_m);
    for (size_t i = 0; i < spec.ids.size(); ++i) {
        engine.setHeight(spec.ids[i], spec.height_m[i]);
    }
    MovementStage stage(engine, params);
    auto apply = [](MovementStage &to, const RobotEvent &event) {
        switch (event.kind) {
        case RobotEvent::Kind::Odometry: to.addOdometry(event.t_s, event.step); break;
        case RobotEvent::Kind::Range: to.addRange(event.from, event.to, event.range_m, event.t_s); break;
        case RobotEvent::Kind::Motion: to.setMoving(event.id, event.moving, event.t_s); break;
        }
    };
    size_t next = 0;
    for (; next < world.events.size() && world.events[next].t_s < 33.0; ++next) {
        apply(stage, world.events[next]);
    }
    ASSERT_TRUE(stage.robot()->localized) << "the EKF has not started by the save";
    Engine restored_engine = engine; // stage 1 copied (its own checkpoint is tested in tests/hostd)
    MovementStage restored(restored_engine, params);
    restored.restore(stage.saved());
    Engine fresh_engine = engine; // what a resume did before: stage 2 started afresh
    MovementStage fresh(fresh_engine, params);
    double fresh_apart_m = 0.0;
    for (; next < world.events.size(); ++next) {
        apply(stage, world.events[next]);
        apply(restored, world.events[next]);
        apply(fresh, world.events[next]);
        if (world.events[next].kind == RobotEvent::Kind::Odometry) {
            ASSERT_TRUE(sameRobot(*stage.robot(), *restored.robot())) << "at t " << world.events[next].t_s << " s";
            const Pose2 a = stage.robot()->pose;
            const Pose2 b = fresh.robot()->pose;
            fresh_apart_m = std::max(fresh_apart_m, std::hypot(a.x_m - b.x_m, a.y_m - b.y_m));
        }
    }
    EXPECT_TRUE(identical(stage.estimates(), restored.estimates()));
    EXPECT_EQ(std::memcmp(&stage.counters(), &restored.counters(), sizeof(engine::MovementCounters)), 0);
    // The comparison can fail: a stage started afresh at the same point does not follow the same path.
    EXPECT_GT(fresh_apart_m, 0.01);
}

TEST(MovementStage, TheSameInputsGiveBitIdenticalOutputs)
{
    const uint64_t seed = testSeed(5105);
    SCOPED_TRACE(seedTrace(seed));
    // Every path of the stage: the heading bank, a carried node, then (below) beacon rings.
    RobotWorldSpec spec = lShapeInAMap();
    spec.carry = Carry{16, 50.0, 55.0, Vector2(10.0, 11.0)};
    const RobotWorld world = simulateRobot(spec, seed);
    const std::vector<size_t> snapshots = {indexAt(30.0), indexAt(45.0), indexAt(52.0), indexAt(70.0)};
    const StageRun first = runStage(world, snapshots);
    const StageRun second = runStage(world, snapshots);
    ASSERT_EQ(first.robot.size(), world.robot_truth.size());
    EXPECT_EQ(firstDifference(first, second), first.robot.size());
    ASSERT_EQ(first.snapshots.size(), second.snapshots.size());
    for (size_t k = 0; k < first.snapshots.size(); ++k) {
        EXPECT_TRUE(identical(first.snapshots[k], second.snapshots[k])) << "snapshot " << k;
    }
    EXPECT_TRUE(identical(first.final_estimates, second.final_estimates));
    EXPECT_EQ(std::memcmp(&first.counters, &second.counters, sizeof first.counters), 0);

    // The comparison can fail: one range 1 mm longer after the robot started changes the outputs
    // from there on, and not before.
    RobotWorld changed = world;
    size_t changed_event = 0;
    for (size_t i = 0; i < changed.events.size(); ++i) {
        if (changed.events[i].kind == RobotEvent::Kind::Range && changed.events[i].from == spec.robot_id &&
            changed.events[i].t_s > 30.0) {
            changed.events[i].range_m += 0.001;
            changed_event = i;
            break;
        }
    }
    const StageRun third = runStage(changed, snapshots);
    const size_t differs_at = firstDifference(first, third);
    EXPECT_LT(differs_at, first.robot.size());
    EXPECT_GE(static_cast<double>(differs_at + 1) * kOdometryTickS, changed.events[changed_event].t_s);
    EXPECT_FALSE(identical(first.final_estimates, third.final_estimates));

    // And the no-map path (beacon rings around the robot).
    const RobotWorld loop = simulateRobot(loopAmongBeacons(), seed);
    const StageRun a = runStage(loop, {indexAt(20.0)});
    const StageRun b = runStage(loop, {indexAt(20.0)});
    EXPECT_EQ(firstDifference(a, b), a.robot.size());
    ASSERT_EQ(a.snapshots.size(), 1U);
    ASSERT_EQ(b.snapshots.size(), 1U);
    EXPECT_TRUE(identical(a.snapshots[0], b.snapshots[0]));
    EXPECT_TRUE(identical(a.final_estimates, b.final_estimates));
}

} // namespace
} // namespace cdro::enginetest
