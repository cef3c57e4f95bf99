// map_lift.hpp: the map solved in more dimensions than it has, then brought down to the plane.
//
// In the plane, a part of the network folded over a line of nodes (a mirror image) or turned
// about a node is a local minimum: to get back it would have to pass through maps that break
// its links. In three or more dimensions the same part can turn out of the plane and back on
// the other side without breaking a link, so robust stress minimisation from a coarse start
// (MDS-MAP in D dimensions, or a planar map lifted a little) finds the consistent map far more
// often. The extra coordinates are then squeezed out gradually (a penalty on them that grows
// stage by stage, the map turned each time so that the penalty falls on its thinnest
// directions), and the planar map is refined (map_refine.hpp).
#pragma once

#include <cstdint>
#include <vector>

#include "cdro/engine/map_problem.hpp"
#include "cdro/engine/map_refine.hpp"

namespace cdro::engine {

struct MapLiftParams {
    uint32_t dimensions = 3; // 3 <= D <= kMaxEmbeddingDimensions (map_refine.hpp)
    std::vector<RefineStage> stages{{8.0, 0.5, 3.0}, {4.0, 0.3, 2.0}, {2.0, -1.0, -1.0}, {1.0, -1.0, -1.0}};
    // stages at D dimensions, no penalty
    std::vector<double> squeeze{1e-2, 1e-1, 1.0, 10.0, 100.0, 1e4}; // penalty stages (1/m^2 per node)
    uint32_t iterations_per_stage = 15;
    double lift_m = 1.0; // m, out-of-plane offsets given to a planar start
};

// Refines `estimate` (its placed nodes; the part must be connected) through the lifted space and
// back. With `mds_start`, the start is MDS-MAP in D dimensions instead of the estimate.
MapRefineResult liftedRefine(const MapProblem &problem, MapEstimate &estimate, const RangeLikelihood &likelihood,
                             const MapLiftParams &params, bool mds_start);

} // namespace cdro::engine
