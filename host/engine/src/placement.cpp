#include "cdro/engine/placement.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace cdro::engine {

namespace {
constexpr size_t kSeedNeighbours = 16; // links whose pairs seed a node's candidates, at most
} // namespace

std::vector<PlacementCandidate> placementCandidates(const std::vector<RangeConstraint> &constraints,
                                                    const RangeLikelihood &likelihood, const PointSolverParams &solver,
                                                    const PlacementParams &params)
{
    std::vector<PlacementCandidate> solutions;
    // The seeds come from pairs of the kSeedNeighbours shortest links (the likeliest in line of
    // sight; every link where there are no more), each polished on all of them: a node with k
    // neighbours would otherwise be tried from k(k - 1) / 2 pairs, each polish O(k), and in a
    // room where every pair of 40 nodes ranges that is most of the map's time (docs/bench.md).
    std::vector<size_t> seeding(constraints.size());
    for (size_t i = 0; i < seeding.size(); ++i) {
        seeding[i] = i;
    }
    if (seeding.size() > kSeedNeighbours) {
        std::stable_sort(seeding.begin(), seeding.end(),
                         [&](size_t x, size_t y) { return constraints[x].range_m < constraints[y].range_m; });
        seeding.resize(kSeedNeighbours);
        std::sort(seeding.begin(), seeding.end());
    }
    const size_t count = seeding.size();
    for (size_t first = 0; first < count; ++first) {
        for (size_t second = first + 1; second < count; ++second) {
            const RangeConstraint &a = constraints[seeding[first]];
            const RangeConstraint &b = constraints[seeding[second]];
            const Vector2 baseline = b.anchor_m - a.anchor_m;
            const double length = baseline.norm();
            if (length < params.min_baseline_m) {
                continue;
            }
            // Eq. 4 in the frame of the pair: x along the baseline, y off it (both signs).
            const double along = (length * length + a.range_m * a.range_m - b.range_m * b.range_m) / (2.0 * length);
            const double across = std::sqrt(std::max(a.range_m * a.range_m - along * along, 0.0));
            const Vector2 unit_x = baseline / length;
            const Vector2 unit_y(-unit_x.y(), unit_x.x());
            for (double sign : {1.0, -1.0}) {
                const Vector2 seed = a.anchor_m + along * unit_x + sign * across * unit_y;
                const PointSolution polished = solvePoint(constraints, seed, likelihood, solver);
                PlacementCandidate candidate;
                candidate.position_m = polished.position_m;
                candidate.covariance_m2 = polished.covariance_m2;
                candidate.cost = polished.cost;
                solutions.push_back(candidate);
                if (across == 0.0) {
                    break; // tangent circles: one seed
                }
            }
        }
    }
    std::stable_sort(solutions.begin(), solutions.end(),
                     [](const PlacementCandidate &x, const PlacementCandidate &y) { return x.cost < y.cost; });
    std::vector<PlacementCandidate> distinct;
    for (const PlacementCandidate &candidate : solutions) {
        const bool known = std::any_of(distinct.begin(), distinct.end(), [&](const PlacementCandidate &kept) {
            return (kept.position_m - candidate.position_m).norm() < params.distinct_m;
        });
        if (!known) {
            distinct.push_back(candidate);
        }
    }
    return distinct;
}

PlacementChoice choosePlacement(const std::vector<PlacementCandidate> &candidates, size_t constraint_count,
                                const PlacementParams &params)
{
    PlacementChoice choice;
    if (candidates.empty()) {
        return choice;
    }
    // Two neighbours never decide by themselves (two mirror images fit exactly, or, tangent,
    // one that the next range may move to either side). Three or more decide when every seed
    // led to one solution, or the best beats every rival clearly.
    choice.decision = PlacementDecision::Ambiguous;
    if (constraint_count >= 3 &&
        (candidates.size() == 1 || candidates[1].cost - candidates[0].cost >= params.ambiguity_gap_nats)) {
        choice.decision = PlacementDecision::Placed;
        choice.chosen = candidates[0];
    }
    return choice;
}

