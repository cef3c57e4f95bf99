// map_problem.hpp: the map as the global solve sees it: a plain value, built from the links
// seen so far and nothing of the streaming filter. Nodes are numbered in the order of their ids
// and links sorted by their ends, so that the same links give the same problem whatever order
// the ranges came in.
#pragma once

#include <cstdint>
#include <functional>
#include <vector>

#include <Eigen/Core>

#include "cdro/engine/range_likelihood.hpp"
#include "cdro/engine/types.hpp"

namespace cdro::engine {

struct MapLink {
    uint32_t a = 0; // node numbers (a < b)
    uint32_t b = 0;
    double range_m = 0.0; // m, the link's range (median of its recent ranges, projected)
};

struct MapProblem {
    std::vector<NodeId> ids;    // by node number, ascending
    std::vector<MapLink> links; // sorted by (a, b)
    std::vector<uint8_t> fixed; // 0/1: known coordinates, never moved
    std::vector<Vector2> fixed_position_m;
    double sigma_m = 0.10; // m, line-of-sight range noise
    // Pairs that never heard each other, although both listened long enough (`listens`), are
    // rarely close: each such pair closer than unheard_radius_m costs
    // unheard_cost_nats (1 - d / radius)^2 (0 radius: not used).
    std::vector<uint8_t> listens;   // 0/1 per node
    double unheard_radius_m = 0.0;  // m
    double unheard_cost_nats = 3.0; // nats at distance 0
    // Derived by finish(): per node, the indices of its links, and its neighbours sorted.
    std::vector<std::vector<uint32_t>> node_links;
    std::vector<std::vector<uint32_t>> neighbours;

    uint32_t nodeCount() const { return static_cast<uint32_t>(ids.size()); }
    uint32_t other(uint32_t link, uint32_t node) const { return links[link].a == node ? links[link].b : links[link].a; }
    // Sorts the links, sizes fixed / fixed_position_m and builds node_links.
    void finish();
    uint32_t fixedCount() const;
    bool linked(uint32_t a, uint32_t b) const;
    // Whether the pair counts as unheard (not linked, both listen).
    bool unheardPair(uint32_t a, uint32_t b) const { return listens[a] != 0 && listens[b] != 0 && !linked(a, b); }
    double unheardCost(double distance_m) const
    {
        if (distance_m >= unheard_radius_m) {
            return 0.0;
        }
        const double closeness = 1.0 - distance_m / unheard_radius_m;
        return unheard_cost_nats * closeness * closeness;
    }
};

// The unheard radius that suits a problem: `share` of its median link range.
double unheardRadiusFor(const MapProblem &problem, double share);

// Positions of the nodes a map places (by node number).
struct MapEstimate {
    std::vector<uint8_t> placed;
    std::vector<Vector2> position_m;

    static MapEstimate unplaced(uint32_t nodes);
    uint32_t placedCount() const;
};

// -sum log p(e) over the links with both ends placed, the likelihood without its floor
// (range_likelihood.hpp), at the noise sigma_m * sigma_scale, plus the cost of the unheard pairs
// that the map puts close (nats).
double mapCost(const MapProblem &problem, const MapEstimate &estimate, const RangeLikelihood &likelihood,
               double sigma_scale = 1.0);
// Every unheard pair of placed nodes closer than the unheard radius (by the first two
// coordinates of `positions`, one row per node, then the full distance), once each.
void forEachCloseUnheardPair(const MapProblem &problem, const std::vector<uint8_t> &placed,
                             const Eigen::MatrixXd &positions,
                             const std::function<void(uint32_t, uint32_t, double)> &visit);

// The same for the links of one node, and its unheard pairs (its part of the cost).
double nodeCost(const MapProblem &problem, const MapEstimate &estimate, const RangeLikelihood &likelihood,
                uint32_t node, const Vector2 &position_m);

// The unheard part alone.
double unheardNodeCost(const MapProblem &problem, const MapEstimate &estimate, uint32_t node,
                       const Vector2 &position_m);

// The likelihood of the global solve: the engine's, without the floor.
RangeLikelihood mapLikelihood(const RangeLikelihoodParams &params);

// Connected components of the link graph, largest first (ties: the one with the smallest node).
std::vector<std::vector<uint32_t>> mapComponents(const MapProblem &problem);

} // namespace cdro::engine
