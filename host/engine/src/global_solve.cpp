#include "cdro/engine/global_solve.hpp"
#include "cdro/engine/map_connectivity.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <functional>
#include <limits>
#include <optional>
#include <sstream>
#include <thread>

#include "cdro/engine/alignment.hpp"
#include "cdro/engine/map_mds.hpp"
#include "cdro/engine/map_patches.hpp"
#include "cdro/engine/placement.hpp"
#include "cdro/engine/point_solver.hpp"

namespace cdro::engine {

uint32_t escapeNodeMinima(const MapProblem &problem, MapEstimate &estimate, const RangeLikelihood &likelihood,
                          const MapGrowthParams &growth, double gap_nats)
{
    PointSolverParams solver;
    solver.range_sigma_m = problem.sigma_m;
    solver.max_iterations = 8;
    PlacementParams placement;
    placement.min_baseline_m = growth.min_baseline_m;
    placement.distinct_m = growth.distinct_m;
    uint32_t moved = 0;
    for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
        if (estimate.placed[node] == 0 || problem.fixed[node] != 0) {
            continue;
        }
        const std::vector<RangeConstraint> constraints = placedConstraints(problem, estimate, node);
        if (constraints.size() < 3) {
            continue;
        }
        const Vector2 here = estimate.position_m[node];
        const double here_cost = nodeCost(problem, estimate, likelihood, node, here);
        Vector2 best = here;
        double best_cost = here_cost;
        for (const PlacementCandidate &candidate : placementCandidates(constraints, likelihood, solver, placement)) {
            if ((candidate.position_m - here).norm() < growth.distinct_m) {
                continue;
            }
            const double cost = nodeCost(problem, estimate, likelihood, node, candidate.position_m);
            if (cost + gap_nats < best_cost) {
                best = candidate.position_m;
                best_cost = cost;
            }
        }
        if (best != here) {
            estimate.position_m[node] = best;
            ++moved;
        }
    }
    return moved;
}

RangeLikelihoodParams learnNlosModel(const MapProblem &problem, const MapEstimate &estimate,
                                     const RangeLikelihood &likelihood)
{
    RangeLikelihoodParams params = likelihood.params();
    const double variance = problem.sigma_m * problem.sigma_m;
    for (int iteration = 0; iteration < 5; ++iteration) {
        const RangeLikelihood current(params);
        double nlos = 0.0;
        double excess = 0.0;
        double links = 0.0;
        for (const MapLink &link : problem.links) {
            if (estimate.placed[link.a] == 0 || estimate.placed[link.b] == 0) {
                continue;
            }
            const double residual = link.range_m - (estimate.position_m[link.a] - estimate.position_m[link.b]).norm();
            const ResidualEvaluation at = current.evaluate(residual, variance);
            // The NLOS responsibility (all that is not line of sight; the short term is tiny).
            const double p_nlos = std::max(1.0 - at.inlier_probability, 0.0);
            nlos += p_nlos;
            excess += p_nlos * std::max(residual, 0.0);
            links += 1.0;
        }
        if (links < 10.0 || nlos < 0.5) {
            break;
        }
        params.nlos_fraction = std::clamp(nlos / links, 0.02, 0.6);
        // The NLOS term is an excess the noise cannot explain: at least three of its sigmas.
        params.nlos_mean_excess_m = std::clamp(excess / nlos, 3.0 * problem.sigma_m, 3.0);
    }
    return params;
}

namespace {

// A start made in a frame of its own (MDS-MAP, patches) is brought onto the fixed nodes' one: the
// rigid fit of its fixed nodes onto their coordinates (a shift for a single one), then those
// nodes exactly where they are known.
void anchorToFixed(const MapProblem &problem, MapEstimate &estimate)
{
    std::vector<Vector2> source;
    std::vector<Vector2> target;
    for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
        if (problem.fixed[node] != 0 && estimate.placed[node] != 0) {
            source.push_back(estimate.position_m[node]);
            target.push_back(problem.fixed_position_m[node]);
        }
    }
    if (source.empty()) {
        return;
    }
    const RigidTransform transform = fitRigid(source, target, true);
    for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
        if (estimate.placed[node] != 0) {
            estimate.position_m[node] =
                problem.fixed[node] != 0 ? problem.fixed_position_m[node] : transform.apply(estimate.position_m[node]);
        }
    }
}

