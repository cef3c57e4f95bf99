#include "cdro/engine/map_problem.hpp"

#include <algorithm>
#include <cmath>

namespace cdro::engine {

void MapProblem::finish()
{
    for (MapLink &link : links) {
        if (link.b < link.a) {
            std::swap(link.a, link.b);
        }
    }
    std::sort(links.begin(), links.end(),
              [](const MapLink &x, const MapLink &y) { return x.a != y.a ? x.a < y.a : x.b < y.b; });
    fixed.resize(ids.size(), 0);
    fixed_position_m.resize(ids.size(), Vector2::Zero());
    listens.resize(ids.size(), 0);
    node_links.assign(ids.size(), {});
    neighbours.assign(ids.size(), {});
    for (uint32_t link = 0; link < links.size(); ++link) {
        node_links[links[link].a].push_back(link);
        node_links[links[link].b].push_back(link);
        neighbours[links[link].a].push_back(links[link].b);
        neighbours[links[link].b].push_back(links[link].a);
    }
    for (std::vector<uint32_t> &list : neighbours) {
        std::sort(list.begin(), list.end());
    }
}

bool MapProblem::linked(uint32_t a, uint32_t b) const
{
    return std::binary_search(neighbours[a].begin(), neighbours[a].end(), b);
}

double unheardRadiusFor(const MapProblem &problem, double share)
{
    if (problem.links.empty()) {
        return 0.0;
    }
    std::vector<double> ranges;
    ranges.reserve(problem.links.size());
    for (const MapLink &link : problem.links) {
        ranges.push_back(link.range_m);
    }
    std::nth_element(ranges.begin(), ranges.begin() + static_cast<std::ptrdiff_t>(ranges.size() / 2), ranges.end());
    return share * ranges[ranges.size() / 2];
}

void forEachCloseUnheardPair(const MapProblem &problem, const std::vector<uint8_t> &placed,
                             const Eigen::MatrixXd &positions,
                             const std::function<void(uint32_t, uint32_t, double)> &visit)
{
    const double radius = problem.unheard_radius_m;
    if (radius <= 0.0) {
        return;
    }
    // A grid of cells one radius wide: close pairs are in the same or a neighbouring cell. The
    // occupied cells as one sorted array (cell, then node), without a container per cell: the
    // pairs come out ordered by cell, then by node, so the sums over them are the same every run.
    // A position that is not finite, or so far out that its cell number would not fit (a map
    // a solve step threw away), has no close pair to check: it is left out, not cast.
    constexpr double kFarthestCell = 1e15;
    struct Member {
        int64_t cell_x;
        int64_t cell_y;
        uint32_t node;
    };
    auto before = [](const Member &p, const Member &q) {
        return p.cell_x != q.cell_x ? p.cell_x < q.cell_x
                                    : (p.cell_y != q.cell_y ? p.cell_y < q.cell_y : p.node < q.node);
    };
    std::vector<Member> members;
    members.reserve(problem.nodeCount());
    for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
        if (placed[node] != 0 && problem.listens[node] != 0) {
            const double cell_x = std::floor(positions(node, 0) / radius);
            const double cell_y = std::floor(positions(node, 1) / radius);
            if (!(std::abs(cell_x) < kFarthestCell && std::abs(cell_y) < kFarthestCell)) {
                continue;
            }
            members.push_back(Member{static_cast<int64_t>(cell_x), static_cast<int64_t>(cell_y), node});
        }
    }
    std::sort(members.begin(), members.end(), before);
    for (size_t first = 0; first < members.size();) {
        size_t end = first;
        while (end < members.size() && members[end].cell_x == members[first].cell_x &&
               members[end].cell_y == members[first].cell_y) {
            ++end;
        }
        for (int64_t dx = -1; dx <= 1; ++dx) {
            for (int64_t dy = -1; dy <= 1; ++dy) {
                const Member key{members[first].cell_x + dx, members[first].cell_y + dy, 0};
                auto other = std::lower_bound(members.begin(), members.end(), key, before);
                for (size_t i = first; i < end; ++i) {
                    const uint32_t a = members[i].node;
                    for (auto it = other; it != members.end() && it->cell_x == key.cell_x && it->cell_y == key.cell_y;
                         ++it) {
                        const uint32_t b = it->node;
                        if (b <= a) {
                            continue;
                        }
                        const double distance = (positions.row(a) - positions.row(b)).norm();
                        if (distance < radius && !problem.linked(a, b)) {
                            visit(a, b, distance);
                        }
                    }
                }
            }
        }
        first = end;
    }
}

