// map_mds.hpp: MDS-MAP of one connected part of a map problem, a coarse but globally consistent
// layout from the link ranges alone: shortest-path distances fill the pairs that did not range,
// and classical MDS (double centring, the two leading eigenvectors) lays them out in the plane.
// Its error is metres (2.8 m RMS on PLANT), but it never folds a part of the network over onto
// itself, so it is one of the starts of the global solve. O(n m log n) for the paths; the two
// eigenvectors by subspace iteration, O(n^2) per iteration.
#pragma once

#include <optional>
#include <vector>

#include <Eigen/Core>

#include "cdro/engine/map_problem.hpp"

namespace cdro::engine {

// The layout of `part` in `dims` dimensions (rows: node numbers; rows outside the part are 0).
std::optional<Eigen::MatrixXd> mdsEmbedding(const MapProblem &problem, const std::vector<uint32_t> &part,
                                            uint32_t dims);

// The layout of `part` (node numbers, connected, >= 3) as an estimate placing those nodes.
std::optional<MapEstimate> mdsMap(const MapProblem &problem, const std::vector<uint32_t> &part);

} // namespace cdro::engine
