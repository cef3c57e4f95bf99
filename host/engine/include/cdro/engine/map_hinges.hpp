// map_hinges.hpp: the parts of a map that the ranges leave free, placed where who heard whom puts
// them. A step of the global solve (global_solve.hpp), run on every map it compares.
//
// A part that hangs on one node can turn about it, a part that hangs on two nodes can be
// reflected across the line through them, and a part joined to the rest by two links between
// four distinct nodes can swing through a whole range of places (a four-bar linkage: both links'
// lengths kept), without changing a single range (foldable.hpp). Each start of the solve leaves
// such a part wherever it happened to fall, often swung over nodes it never heard. The ranges say
// nothing about it; who heard whom (map_connectivity.hpp) does: a pair that never heard each
// other is unlikely to sit closer than the links reach. So for each such part this step tries its
// places (`turns` turns about a one-node hinge, in both mirror images; the reflection about a
// two-node hinge; `turns` directions of the first link of a two-link joint, each closing of the
// second, in both mirror images, the best refined by halving the step) and keeps the one whose
// unheard pairs with the rest of the map cost the least, under the map's own fitted P(heard | d)
// (fitted again before each pass after the first, once the parts have left the nodes they lay
// over) and the problem's unheard-pair term (map_problem.hpp). No range changes: the map's fit to
// its ranges is the same, only its pattern of who is close to whom improves. Where a swing
// leaves the part clear of every node it never heard, who heard whom is as flat as the ranges
// are: the part is placed somewhere plausible, not known. The parts stay foldable or flexible:
// the convergence check (convergence.hpp) still does not call their nodes converged.
#pragma once

#include <cstdint>

#include "cdro/engine/map_problem.hpp"

namespace cdro::engine {

struct HingeParams {
    uint32_t turns = 36; // places tried about a one-node hinge and directions of a two-link joint's
                         // first link, per mirror image (10 degrees apart)
};

struct HingeStats {
    uint32_t parts = 0;       // free parts found
    uint32_t swinging = 0;    // of them, joined by two links (four-bar linkages)
    uint32_t moved = 0;       // of them, turned or reflected
    double gained_nats = 0.0; // what the moves took off the unheard pairs' cost (>= 0)
};

// Moves the free parts of the estimate's placed nodes (fixed nodes anchor a part: such a part is
// not free). Deterministic; O(parts x places x part size x placed nodes).
HingeStats placeFreeParts(const MapProblem &problem, MapEstimate &estimate, const HingeParams &params = {});

} // namespace cdro::engine