// job(i) for i in [0, count) on up to `threads` threads (the caller's among them), each index
// once. The jobs write only their own slot, so what they produce does not depend on how many
// threads ran them or in which order they finished.
void forEachIndex(size_t count, uint32_t threads, const std::function<void(size_t)> &job)
{
    const size_t workers = std::min<size_t>(count, std::max<uint32_t>(threads, 1U));
    if (workers <= 1) {
        for (size_t i = 0; i < count; ++i) {
            job(i);
        }
        return;
    }
    std::atomic<size_t> next{0};
    auto work = [&]() {
        for (size_t i = next++; i < count; i = next++) {
            job(i);
        }
    };
    std::vector<std::thread> helpers;
    helpers.reserve(workers - 1);
    for (size_t k = 1; k < workers; ++k) {
        helpers.emplace_back(work);
    }
    work();
    for (std::thread &helper : helpers) {
        helper.join();
    }
}

} // namespace

std::vector<double> discrepancyM(const MapEstimate &map, const MapEstimate &reference,
                                 const std::vector<uint32_t> &part)
{
    std::vector<Vector2> source;
    std::vector<Vector2> target;
    for (uint32_t node : part) {
        if (map.placed[node] != 0 && reference.placed[node] != 0) {
            source.push_back(map.position_m[node]);
            target.push_back(reference.position_m[node]);
        }
    }
    std::vector<double> out(map.placed.size(), 0.0);
    if (source.size() < 2) {
        return out;
    }
    const RigidTransform fit = fitRigid(source, target, true);
    for (uint32_t node : part) {
        if (map.placed[node] != 0 && reference.placed[node] != 0) {
            out[node] = (fit.apply(map.position_m[node]) - reference.position_m[node]).norm();
        } else if (map.placed[node] != reference.placed[node]) {
            out[node] = std::numeric_limits<double>::infinity();
        }
    }
    return out;
}

void priceWhoHeardWhom(const MapProblem &problem, std::vector<MapHypothesis> &hypotheses, uint32_t threads)
{
    if (hypotheses.size() < 2) {
        return;
    }
    // Judged over the nodes that every map placing the most nodes places: a start that grew over
    // one wing only must not narrow the comparison of the whole maps to that wing, where they agree.
    std::vector<uint32_t> placed(hypotheses.size());
    for (size_t i = 0; i < hypotheses.size(); ++i) {
        placed[i] = hypotheses[i].estimate.placedCount();
    }
    const uint32_t most = *std::max_element(placed.begin(), placed.end());
    std::vector<uint8_t> everywhere(problem.nodeCount(), 1);
    for (size_t i = 0; i < hypotheses.size(); ++i) {
        if (placed[i] == most) {
            for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
                everywhere[node] = static_cast<uint8_t>(everywhere[node] & hypotheses[i].estimate.placed[node]);
            }
        }
    }
    forEachIndex(hypotheses.size(), threads, [&](size_t i) {
        if (placed[i] == most) {
            MapEstimate common = hypotheses[i].estimate;
            common.placed = everywhere;
            hypotheses[i].connectivity_nats = connectivityCost(problem, common).cost_nats;
        }
    });
    // A map that places fewer nodes cannot show who heard whom among those it leaves out: it is
    // given the worst of the fullest maps' costs, so that it cannot win by pricing fewer pairs.
    double worst = -std::numeric_limits<double>::infinity();
    for (size_t i = 0; i < hypotheses.size(); ++i) {
        if (placed[i] == most) {
            worst = std::max(worst, hypotheses[i].connectivity_nats);
        }
    }
    for (size_t i = 0; i < hypotheses.size(); ++i) {
        if (placed[i] < most) {
            hypotheses[i].connectivity_nats = worst;
        }
    }
}

