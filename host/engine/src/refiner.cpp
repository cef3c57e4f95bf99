#include "cdro/engine/refiner.hpp"

#include <algorithm>
#include <cmath>
#include <vector>

namespace cdro::engine {

Refiner::Refiner(const EngineParams &params, const RangeLikelihood &likelihood)
    : params_(params.refinement), range_sigma_m_(params.range.sigma_m), likelihood_(likelihood)
{
    solver_.range_sigma_m = params.range.sigma_m;
    solver_.max_iterations = std::max<uint32_t>(params.refinement.max_iterations, 1U);
    solver_.anchor_uncertainty_in_solve = false;
}

Refinement Refiner::refine(MapState &map, uint32_t node, const Gaussian2 &merged, uint32_t ring_count, bool tracked)
{
    const NodeState &state = map.nodes[node];
    Refinement out;
    out.position_m = state.position_m;
    out.covariance_m2 = state.covariance_m2;
    const bool merged_usable = ring_count >= 2; // one ring's moments are its centre, not the node
    if (!params_.enabled) {
        if (merged_usable) {
            out.position_m = merged.mean_m;
            out.covariance_m2 = merged.covariance_m2;
        }
        return out;
    }
    const std::vector<RangeConstraint> constraints = placedConstraints(map, node);
    if (constraints.size() < 2) {
        if (merged_usable) {
            out.position_m = merged.mean_m;
            out.covariance_m2 = merged.covariance_m2;
        }
        return out;
    }
    std::vector<double> inliers;
    PointSolution solution = solvePoint(constraints, state.position_m, likelihood_, solver_, &inliers);
    ++counters_.refinements;
    // The SoG may hold a better hypothesis than the current basin (a flip): try it.
    if (ring_count > 0 && (merged.mean_m - state.position_m).norm() > params_.hypothesis_switch_m) {
        std::vector<double> alternative_inliers;
        const PointSolution alternative =
            solvePoint(constraints, merged.mean_m, likelihood_, solver_, &alternative_inliers);
        if (alternative.well_posed && alternative.cost + params_.switch_gap_nats < solution.cost) {
            solution = alternative;
            inliers = alternative_inliers;
            ++counters_.hypothesis_switches;
        }
    }
    if (solution.well_posed) {
        out.position_m = solution.position_m;
        out.covariance_m2 = solution.covariance_m2;
    } else if (merged_usable) {
        out.position_m = merged.mean_m;
        out.covariance_m2 = merged.covariance_m2;
    }
    counters_.links_downweighted += solution.downweighted;
    uint32_t inconsistent = 0;
    const double inconsistent_m = std::max(params_.inconsistent_residual_m, 4.0 * range_sigma_m_);
    for (size_t i = 0; i < constraints.size(); ++i) {
        map.links[constraints[i].link].inlier_probability = inliers[i];
        const double residual = constraints[i].range_m - (out.position_m - constraints[i].anchor_m).norm();
        inconsistent += std::abs(residual) > inconsistent_m ? 1U : 0U;
    }
    out.inconsistent =
        !tracked && inconsistent >= 2 &&
        static_cast<double>(inconsistent) > params_.inconsistent_fraction * static_cast<double>(constraints.size()) &&
        state.placements < params_.max_placements;
    return out;
}

} // namespace cdro::engine
