#include "cdro/engine/second_place.hpp"

#include <algorithm>

#include "cdro/engine/map_refine.hpp"

namespace cdro::engine {

namespace {
constexpr uint32_t kNotInNeighbourhood = UINT32_MAX;
} // namespace

SecondPlace secondPlaceWithNeighbours(const MapProblem &problem, const MapEstimate &estimate,
                                      const std::vector<uint8_t> &movable, uint32_t node, const Vector2 &start_m,
                                      const RangeLikelihood &likelihood)
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
    std::vector<uint32_t> local(problem.nodeCount(), kNotInNeighbourhood);
    MapProblem part;
    part.sigma_m = problem.sigma_m;
    part.unheard_radius_m = problem.unheard_radius_m;
    part.unheard_cost_nats = problem.unheard_cost_nats;
    for (uint32_t i = 0; i < members.size(); ++i) {
        local[members[i]] = i;
        part.ids.push_back(problem.ids[members[i]]);
        part.listens.push_back(members[i] < problem.listens.size() ? problem.listens[members[i]] : 0);
    }
    std::vector<uint8_t> is_moving(problem.nodeCount(), 0);
    for (const uint32_t m : moving) {
        is_moving[m] = 1;
    }
    for (const MapLink &link : problem.links) {
        if (local[link.a] != kNotInNeighbourhood && local[link.b] != kNotInNeighbourhood &&
            (is_moving[link.a] != 0 || is_moving[link.b] != 0)) {
            part.links.push_back({local[link.a], local[link.b], link.range_m});
        }
    }
    part.finish();
    MapEstimate here = MapEstimate::unplaced(part.nodeCount());
    for (uint32_t i = 0; i < members.size(); ++i) {
        here.placed[i] = 1;
        here.position_m[i] = estimate.position_m[members[i]];
        if (is_moving[members[i]] == 0) {
            part.fixed[i] = 1;
            part.fixed_position_m[i] = estimate.position_m[members[i]];
        }
    }
    MapEstimate there = here;
    there.position_m[local[node]] = start_m;
    MapRefineParams refine;
    refine.stages = {RefineStage{}};
    SecondPlace out;
    refineMap(part, here, likelihood, refine);
    refineMap(part, there, likelihood, refine);
    out.cost_here_nats = mapCost(part, here, likelihood);
    out.cost_there_nats = mapCost(part, there, likelihood);
    out.there_m = there.position_m[local[node]];
    return out;
}

} // namespace cdro::engine
