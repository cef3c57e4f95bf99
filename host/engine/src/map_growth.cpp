#include "cdro/engine/map_growth.hpp"

#include <algorithm>
#include <cmath>
#include <deque>
#include <limits>

#include "cdro/engine/map_refine.hpp"
#include "cdro/engine/placement.hpp"
#include "cdro/engine/point_solver.hpp"

namespace cdro::engine {

namespace {

double triangleHeight(double ab, double bc, double ca)
{
    // Smallest height of the triangle with these sides (0 if degenerate).
    const double s = 0.5 * (ab + bc + ca);
    const double area_sq = s * (s - ab) * (s - bc) * (s - ca);
    if (area_sq <= 0.0) {
        return 0.0;
    }
    const double area = std::sqrt(area_sq);
    return 2.0 * area / std::max({ab, bc, ca});
}

uint32_t findLink(const MapProblem &problem, uint32_t a, uint32_t b)
{
    for (uint32_t link : problem.node_links[a]) {
        if (problem.other(link, a) == b) {
            return link;
        }
    }
    return std::numeric_limits<uint32_t>::max();
}

std::vector<uint32_t> hopsFrom(const MapProblem &problem, const std::vector<uint32_t> &sources)
{
    std::vector<uint32_t> hops(problem.nodeCount(), std::numeric_limits<uint32_t>::max());
    std::deque<uint32_t> frontier;
    for (uint32_t source : sources) {
        hops[source] = 0;
        frontier.push_back(source);
    }
    while (!frontier.empty()) {
        const uint32_t node = frontier.front();
        frontier.pop_front();
        for (uint32_t link : problem.node_links[node]) {
            const uint32_t other = problem.other(link, node);
            if (hops[other] == std::numeric_limits<uint32_t>::max()) {
                hops[other] = hops[node] + 1;
                frontier.push_back(other);
            }
        }
    }
    return hops;
}

struct Decision {
    bool valid = false;
    uint32_t placed_neighbours = 0;
    double gap = 0.0; // nats, rival cost - best cost (infinite with one candidate)
    Vector2 position_m = Vector2::Zero();
    bool usable = false; // a candidate exists
};

} // namespace

std::vector<std::array<uint32_t, 3>> seedTriangles(const MapProblem &problem, const std::vector<uint32_t> &part,
                                                   const MapGrowthParams &params, uint32_t count)
{
    struct Scored {
        std::array<uint32_t, 3> nodes;
        double score;
    };
    std::vector<uint8_t> in_part(problem.nodeCount(), 0);
    for (uint32_t node : part) {
        in_part[node] = 1;
    }
    std::vector<Scored> triangles;
    for (const MapLink &ab : problem.links) {
        if (in_part[ab.a] == 0) {
            continue;
        }
        for (uint32_t link : problem.node_links[ab.a]) {
            const uint32_t c = problem.other(link, ab.a);
            if (c <= ab.b) {
                continue; // each triangle once: a < b < c
            }
            const uint32_t bc = findLink(problem, ab.b, c);
            if (bc == std::numeric_limits<uint32_t>::max()) {
                continue;
            }
            const double height = triangleHeight(ab.range_m, problem.links[bc].range_m, problem.links[link].range_m);
            if (height < params.min_triangle_height_m) {
                continue;
            }
            const double degrees = static_cast<double>(problem.node_links[ab.a].size() +
                                                       problem.node_links[ab.b].size() + problem.node_links[c].size());
            triangles.push_back({{ab.a, ab.b, c}, std::min(height, 5.0) * degrees});
        }
    }
    std::stable_sort(triangles.begin(), triangles.end(),
                     [](const Scored &x, const Scored &y) { return x.score > y.score; });
    std::vector<std::array<uint32_t, 3>> seeds;
    std::vector<uint32_t> used;
    while (seeds.size() < count && !triangles.empty()) {
        if (seeds.empty()) {
            seeds.push_back(triangles.front().nodes);
        } else {
            // The best triangle among those farthest from the seeds so far.
            const std::vector<uint32_t> hops = hopsFrom(problem, used);
            uint32_t farthest = 0;
            for (const Scored &t : triangles) {
                farthest = std::max(farthest, std::min({hops[t.nodes[0]], hops[t.nodes[1]], hops[t.nodes[2]]}));
            }
            if (farthest == 0) {
                break;
            }
            for (const Scored &t : triangles) {
                if (std::min({hops[t.nodes[0]], hops[t.nodes[1]], hops[t.nodes[2]]}) == farthest) {
                    seeds.push_back(t.nodes);
                    break;
                }
            }
        }
        used.insert(used.end(), seeds.back().begin(), seeds.back().end());
    }
    return seeds;
}

MapEstimate growMap(const MapProblem &problem, const std::vector<uint32_t> &part, const std::array<uint32_t, 3> &seed,
                    const RangeLikelihood &likelihood, const MapGrowthParams &params, MapGrowthStats *stats)
{
    MapGrowthStats local;
    MapGrowthStats &counted = stats != nullptr ? *stats : local;
    const uint32_t n = problem.nodeCount();
    MapEstimate estimate = MapEstimate::unplaced(n);
    std::vector<uint8_t> in_part(n, 0);
    for (uint32_t node : part) {
        in_part[node] = 1;
    }
    uint32_t fixed_in_part = 0;
    for (uint32_t node : part) {
        if (problem.fixed[node] != 0) {
            ++fixed_in_part;
        }
    }
    if (fixed_in_part >= 2) {
        for (uint32_t node : part) {
            if (problem.fixed[node] != 0) {
                estimate.placed[node] = 1;
                estimate.position_m[node] = problem.fixed_position_m[node];
            }
        }
    } else {
        // Eq. 1-3: a at the origin, b on +x, c on the +y side.
        const uint32_t ab = findLink(problem, seed[0], seed[1]);
        const uint32_t bc = findLink(problem, seed[1], seed[2]);
        const uint32_t ca = findLink(problem, seed[2], seed[0]);
        const double r_ab = problem.links[ab].range_m;
        const double r_bc = problem.links[bc].range_m;
        const double r_ca = problem.links[ca].range_m;
        const double x = (r_ab * r_ab + r_ca * r_ca - r_bc * r_bc) / (2.0 * r_ab);
        const double y = std::sqrt(std::max(r_ca * r_ca - x * x, 0.0));
        estimate.position_m[seed[0]] = Vector2::Zero();
        estimate.position_m[seed[1]] = Vector2(r_ab, 0.0);
        estimate.position_m[seed[2]] = Vector2(x, y);
        for (uint32_t node : seed) {
            estimate.placed[node] = 1;
        }
    }
    const double radius_m = problem.unheard_radius_m;
    PointSolverParams solver;
    solver.range_sigma_m = problem.sigma_m;
    solver.max_iterations = 8;
    PlacementParams placement;
    placement.min_baseline_m = params.min_baseline_m;
    placement.distinct_m = params.distinct_m;
    MapRefineParams quick;
    quick.stages = {{2.0, -1.0, -1.0}, {1.0, -1.0, -1.0}};
    quick.iterations_per_stage = 4;

    std::vector<uint32_t> placed_neighbours(n, 0);
    for (uint32_t node = 0; node < n; ++node) {
        if (estimate.placed[node] != 0) {
            for (uint32_t link : problem.node_links[node]) {
                ++placed_neighbours[problem.other(link, node)];
            }
        }
    }
    std::vector<Decision> decisions(n);
    uint32_t placed_count = estimate.placedCount();
    uint32_t refined_at = placed_count;
    auto decide = [&](uint32_t node) {
        Decision &decision = decisions[node];
        decision = Decision{};
        decision.valid = true;
        decision.placed_neighbours = placed_neighbours[node];
        const std::vector<RangeConstraint> constraints = placedConstraints(problem, estimate, node);
        std::vector<PlacementCandidate> candidates = placementCandidates(constraints, likelihood, solver, placement);
        if (candidates.empty()) {
            return;
        }
        for (PlacementCandidate &candidate : candidates) {
            candidate.cost += unheardNodeCost(problem, estimate, node, candidate.position_m);
        }
        std::stable_sort(candidates.begin(), candidates.end(),
                         [](const PlacementCandidate &a, const PlacementCandidate &b) { return a.cost < b.cost; });
        decision.usable = true;
        decision.position_m = candidates.front().position_m;
        decision.gap =
            candidates.size() > 1 ? candidates[1].cost - candidates[0].cost : std::numeric_limits<double>::infinity();
    };
    for (;;) {
        // The next node: decisive with the most placed neighbours, else the least ambiguous.
        uint32_t best = std::numeric_limits<uint32_t>::max();
        bool best_decisive = false;
        for (uint32_t node : part) {
            if (estimate.placed[node] != 0 || placed_neighbours[node] < 2) {
                continue;
            }
            if (!decisions[node].valid || decisions[node].placed_neighbours != placed_neighbours[node]) {
                decide(node);
            }
            const Decision &d = decisions[node];
            if (!d.usable) {
                continue;
            }
            const bool decisive = d.placed_neighbours >= 3 && d.gap >= params.ambiguity_gap_nats;
            if (best == std::numeric_limits<uint32_t>::max()) {
                best = node;
                best_decisive = decisive;
                continue;
            }
            const Decision &b = decisions[best];
            bool better = false;
            if (decisive != best_decisive) {
                better = decisive;
            } else if (decisive) {
                better = d.placed_neighbours > b.placed_neighbours ||
                         (d.placed_neighbours == b.placed_neighbours && d.gap > b.gap);
            } else {
                // Neither decisive: three or more neighbours first, then the larger gap.
                const bool three = d.placed_neighbours >= 3;
                const bool best_three = b.placed_neighbours >= 3;
                better = three != best_three ? three : d.gap > b.gap;
            }
            if (better) {
                best = node;
                best_decisive = decisive;
            }
        }
        if (best == std::numeric_limits<uint32_t>::max()) {
            break;
        }
        const Decision &chosen = decisions[best];
        if (best_decisive) {
            ++counted.decisive;
        } else if (chosen.placed_neighbours >= 3) {
            ++counted.forced;
        } else {
            ++counted.two_links;
        }
        estimate.placed[best] = 1;
        estimate.position_m[best] = chosen.position_m;
        ++placed_count;
        for (uint32_t link : problem.node_links[best]) {
            ++placed_neighbours[problem.other(link, best)];
        }
        // The unheard cost of every pending decision may have changed near the new node.
        for (uint32_t node : part) {
            if (estimate.placed[node] == 0 && decisions[node].valid &&
                (decisions[node].position_m - chosen.position_m).norm() < radius_m + params.distinct_m) {
                decisions[node].valid = false;
            }
        }
        if (placed_count >= 6 &&
            static_cast<double>(placed_count) >= params.refine_growth * static_cast<double>(refined_at)) {
            refineMap(problem, estimate, likelihood, quick);
            ++counted.refinements;
            refined_at = placed_count;
            for (Decision &decision : decisions) {
                decision.valid = false;
            }
        }
    }
    return estimate;
}

} // namespace cdro::engine
