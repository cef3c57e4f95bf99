// The robot world (robot_world.hpp): the robot drives what the spec says, the ranges and the
// odometry err as the spec says and no otherwise, a carried node goes where it is taken with its
// motion reports, a seed is a world, and a spec that cannot be simulated is refused by name.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "cdro/netgen/robot_world.hpp"

namespace cdro::netgen {
namespace {

constexpr double kPi = 3.14159265358979323846;

// Four nodes at the corners of a 20 x 16 m room, all linked; the robot stands 2 s, drives 10 m
// east, a left quarter turn, 6 m north, and stands 1 s.
RobotWorldSpec room()
{
    RobotWorldSpec spec;
    spec.ids = {11, 12, 13, 14};
    spec.truth_m = {{-5.0, -4.0}, {15.0, -4.0}, {15.0, 12.0}, {-5.0, 12.0}};
    spec.height_m = {2.0, 2.4, 1.6, 2.2};
    spec.links = {{0, 1}, {0, 2}, {0, 3}, {1, 2}, {1, 3}, {2, 3}};
    spec.robot_start = engine::Pose2{0.0, 0.0, 0.0};
    spec.stand_s = 2.0;
    spec.drive = {{20.0, 0.5, 0.0}, {kPi, 0.2, 0.5}, {12.0, 0.5, 0.0}};
    spec.end_stand_s = 1.0;
    return spec;
}

// Without noise: exact odometry, exact ranges.
RobotWorldSpec exact(RobotWorldSpec spec)
{
    spec.range_noise_m = 0.0;
    spec.range_scale = 1.0;
    spec.distance_noise_fraction = 0.0;
    spec.heading_noise_rad = 0.0;
    spec.heading_drift_rad_s = 0.0;
    return spec;
}

bool sameBits(double a, double b) { return std::memcmp(&a, &b, sizeof a) == 0; }

bool sameEvents(const RobotWorld &a, const RobotWorld &b)
{
    if (a.events.size() != b.events.size()) {
        return false;
    }
    for (size_t i = 0; i < a.events.size(); ++i) {
        const RobotEvent &x = a.events[i];
        const RobotEvent &y = b.events[i];
        if (x.kind != y.kind || !sameBits(x.t_s, y.t_s) || !sameBits(x.step.distance_m, y.step.distance_m) ||
            !sameBits(x.step.dheading_rad, y.step.dheading_rad) || x.from != y.from || x.to != y.to ||
            !sameBits(x.range_m, y.range_m) || x.id != y.id || x.moving != y.moving) {
            return false;
        }
    }
    return true;
}

double distance3dM(const Vector2 &a_m, double a_height_m, const Vector2 &b_m, double b_height_m)
{
    const double dz_m = a_height_m - b_height_m;
    return std::sqrt((a_m - b_m).squaredNorm() + dz_m * dz_m);
}

TEST(RobotWorld, ASeedIsAWorld)
{
    const RobotWorld first = simulateRobot(room(), 3);
    EXPECT_TRUE(sameEvents(first, simulateRobot(room(), 3)));
    EXPECT_FALSE(sameEvents(first, simulateRobot(room(), 4)));
}

TEST(RobotWorld, WithoutNoiseTheRobotDrivesItsPlanAndEveryRangeIsTheTrueDistance)
{
    const RobotWorldSpec spec = exact(room());
    const RobotWorld world = simulateRobot(spec, 1);

    // Ticks: 2 s + 20 s + pi s (31 ticks) + 12 s + 1 s.
    const size_t ticks = 20 + 200 + 31 + 120 + 10;
    ASSERT_EQ(world.robot_truth.size(), ticks);
    ASSERT_EQ(world.dead_reckoning.size(), ticks);
    // Standing: the wheels report exactly nothing, the robot is where it started.
    for (size_t i = 0; i < 20; ++i) {
        EXPECT_EQ(world.robot_truth[i].x_m, 0.0);
        EXPECT_EQ(world.robot_truth[i].y_m, 0.0);
    }
    // 10 m east, then a quarter turn of radius 0.4 m (31 ticks of 0.05 rad: 1.55 rad), then 6 m
    // along the new heading.
    EXPECT_NEAR(world.robot_truth[219].x_m, 10.0, 1e-9);
    EXPECT_NEAR(world.robot_truth[219].y_m, 0.0, 1e-9);
    EXPECT_NEAR(world.robot_truth[250].heading_rad, 31 * 0.05, 1e-9);
    EXPECT_NEAR(world.robot_truth.back().heading_rad, 31 * 0.05, 1e-9);
    const double turned_m = std::hypot(world.robot_truth.back().x_m - world.robot_truth[250].x_m,
                                       world.robot_truth.back().y_m - world.robot_truth[250].y_m);
    EXPECT_NEAR(turned_m, 6.0, 1e-9);

    size_t odometry = 0;
    size_t robot_ranges = 0;
    size_t link_ranges = 0;
    double last_t_s = 0.0;
    for (const RobotEvent &event : world.events) {
        EXPECT_GE(event.t_s, last_t_s); // in time order
        last_t_s = event.t_s;
        if (event.kind == RobotEvent::Kind::Odometry) {
            ++odometry;
            // Exact odometry: dead reckoning is the truth.
            EXPECT_EQ(world.dead_reckoning[odometry - 1].x_m, world.robot_truth[odometry - 1].x_m);
            EXPECT_EQ(world.dead_reckoning[odometry - 1].y_m, world.robot_truth[odometry - 1].y_m);
            continue;
        }
        ASSERT_EQ(event.kind, RobotEvent::Kind::Range);
        const auto node = [&](NodeId id) {
            return static_cast<size_t>(std::find(spec.ids.begin(), spec.ids.end(), id) - spec.ids.begin());
        };
        if (event.from == spec.robot_id) {
            // Round robin over the nodes: the k-th robot range is to node k mod 4.
            EXPECT_EQ(node(event.to), robot_ranges % spec.ids.size());
            ++robot_ranges;
            const engine::Pose2 &robot = world.robot_truth[odometry - 1];
            const size_t to = node(event.to);
            EXPECT_NEAR(event.range_m,
                        distance3dM(Vector2(robot.x_m, robot.y_m), spec.robot_height_m, spec.truth_m[to],
                                    spec.height_m[to]),
                        1e-12);
        } else {
            // Round robin over the links, in their order.
            const auto [a, b] = spec.links[link_ranges % spec.links.size()];
            EXPECT_EQ(event.from, spec.ids[a]);
            EXPECT_EQ(event.to, spec.ids[b]);
            ++link_ranges;
            EXPECT_NEAR(event.range_m,
                        distance3dM(spec.truth_m[a], spec.height_m[a], spec.truth_m[b], spec.height_m[b]), 1e-12);
        }
    }
    EXPECT_EQ(odometry, ticks);
    EXPECT_EQ(robot_ranges, ticks); // one a tick, every node within reach
    EXPECT_EQ(link_ranges, ticks);
}

TEST(RobotWorld, TheRobotRangesOnlyTheNodesWithinItsReach)
{
    RobotWorldSpec spec = exact(room());
    spec.robot_max_range_m = 9.0; // the robot's path passes within 9 m of nodes 11 (at first) and 12 (on the way)
    const RobotWorld world = simulateRobot(spec, 1);
    size_t to_11 = 0;
    size_t to_12 = 0;
    size_t odometry = 0;
    for (const RobotEvent &event : world.events) {
        odometry += event.kind == RobotEvent::Kind::Odometry ? 1U : 0U;
        if (event.kind != RobotEvent::Kind::Range || event.from != spec.robot_id) {
            continue;
        }
        const size_t to = static_cast<size_t>(std::find(spec.ids.begin(), spec.ids.end(), event.to) - spec.ids.begin());
        const engine::Pose2 &robot = world.robot_truth[odometry - 1];
        EXPECT_LE((spec.truth_m[to] - Vector2(robot.x_m, robot.y_m)).norm(), 9.0) << "node " << event.to;
        to_11 += event.to == 11 ? 1U : 0U;
        to_12 += event.to == 12 ? 1U : 0U;
    }
    EXPECT_GT(to_11, 0U);
    EXPECT_GT(to_12, 0U);
}

TEST(RobotWorld, SeveralRobotRangesATickGoRoundRobinWithinTheTick)
{
    RobotWorldSpec spec = exact(room());
    spec.robot_ranges_per_tick = 3;
    const RobotWorld world = simulateRobot(spec, 1);
    size_t robot_ranges = 0;
    double tick_s = 0.0;
    size_t in_tick = 0;
    for (const RobotEvent &event : world.events) {
        if (event.kind == RobotEvent::Kind::Odometry) {
            EXPECT_TRUE(tick_s == 0.0 || in_tick == 3) << "at t " << tick_s << " s";
            tick_s = event.t_s;
            in_tick = 0;
        } else if (event.kind == RobotEvent::Kind::Range && event.from == spec.robot_id) {
            EXPECT_EQ(event.to, spec.ids[robot_ranges % spec.ids.size()]);
            EXPECT_GT(event.t_s, tick_s);
            EXPECT_LE(event.t_s, tick_s + 0.03 + 1e-9);
            ++robot_ranges;
            ++in_tick;
        }
    }
    EXPECT_EQ(robot_ranges, 3 * world.robot_truth.size());
}

TEST(RobotWorld, TheNoiseIsTheSpecsNoise)
{
    const uint64_t seed = 7;
    std::printf("seed %llu\n", static_cast<unsigned long long>(seed));
    RobotWorldSpec spec = room();
    spec.drive = {{400.0, 0.05, 0.0}}; // 20 m east, slowly: 4000 steps to measure the odometry's noise on
    const RobotWorld world = simulateRobot(spec, seed);
    const RobotWorld truth = simulateRobot(exact(spec), seed);
    ASSERT_EQ(world.events.size(), truth.events.size());
    double sum = 0.0;
    double sum2 = 0.0;
    size_t ranges = 0;
    double distance_sum = 0.0;
    double distance_sum2 = 0.0;
    double heading_sum = 0.0;
    size_t steps = 0;
    for (size_t i = 0; i < world.events.size(); ++i) {
        const RobotEvent &noisy = world.events[i];
        const RobotEvent &exact_event = truth.events[i];
        if (noisy.kind == RobotEvent::Kind::Range) {
            const double residual_m = noisy.range_m - spec.range_scale * exact_event.range_m;
            sum += residual_m;
            sum2 += residual_m * residual_m;
            ++ranges;
        } else if (noisy.kind == RobotEvent::Kind::Odometry && exact_event.step.distance_m != 0.0) {
            const double ratio = noisy.step.distance_m / exact_event.step.distance_m - 1.0;
            distance_sum += ratio;
            distance_sum2 += ratio * ratio;
            heading_sum += noisy.step.dheading_rad - exact_event.step.dheading_rad;
            ++steps;
        }
    }
    const double n = static_cast<double>(ranges);
    const double mean_m = sum / n;
    const double sigma_m = std::sqrt(sum2 / n - mean_m * mean_m);
    const double distance_mean = distance_sum / static_cast<double>(steps);
    const double distance_sigma = std::sqrt(distance_sum2 / static_cast<double>(steps) - distance_mean * distance_mean);
    const double drift_rad_s = heading_sum / (static_cast<double>(steps) * kOdometryTickS);
    std::printf("%zu ranges: noise mean %.4f m, std %.4f m; %zu steps: distance error mean %.5f, std %.4f, heading "
                "drift %.5f rad/s\n",
                ranges, mean_m, sigma_m, steps, distance_mean, distance_sigma, drift_rad_s);
    // 8060 ranges: the mean within 4.5 standard errors (0.0011 m each), the std within 5 %.
    EXPECT_NEAR(mean_m, 0.0, 0.005);
    EXPECT_NEAR(sigma_m, spec.range_noise_m, 0.005);
    EXPECT_NEAR(distance_mean, 0.0, 0.0015); // a standard error of 0.0003
    EXPECT_NEAR(distance_sigma, spec.distance_noise_fraction, 0.001);
    // The drift, 5 mrad/s, under a per-step noise of 3 mrad: its mean over 4000 steps has a standard error
    // of 0.0005 rad/s.
    EXPECT_NEAR(drift_rad_s, spec.heading_drift_rad_s, 0.0015);
    // The dead reckoning drifts off the truth (the heading bias alone turns it 2 rad in 400 s).
    EXPECT_GT(std::hypot(world.dead_reckoning.back().x_m - world.robot_truth.back().x_m,
                         world.dead_reckoning.back().y_m - world.robot_truth.back().y_m),
              1.0);
}

TEST(RobotWorld, ACarriedNodeGoesWhereItIsTakenWithItsMotionReports)
{
    RobotWorldSpec spec = exact(room());
    spec.carry = Carry{13, 10.0, 14.0, Vector2(11.0, 12.0)};
    const RobotWorld world = simulateRobot(spec, 1);
    EXPECT_EQ(nodePositionM(spec, 2, 10.0), Vector2(15.0, 12.0));
    EXPECT_NEAR((nodePositionM(spec, 2, 12.0) - Vector2(13.0, 12.0)).norm(), 0.0, 1e-12); // half way
    EXPECT_EQ(nodePositionM(spec, 2, 30.0), Vector2(11.0, 12.0));
    EXPECT_EQ(nodePositionM(spec, 0, 12.0), spec.truth_m[0]); // the others stay
    EXPECT_EQ(world.final_truth_m[2], Vector2(11.0, 12.0));
    EXPECT_EQ(world.final_truth_m[0], spec.truth_m[0]);

    std::vector<std::pair<double, bool>> reports;
    for (const RobotEvent &event : world.events) {
        if (event.kind == RobotEvent::Kind::Motion) {
            EXPECT_EQ(event.id, 13);
            reports.emplace_back(event.t_s, event.moving);
        }
        // The carried node's ranges follow it.
        if (event.kind == RobotEvent::Kind::Range && event.from == 12 && event.to == 13) {
            const double t_s = event.t_s - 0.06; // the tick it was drawn in
            EXPECT_NEAR(event.range_m,
                        distance3dM(spec.truth_m[1], spec.height_m[1], nodePositionM(spec, 2, t_s), spec.height_m[2]),
                        1e-9);
        }
    }
    ASSERT_EQ(reports.size(), 2U);
    EXPECT_NEAR(reports[0].first, 10.0, 1e-9);
    EXPECT_TRUE(reports[0].second);
    EXPECT_NEAR(reports[1].first, 14.0, 1e-9);
    EXPECT_FALSE(reports[1].second);
}

// The message of the std::invalid_argument that simulating `spec` throws ("" when none).
std::string refusal(const RobotWorldSpec &spec)
{
    try {
        simulateRobot(spec, 1);
    } catch (const std::invalid_argument &error) {
        return error.what();
    }
    return "";
}

TEST(RobotWorld, ASpecThatCannotBeSimulatedIsRefusedSayingWhy)
{
    EXPECT_EQ(refusal(room()), "");
    RobotWorldSpec spec = room();
    spec.height_m.pop_back();
    EXPECT_NE(refusal(spec).find("height_m has 3 heights for 4 ids"), std::string::npos) << refusal(spec);
    spec = room();
    spec.truth_m.push_back(Vector2::Zero());
    EXPECT_NE(refusal(spec).find("truth_m has 5 positions for 4 ids"), std::string::npos) << refusal(spec);
    spec = room();
    spec.links.emplace_back(1, 4);
    EXPECT_NE(refusal(spec).find("link (1, 4)"), std::string::npos) << refusal(spec);
    spec = room();
    spec.carry = Carry{99, 1.0, 2.0, Vector2::Zero()};
    EXPECT_NE(refusal(spec).find("carried node 99"), std::string::npos) << refusal(spec);
    spec = room();
    spec.carry = Carry{12, 5.0, 5.0, Vector2::Zero()};
    EXPECT_NE(refusal(spec).find("stops"), std::string::npos) << refusal(spec);
    spec = room();
    spec.drive.push_back({-1.0, 0.5, 0.0});
    EXPECT_NE(refusal(spec).find("negative duration"), std::string::npos) << refusal(spec);
    spec = room();
    spec.range_noise_m = -0.1;
    EXPECT_NE(refusal(spec).find("negative noise"), std::string::npos) << refusal(spec);
}

} // namespace
} // namespace cdro::netgen
