// map_connectivity.hpp: how well a map explains which pairs heard each other at all.
//
// Two nodes hear each other when they are close enough and nothing between them blocks too much
// of the signal: the chance of a link falls with distance. A map that bends a corridor or swings
// a wing around its few links brings pairs close together that never heard each other, and moves
// apart pairs that did; the ranges alone may be explained almost as well by such a map (a flexible
// part has no range that says it is bent), its pattern of links is not.
//
// The model: P(heard | d) = floor + (ceiling - floor) / (1 + exp((d - d_half) / width)), over every
// pair of placed nodes that both listened (a node switched on late, or a pair one of which never
// listened, says nothing), with d the pair's distance in the map. Its two parameters are fitted to
// each map (a profile likelihood, as the NLOS model is in global_solve.hpp): a building decides how
// far links reach, not a constant here. The ceiling (0.98) allows a close pair to miss each other
// now and then (a wall, a node behind metal); the floor (0.001) a rare long link.
//
// The cost is -sum log P(heard) - sum log(1 - P(unheard)) at the fitted parameters (nats); only
// differences between maps of the same links mean anything. Its price is O(nodes^2) distances and
// a fit over a histogram of them.
#pragma once

#include <cstdint>

#include "cdro/engine/map_problem.hpp"

namespace cdro::engine {

struct ConnectivityFit {
    double cost_nats = 0.0;
    double half_distance_m = 0.0; // m, the distance at which the fitted P(heard) is halfway
    double width_m = 0.0;         // m, how quickly it falls there
    uint32_t heard_pairs = 0;     // the linked pairs of placed nodes counted
    uint32_t unheard_pairs = 0;   // the pairs of placed, listening nodes that never heard each other
};

// The connectivity cost of a map (zero and no pairs counted when it places fewer than three nodes
// or the problem has no links between placed nodes).
ConnectivityFit connectivityCost(const MapProblem &problem, const MapEstimate &estimate);

// P(heard | d) of a fit (its width 0: no fit, 0).
double heardProbability(const ConnectivityFit &fit, double distance_m);

} // namespace cdro::engine
