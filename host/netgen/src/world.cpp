#include "cdro/netgen/world.hpp"

#include <algorithm>
#include <cmath>
#include <set>

namespace cdro::netgen {

double World::distance3dM(const WorldLink &link) const
{
    return (nodes[link.a].position_m - nodes[link.b].position_m).norm();
}

double World::distance2dM(const WorldLink &link) const
{
    return (nodes[link.a].position_m.head<2>() - nodes[link.b].position_m.head<2>()).norm();
}

double World::biasM(const WorldLink &link) const
{
    return nodes[link.a].antenna_delay_m + nodes[link.b].antenna_delay_m + link.excess_m;
}

double World::measureM(const WorldLink &link, Random &random) const
{
    double range_m = distance3dM(link) + biasM(link) + noise.sigma_m * random.normal();
    if (noise.sporadic_probability > 0.0 && random.chance(noise.sporadic_probability)) {
        range_m += random.exponential(noise.sporadic_mean_m);
    }
    return std::max(range_m, 0.01);
}

bool connectedGraph(const std::vector<std::vector<uint32_t>> &adjacent)
{
    if (adjacent.empty()) {
        return true;
    }
    std::vector<bool> seen(adjacent.size(), false);
    std::vector<uint32_t> stack{0};
    seen[0] = true;
    size_t reached = 1;
    while (!stack.empty()) {
        const uint32_t node = stack.back();
        stack.pop_back();
        for (uint32_t other : adjacent[node]) {
            if (!seen[other]) {
                seen[other] = true;
                ++reached;
                stack.push_back(other);
            }
        }
    }
    return reached == adjacent.size();
}

bool World::connected() const
{
    std::vector<std::vector<uint32_t>> adjacent(nodes.size());
    for (const WorldLink &link : links) {
        adjacent[link.a].push_back(link.b);
        adjacent[link.b].push_back(link.a);
    }
    return connectedGraph(adjacent);
}

uint32_t World::degree(uint32_t node) const
{
    return static_cast<uint32_t>(std::count_if(links.begin(), links.end(), [&](const WorldLink &link) {
        return link.a == node || link.b == node;
    }));
}

namespace {

double cross(const Vector2 &u, const Vector2 &v) { return u.x() * v.y() - u.y() * v.x(); }

bool segmentsIntersect(const Vector2 &p, const Vector2 &p2, const Vector2 &q, const Vector2 &q2)
{
    const Vector2 r = p2 - p;
    const Vector2 s = q2 - q;
    const double denominator = cross(r, s);
    if (std::abs(denominator) < 1e-12) {
        return false; // parallel: a path along a wall does not cross it
    }
    const double t = cross(q - p, s) / denominator;
    const double u = cross(q - p, r) / denominator;
    return t >= 0.0 && t <= 1.0 && u >= 0.0 && u <= 1.0;
}

} // namespace

uint32_t wallsCrossed(const std::vector<WallSegment> &walls, const Vector2 &from_m, const Vector2 &to_m)
{
    uint32_t count = 0;
    for (const WallSegment &wall : walls) {
        count += segmentsIntersect(from_m, to_m, wall.from_m, wall.to_m) ? 1U : 0U;
    }
    return count;
}

std::vector<NodeId> drawNodeIds(Random &random, size_t count)
{
    std::set<NodeId> used;
    std::vector<NodeId> ids;
    while (ids.size() < count) {
        const auto id = static_cast<NodeId>(0x1000 + random.below(0xFEFF - 0x1000 + 1));
        if (used.insert(id).second) {
            ids.push_back(id);
        }
    }
    return ids;
}

} // namespace cdro::netgen
