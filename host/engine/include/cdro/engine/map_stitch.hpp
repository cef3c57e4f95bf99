// map_stitch.hpp: one map from partial maps that each hold one part of the network well. A map
// grown from a seed triangle (map_growth.hpp) stops where nodes have fewer than two links into
// it: at the few links that join the wings of a building, or the rooms along a corridor. Each
// grown map is then exact over its part, and the whole-map starts (MDS-MAP, patches) are what is
// left to place the parts relative to each other, which they often do badly (a wing turned about
// its two or three links). Stitching places the parts as the links between them say:
//
// - the patches are taken largest first; a patch sharing three or more nodes with the map joined
//   so far is fitted onto it on those nodes (rigid, reflected if that fits better);
// - a patch sharing fewer is placed by its links to the joined map: a rotation, a reflection and a
//   translation (three unknowns) solved by Gauss-Newton on those links from `angles` starting
//   rotations, each reflection; of these the one that costs least under the links' likelihood and
//   who heard whom (map_connectivity.hpp) is taken. Two links leave the patch free to turn: then
//   only who heard whom decides, as the ranges cannot;
// - patches with fewer than two links to the joined map wait until another patch brings some;
// - nodes no patch places are taken from `fill` (a map placing every node), fitted onto the
//   joined map on the nodes both place.
//
// The result is a start of the global solve (global_solve.hpp), refined there like any other.
#pragma once

#include <cstdint>
#include <optional>
#include <vector>

#include "cdro/engine/map_problem.hpp"
#include "cdro/engine/range_likelihood.hpp"

namespace cdro::engine {

struct MapStitchParams {
    uint32_t angles = 36;     // starting rotations per reflection for a patch placed by its links
    uint32_t iterations = 20; // Gauss-Newton iterations from each
};

struct MapStitchStats {
    uint32_t fitted = 0; // patches joined on three or more shared nodes
    uint32_t linked = 0; // patches placed by their links to the joined map
    uint32_t filled = 0; // nodes taken from `fill`
};

// `patches` partial maps of `problem` (largest first after a stable sort by placed count);
// `fill` may be null. Returns nothing unless at least two patches were joined.
std::optional<MapEstimate> stitchPatches(const MapProblem &problem, const std::vector<MapEstimate> &patches,
                                         const MapEstimate *fill, const RangeLikelihood &likelihood,
                                         const MapStitchParams &params = {}, MapStitchStats *stats = nullptr);

} // namespace cdro::engine
