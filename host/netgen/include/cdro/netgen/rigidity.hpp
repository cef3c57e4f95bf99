// rigidity.hpp: whether the ranges of a planar network allow one map only (up to a rigid
// motion and a reflection). A test that asks the engine for the true map needs such a network,
// and geometric.hpp can be told to draw only those.
#pragma once

#include <cstddef>
#include <utility>
#include <vector>

#include "cdro/netgen/random.hpp"
#include "cdro/netgen/world.hpp"

namespace cdro::netgen {

// Generic global rigidity in the plane at the given positions (m): the rigidity matrix has rank
// 2n - 3 and a random equilibrium stress has a stress matrix of rank n - 3 (Connelly; Gortler,
// Healy, Thurston). `links` are pairs of indices into position_m. The stress is a random
// combination drawn from `random` (one normal per independent stress).
bool globallyRigid(const std::vector<Vector2> &position_m, const std::vector<std::pair<size_t, size_t>> &links,
                   RandomSource &random);

} // namespace cdro::netgen
