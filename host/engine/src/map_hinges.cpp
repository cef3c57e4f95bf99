#include "cdro/engine/map_hinges.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <optional>
#include <utility>
#include <vector>

#include "cdro/engine/foldable.hpp"
#include "cdro/engine/map_connectivity.hpp"

namespace cdro::engine {
namespace {

constexpr double kTwoPi = 6.28318530717958647692;
// A move must take at least this off the unheard pairs' cost: below it, two places are the same
// to the model, and the part stays where the start put it.
constexpr double kMinGainNats = 0.01;
// Hinge nodes closer than this give no line to reflect across (m).
constexpr double kShortestHingeM = 1e-6;
constexpr uint32_t kPasses = 3;

struct FreePart {
    std::array<uint32_t, 2> hinge{kNoHinge, kNoHinge}; // the second kNoHinge: a one-node hinge
    std::vector<uint32_t> nodes;                       // ascending
};

// The nodes reached from `start` over links between placed nodes without entering the hinge.
std::vector<uint32_t> reachedWithout(const MapProblem &problem, const MapEstimate &estimate, uint32_t start,
                                     const std::array<uint32_t, 2> &hinge)
{
    std::vector<uint8_t> seen(problem.nodeCount(), 0);
    for (uint32_t h : hinge) {
        if (h != kNoHinge) {
            seen[h] = 1;
        }
    }
    std::vector<uint32_t> reached{start};
    seen[start] = 1;
    for (size_t next = 0; next < reached.size(); ++next) {
        for (uint32_t link : problem.node_links[reached[next]]) {
            const uint32_t other = problem.other(link, reached[next]);
            if (seen[other] == 0 && estimate.placed[other] != 0) {
                seen[other] = 1;
                reached.push_back(other);
            }
        }
    }
    std::sort(reached.begin(), reached.end());
    return reached;
}

// The part's hinge as its links say: the nodes outside it that it has links to (kNoHinge
// padded), or nothing when there are more than two or it holds a fixed node.
std::optional<std::array<uint32_t, 2>> hingeOf(const MapProblem &problem, const MapEstimate &estimate,
                                               const std::vector<uint32_t> &nodes)
{
    std::array<uint32_t, 2> hinge{kNoHinge, kNoHinge};
    uint32_t count = 0;
    for (uint32_t node : nodes) {
        if (problem.fixed[node] != 0) {
            return std::nullopt;
        }
        for (uint32_t link : problem.node_links[node]) {
            const uint32_t other = problem.other(link, node);
            if (estimate.placed[other] == 0 || std::binary_search(nodes.begin(), nodes.end(), other) ||
                (count > 0 && hinge[0] == other) || (count > 1 && hinge[1] == other)) {
                continue;
            }
            if (count == 2) {
                return std::nullopt;
            }
            hinge[count++] = other;
        }
    }
    if (count == 0) {
        return std::nullopt;
    }
    if (count == 2 && hinge[1] < hinge[0]) {
        std::swap(hinge[0], hinge[1]);
    }
    return hinge;
}

// Every part that hangs on one or two nodes and is the smaller side of its cut, largest first (an
// outer part before the parts inside it), each once: the parts each cut node's removal cuts off,
// and the parts cut off by the two-node hinges foldable.hpp finds.
std::vector<FreePart> freeParts(const MapProblem &problem, const MapEstimate &estimate)
{
    const uint32_t count = problem.nodeCount();
    const uint32_t placed = estimate.placedCount();
    std::vector<FreePart> parts;
    auto consider = [&](std::vector<uint32_t> nodes) {
        if (2 * nodes.size() >= placed) {
            return;
        }
        const std::optional<std::array<uint32_t, 2>> hinge = hingeOf(problem, estimate, nodes);
        if (!hinge) {
            return;
        }
        const bool known = std::any_of(parts.begin(), parts.end(), [&](const FreePart &other) {
            return other.hinge == *hinge && other.nodes == nodes;
        });
        if (!known) {
            parts.push_back(FreePart{*hinge, std::move(nodes)});
        }
    };
    std::vector<std::pair<uint32_t, uint32_t>> edges;
    edges.reserve(problem.links.size());
    for (const MapLink &link : problem.links) {
        edges.emplace_back(link.a, link.b);
    }
    for (uint32_t cut : cutNodes(count, edges, estimate.placed)) {
        std::vector<uint8_t> done(count, 0);
        for (uint32_t link : problem.node_links[cut]) {
            const uint32_t start = problem.other(link, cut);
            if (estimate.placed[start] != 0 && done[start] == 0) {
                std::vector<uint32_t> nodes = reachedWithout(problem, estimate, start, {cut, kNoHinge});
                for (uint32_t node : nodes) {
                    done[node] = 1;
                }
                consider(std::move(nodes));
            }
        }
    }
    const Foldable folds = findFoldable(count, edges, estimate.placed, problem.fixed);
    for (uint32_t node = 0; node < count; ++node) {
        if (folds.foldable[node] != 0 && folds.hinge[node][1] != kNoHinge && estimate.placed[node] != 0) {
            consider(reachedWithout(problem, estimate, node, folds.hinge[node]));
        }
    }
    std::stable_sort(parts.begin(), parts.end(),
                     [](const FreePart &x, const FreePart &y) { return x.nodes.size() > y.nodes.size(); });
    return parts;
}

// x -> centre + linear (x - centre).
struct PartMove {
    Matrix2 linear = Matrix2::Identity();
    Vector2 centre_m = Vector2::Zero();
};

} // namespace

HingeStats placeFreeParts(const MapProblem &problem, MapEstimate &estimate, const HingeParams &params)
{
    HingeStats stats;
    if (estimate.placedCount() < 4) {
        return stats;
    }
    const ConnectivityFit fit = connectivityCost(problem, estimate);
    if (!(fit.width_m > 0.0)) {
        return stats;
    }
    const std::vector<FreePart> parts = freeParts(problem, estimate);
    stats.parts = static_cast<uint32_t>(parts.size());
    // The unheard pairs between each part and the rest: the only pairs a move changes (the part's
    // links go to its hinge, whose distances to it a move keeps).
    std::vector<std::vector<std::pair<uint32_t, uint32_t>>> unheard(parts.size());
    for (size_t p = 0; p < parts.size(); ++p) {
        std::vector<uint8_t> inside(problem.nodeCount(), 0);
        for (uint32_t node : parts[p].nodes) {
            inside[node] = 1;
        }
        for (uint32_t node : parts[p].nodes) {
            for (uint32_t other = 0; other < problem.nodeCount(); ++other) {
                if (inside[other] == 0 && estimate.placed[other] != 0 && problem.unheardPair(node, other)) {
                    unheard[p].emplace_back(node, other);
                }
            }
        }
    }
    // An inner part's best place depends on where its outer part went, and back: a few passes.
    for (uint32_t pass = 0; pass < kPasses; ++pass) {
        const uint32_t moved_before = stats.moved;
        for (size_t p = 0; p < parts.size(); ++p) {
            const FreePart &part = parts[p];
            const std::vector<std::pair<uint32_t, uint32_t>> &pairs = unheard[p];
            if (pairs.empty()) {
                continue;
            }
            auto costOf = [&](const PartMove &move) {
                double cost = 0.0;
                for (const auto &[node, other] : pairs) {
                    const Vector2 at_m = move.centre_m + move.linear * (estimate.position_m[node] - move.centre_m);
                    const double distance_m = (at_m - estimate.position_m[other]).norm();
                    cost += -std::log(1.0 - heardProbability(fit, distance_m)) + problem.unheardCost(distance_m);
                }
                return cost;
            };
            std::vector<PartMove> moves;
            if (part.hinge[1] == kNoHinge) {
                const Vector2 centre_m = estimate.position_m[part.hinge[0]];
                for (const Matrix2 &mirror :
                     {Matrix2(Matrix2::Identity()), Matrix2(Eigen::Vector2d(1.0, -1.0).asDiagonal())}) {
                    for (uint32_t k = 0; k < params.turns; ++k) {
                        const double angle = kTwoPi * k / params.turns;
                        Matrix2 turn;
                        turn << std::cos(angle), -std::sin(angle), std::sin(angle), std::cos(angle);
                        if (k == 0 && mirror(1, 1) > 0.0) {
                            continue; // where it is
                        }
                        moves.push_back({turn * mirror, centre_m});
                    }
                }
            } else {
                const Vector2 along = estimate.position_m[part.hinge[1]] - estimate.position_m[part.hinge[0]];
                if (along.norm() < kShortestHingeM) {
                    continue;
                }
                const Vector2 unit = along.normalized();
                moves.push_back(
                    {2.0 * unit * unit.transpose() - Matrix2::Identity(), estimate.position_m[part.hinge[0]]});
            }
            const double here = costOf(PartMove{}); // where it is
            double best = here;
            const PartMove *chosen = nullptr;
            for (const PartMove &move : moves) {
                const double cost = costOf(move);
                if (cost < best) {
                    best = cost;
                    chosen = &move;
                }
            }
            if (chosen != nullptr && best < here - kMinGainNats) {
                for (uint32_t node : part.nodes) {
                    estimate.position_m[node] =
                        chosen->centre_m + chosen->linear * (estimate.position_m[node] - chosen->centre_m);
                }
                ++stats.moved;
                stats.gained_nats += here - best;
            }
        }
        if (stats.moved == moved_before) {
            break;
        }
    }
    return stats;
}

} // namespace cdro::engine
