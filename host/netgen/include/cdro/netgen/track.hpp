// track.hpp: a node's motion: where it is at any time and what its accelerometer reads. The
// C++ model of a carried node, for the firmware-in-the-loop harness (cdro-fil) and whatever else
// simulates a node that someone picks up and carries; the scenario files' `motion[]` stretches
// (docs/tools.md, "Scenario files") map onto it one to one. (robot_world.hpp's carried node keeps
// its own straight line between two times: it leaves the node at from + 1 * (to - from) after the
// stop, which is not `to` to the bit for every pair of points, and its outputs are pinned.)
//
// The node stands at its start position until its first stretch. A stretch carries it from where
// it is at start_s through its waypoints in straight legs at one constant speed, given or
// following from the path's length and the stretch's end time; it then stands at the last
// waypoint until its next stretch. Time is seconds from the start of the simulation.
//
// The accelerometer (mg, body frame = world frame, gravity included) reads exactly (0, 0, 1000)
// at rest; while carried, the bounce of a walking person (see Gait), whose norm swings about
// 1 g by about the bounce amplitude. Sensor noise is the simulator's, not the track's.
#pragma once

#include <optional>
#include <vector>

#include "cdro/netgen/world.hpp"

namespace cdro::netgen {

// A point a stretch passes through; without z the node keeps the height of its start position.
struct Waypoint {
    double x_m = 0.0;
    double y_m = 0.0;
    std::optional<double> z_m; // m
};

// One carried stretch. Give the speed, or leave it 0 and give the end time: the speed is then
// the path's length over end_s - start_s.
struct Stretch {
    double start_s = 0.0;
    double speed_mps = 0.0;
    double end_s = 0.0; // s, used only when speed_mps is 0
    std::vector<Waypoint> waypoints;
};

// How a carried node's accelerometer moves: the vertical bounce at the step frequency, a surge
// along the walking direction (0.3 of the bounce) and a sway across it (0.2, at half the step
// frequency), in phase with the start of the stretch.
struct Gait {
    double amplitude_mg = 250.0; // mg, vertical bounce
    double frequency_hz = 1.8;   // Hz, steps
};

class Track {
public:
    struct Leg {
        double t0_s = 0.0; // s: leaves `from_m` at t0_s, reaches `to_m` at t1_s
        double t1_s = 0.0;
        Vector3 from_m = Vector3::Zero();
        Vector3 to_m = Vector3::Zero();
        double stretch_start_s = 0.0; // s: start of the stretch this leg belongs to (the gait's phase)
    };

    // A span of time the node is carried without stopping: back-to-back legs, even of several
    // stretches, make one span.
    struct Span {
        double from_s = 0.0;
        double to_s = 0.0;
        double length_m = 0.0;
    };

    // A standing node.
    explicit Track(const Vector3 &start_m);
    // Stretches in any order. Throws std::invalid_argument naming the stretch when one cannot be
    // walked: no waypoints, a coordinate, time or speed that is not finite, a speed that is not
    // positive (given, or from an end time that is not after the start), or a stretch that starts
    // before the previous one ends.
    Track(const Vector3 &start_m, std::vector<Stretch> stretches, const Gait &gait);

    Vector3 positionM(double t_s) const;
    // The leg being walked at t_s, or nullptr when the node stands still.
    const Leg *legAt(double t_s) const;
    bool moving(double t_s) const { return legAt(t_s) != nullptr; }
    // mg: (0, 0, 1000) at rest.
    Vector3 accelMg(double t_s) const;

    const std::vector<Leg> &legs() const { return legs_; }
    std::vector<Span> spans() const;

private:
    Vector3 start_m_;
    std::vector<Leg> legs_;
    Gait gait_;
};

} // namespace cdro::netgen
