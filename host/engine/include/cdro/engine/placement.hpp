// placement.hpp: initialization by iterative multilateration (paper eq. 1-4), made streaming
// and multi-hop.
//
// The frame: three nodes that ranged to each other, chosen for a long baseline, a large
// height (non-collinear) and many links (not simply the first three ids), placed as the paper
// does: p0 = (0, 0), p1 = (r01, 0), p2 on the +y side.
//
// Every further node is placed from the placed nodes it ranged to: each pair of them with a
// usable baseline gives the two circle intersections (eq. 4, the sign chosen by the others; of a
// node with more than 16 placed neighbours, the pairs of its 16 shortest links only),
// every intersection is polished by robust Gauss-Newton against all placed neighbours
// (point_solver.hpp), and the distinct local optima are the candidates. A node is placed
// only when the decision is clear: the best candidate's cost beats every distinct rival by
// `ambiguity_gap_nats`. The paper's sign rule alone is not enough on real networks: three
// nearly collinear neighbours, or one NLOS link among three, make both mirror images fit.
// Multi-hop placement follows from this: a node that does not see the frame nodes is placed
// from any placed nodes it sees, as soon as it sees enough of them.
//
// Where ranges cannot decide (a node with two placed neighbours, or mirror images that fit
// equally), the node waits: the global solve (global_step.hpp), which sees every link at once,
// places it, or its patience runs out.
#pragma once

#include <array>
#include <optional>
#include <vector>

#include "cdro/engine/map_state.hpp"
#include "cdro/engine/point_solver.hpp"
#include "cdro/engine/range_likelihood.hpp"

namespace cdro::engine {

struct PlacementParams {
    double min_triangle_height_m = 1.0; // m, a frame triangle's smallest height (non-collinear)
    double min_baseline_m = 1.0;        // m, neighbours closer than this give no intersection
    double ambiguity_gap_nats = 4.0;    // nats, how much better than any rival the best must be
    double distinct_m = 1.0;            // m, candidates closer than this are one solution
    uint32_t patience_ranges = 60;      // a node with 3+ placed neighbours still ambiguous after
                                        // this many of its ranges is placed at its best candidate
};

struct PlacementCandidate {
    Vector2 position_m = Vector2::Zero();        // m
    Matrix2 covariance_m2 = Matrix2::Identity(); // m^2
    double cost = 0.0;                           // nats (point_solver.hpp)
};

// Distinct local optima of a node's robust cost against its constraints, best first.
std::vector<PlacementCandidate> placementCandidates(const std::vector<RangeConstraint> &constraints,
                                                    const RangeLikelihood &likelihood, const PointSolverParams &solver,
                                                    const PlacementParams &params);

enum class PlacementDecision { Placed, Ambiguous, NoCandidate };

struct PlacementChoice {
    PlacementDecision decision = PlacementDecision::NoCandidate;
    PlacementCandidate chosen;
};

// Decides among candidates found from constraint_count constraints, by the cost gap.
PlacementChoice choosePlacement(const std::vector<PlacementCandidate> &candidates, size_t constraint_count,
                                const PlacementParams &params);

struct FrameTriangle {
    uint32_t origin = kNoIndex;     // p0 = (0, 0)
    uint32_t x_axis = kNoIndex;     // p1 = (r01, 0)
    uint32_t positive_y = kNoIndex; // p2, y > 0
    Vector2 origin_m = Vector2::Zero();
    Vector2 x_axis_m = Vector2::Zero();
    Vector2 positive_y_m = Vector2::Zero();
};

// The frame's triangle among the links so far, or nullopt if none is usable yet. `preferred`
// (origin, x-axis, +y node indices) is taken when those three ranged to each other and are
// not collinear. Only nodes for which `eligible` is true are considered.
std::optional<FrameTriangle> chooseFrameTriangle(const MapState &network, const PlacementParams &params,
                                                 const std::vector<bool> &eligible,
                                                 const std::optional<std::array<uint32_t, 3>> &preferred);

} // namespace cdro::engine
