#include "cdro/engine/map_stitch.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

#include "cdro/engine/alignment.hpp"
#include "cdro/engine/map_connectivity.hpp"
#include "cdro/engine/range_model.hpp"

namespace cdro::engine {
namespace {

constexpr double kTwoPi = 6.28318530717958647692;

struct Bridge {
    Vector2 joined_m; // m, the end in the joined map
    Vector2 patch_m;  // m, the end in the patch's own frame
    double range_m;   // m
};

// R(angle) diag(1, mirror): the patch's frame turned (and reflected when mirror = -1).
Matrix2 turn(double angle, double mirror)
{
    Matrix2 rotation;
    rotation << std::cos(angle), -std::sin(angle), std::sin(angle), std::cos(angle);
    Matrix2 reflect = Matrix2::Identity();
    reflect(1, 1) = mirror;
    return rotation * reflect;
}

struct Placement {
    double angle = 0.0;
    Vector2 translation_m = Vector2::Zero();
};

// Gauss-Newton (Levenberg-damped) on (angle, translation) over the bridges.
Placement solveBridges(const std::vector<Bridge> &bridges, double mirror, double angle, uint32_t iterations)
{
    Placement p;
    p.angle = angle;
    Vector2 joined_centre = Vector2::Zero();
    Vector2 patch_centre = Vector2::Zero();
    for (const Bridge &b : bridges) {
        joined_centre += b.joined_m;
        patch_centre += b.patch_m;
    }
    joined_centre /= static_cast<double>(bridges.size());
    patch_centre /= static_cast<double>(bridges.size());
    p.translation_m = joined_centre - turn(angle, mirror) * patch_centre;
    double damping = 1e-3;
    auto cost = [&](const Placement &at) {
        double sum = 0.0;
        const Matrix2 r = turn(at.angle, mirror);
        for (const Bridge &b : bridges) {
            const double e = (r * b.patch_m + at.translation_m - b.joined_m).norm() - b.range_m;
            sum += e * e;
        }
        return sum;
    };
    double current = cost(p);
    for (uint32_t iteration = 0; iteration < iterations; ++iteration) {
        const Matrix2 r = turn(p.angle, mirror);
        Matrix2 d_r; // d turn / d angle
        d_r << -std::sin(p.angle), -std::cos(p.angle) * mirror, std::cos(p.angle), -std::sin(p.angle) * mirror;
        Eigen::Matrix3d normal = Eigen::Matrix3d::Zero();
        Eigen::Vector3d gradient = Eigen::Vector3d::Zero();
        for (const Bridge &b : bridges) {
            const RangePrediction prediction = predictRange(r * b.patch_m + p.translation_m, b.joined_m);
            if (prediction.singular) {
                continue;
            }
            Eigen::RowVector3d j;
            j << prediction.jacobian_point * (d_r * b.patch_m), prediction.jacobian_point;
            const double e = b.range_m - prediction.range_m;
            normal += j.transpose() * j;
            gradient += j.transpose() * e;
        }
        bool improved = false;
        for (int attempt = 0; attempt < 8 && !improved; ++attempt) {
            Eigen::Matrix3d damped = normal;
            damped.diagonal() += damping * (normal.diagonal().array() + 1e-9).matrix();
            const Eigen::Vector3d step = damped.ldlt().solve(gradient);
            if (!step.allFinite()) {
                break;
            }
            Placement next = p;
            next.angle += step(0);
            next.translation_m += step.tail<2>();
            const double next_cost = cost(next);
            if (next_cost < current) {
                p = next;
                current = next_cost;
                damping = std::max(damping / 10.0, 1e-9);
                improved = true;
            } else {
                damping *= 10.0;
            }
        }
        if (!improved) {
            break;
        }
    }
    return p;
}

// Fits `other` onto `joined` on the nodes both place (three at least: else nothing is done and
// false returned) and places there the nodes only `other` places; returns whether it did.
bool joinByFit(MapEstimate &joined, const MapEstimate &other, uint32_t *added)
{
    std::vector<Vector2> source;
    std::vector<Vector2> target;
    for (size_t node = 0; node < joined.placed.size(); ++node) {
        if (other.placed[node] != 0 && joined.placed[node] != 0) {
            source.push_back(other.position_m[node]);
            target.push_back(joined.position_m[node]);
        }
    }
    if (source.size() < 3) {
        return false;
    }
    const RigidTransform fit = fitRigid(source, target, true);
    for (size_t node = 0; node < joined.placed.size(); ++node) {
        if (other.placed[node] != 0 && joined.placed[node] == 0) {
            joined.placed[node] = 1;
            joined.position_m[node] = fit.apply(other.position_m[node]);
            ++*added;
        }
    }
    return true;
}

} // namespace

std::optional<MapEstimate> stitchPatches(const MapProblem &problem, const std::vector<MapEstimate> &patches,
                                         const MapEstimate *fill, const RangeLikelihood &likelihood,
                                         const MapStitchParams &params, MapStitchStats *stats)
{
    MapStitchStats local;
    MapStitchStats &counted = stats != nullptr ? *stats : local;
    if (patches.size() < 2) {
        return std::nullopt;
    }
    std::vector<size_t> order(patches.size());
    std::iota(order.begin(), order.end(), size_t{0});
    std::stable_sort(order.begin(), order.end(),
                     [&](size_t x, size_t y) { return patches[x].placedCount() > patches[y].placedCount(); });
    const uint32_t count = problem.nodeCount();
    MapEstimate joined = patches[order.front()];
    std::vector<uint8_t> merged(patches.size(), 0);
    merged[order.front()] = 1;
    uint32_t joined_patches = 1;
    for (bool progress = true; progress;) {
        progress = false;
        for (const size_t k : order) {
            if (merged[k] != 0) {
                continue;
            }
            const MapEstimate &patch = patches[k];
            uint32_t common = 0;
            std::vector<uint32_t> fresh;
            for (uint32_t node = 0; node < count; ++node) {
                if (patch.placed[node] == 0) {
                    continue;
                }
                if (joined.placed[node] != 0) {
                    ++common;
                } else {
                    fresh.push_back(node);
                }
            }
            if (fresh.empty()) {
                merged[k] = 1; // nothing to add
                continue;
            }
            uint32_t added = 0;
            if (common >= 3 && joinByFit(joined, patch, &added)) {
                merged[k] = 1;
                ++counted.fitted;
                ++joined_patches;
                progress = true;
                continue;
            }
            std::vector<Bridge> bridges;
            std::vector<uint8_t> is_fresh(count, 0);
            for (const uint32_t node : fresh) {
                is_fresh[node] = 1;
            }
            for (const MapLink &link : problem.links) {
                if (is_fresh[link.a] != 0 && joined.placed[link.b] != 0 && is_fresh[link.b] == 0) {
                    bridges.push_back({joined.position_m[link.b], patch.position_m[link.a], link.range_m});
                } else if (is_fresh[link.b] != 0 && joined.placed[link.a] != 0 && is_fresh[link.a] == 0) {
                    bridges.push_back({joined.position_m[link.a], patch.position_m[link.b], link.range_m});
                }
            }
            if (bridges.size() < 2) {
                continue; // perhaps once another patch has joined
            }
            double best_nats = std::numeric_limits<double>::infinity();
            MapEstimate best;
            for (const double mirror : {1.0, -1.0}) {
                for (uint32_t a = 0; a < params.angles; ++a) {
                    const double start = kTwoPi * static_cast<double>(a) / static_cast<double>(params.angles);
                    const Placement placement = solveBridges(bridges, mirror, start, params.iterations);
                    const Matrix2 r = turn(placement.angle, mirror);
                    MapEstimate candidate = joined;
                    for (const uint32_t node : fresh) {
                        candidate.placed[node] = 1;
                        candidate.position_m[node] = r * patch.position_m[node] + placement.translation_m;
                    }
                    const double nats =
                        mapCost(problem, candidate, likelihood) + connectivityCost(problem, candidate).cost_nats;
                    if (nats < best_nats) {
                        best_nats = nats;
                        best = std::move(candidate);
                    }
                }
            }
            if (!std::isfinite(best_nats)) {
                continue;
            }
            joined = std::move(best);
            merged[k] = 1;
            ++counted.linked;
            ++joined_patches;
            progress = true;
        }
    }
    if (joined_patches < 2) {
        return std::nullopt;
    }
    if (fill != nullptr) {
        joinByFit(joined, *fill, &counted.filled);
    }
    return joined;
}

} // namespace cdro::engine
