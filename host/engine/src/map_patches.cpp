#include "cdro/engine/map_patches.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>

#include "cdro/engine/alignment.hpp"
#include "cdro/engine/map_growth.hpp"
#include "cdro/engine/map_lift.hpp"
#include "cdro/engine/map_mds.hpp"
#include "cdro/engine/map_refine.hpp"

namespace cdro::engine {

MapProblem subProblem(const MapProblem &problem, const std::vector<uint32_t> &nodes)
{
    MapProblem sub;
    sub.sigma_m = problem.sigma_m;
    sub.unheard_radius_m = problem.unheard_radius_m;
    sub.unheard_cost_nats = problem.unheard_cost_nats;
    std::vector<int> local(problem.nodeCount(), -1);
    for (size_t i = 0; i < nodes.size(); ++i) {
        local[nodes[i]] = static_cast<int>(i);
        sub.ids.push_back(problem.ids[nodes[i]]);
        sub.fixed.push_back(problem.fixed[nodes[i]]);
        sub.fixed_position_m.push_back(problem.fixed_position_m[nodes[i]]);
        sub.listens.push_back(problem.listens[nodes[i]]);
    }
    for (const MapLink &link : problem.links) {
        if (local[link.a] >= 0 && local[link.b] >= 0) {
            sub.links.push_back(
                MapLink{static_cast<uint32_t>(local[link.a]), static_cast<uint32_t>(local[link.b]), link.range_m});
        }
    }
    sub.finish();
    return sub;
}

namespace {

struct Patch {
    std::vector<uint32_t> nodes;     // problem node numbers
    std::vector<Vector2> position_m; // local frame, same order
    std::vector<uint8_t> placed;
    double cost_per_link = 0.0;
    bool merged = false;
};

Patch solvePatch(const MapProblem &problem, const std::vector<uint32_t> &nodes, const RangeLikelihood &likelihood)
{
    Patch patch;
    patch.nodes = nodes;
    MapProblem sub = subProblem(problem, nodes);
    // Fixed coordinates mean nothing in a patch's own frame.
    std::fill(sub.fixed.begin(), sub.fixed.end(), uint8_t{0});
    const std::vector<std::vector<uint32_t>> parts = mapComponents(sub);
    patch.placed.assign(nodes.size(), 0);
    patch.position_m.assign(nodes.size(), Vector2::Zero());
    if (parts.empty() || parts.front().size() < 3) {
        return patch;
    }
    std::vector<MapEstimate> starts;
    const MapGrowthParams growth;
    for (const auto &seed : seedTriangles(sub, parts.front(), growth, 2)) {
        starts.push_back(growMap(sub, parts.front(), seed, likelihood, growth));
    }
    if (std::optional<MapEstimate> layout = mdsMap(sub, parts.front())) {
        starts.push_back(std::move(*layout));
    }
    double best_cost = std::numeric_limits<double>::infinity();
    MapLiftParams lift;
    lift.iterations_per_stage = 10;
    for (MapEstimate &start : starts) {
        liftedRefine(sub, start, likelihood, lift, false);
        // Unplaced nodes of a grown start are priced at a perfect link each (map_problem.hpp).
        const double cost = mapCost(sub, start, likelihood);
        const uint32_t placed = start.placedCount();
        const uint32_t best_placed = static_cast<uint32_t>(std::count(patch.placed.begin(), patch.placed.end(), 1));
        if (placed > best_placed || (placed == best_placed && cost < best_cost)) {
            best_cost = cost;
            patch.placed = start.placed;
            patch.position_m = start.position_m;
        }
    }
    patch.cost_per_link = sub.links.empty() ? 0.0 : best_cost / static_cast<double>(sub.links.size());
    return patch;
}

} // namespace

MapEstimate patchMap(const MapProblem &problem, const std::vector<uint32_t> &part, const RangeLikelihood &likelihood,
                     const MapPatchParams &params)
{
    const uint32_t n = problem.nodeCount();
    MapEstimate map = MapEstimate::unplaced(n);
    std::vector<uint8_t> in_part(n, 0);
    for (uint32_t node : part) {
        in_part[node] = 1;
    }
    std::vector<Patch> patches;
    // A patch is solved from its node set alone: where two centres gather the same nodes (every
    // pair of a room ranging, a clique), the second is a copy of the first, not a second solve.
    std::map<std::vector<uint32_t>, Patch> solved;
    for (uint32_t centre : part) {
        if (problem.node_links[centre].size() < 2) {
            continue;
        }
        std::vector<uint32_t> nodes{centre};
        for (uint32_t other : problem.neighbours[centre]) {
            nodes.push_back(other);
        }
        if (nodes.size() < params.min_patch_nodes) {
            // Neighbours of neighbours, the best linked to the patch first.
            std::vector<std::pair<uint32_t, uint32_t>> extra; // (-links into the patch, node)
            for (uint32_t member : std::vector<uint32_t>(nodes)) {
                for (uint32_t other : problem.neighbours[member]) {
                    if (std::find(nodes.begin(), nodes.end(), other) != nodes.end() ||
                        std::any_of(extra.begin(), extra.end(), [&](const auto &e) { return e.second == other; })) {
                        continue;
                    }
                    uint32_t into = 0;
                    for (uint32_t inside : nodes) {
                        into += problem.linked(other, inside) ? 1U : 0U;
                    }
                    extra.emplace_back(into, other);
                }
            }
            std::stable_sort(extra.begin(), extra.end(),
                             [](const auto &x, const auto &y) { return x.first > y.first; });
            for (const auto &[into, other] : extra) {
                if (nodes.size() >= params.min_patch_nodes) {
                    break;
                }
                nodes.push_back(other);
            }
        }
        std::sort(nodes.begin(), nodes.end());
        auto known = solved.find(nodes);
        if (known == solved.end()) {
            known = solved.emplace(nodes, solvePatch(problem, nodes, likelihood)).first;
        }
        const Patch &patch = known->second;
        if (std::count(patch.placed.begin(), patch.placed.end(), 1) >= 3) {
            patches.push_back(patch);
        }
    }
    if (patches.empty()) {
        return map;
    }
    // The first patch: the most nodes placed, then the best fit.
    size_t first = 0;
    for (size_t i = 1; i < patches.size(); ++i) {
        const auto placed_i = std::count(patches[i].placed.begin(), patches[i].placed.end(), 1);
        const auto placed_f = std::count(patches[first].placed.begin(), patches[first].placed.end(), 1);
        if (placed_i > placed_f || (placed_i == placed_f && patches[i].cost_per_link < patches[first].cost_per_link)) {
            first = i;
        }
    }
    auto adopt = [&](Patch &patch, const RigidTransform &transform) {
        for (size_t k = 0; k < patch.nodes.size(); ++k) {
            const uint32_t node = patch.nodes[k];
            if (patch.placed[k] != 0 && map.placed[node] == 0) {
                map.placed[node] = 1;
                map.position_m[node] = transform.apply(patch.position_m[k]);
            }
        }
        patch.merged = true;
    };
    adopt(patches[first], RigidTransform{});
    uint32_t placed_count = map.placedCount();
    uint32_t refined_at = placed_count;
    MapRefineParams quick;
    quick.stages = {{2.0, -1.0, -1.0}, {1.0, -1.0, -1.0}};
    quick.iterations_per_stage = 5;
    for (;;) {
        // The patch sharing the most nodes with the map that adds one; ties: the better fit.
        size_t best = patches.size();
        uint32_t best_shared = 0;
        for (size_t i = 0; i < patches.size(); ++i) {
            const Patch &patch = patches[i];
            if (patch.merged) {
                continue;
            }
            uint32_t shared = 0;
            uint32_t fresh = 0;
            for (size_t k = 0; k < patch.nodes.size(); ++k) {
                if (patch.placed[k] == 0) {
                    continue;
                }
                (map.placed[patch.nodes[k]] != 0 ? shared : fresh) += 1;
            }
            if (fresh == 0) {
                patches[i].merged = true;
                continue;
            }
            if (shared >= params.min_shared &&
                (shared > best_shared || (shared == best_shared && best < patches.size() &&
                                          patch.cost_per_link < patches[best].cost_per_link))) {
                best = i;
                best_shared = shared;
            }
        }
        if (best == patches.size()) {
            break;
        }
        Patch &patch = patches[best];
        std::vector<Vector2> source;
        std::vector<Vector2> target;
        for (size_t k = 0; k < patch.nodes.size(); ++k) {
            if (patch.placed[k] != 0 && map.placed[patch.nodes[k]] != 0) {
                source.push_back(patch.position_m[k]);
                target.push_back(map.position_m[patch.nodes[k]]);
            }
        }
        // Both handednesses; the links of the new nodes decide when the fits are close.
        const RigidTransform proper = fitRigid(source, target, false);
        RigidTransform mirrored = proper;
        {
            std::vector<Vector2> flipped = source;
            for (Vector2 &p : flipped) {
                p.y() = -p.y();
            }
            mirrored = fitRigid(flipped, target, false);
            mirrored.rotation = mirrored.rotation * Matrix2(Eigen::Vector2d(1.0, -1.0).asDiagonal());
            mirrored.reflected = true;
        }
        RigidTransform chosen = proper.rms_error_m <= mirrored.rms_error_m ? proper : mirrored;
        const double spread = std::abs(proper.rms_error_m - mirrored.rms_error_m);
        if (spread < 3.0 * problem.sigma_m) {
            double best_cost = std::numeric_limits<double>::infinity();
            for (const RigidTransform &option : {proper, mirrored}) {
                MapEstimate trial = map;
                for (size_t k = 0; k < patch.nodes.size(); ++k) {
                    if (patch.placed[k] != 0 && trial.placed[patch.nodes[k]] == 0) {
                        trial.placed[patch.nodes[k]] = 1;
                        trial.position_m[patch.nodes[k]] = option.apply(patch.position_m[k]);
                    }
                }
                const double cost = mapCost(problem, trial, likelihood);
                if (cost < best_cost) {
                    best_cost = cost;
                    chosen = option;
                }
            }
        }
        adopt(patch, chosen);
        placed_count = map.placedCount();
        if (static_cast<double>(placed_count) >= params.refine_growth * static_cast<double>(refined_at)) {
            refineMap(problem, map, likelihood, quick);
            refined_at = placed_count;
        }
    }
    return map;
}

} // namespace cdro::engine
