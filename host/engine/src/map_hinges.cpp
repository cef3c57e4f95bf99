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
// A part on two links: the best sampled swing is refined by this many halvings of the step.
constexpr uint32_t kSwingHalvings = 5;

// How a free part hangs on the rest of the map, and so how it can move without changing a range.
enum class Joint : uint8_t {
    kOneNode,  // turns about the hinge node (in both mirror images)
    kTwoNodes, // reflected across the line through the two hinge nodes
    kTwoLinks, // two links from the part to two other nodes: swings, both lengths kept
};

struct FreePart {
    Joint joint = Joint::kOneNode;
    std::array<uint32_t, 2> hinge{kNoHinge, kNoHinge}; // the hinge's nodes (kOneNode: the second kNoHinge)
    std::array<uint32_t, 2> links{kNoHinge, kNoHinge}; // kTwoLinks: the two links, else kNoHinge
    std::vector<uint32_t> nodes;                       // ascending
};

// The nodes reached from `start` over links between placed nodes without entering the hinge's
// nodes or crossing the given links (kNoHinge: none).
std::vector<uint32_t> reachedWithout(const MapProblem &problem, const MapEstimate &estimate, uint32_t start,
                                     const std::array<uint32_t, 2> &hinge,
                                     const std::array<uint32_t, 2> &cut_links = {kNoHinge, kNoHinge})
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
            if (seen[other] == 0 && estimate.placed[other] != 0 && link != cut_links[0] && link != cut_links[1]) {
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

// Every part that hangs on one or two nodes, or on two links, and is the smaller side of its cut,
// largest first (an outer part before the parts inside it), each once: the parts each cut node's
// removal cuts off, the parts cut off by the two-node hinges foldable.hpp finds, and those cut off
// by two links to two other nodes (twoLinkCuts; one of those parts is the same as a two-node
// hinge's only where both links leave one of its nodes, and is then turned about that node too).
std::vector<FreePart> freeParts(const MapProblem &problem, const MapEstimate &estimate)
{
    const uint32_t count = problem.nodeCount();
    const uint32_t placed = estimate.placedCount();
    std::vector<FreePart> parts;
    auto known = [&](const FreePart &part) {
        return std::any_of(parts.begin(), parts.end(), [&](const FreePart &other) {
            return other.joint == part.joint && other.hinge == part.hinge && other.links == part.links &&
                   other.nodes == part.nodes;
        });
    };
    auto consider = [&](std::vector<uint32_t> nodes) {
        if (2 * nodes.size() >= placed) {
            return;
        }
        const std::optional<std::array<uint32_t, 2>> hinge = hingeOf(problem, estimate, nodes);
        if (!hinge) {
            return;
        }
        FreePart part{(*hinge)[1] == kNoHinge ? Joint::kOneNode : Joint::kTwoNodes,
                      *hinge,
                      {kNoHinge, kNoHinge},
                      std::move(nodes)};
        if (!known(part)) {
            parts.push_back(std::move(part));
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
    for (const std::array<uint32_t, 2> &cut : twoLinkCuts(count, edges, estimate.placed)) {
        const MapLink &first = problem.links[cut[0]];
        const MapLink &second = problem.links[cut[1]];
        std::vector<uint32_t> nodes = reachedWithout(problem, estimate, first.a, {kNoHinge, kNoHinge}, cut);
        if (std::binary_search(nodes.begin(), nodes.end(), first.b)) {
            continue; // the two links do not cut the map (two labels that collided)
        }
        if (2 * nodes.size() >= placed) {
            nodes = reachedWithout(problem, estimate, first.b, {kNoHinge, kNoHinge}, cut);
        }
        const auto inside = [&](uint32_t node) { return std::binary_search(nodes.begin(), nodes.end(), node); };
        const uint32_t outer_first = inside(first.a) ? first.b : first.a;
        const uint32_t outer_second = inside(second.a) ? second.b : second.a;
        const bool anchored =
            std::any_of(nodes.begin(), nodes.end(), [&](uint32_t node) { return problem.fixed[node] != 0; });
        // Both links to one node outside: a one-node hinge, found above.
        if (2 * nodes.size() >= placed || outer_first == outer_second || anchored) {
            continue;
        }
        FreePart part{Joint::kTwoLinks, {kNoHinge, kNoHinge}, cut, std::move(nodes)};
        if (!known(part)) {
            parts.push_back(std::move(part));
        }
    }
    std::stable_sort(parts.begin(), parts.end(),
                     [](const FreePart &x, const FreePart &y) { return x.nodes.size() > y.nodes.size(); });
    return parts;
}

// x -> to + linear (x - from).
struct PartMove {
    Matrix2 linear = Matrix2::Identity();
    Vector2 from_m = Vector2::Zero();
    Vector2 to_m = Vector2::Zero();

    Vector2 apply(const Vector2 &x_m) const { return to_m + linear * (x_m - from_m); }
};

Matrix2 turnBy(double angle)
{
    Matrix2 turn;
    turn << std::cos(angle), -std::sin(angle), std::sin(angle), std::cos(angle);
    return turn;
}

// The reflection across a line along `unit`.
Matrix2 mirrorAlong(const Vector2 &unit) { return 2.0 * unit * unit.transpose() - Matrix2::Identity(); }

// A part joined by two links: their ends in the part (inner) and outside it (outer), and the
// lengths the map gives them, which every swing keeps.
struct TwoLinkJoint {
    std::array<Vector2, 2> inner_m;
    std::array<Vector2, 2> outer_m;
    std::array<double, 2> length_m{};
    double span_m = 0.0; // between the inner ends
};

TwoLinkJoint jointOf(const MapProblem &problem, const MapEstimate &estimate, const FreePart &part)
{
    TwoLinkJoint joint;
    for (size_t k = 0; k < 2; ++k) {
        const MapLink &link = problem.links[part.links[k]];
        const bool a_inside = std::binary_search(part.nodes.begin(), part.nodes.end(), link.a);
        joint.inner_m[k] = estimate.position_m[a_inside ? link.a : link.b];
        joint.outer_m[k] = estimate.position_m[a_inside ? link.b : link.a];
        joint.length_m[k] = (joint.inner_m[k] - joint.outer_m[k]).norm();
    }
    joint.span_m = (joint.inner_m[1] - joint.inner_m[0]).norm();
    return joint;
}

// The part swung so that its first link points at `angle` from its outer end, its second link
// closing on the `branch` (0, 1) side, mirrored first across the line of its inner ends when
// `mirrored`; nothing where the second link cannot close.
std::optional<PartMove> swing(const TwoLinkJoint &joint, double angle, int branch, bool mirrored)
{
    const Vector2 first_m = joint.outer_m[0] + joint.length_m[0] * Vector2(std::cos(angle), std::sin(angle));
    // The second inner end: on the circle about `first_m` of the span, and on the circle about
    // the second outer end of the second link's length.
    const Vector2 apart = joint.outer_m[1] - first_m;
    const double d = apart.norm();
    if (d < kShortestHingeM || d > joint.span_m + joint.length_m[1] || d < std::abs(joint.span_m - joint.length_m[1])) {
        return std::nullopt;
    }
    const double along = (joint.span_m * joint.span_m - joint.length_m[1] * joint.length_m[1] + d * d) / (2.0 * d);
    const double across = std::sqrt(std::max(joint.span_m * joint.span_m - along * along, 0.0));
    const Vector2 unit = apart / d;
    const Vector2 normal(-unit.y(), unit.x());
    const Vector2 second_m = first_m + along * unit + (branch == 0 ? across : -across) * normal;
    const Vector2 from = (joint.inner_m[1] - joint.inner_m[0]) / joint.span_m;
    const Vector2 to = (second_m - first_m) / joint.span_m;
    Matrix2 turn;
    const double c = from.dot(to);
    const double s = from.x() * to.y() - from.y() * to.x();
    turn << c, -s, s, c;
    return PartMove{mirrored ? Matrix2(turn * mirrorAlong(from)) : turn, joint.inner_m[0], first_m};
}

} // namespace

HingeStats placeFreeParts(const MapProblem &problem, MapEstimate &estimate, const HingeParams &params)
{
    HingeStats stats;
    if (estimate.placedCount() < 4) {
        return stats;
    }
    ConnectivityFit fit = connectivityCost(problem, estimate);
    if (!(fit.width_m > 0.0)) {
        return stats;
    }
    const std::vector<FreePart> parts = freeParts(problem, estimate);
    stats.parts = static_cast<uint32_t>(parts.size());
    stats.swinging = static_cast<uint32_t>(
        std::count_if(parts.begin(), parts.end(), [](const FreePart &part) { return part.joint == Joint::kTwoLinks; }));
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
    // P(heard | d) is fitted to the map again before each pass after the first: a part that lay
    // over nodes it never heard made unheard pairs look close, and the first fit too lenient on
    // them.
    for (uint32_t pass = 0; pass < kPasses; ++pass) {
        const uint32_t moved_before = stats.moved;
        if (pass > 0) {
            const ConnectivityFit refit = connectivityCost(problem, estimate);
            if (!(refit.width_m > 0.0)) {
                break;
            }
            fit = refit;
        }
        for (size_t p = 0; p < parts.size(); ++p) {
            const FreePart &part = parts[p];
            const std::vector<std::pair<uint32_t, uint32_t>> &pairs = unheard[p];
            if (pairs.empty()) {
                continue;
            }
            auto costOf = [&](const PartMove &move) {
                double cost = 0.0;
                for (const auto &[node, other] : pairs) {
                    const double distance_m =
                        (move.apply(estimate.position_m[node]) - estimate.position_m[other]).norm();
                    cost += -std::log(1.0 - heardProbability(fit, distance_m)) + problem.unheardCost(distance_m);
                }
                return cost;
            };
            const double here = costOf(PartMove{}); // where it is
            double best = here;
            std::optional<PartMove> chosen;
            auto consider = [&](const PartMove &move) {
                const double cost = costOf(move);
                if (cost < best) {
                    best = cost;
                    chosen = move;
                    return true;
                }
                return false;
            };
            // Turned about a point in both mirror images (the unturned, unmirrored place skipped).
            auto turnAbout = [&](const Vector2 &from_m, const Vector2 &to_m) {
                for (const Matrix2 &mirror :
                     {Matrix2(Matrix2::Identity()), Matrix2(Eigen::Vector2d(1.0, -1.0).asDiagonal())}) {
                    for (uint32_t k = 0; k < params.turns; ++k) {
                        if (k == 0 && mirror(1, 1) > 0.0 && from_m == to_m) {
                            continue; // where it is
                        }
                        consider(PartMove{turnBy(kTwoPi * k / params.turns) * mirror, from_m, to_m});
                    }
                }
            };
            if (part.joint == Joint::kOneNode) {
                const Vector2 centre_m = estimate.position_m[part.hinge[0]];
                turnAbout(centre_m, centre_m);
            } else if (part.joint == Joint::kTwoNodes) {
                const Vector2 along = estimate.position_m[part.hinge[1]] - estimate.position_m[part.hinge[0]];
                if (along.norm() < kShortestHingeM) {
                    continue;
                }
                const Vector2 centre_m = estimate.position_m[part.hinge[0]];
                consider(PartMove{mirrorAlong(along.normalized()), centre_m, centre_m});
            } else {
                const TwoLinkJoint joint = jointOf(problem, estimate, part);
                if (joint.span_m < kShortestHingeM) {
                    // Both links leave one node of the part: it stays where both lengths put it
                    // (or goes to the mirror place across its outer ends), and the part turns about it.
                    const Vector2 pivot_m = joint.inner_m[0];
                    turnAbout(pivot_m, pivot_m);
                    const Vector2 outer = joint.outer_m[1] - joint.outer_m[0];
                    if (outer.norm() >= kShortestHingeM) {
                        const Vector2 mirrored_m =
                            joint.outer_m[0] + mirrorAlong(outer.normalized()) * (pivot_m - joint.outer_m[0]);
                        turnAbout(pivot_m, mirrored_m);
                    }
                } else {
                    // The first link's direction sampled around its outer end, each closing of the
                    // second link, both mirror images; then the best of them refined by halving steps.
                    const Vector2 first = joint.inner_m[0] - joint.outer_m[0];
                    const double start = std::atan2(first.y(), first.x());
                    double step = kTwoPi / params.turns;
                    double best_angle = start;
                    int best_branch = 0;
                    bool best_mirrored = false;
                    for (const bool mirrored : {false, true}) {
                        for (int branch = 0; branch < 2; ++branch) {
                            for (uint32_t k = 0; k < params.turns; ++k) {
                                const double angle = start + step * k;
                                const std::optional<PartMove> move = swing(joint, angle, branch, mirrored);
                                if (move && consider(*move)) {
                                    best_angle = angle;
                                    best_branch = branch;
                                    best_mirrored = mirrored;
                                }
                            }
                        }
                    }
                    if (chosen) {
                        for (uint32_t halving = 0; halving < kSwingHalvings; ++halving) {
                            step *= 0.5;
                            const double centre = best_angle;
                            for (const double angle : {centre - step, centre + step}) {
                                const std::optional<PartMove> move = swing(joint, angle, best_branch, best_mirrored);
                                if (move && consider(*move)) {
                                    best_angle = angle;
                                }
                            }
                        }
                    }
                }
            }
            if (chosen && best < here - kMinGainNats) {
                for (uint32_t node : part.nodes) {
                    estimate.position_m[node] = chosen->apply(estimate.position_m[node]);
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