GlobalSolveResult solveGlobally(const MapProblem &problem, const RangeLikelihood &likelihood,
                                const GlobalSolveParams &params, const MapEstimate *current)
{
    GlobalSolveResult result;
    result.disputed.assign(problem.nodeCount(), 0);
    result.rival_apart_m.assign(problem.nodeCount(), 0.0);
    const std::vector<std::vector<uint32_t>> parts = mapComponents(problem);
    result.best.estimate = MapEstimate::unplaced(problem.nodeCount());
    if (parts.empty() || parts.front().size() < 3) {
        return result;
    }
    result.part = parts.front();
    const std::vector<uint32_t> &part = result.part;
    // Each start is built and refined on its own (in parallel when params.threads allow); they
    // are then taken in this order, whatever order they finished in.
    struct Refined {
        std::optional<MapHypothesis> hypothesis;
        GlobalSolveCounters counters;
    };
    auto finish = [&](MapHypothesis hypothesis, bool lifted_mds, GlobalSolveCounters &counters) {
        ++counters.starts;
        anchorToFixed(problem, hypothesis.estimate);
        MapRefineResult refined =
            params.lift || lifted_mds
                ? liftedRefine(problem, hypothesis.estimate, likelihood, params.lifting, lifted_mds)
                : refineMap(problem, hypothesis.estimate, likelihood, params.refine);
        counters.refine_iterations += refined.iterations;
        if (params.lift || lifted_mds) {
            // The lifted refinement ends in the plane at the nominal noise, in the basin its own
            // schedule chose; annealing again in the plane (from the widest stage) lets the
            // links it judged outliers be judged again, where the map now is.
            MapEstimate annealed = hypothesis.estimate;
            const MapRefineResult again = refineMap(problem, annealed, likelihood, params.refine);
            counters.refine_iterations += again.iterations;
            if (again.cost < mapCost(problem, hypothesis.estimate, likelihood)) {
                hypothesis.estimate = std::move(annealed);
            }
        }
        for (uint32_t round = 0; round < params.escape_rounds; ++round) {
            const uint32_t moved =
                escapeNodeMinima(problem, hypothesis.estimate, likelihood, params.growth, params.escape_gap_nats);
            counters.escapes += moved;
            if (moved == 0) {
                break;
            }
            MapRefineParams again = params.refine;
            again.stages = {RefineStage{}};
            refined = refineMap(problem, hypothesis.estimate, likelihood, again);
            counters.refine_iterations += refined.iterations;
        }
        if (params.connectivity && params.free_parts) {
            counters.free_parts_moved += placeFreeParts(problem, hypothesis.estimate, params.hinges).moved;
        }
        hypothesis.cost = mapCost(problem, hypothesis.estimate, likelihood);
        return hypothesis;
    };
    std::vector<std::function<void(Refined &)>> starts;
    bool current_start = false;
    if (current != nullptr) {
        MapHypothesis start;
        start.estimate = MapEstimate::unplaced(problem.nodeCount());
        for (uint32_t node : part) {
            start.estimate.placed[node] = current->placed[node];
            start.estimate.position_m[node] = current->position_m[node];
        }
        if (start.estimate.placedCount() >= 3) {
            start.origin = "current";
            current_start = true;
            starts.emplace_back([start = std::move(start), &finish](Refined &out) mutable {
                out.hypothesis = finish(std::move(start), false, out.counters);
            });
        }
    }
    const bool more_starts = !(params.only_current && current_start);
    for (const auto &seed : more_starts ? seedTriangles(problem, part, params.growth, params.growth_seeds)
                                        : std::vector<std::array<uint32_t, 3>>{}) {
        starts.emplace_back([&, seed](Refined &out) {
            MapHypothesis start;
            start.estimate = growMap(problem, part, seed, likelihood, params.growth);
            std::ostringstream origin;
            origin << "grown from " << problem.ids[seed[0]] << "," << problem.ids[seed[1]] << ","
                   << problem.ids[seed[2]];
            start.origin = origin.str();
            out.hypothesis = finish(std::move(start), false, out.counters);
        });
    }
    if (params.patch_start && more_starts) {
        starts.emplace_back([&](Refined &out) {
            MapHypothesis start;
            start.estimate = patchMap(problem, part, likelihood);
            start.origin = "patches";
            if (start.estimate.placedCount() >= 3) {
                out.hypothesis = finish(std::move(start), false, out.counters);
            }
        });
    }
    if (params.mds_start && more_starts && problem.fixedCount() < 2) {
        starts.emplace_back([&](Refined &out) {
            if (std::optional<MapEstimate> layout = mdsMap(problem, part)) {
                MapHypothesis start;
                start.estimate = std::move(*layout);
                start.origin = "MDS-MAP";
                out.hypothesis = finish(std::move(start), false, out.counters);
            }
        });
    }
    if (params.lifted_mds_start && more_starts && problem.fixedCount() < 2) {
        starts.emplace_back([&](Refined &out) {
            MapHypothesis start;
            start.estimate = MapEstimate::unplaced(problem.nodeCount());
            for (uint32_t node : part) {
                start.estimate.placed[node] = 1;
            }
            start.origin = "MDS-MAP in " + std::to_string(params.lifting.dimensions) + "D";
            out.hypothesis = finish(std::move(start), true, out.counters);
        });
    }
    std::vector<Refined> refined(starts.size());
    forEachIndex(starts.size(), params.threads, [&](size_t i) { starts[i](refined[i]); });
    std::vector<MapHypothesis> hypotheses;
    for (Refined &one : refined) {
        result.counters += one.counters;
        if (one.hypothesis) {
            hypotheses.push_back(std::move(*one.hypothesis));
        }
    }
    if (hypotheses.empty()) {
        return result;
    }
    if (params.stitch_start && more_starts && problem.fixedCount() < 2) {
        // The grown maps that stop short of the fullest, each exact over its part, joined by the
        // links between the parts; the nodes none of them places from the cheapest fullest map.
        uint32_t most = 0;
        for (const MapHypothesis &h : hypotheses) {
            most = std::max(most, h.estimate.placedCount());
        }
        std::vector<MapEstimate> patches;
        const MapHypothesis *fill = nullptr;
        for (const MapHypothesis &h : hypotheses) {
            if (h.estimate.placedCount() < most && h.origin.rfind("grown from", 0) == 0) {
                patches.push_back(h.estimate);
            } else if (h.estimate.placedCount() == most && (fill == nullptr || h.cost < fill->cost)) {
                fill = &h;
            }
        }
        if (std::optional<MapEstimate> stitched =
                stitchPatches(problem, patches, fill != nullptr ? &fill->estimate : nullptr, likelihood)) {
            MapHypothesis start;
            start.estimate = std::move(*stitched);
            start.origin = "stitched";
            GlobalSolveCounters counters;
            hypotheses.push_back(finish(std::move(start), false, counters));
            result.counters += counters;
        }
    }
    // The best map places the most nodes, then costs the least.
    // A map that leaves a node unplaced has not explained its links: each is priced a little
    // above a perfect fit, so that leaving a node out is never cheaper than placing it well.
    const double unexplained = -likelihood.logDensity(0.0, problem.sigma_m * problem.sigma_m) + 2.0;
    auto comparable = [&](const MapHypothesis &h) {
        uint32_t open = 0;
        for (const MapLink &link : problem.links) {
            const bool a = h.estimate.placed[link.a] != 0;
            const bool b = h.estimate.placed[link.b] != 0;
            open += (a != b || (!a && !b && std::binary_search(part.begin(), part.end(), link.a))) ? 1U : 0U;
        }
        return h.cost + unexplained * static_cast<double>(open) + h.connectivity_nats;
    };
    auto rank = [&]() {
        std::stable_sort(hypotheses.begin(), hypotheses.end(),
                         [&](const MapHypothesis &x, const MapHypothesis &y) { return comparable(x) < comparable(y); });
    };
    rank();
    // Each map is judged under the NLOS model that suits it best (a profile likelihood): a map
    // that bends to fit long readings exactly must not win only because the prior thought long
    // readings rare.
    if (params.learn_rounds > 0) {
        forEachIndex(hypotheses.size(), params.threads, [&](size_t i) {
            MapHypothesis &hypothesis = hypotheses[i];
            RangeLikelihood own = likelihood;
            for (uint32_t round = 0; round < params.learn_rounds; ++round) {
                own = RangeLikelihood(learnNlosModel(problem, hypothesis.estimate, own));
                MapRefineParams again = params.refine;
                again.stages = {RefineStage{}};
                refineMap(problem, hypothesis.estimate, own, again);
            }
            hypothesis.cost = mapCost(problem, hypothesis.estimate, own);
            hypothesis.nlos_fraction = own.params().nlos_fraction;
            hypothesis.nlos_mean_excess_m = own.params().nlos_mean_excess_m;
        });
    }
    if (params.connectivity) {
        priceWhoHeardWhom(problem, hypotheses, params.threads);
    }
    if (params.learn_rounds > 0 || params.connectivity) {
        rank();
    }
    // Maps that place the same nodes within disputed_m of one another are one map found twice:
    // who heard whom tells them apart only by where its pairs' distances fall in their bins, so
    // the one that fits the ranges best leads.
    size_t closest_fit = 0;
    for (size_t i = 1; i < hypotheses.size(); ++i) {
        if (hypotheses[i].estimate.placed != hypotheses.front().estimate.placed ||
            hypotheses[i].cost >= hypotheses[closest_fit].cost) {
            continue;
        }
        const std::vector<double> apart = discrepancyM(hypotheses[i].estimate, hypotheses.front().estimate, part);
        if (*std::max_element(apart.begin(), apart.end()) < params.disputed_m) {
            closest_fit = i;
        }
    }
    std::rotate(hypotheses.begin(), hypotheses.begin() + static_cast<std::ptrdiff_t>(closest_fit),
                hypotheses.begin() + static_cast<std::ptrdiff_t>(closest_fit) + 1);
    result.learnt_nlos_fraction = params.learn_rounds > 0 ? hypotheses.front().nlos_fraction : -1.0;
    result.learnt_nlos_mean_excess_m = params.learn_rounds > 0 ? hypotheses.front().nlos_mean_excess_m : -1.0;
    result.best = hypotheses.front();
    result.all = hypotheses;
    for (size_t i = 1; i < hypotheses.size(); ++i) {
        const MapHypothesis &rival = hypotheses[i];
        if (comparable(rival) > comparable(result.best) + params.rival_gap_nats) {
            continue;
        }
        const std::vector<double> apart = discrepancyM(rival.estimate, result.best.estimate, part);
        bool distinct = false;
        for (uint32_t node : part) {
            if (apart[node] >= params.disputed_m) {
                result.disputed[node] = 1;
                distinct = true;
            }
        }
        if (distinct) {
            // Another map, not the same one found twice: where it places a node closer than
            // disputed_m, the node may be there too.
            for (uint32_t node : part) {
                result.rival_apart_m[node] = std::max(result.rival_apart_m[node], apart[node]);
            }
            result.rivals.push_back(rival);
        }
    }
    // The rivals were judged under the ranges as read; the offsets are the best map's.
    if (params.range_offsets) {
        MapHypothesis &best = result.best;
        RangeLikelihoodParams own = likelihood.params();
        if (best.nlos_fraction >= 0.0) {
            own.nlos_fraction = best.nlos_fraction;
            own.nlos_mean_excess_m = best.nlos_mean_excess_m;
        }
        result.offsets = calibrateRangeOffsets(problem, best.estimate, RangeLikelihood(own));
        result.counters.offset_evaluations += result.offsets.evaluations;
        if (result.offsets.adopted) {
            best.estimate = result.offsets.estimate;
            best.cost = result.offsets.cost_nats;
            best.origin += ", range offsets";
            result.all.front() = best;
        }
    }
    return result;
}

} // namespace cdro::engine
