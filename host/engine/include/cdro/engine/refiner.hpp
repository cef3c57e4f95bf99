// refiner.hpp: step 4b of a range (beyond the paper). The merged SoG is a moment match of rings
// whose components are metres apart, pulled by every NLOS link; the node's estimate is therefore
// polished against all its links by robust Gauss-Newton (point_solver.hpp), from the current
// estimate, and from the merged SoG as well when that is far away (the SoG proposes, the links
// decide). In the solve a link weighs the same at both of its ends (the noise alone), so that the
// forces along a link cancel and the map does not drift. A node most of whose links disagree with
// it is asked to be placed again.
#pragma once

#include <cstdint>

#include "cdro/engine/map_state.hpp"
#include "cdro/engine/params.hpp"
#include "cdro/engine/point_solver.hpp"
#include "cdro/engine/range_likelihood.hpp"

namespace cdro::engine {

struct RefinerCounters {
    uint64_t refinements = 0;
    uint64_t links_downweighted = 0;  // links with inlier probability < 0.5, summed
    uint64_t hypothesis_switches = 0; // the merged SoG won over the previous estimate
};

struct Refinement {
    Vector2 position_m = Vector2::Zero();
    Matrix2 covariance_m2 = Matrix2::Identity();
    bool inconsistent = false; // most of its links disagree: place it again
};

class Refiner {
public:
    Refiner(const EngineParams &params, const RangeLikelihood &likelihood);

    // The node's new estimate from its links to placed anchors and the merged SoG (ring_count SoGs
    // took part); the links' inlier probabilities are updated. Without refinement (the paper's
    // filter) the merged SoG is the estimate once two or more SoGs describe the node.
    Refinement refine(MapState &map, uint32_t node, const Gaussian2 &merged, uint32_t ring_count, bool tracked);

    const RefinerCounters &counters() const { return counters_; }
    void restoreCounters(const RefinerCounters &counters) { counters_ = counters; }

private:
    RefinementParams params_;
    double range_sigma_m_;
    RangeLikelihood likelihood_;
    PointSolverParams solver_;
    RefinerCounters counters_;
};

} // namespace cdro::engine
