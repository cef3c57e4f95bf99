#include "cdro/engine/second_place.hpp"

#include <algorithm>

#include "cdro/engine/map_patches.hpp"
#include "cdro/engine/map_refine.hpp"

namespace cdro::engine {

namespace {
// One stage at the nominal noise: each start stays in its own basin.
MapRefineParams localRefine()
{
    MapRefineParams refine;
    refine.stages = {RefineStage{}};
    return refine;
}
} // namespace

NodeNeighbourhood::NodeNeighbourhood(const MapProblem &problem, const MapEstimate &estimate,
                                     const std::vector<uint8_t> &movable, uint32_t node,
                                     const RangeLikelihood &likelihood)
    : likelihood_(likelihood)
{
    // The moving part: the node and its movable neighbours; the held part: their other placed
    // neighbours.
    std::vector<uint32_t> moving{node};
    for (const uint32_t neighbour : problem.neighbours[node]) {
        if (estimate.placed[neighbour] != 0 && movable[neighbour] != 0) {
            moving.push_back(neighbour);
        }
    }
    std::vector<uint32_t> members = moving;
    for (const uint32_t m : moving) {
        for (const uint32_t neighbour : problem.neighbours[m]) {
            if (estimate.placed[neighbour] != 0) {
                members.push_back(neighbour);
            }
        }
    }
    std::sort(members.begin(), members.end());
    members.erase(std::unique(members.begin(), members.end()), members.end());
    std::sort(moving.begin(), moving.end());
    // The links between two held nodes cost the same from either start.
    part_ = subProblem(problem, members);
    start_ = MapEstimate::unplaced(part_.nodeCount());
    for (uint32_t i = 0; i < members.size(); ++i) {
        start_.placed[i] = 1;
        start_.position_m[i] = estimate.position_m[members[i]];
        if (members[i] == node) {
            node_ = i;
        }
        if (!std::binary_search(moving.begin(), moving.end(), members[i])) {
            part_.fixed[i] = 1;
            part_.fixed_position_m[i] = estimate.position_m[members[i]];
        }
    }
    MapEstimate here = start_;
    refineMap(part_, here, likelihood_, localRefine());
    cost_here_nats_ = mapCost(part_, here, likelihood_);
}

SecondPlace NodeNeighbourhood::from(const Vector2 &start_m) const
{
    MapEstimate there = start_;
    there.position_m[node_] = start_m;
    refineMap(part_, there, likelihood_, localRefine());
    return {mapCost(part_, there, likelihood_), there.position_m[node_]};
}

} // namespace cdro::engine
