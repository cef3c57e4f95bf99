// second_place.hpp: whether a node has a second place once its neighbours may follow it.
//
// The structure check (convergence.hpp) asks of each node whether a distinct position explains its
// links about as well as where it is, its neighbours held where the map has them. Held, they
// defend the map around them: where a third to a half of a node's links read long (walls), the
// map puts the node where two of them fit and bends its neighbours a little to suit, and the
// place on the truth's side then costs a few nats more only because the neighbours stay bent
// (a wings draw at 20 % NLOS: 3.6 nats, 1.27 m off, called converged). Here the node starts at
// the distinct position and its free neighbours are refined with it, their own other neighbours
// held; the node's current place is refined the same way (once per node), and the costs compared.
#pragma once

#include <cstdint>
#include <vector>

#include "cdro/engine/map_problem.hpp"
#include "cdro/engine/range_likelihood.hpp"
#include "cdro/engine/types.hpp"

namespace cdro::engine {

struct SecondPlace {
    double cost_nats = 0.0;            // the neighbourhood's cost, refined from the other start
    Vector2 there_m = Vector2::Zero(); // where the node ended from it
};

class NodeNeighbourhood {
public:
    // `movable[n]` != 0: a node that may follow (free and placed). The neighbourhood is `node` and
    // its movable neighbours; every other placed neighbour of theirs is held. Refines it from the
    // map as it is.
    NodeNeighbourhood(const MapProblem &problem, const MapEstimate &estimate, const std::vector<uint8_t> &movable,
                      uint32_t node, const RangeLikelihood &likelihood);

    double costHereNats() const { return cost_here_nats_; } // refined from the node's place
    // The same refined with the node started at `start_m`.
    SecondPlace from(const Vector2 &start_m) const;

private:
    MapProblem part_;   // the problem restricted to the neighbourhood, the held nodes fixed
    MapEstimate start_; // the map's positions, renumbered
    uint32_t node_ = 0; // the node's number in part_
    const RangeLikelihood &likelihood_;
    double cost_here_nats_ = 0.0;
};

} // namespace cdro::engine
