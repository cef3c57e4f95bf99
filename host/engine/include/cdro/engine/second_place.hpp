// second_place.hpp: whether a node has a second place once its neighbours may follow it.
//
// The structure check (convergence.hpp) asks of each node whether a distinct position explains its
// links about as well as where it is, its neighbours held where the map has them. Held, they
// defend the map around them: where a third to a half of a node's links read long (walls), the
// map puts the node where two of them fit and bends its neighbours a little to suit, and the
// place on the truth's side then costs a few nats more only because the neighbours stay bent
// (a wings draw at 20 % NLOS: 3.6 nats, 1.27 m off, called converged). Here the node starts at
// the distinct position and its free neighbours are refined with it, their own other neighbours
// held; the node's current place is refined the same way, and the two costs compared.
#pragma once

#include <cstdint>
#include <vector>

#include "cdro/engine/map_problem.hpp"
#include "cdro/engine/range_likelihood.hpp"
#include "cdro/engine/types.hpp"

namespace cdro::engine {

struct SecondPlace {
    double cost_here_nats = 0.0;       // the neighbourhood's cost, refined from the node's place
    double cost_there_nats = 0.0;      // the same from the other start
    Vector2 there_m = Vector2::Zero(); // where the node ended from the other start
};

// `movable[n]` != 0: a node that may follow (free and placed). The neighbourhood is `node` and its
// movable neighbours; every other placed neighbour of theirs is held.
SecondPlace secondPlaceWithNeighbours(const MapProblem &problem, const MapEstimate &estimate,
                                      const std::vector<uint8_t> &movable, uint32_t node, const Vector2 &start_m,
                                      const RangeLikelihood &likelihood);

} // namespace cdro::engine
