// map_refine.hpp: every placed node of a map at once, by robust Levenberg-Marquardt over every
// link, and the map's covariance.
//
// One sparse 2M x 2M system per iteration (Eigen's sparse LDL^T, the pattern analysed once per
// solve); iteratively reweighted least squares with the weights of the robust likelihood
// (RangeLikelihood::irlsWeight) and the true slope of the cost in the gradient; damping that
// adapts (a step that does not lower the cost is refused and the damping raised); graduated
// non-convexity (the noise seen as larger in the first stages, so that a disagreeing link still
// pulls before it is written off as NLOS). Fixed nodes stay where they are; without two of them
// the gauge (rotation, translation) is free and the damping keeps the system regular.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "cdro/engine/map_problem.hpp"

namespace cdro::engine {

// One stage of graduated non-convexity: the noise seen as larger, and the NLOS term as more
// likely and longer (so that a link reading long pulls the map less than in the end).
struct RefineStage {
    double sigma_scale = 1.0;         // multiple of the noise
    double nlos_fraction = -1.0;      // < 0: the likelihood's own
    double nlos_mean_excess_m = -1.0; // m; < 0: the likelihood's own
};

struct MapRefineParams {
    std::vector<RefineStage> stages{{8.0, 0.5, 3.0}, {4.0, 0.3, 2.0}, {2.0, -1.0, -1.0}, {1.0, -1.0, -1.0}};
    uint32_t iterations_per_stage = 12; // LM iterations per stage (the last stage: 3x)
    double initial_damping = 1e-4;      // lambda, relative to the diagonal
    double step_tolerance_m = 1e-5;     // m, a stage ends when every node moved less
};

struct MapRefineResult {
    double cost = 0.0;       // nats at the nominal noise
    uint32_t iterations = 0; // accepted steps
    uint32_t refused = 0;    // steps that did not lower the cost
};

// Moves the placed, not fixed nodes of `estimate` to the robust optimum near where they are.
MapRefineResult refineMap(const MapProblem &problem, MapEstimate &estimate, const RangeLikelihood &likelihood,
                          const MapRefineParams &params = {});

// The most dimensions an embedding may have (map_lift.hpp clamps its D to it).
constexpr uint32_t kMaxEmbeddingDimensions = 8;

// The same on an embedding in 2 <= D <= kMaxEmbeddingDimensions dimensions (one row per node), with an optional penalty
// squeeze_per_m2 * |x_{2..D-1}|^2 per node on the coordinates beyond the plane (map_lift.hpp); one
// LM run per stage. Returns the cost at the nominal noise without the penalty.
MapRefineResult refineEmbedding(const MapProblem &problem, const std::vector<uint8_t> &placed,
                                Eigen::MatrixXd &positions, const RangeLikelihood &likelihood,
                                const std::vector<RefineStage> &stages, uint32_t iterations_per_stage,
                                double squeeze_per_m2, const MapRefineParams &params);

// Baarda's delta0 (a blunder this many of its standard deviations is found with 80 % power at
// a 0.1 % test level); geodesy's usual value, rounded.
constexpr double kReliabilityDelta = 4.0;
// A link whose redundancy is below this is not checked by the others.
constexpr double kCheckedRedundancy = 0.02;
// The frame of the covariances is the main part's nodes that no single unnoticed error moves by
// more than this (m).
constexpr double kReliableCoreM = 1.0;

struct MapCovariance {
    std::vector<Matrix2> covariance_m2;    // per node (zero for unplaced and fixed nodes), m^2
    std::vector<Matrix2> shared_excess_m2; // per node, m^2: the part of covariance_m2 that the
                                           // nodes' shared excesses give (a model error of the
                                           // map, which a filter placing the node does not carry)
    std::vector<double> link_redundancy;   // per link, 0..1 (< 0: not evaluated): the share of an
                                           // error in the link that its residual shows; 0 when no
                                           // other link checks it
    std::vector<double> reliability_m;     // per node, m: the most that an error in one link, too
                                           // small to be noticed there, would move the node
                                           // (infinite: it hangs on a link nothing checks)
    std::vector<uint8_t> main_part;        // per node: in the largest part joined by checked,
                                           // line-of-sight links (the frame of the covariances)
    double variance_factor = 1.0;          // a-posteriori variance of unit weight (applied)
    double common_excess_m = 0.0;          // m, the std of the common excess given to this map: the
                                           // model error's, scaled by the evidence for it (the
                                           // variance factor: mapCovariance)
    double room_excess_m = 0.0;            // m, the same for the excess a node's links share
    bool gauge_free = true;                // no frame from fixed nodes: the covariance is the map's
                                           // shape, relative to the map as a whole (rotation and
                                           // translation projected out)
};

// What the measurement model leaves out and the covariance must not: NLOS and uncalibrated
// antenna delays make links read long, in walled buildings nearly all of them a little, and the
// map then reads larger by what no range can tell apart from a larger building: an excess every
// link shares, of std common_excess_m, whatever frame fixed nodes give (scaled by the evidence:
// MapCovariance::common_excess_m).
struct MapModelError {
    double common_excess_m = 0.0; // m, std of an excess every link shares unseen, in a map whose
                                  // residuals spread well beyond the noise
    double room_excess_m = 0.0;   // m, std of an excess each node's links share (its own, independent
                                  // of the other nodes'), given to a map as common_excess_m is
    // > 0: the links' ranges were corrected by range offsets estimated with the map
    // (range_offsets.hpp), each node's a deviation of this std (m) around a common part; their
    // uncertainty goes into the positions' covariance. 0: the ranges' offsets are known.
    double range_offset_spread_sigma_m = 0.0;
    // Nodes whose height is not known (problem numbering; empty: all known) range in 3D and are
    // mapped in the plane: a link reads about (z_a - z_b)^2 / 2d long. With the heights random, of
    // std height_spread_m, that excess varies from link to link by sqrt(2) s^2 / d and is
    // correlated between the links of a node; it goes into the covariance as a model error.
    std::vector<uint8_t> height_unknown;
    double height_spread_m = 0.0;
};

// The covariance of the placed nodes from the information of every link at the solution (line-
// of-sight weight / sigma^2), correlations across the map included, scaled by the variance factor
// (the weighted residuals' spread over its expected value, at least 1) so that a map whose links
// disagree more than the noise says so, and the model errors' modes added.
MapCovariance mapCovariance(const MapProblem &problem, const MapEstimate &estimate, const RangeLikelihood &likelihood,
                            const MapModelError &model_error = {});

} // namespace cdro::engine