uint32_t MapProblem::fixedCount() const
{
    return static_cast<uint32_t>(std::count(fixed.begin(), fixed.end(), uint8_t{1}));
}

MapEstimate MapEstimate::unplaced(uint32_t nodes)
{
    MapEstimate estimate;
    estimate.placed.assign(nodes, 0);
    estimate.position_m.assign(nodes, Vector2::Zero());
    return estimate;
}

uint32_t MapEstimate::placedCount() const
{
    return static_cast<uint32_t>(std::count(placed.begin(), placed.end(), uint8_t{1}));
}

double mapCost(const MapProblem &problem, const MapEstimate &estimate, const RangeLikelihood &likelihood,
               double sigma_scale)
{
    const double sigma = problem.sigma_m * sigma_scale;
    const double variance = sigma * sigma;
    double cost = 0.0;
    for (const MapLink &link : problem.links) {
        if (estimate.placed[link.a] != 0 && estimate.placed[link.b] != 0) {
            const double distance = (estimate.position_m[link.a] - estimate.position_m[link.b]).norm();
            cost -= likelihood.logDensity(link.range_m - distance, variance);
        }
    }
    if (problem.unheard_radius_m > 0.0) {
        Eigen::MatrixXd positions(problem.nodeCount(), 2);
        for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
            positions.row(node) = estimate.position_m[node].transpose();
        }
        forEachCloseUnheardPair(problem, estimate.placed, positions,
                                [&](uint32_t, uint32_t, double distance) { cost += problem.unheardCost(distance); });
    }
    return cost;
}

double nodeCost(const MapProblem &problem, const MapEstimate &estimate, const RangeLikelihood &likelihood,
                uint32_t node, const Vector2 &position_m)
{
    const double variance = problem.sigma_m * problem.sigma_m;
    double cost = 0.0;
    for (uint32_t link : problem.node_links[node]) {
        const uint32_t other = problem.other(link, node);
        if (estimate.placed[other] != 0) {
            const double distance = (position_m - estimate.position_m[other]).norm();
            cost -= likelihood.logDensity(problem.links[link].range_m - distance, variance);
        }
    }
    return cost + unheardNodeCost(problem, estimate, node, position_m);
}

double unheardNodeCost(const MapProblem &problem, const MapEstimate &estimate, uint32_t node, const Vector2 &position_m)
{
    double cost = 0.0;
    if (problem.unheard_radius_m > 0.0 && problem.listens[node] != 0) {
        for (uint32_t other = 0; other < problem.nodeCount(); ++other) {
            if (other != node && estimate.placed[other] != 0 && problem.unheardPair(node, other)) {
                cost += problem.unheardCost((estimate.position_m[other] - position_m).norm());
            }
        }
    }
    return cost;
}

RangeLikelihood mapLikelihood(const RangeLikelihoodParams &params)
{
    RangeLikelihoodParams unfloored = params;
    unfloored.gross_density_per_m = 0.0;
    return RangeLikelihood(unfloored);
}

std::vector<std::vector<uint32_t>> mapComponents(const MapProblem &problem)
{
    const uint32_t count = problem.nodeCount();
    std::vector<uint8_t> seen(count, 0);
    std::vector<std::vector<uint32_t>> parts;
    for (uint32_t start = 0; start < count; ++start) {
        if (seen[start] != 0 || problem.node_links[start].empty()) {
            continue;
        }
        std::vector<uint32_t> part;
        std::vector<uint32_t> stack{start};
        seen[start] = 1;
        while (!stack.empty()) {
            const uint32_t node = stack.back();
            stack.pop_back();
            part.push_back(node);
            for (uint32_t link : problem.node_links[node]) {
                const uint32_t other = problem.other(link, node);
                if (seen[other] == 0) {
                    seen[other] = 1;
                    stack.push_back(other);
                }
            }
        }
        std::sort(part.begin(), part.end());
        parts.push_back(std::move(part));
    }
    std::stable_sort(parts.begin(), parts.end(), [](const auto &x, const auto &y) { return x.size() > y.size(); });
    return parts;
}

} // namespace cdro::engine
