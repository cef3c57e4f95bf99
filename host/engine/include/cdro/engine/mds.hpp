// mds.hpp: MDS-MAP, a coarse but globally consistent layout of a connected set of nodes from
// the link ranges alone: shortest-path distances fill the pairs that did not range, and
// classical MDS (double centring, two leading eigenvectors) lays them out in the plane.
//
// Its error is metres (2.8 m RMS on PLANT), far too coarse for a map, but it never folds a
// part of the network over onto itself. Placement uses it only to break ties that ranges to
// two placed neighbours cannot: which of two mirror-image positions a node takes.
// Cost O(n^3) for n nodes; placement calls it rarely (see placement.hpp).
#pragma once

#include <optional>
#include <vector>

#include "cdro/engine/network.hpp"

namespace cdro::engine {

// Layout of the given nodes (indices into network.nodes), same order; nullopt if they are not
// connected through links among themselves or fewer than 3.
std::optional<std::vector<Vector2>> mdsLayout(const Network &network, const std::vector<uint32_t> &nodes);

} // namespace cdro::engine
