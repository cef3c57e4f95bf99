// map_patches.hpp: a map of one connected part assembled from local maps (MDS-MAP(P), Shang &
// Ruml 2004, with robust local solves): each node and its neighbours form a patch, small enough
// to be solved well on its own links (several starts, map_growth.hpp and map_mds.hpp, refined
// through the lifted space, map_lift.hpp); the patches are then merged into one map, the patch
// that shares the most nodes with the map first, each aligned by a rigid fit on the shared nodes
// (its mirror image too, when the shared nodes are nearly collinear the links decide). Where a
// greedy growth lets errors pile up along a corridor, a patch brings its own shape, solved from
// every link inside it.
#pragma once

#include <cstdint>
#include <vector>

#include "cdro/engine/map_problem.hpp"

namespace cdro::engine {

struct MapPatchParams {
    uint32_t min_patch_nodes = 6; // a node's neighbours, then its neighbours' until this many
    uint32_t min_shared = 3;      // nodes a patch must share with the map to be merged
    double refine_growth = 1.25;  // refine the merged map jointly when it has grown by this
};

MapEstimate patchMap(const MapProblem &problem, const std::vector<uint32_t> &part, const RangeLikelihood &likelihood,
                     const MapPatchParams &params = {});

// The problem restricted to `nodes` (their links among themselves), renumbered in that order.
MapProblem subProblem(const MapProblem &problem, const std::vector<uint32_t> &nodes);

} // namespace cdro::engine
