// map_growth.hpp: a map of one connected part of the network grown from a seed triangle, one
// node at a time, the best-determined node first, from all the links known (so the result does
// not depend on the order the ranges came in).
//
// Each round, every unplaced node with three or more placed neighbours is placed tentatively
// against them (the paper's multilateration, eq. 4, every pair of neighbours giving the two
// circle intersections, each polished by robust Gauss-Newton: placement.hpp) and scored by how
// clearly its best candidate beats the distinct rivals. The cost of a candidate counts its links
// and, softly, the placed nodes that did not hear the node although the candidate puts them
// close (an unheard pair is rarely a near one: that is what decides a mirror image that the
// links alone cannot; MapProblem's unheard pairs). The node with the most placed neighbours among the decisive ones is
// placed; if none is decisive, the least ambiguous one; nodes with two placed neighbours only
// come last (they cannot be decided by their links). The placed part is refined jointly
// (map_refine.hpp) whenever it has grown by a third.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "cdro/engine/map_problem.hpp"

namespace cdro::engine {

struct MapGrowthParams {
    double ambiguity_gap_nats = 4.0; // a decisive candidate beats every distinct rival by this
    double distinct_m = 1.0;         // candidates closer than this are one
    double min_baseline_m = 1.0;     // neighbour pairs closer than this give no intersection
    double min_triangle_height_m = 1.0;
    double refine_growth = 1.33; // refine the placed part jointly when it has grown by this
};

struct MapGrowthStats {
    uint32_t decisive = 0;  // nodes placed with a clear best candidate
    uint32_t forced = 0;    // nodes placed at the least ambiguous candidate
    uint32_t two_links = 0; // nodes placed from two placed neighbours only
    uint32_t refinements = 0;
};

// Triangles of mutually linked nodes usable as seeds (smallest height at least
// min_triangle_height_m), best first: by min(height, 5 m) x (the three nodes' degrees), then
// ones that are far (in hops) from the seeds before them. At most `count`.
std::vector<std::array<uint32_t, 3>> seedTriangles(const MapProblem &problem, const std::vector<uint32_t> &part,
                                                   const MapGrowthParams &params, uint32_t count);

// Grows the map of `part` (node numbers of one connected part) from the seed; nodes it cannot
// place (fewer than two placed neighbours) stay unplaced. Fixed nodes of the part are placed at
// their coordinates first and the seed is then ignored if two or more are fixed.
MapEstimate growMap(const MapProblem &problem, const std::vector<uint32_t> &part, const std::array<uint32_t, 3> &seed,
                    const RangeLikelihood &likelihood, const MapGrowthParams &params, MapGrowthStats *stats = nullptr);

} // namespace cdro::engine
