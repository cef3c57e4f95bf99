// moving_calibration.hpp: static anchors whose positions are not given, calibrated from the ranges
// of moving nodes alone (docs/engine.md, "Nodes that never stop: anchors not given").
//
// The data: ranges between moving nodes (tags) and static anchors, and between tags; none between
// anchors. Unknowns: each anchor's position (x, y, z; z given when its height is known) and each
// tag's position at each time it ranged (an epoch). A batch solve, in three steps:
//   1. virtual static nodes: a tag's ranges within one window of window_s form one node (the tag
//      moves less than the window's extent), so that anchors and windows are a bipartite static
//      network (plus the tag-to-tag edges); each edge's length is the median of its ranges;
//   2. initialisation, without any position: the shortest-path distances over that graph stand in
//      for the missing ones (MDS-MAP), classical MDS places every node connected to the anchors in
//      3D; the anchors' best-fit plane becomes horizontal, its normal turned so that the windows
//      lie below the anchors (the tags fly under anchors on walls and ceilings: the mirror image
//      through the plane fits the ranges as well), and the plane is put at the anchors' mean given
//      height (or unknown_plane_height_m when no height is given); then the static network
//      (anchors + windows, every range its own residual) is refined by a robust least squares;
//   3. the batch: every epoch starts at its window's position, and anchors + epochs are refined
//      together: each range a residual (Huber loss, range_sigma_m; a range read long behind an
//      obstacle costs linearly), consecutive epochs of a tag tied by the tracker's motion prior
//      (each velocity component an Ornstein-Uhlenbeck process, MotionParams::flight_speed_sigma_mps
//      and flight_speed_tau_s, its position increment over dt: variance 2 s^2 tau^2 (dt/tau - 1 +
//      exp(-dt/tau)) per axis).
// The least squares are Levenberg-Marquardt on sparse normal equations (the damping also holds the
// gauge: the solution is known up to a rotation about the vertical, a translation and a
// reflection when the heights are given, a rigid motion otherwise; the caller's frame is the
// solution's own). Deterministic: no clock, no randomness, a fixed order everywhere.
#pragma once

#include <cstdint>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "cdro/engine/params.hpp"
#include "cdro/engine/types.hpp"

namespace cdro::engine {

struct MovingCalibrationParams {
    // s, a tag's ranges within one window: one virtual static node. Chosen on the simulated flights
    // of scripts/flights_sim.py (seeds 1-5, 1000 iterations; the anchors' aligned RMSE on the sparse
    // schedule: 1 s 0.74 m, 2 s 0.41 m, 4 s 0.38 m, 6 s 0.39 m; on the dense one 0.075 m with any).
    double window_s = 4.0;
    double range_sigma_m = 0.10;         // m, the ranges' noise in the least squares
    double huber_sigmas = 2.0;           // the loss is quadratic within this many sigmas, linear beyond
    uint32_t max_iterations = 1000;      // per least-squares step (200 stopped the sparse flights early)
    double unknown_plane_height_m = 1.8; // m, the anchors' mean height when none is given (the frame's z)
    double min_prior_sigma_m = 1e-3;     // m, the motion prior's smallest sigma (two ranges at one time)
};

struct CalibrationRange {
    double t_s = 0.0; // s
    NodeId a = 0;
    NodeId b = 0;
    double range_m = 0.0; // m
};

struct CalibratedAnchor {
    NodeId id = 0;
    Eigen::Vector3d position_m = Eigen::Vector3d::Zero(); // m, the solution's frame
    bool height_given = false;
};

struct CalibratedEpoch {
    NodeId id = 0;
    double t_s = 0.0;                                     // s
    Eigen::Vector3d position_m = Eigen::Vector3d::Zero(); // m
};

struct MovingCalibrationCounters {
    uint64_t ranges = 0;            // ranges used (tag-anchor and tag-tag)
    uint64_t ignored = 0;           // ranges between two static nodes or of a bad value: not used
    uint64_t windows = 0;           // virtual static nodes (a tag's windows with a range)
    uint64_t windows_placed = 0;    // ... of those connected to the anchors, placed by the MDS
    uint64_t epochs = 0;            // tag positions solved in the batch
    uint32_t static_iterations = 0; // step 2's refinement
    uint32_t batch_iterations = 0;  // step 3
    uint64_t outliers = 0;          // ranges beyond huber_sigmas at the end (down-weighted by the loss)
    double rms_residual_m = 0.0;    // m, the RMS of the ranges' residuals at the end
};

class MovingCalibration {
public:
    MovingCalibration(const MovingCalibrationParams &params, const MotionParams &motion);

    // ranges: any order; moving: the tags (every other node ranged by a tag is a static anchor);
    // heights: (id, m) for the anchors whose height is known. Returns the anchors in id order.
    // Throws std::invalid_argument, naming what is wrong, for fewer than 4 anchors, a tag
    // without a range, or anchors the ranges do not connect.
    std::vector<CalibratedAnchor> solve(const std::vector<CalibrationRange> &ranges, const std::vector<NodeId> &moving,
                                        const std::vector<std::pair<NodeId, double>> &heights);

    // The batch's tag positions (in the tags' order, then time), after solve.
    const std::vector<CalibratedEpoch> &epochs() const { return epochs_; }
    const MovingCalibrationCounters &counters() const { return counters_; }

private:
    MovingCalibrationParams params_;
    MotionParams motion_;
    std::vector<CalibratedEpoch> epochs_;
    MovingCalibrationCounters counters_;
};

} // namespace cdro::engine
