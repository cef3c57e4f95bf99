#include "cdro/netgen/robot_world.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace cdro::netgen {

using engine::OdometryStep;
using engine::Pose2;
using engine::predictOdometry;

namespace {

void require(bool condition, const std::string &what)
{
    if (!condition) {
        throw std::invalid_argument("robot world: " + what);
    }
}

void validate(const RobotWorldSpec &spec)
{
    require(spec.truth_m.size() == spec.ids.size(), "truth_m has " + std::to_string(spec.truth_m.size()) +
                                                        " positions for " + std::to_string(spec.ids.size()) + " ids");
    require(spec.height_m.size() == spec.ids.size(), "height_m has " + std::to_string(spec.height_m.size()) +
                                                         " heights for " + std::to_string(spec.ids.size()) + " ids");
    for (const auto &[a, b] : spec.links) {
        require(a < spec.ids.size() && b < spec.ids.size() && a != b,
                "link (" + std::to_string(a) + ", " + std::to_string(b) + ") is not a pair of the " +
                    std::to_string(spec.ids.size()) + " nodes");
    }
    require(spec.stand_s >= 0.0 && spec.end_stand_s >= 0.0, "a negative standing time");
    for (const DriveSegment &segment : spec.drive) {
        require(segment.duration_s >= 0.0, "a drive segment of negative duration");
    }
    require(spec.range_noise_m >= 0.0 && spec.distance_noise_fraction >= 0.0 && spec.heading_noise_rad >= 0.0,
            "a negative noise standard deviation");
    if (spec.carry) {
        require(std::find(spec.ids.begin(), spec.ids.end(), spec.carry->id) != spec.ids.end(),
                "the carried node " + std::to_string(spec.carry->id) + " is not one of the nodes");
        require(spec.carry->stop_s > spec.carry->start_s, "the carry stops at " + std::to_string(spec.carry->stop_s) +
                                                              " s, not after it starts at " +
                                                              std::to_string(spec.carry->start_s) + " s");
    }
}

} // namespace

Vector2 nodePositionM(const RobotWorldSpec &spec, size_t node, double t_s)
{
    if (spec.carry && spec.carry->id == spec.ids[node] && t_s > spec.carry->start_s) {
        const double f = std::min((t_s - spec.carry->start_s) / (spec.carry->stop_s - spec.carry->start_s), 1.0);
        return spec.truth_m[node] + f * (spec.carry->to_m - spec.truth_m[node]);
    }
    return spec.truth_m[node];
}

RobotWorld simulateRobot(const RobotWorldSpec &spec, uint64_t seed)
{
    validate(spec);
    Random random(seed);
    RobotWorld world;
    world.spec = spec;
    std::vector<DriveSegment> plan;
    plan.push_back({spec.stand_s, 0.0, 0.0});
    plan.insert(plan.end(), spec.drive.begin(), spec.drive.end());
    plan.push_back({spec.end_stand_s, 0.0, 0.0});
    Pose2 truth = spec.robot_start;
    Pose2 dead = spec.robot_start;
    size_t next_robot_node = 0;
    size_t next_link = 0;
    bool carry_started = false;
    bool carry_stopped = false;
    long tick = 0;
    for (const DriveSegment &segment : plan) {
        const long ticks = std::lround(segment.duration_s / kOdometryTickS);
        for (long k = 0; k < ticks; ++k, ++tick) {
            const double t_s = static_cast<double>(tick + 1) * kOdometryTickS;
            const OdometryStep true_step{segment.speed_mps * kOdometryTickS, segment.turn_rate_rad_s * kOdometryTickS};
            truth = predictOdometry(truth, true_step).pose;
            const bool moving = true_step.distance_m != 0.0 || true_step.dheading_rad != 0.0;
            OdometryStep measured = true_step;
            if (moving) { // a standing robot's wheels report nothing
                measured.distance_m *= 1.0 + spec.distance_noise_fraction * random.normal();
                measured.dheading_rad +=
                    spec.heading_noise_rad * random.normal() + spec.heading_drift_rad_s * kOdometryTickS;
            }
            dead = predictOdometry(dead, measured).pose;
            RobotEvent odometry;
            odometry.kind = RobotEvent::Kind::Odometry;
            odometry.t_s = t_s;
            odometry.step = measured;
            world.events.push_back(odometry);
            world.robot_truth.push_back(truth);
            world.dead_reckoning.push_back(dead);
            if (spec.carry && !carry_started && t_s >= spec.carry->start_s) {
                carry_started = true;
                world.events.push_back({RobotEvent::Kind::Motion, t_s, {}, 0, 0, 0.0, spec.carry->id, true});
            }
            if (spec.carry && carry_started && !carry_stopped && t_s >= spec.carry->stop_s) {
                carry_stopped = true;
                world.events.push_back({RobotEvent::Kind::Motion, t_s, {}, 0, 0, 0.0, spec.carry->id, false});
            }
            const Vector2 robot_m(truth.x_m, truth.y_m);
            auto range = [&](const Vector2 &a_m, double a_height_m, const Vector2 &b_m, double b_height_m) {
                const double dz_m = a_height_m - b_height_m;
                const double distance_m = std::sqrt((a_m - b_m).squaredNorm() + dz_m * dz_m);
                return spec.range_scale * distance_m + spec.range_noise_m * random.normal();
            };
            for (size_t r = 0; r < spec.robot_ranges_per_tick; ++r) {
                // Spread over the tick's first 0.03 s; the last one at t + 0.03 s.
                const double range_t_s =
                    t_s + 0.03 * static_cast<double>(r + 1) / static_cast<double>(spec.robot_ranges_per_tick);
                for (size_t tries = 0; tries < spec.ids.size(); ++tries) {
                    const size_t node = next_robot_node;
                    next_robot_node = (next_robot_node + 1) % spec.ids.size();
                    const Vector2 node_m = nodePositionM(spec, node, t_s);
                    if ((node_m - robot_m).norm() <= spec.robot_max_range_m) {
                        const double range_m = range(robot_m, spec.robot_height_m, node_m, spec.height_m[node]);
                        world.events.push_back(
                            {RobotEvent::Kind::Range, range_t_s, {}, spec.robot_id, spec.ids[node], range_m, 0, false});
                        break;
                    }
                }
            }
            if (!spec.links.empty()) {
                const auto [a, b] = spec.links[next_link];
                next_link = (next_link + 1) % spec.links.size();
                world.events.push_back({RobotEvent::Kind::Range,
                                        t_s + 0.06,
                                        {},
                                        spec.ids[a],
                                        spec.ids[b],
                                        range(nodePositionM(spec, a, t_s), spec.height_m[a],
                                              nodePositionM(spec, b, t_s), spec.height_m[b]),
                                        0,
                                        false});
            }
        }
    }
    const double end_s = static_cast<double>(tick) * kOdometryTickS;
    for (size_t i = 0; i < spec.ids.size(); ++i) {
        world.final_truth_m.push_back(nodePositionM(spec, i, end_s));
    }
    return world;
}

} // namespace cdro::netgen