std::optional<FrameTriangle> chooseFrameTriangle(const MapState &network, const PlacementParams &params,
                                                 const std::vector<bool> &eligible,
                                                 const std::optional<std::array<uint32_t, 3>> &preferred)
{
    auto range = [&](uint32_t x, uint32_t y) {
        const uint32_t link = network.findLink(x, y);
        return link == kNoIndex ? -1.0 : network.links[link].representative_m;
    };
    // Height of the triangle with sides ab, ac, bc over its longest side (Heron); 0 if degenerate.
    auto minimumHeight = [](double ab, double ac, double bc) {
        const double half = 0.5 * (ab + ac + bc);
        const double area_squared = half * (half - ab) * (half - ac) * (half - bc);
        if (!(area_squared > 0.0)) {
            return 0.0;
        }
        return 2.0 * std::sqrt(area_squared) / std::max({ab, ac, bc});
    };
    auto place = [&](uint32_t origin, uint32_t x_axis, uint32_t positive_y) {
        const double r01 = range(origin, x_axis);
        const double r02 = range(origin, positive_y);
        const double r12 = range(x_axis, positive_y);
        FrameTriangle triangle;
        triangle.origin = origin;
        triangle.x_axis = x_axis;
        triangle.positive_y = positive_y;
        triangle.x_axis_m = Vector2(r01, 0.0);
        const double x2 = (r01 * r01 + r02 * r02 - r12 * r12) / (2.0 * r01);
        triangle.positive_y_m = Vector2(x2, std::sqrt(std::max(r02 * r02 - x2 * x2, 0.0)));
        return triangle;
    };

    if (preferred) {
        const auto [o, x, y] = *preferred;
        if (o != kNoIndex && x != kNoIndex && y != kNoIndex && eligible[o] && eligible[x] && eligible[y]) {
            const double ox = range(o, x);
            const double oy = range(o, y);
            const double xy = range(x, y);
            if (ox > 0.0 && oy > 0.0 && xy > 0.0 && minimumHeight(ox, oy, xy) >= params.min_triangle_height_m) {
                return place(o, x, y);
            }
        }
    }

    double best_score = -1.0;
    std::optional<FrameTriangle> best;
    for (const LinkState &ab : network.links) {
        const uint32_t a = ab.node_a;
        const uint32_t b = ab.node_b;
        if (!eligible[a] || !eligible[b]) {
            continue;
        }
        for (uint32_t link_ac : network.nodes[a].links) {
            const uint32_t c = network.otherNode(link_ac, a);
            // Each triangle once: c after both a and b in node order.
            if (c <= a || c <= b || !eligible[c]) {
                continue;
            }
            const double bc = range(b, c);
            if (bc <= 0.0) {
                continue;
            }
            const double ac = network.links[link_ac].representative_m;
            const double height = minimumHeight(ab.representative_m, ac, bc);
            if (height < params.min_triangle_height_m) {
                continue;
            }
            const double degree = static_cast<double>(network.nodes[a].links.size() + network.nodes[b].links.size() +
                                                      network.nodes[c].links.size());
            // Well spread (height up to 5 m counts) and well connected (more nodes will see it).
            const double score = std::min(height, 5.0) * degree;
            if (score <= best_score) {
                continue;
            }
            best_score = score;
            // The longest side is the baseline p0-p1; p0 is its better-connected end.
            std::array<std::array<uint32_t, 3>, 3> orders{{{a, b, c}, {a, c, b}, {b, c, a}}};
            const std::array<double, 3> lengths{ab.representative_m, ac, bc};
            const size_t longest =
                static_cast<size_t>(std::max_element(lengths.begin(), lengths.end()) - lengths.begin());
            auto [p0, p1, p2] = orders[longest];
            if (network.nodes[p1].links.size() > network.nodes[p0].links.size()) {
                std::swap(p0, p1);
            }
            best = place(p0, p1, p2);
        }
    }
    return best;
}

} // namespace cdro::engine
