#include "cdro/engine/global_step.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <future>
#include <memory>
#include <thread>

#include "cdro/engine/alignment.hpp"
#include "cdro/engine/map_refine.hpp"
#include "cdro/engine/worker_priority.hpp"

namespace cdro::engine {

namespace {

// An unheard pair counts once both nodes have listened for two sweeps of the network: before,
// "not heard" may only mean "not asked yet".
constexpr double kListenSweeps = 2.0;

// The unheard pairs' soft cost falls to 0 at this share of the median link range (map_problem.hpp).
constexpr double kUnheardRadiusShare = 0.5;
// The evidence has changed enough to solve again when this share of the links' ranges has moved
// by more than kChangedSigmas times the noise since the last solve (a window's median flickers by
// about a third of the noise: twice the noise is a change, not flicker).
constexpr double kChangedLinkShare = 0.1;
constexpr double kChangedSigmas = 2.0;
// Once the ranges behind the last full solve have doubled, their medians have settled further than
// the flicker test sees, and the map they support may be another one (settle() finds it offline; a
// live run never settles): one more solve from every start, until a solve has seen the links'
// windows full. Geometric, so a handful in any run.
constexpr double kMaturedRanges = 2.0;
// Whether the nodes to solve changed (a carried node settled) is looked at this many times a sweep
// of the network: a node that stopped waits for the solve that takes it back in (convergence needs
// it), so a quarter sweep plus the adoption's lag, not a whole sweep. It costs a pass over the
// nodes each time, a few per sweep of the links.
constexpr uint64_t kSolvableChecksPerSweep = 4;

// Whether a share of the links' ranges moved by more than the noise since the last solve saw them.
bool linksChanged(const MapState &map, double sigma_m)
{
    size_t changed = 0;
    for (const LinkState &link : map.links) {
        changed +=
            link.solved_range_m > 0.0 && std::abs(link.representative_m - link.solved_range_m) > sigma_m ? 1U : 0U;
    }
    return static_cast<double>(changed) >= kChangedLinkShare * static_cast<double>(map.links.size());
}

// The nodes the map solve works on: linked, and neither moving nor settling.
bool solvable(const NodeState &state) { return !state.links.empty() && !state.moving() && !state.settling(); }

uint64_t solvableNodes(const MapState &map)
{
    uint64_t count = 0;
    for (const NodeState &state : map.nodes) {
        count += solvable(state) ? 1U : 0U;
    }
    return count;
}

// The filter's map in the problem's numbering: the start the solve refines, and what its result
// is compared with.
MapEstimate filterMapOf(const MapState &map, const StateProblem &built)
{
    MapEstimate estimate = MapEstimate::unplaced(built.problem.nodeCount());
    for (uint32_t i = 0; i < built.problem.nodeCount(); ++i) {
        const NodeState &state = map.nodes[built.node_of[i]];
        estimate.placed[i] = state.placed() ? 1 : 0;
        estimate.position_m[i] = state.position_m;
    }
    return estimate;
}

} // namespace

StateProblem mapProblemOf(const MapState &map, const EngineParams &params, uint64_t ranges_taken)
{
    StateProblem out;
    std::vector<std::pair<NodeId, uint32_t>> by_id;
    for (uint32_t node = 0; node < map.nodes.size(); ++node) {
        const NodeState &state = map.nodes[node];
        // A moving node's links describe where it was: it is left out until it has settled.
        if (solvable(state)) {
            by_id.emplace_back(state.id, node);
        }
    }
    std::sort(by_id.begin(), by_id.end());
    std::vector<int> number(map.nodes.size(), -1);
    MapProblem &problem = out.problem;
    problem.sigma_m = params.range.sigma_m;
    for (const auto &[id, node] : by_id) {
        number[node] = static_cast<int>(problem.ids.size());
        problem.ids.push_back(id);
        out.node_of.push_back(node);
        const NodeState &state = map.nodes[node];
        problem.fixed.push_back(state.fixed() || state.pinned() ? 1 : 0);
        problem.fixed_position_m.push_back(state.position_m);
        const double listened = static_cast<double>(ranges_taken - std::min(ranges_taken, state.first_range));
        problem.listens.push_back(listened >= kListenSweeps * static_cast<double>(map.links.size()) ? 1 : 0);
    }
    for (const LinkState &link : map.links) {
        const int a = number[link.node_a];
        const int b = number[link.node_b];
        // The range as read: the solve estimates the offsets afresh.
        const double read_m =
            link.representative_m + map.nodes[link.node_a].range_offset_m + map.nodes[link.node_b].range_offset_m;
        if (a >= 0 && b >= 0 && link.window.size() > 0 && read_m > 0.0) {
            problem.links.push_back(MapLink{static_cast<uint32_t>(a), static_cast<uint32_t>(b), read_m});
        }
    }
    problem.finish();
    problem.unheard_radius_m = unheardRadiusFor(problem, kUnheardRadiusShare);
    return out;
}

GlobalStep::SolvedMap GlobalStep::solveAndAssess(const PendingSolve &job, const RangeLikelihood &likelihood,
                                                 const GlobalSolveParams &solve, double min_gain_nats,
                                                 MapModelError model_error, const StructureCheck &check)
{
    SolvedMap out;
    out.solved = solveGlobally(job.built.problem, likelihood, solve, &job.current);
    const GlobalSolveResult &solved = out.solved;
    const MapProblem &problem = job.built.problem;
    if (solved.best.estimate.placedCount() < 3) {
        return out;
    }
    // The filter's own map, refined, unless the solve found a map clearly better. When the two
    // are different maps (a rival: some node a metre or more apart), the better one, however
    // small the gain: the margin only saves the map from jumps that change nothing.
    auto rival = [&](const MapHypothesis &hypothesis) {
        for (const MapHypothesis &other : solved.rivals) {
            if (other.origin == hypothesis.origin) {
                return true;
            }
        }
        return false;
    };
    const MapHypothesis *chosen = &solved.best;
    for (const MapHypothesis &hypothesis : solved.all) {
        if (!job.settling && hypothesis.origin == "current" && hypothesis.origin != solved.best.origin &&
            !rival(hypothesis) && hypothesis.estimate.placedCount() == solved.best.estimate.placedCount() &&
            hypothesis.cost + hypothesis.connectivity_nats <
                solved.best.cost + solved.best.connectivity_nats + min_gain_nats) {
            chosen = &hypothesis;
        }
    }
    // The range offsets come with the best map (its positions explain the corrected ranges).
    out.offsets = chosen == &solved.best && solved.offsets.adopted;
    out.chosen = *chosen;
    // What the model leaves out (an excess every link may share: walls; unknown heights) and the
    // offsets' own uncertainty, in the chosen map's confidence.
    const MapProblem corrected = out.offsets ? withRangeOffsets(problem, solved.offsets.offset_m) : MapProblem{};
    model_error.range_offset_spread_sigma_m = out.offsets ? kRangeOffsetSpreadSigmaM : 0.0;
    model_error.height_unknown = job.height_unknown;
    const MapProblem &solved_problem = out.offsets ? corrected : problem;
    const MapCovariance confidence = mapCovariance(solved_problem, out.chosen.estimate, likelihood, model_error);
    // Where the margin between range offsets and none barely decided (uncalibrated radios in a
    // small room read as a map bent to fit them), the other model's map is about as good: how far
    // from each node's position its 95 % region reaches.
    std::vector<double> other_model_reach_m(problem.nodeCount(), 0.0);
    if (chosen == &solved.best && solved.offsets.evaluations > 0 &&
        std::abs(solved.offsets.decision_nats) < solve.rival_gap_nats) {
        MapModelError other_error = model_error;
        other_error.range_offset_spread_sigma_m = out.offsets ? 0.0 : kRangeOffsetSpreadSigmaM;
        const MapProblem other_problem = withRangeOffsets(problem, solved.offsets.other_offset_m);
        const MapCovariance other =
            mapCovariance(other_problem, solved.offsets.other_estimate, likelihood, other_error);
        const std::vector<double> apart = discrepancyM(solved.offsets.other_estimate, out.chosen.estimate, solved.part);
        for (uint32_t node : solved.part) {
            other_model_reach_m[node] = apart[node] + regionSemiAxisM(other.covariance_m2[node]);
        }
    }
    // What the solve says of each node it places. A refresh tried no other start: what the full
    // solve found disputed stays disputed.
    out.views.assign(problem.nodeCount(), NodeSolveView{});
    out.shared_excess_m2 = confidence.shared_excess_m2;
    for (uint32_t i = 0; i < problem.nodeCount(); ++i) {
        if (out.chosen.estimate.placed[i] == 0) {
            continue;
        }
        NodeSolveView &view = out.views[i];
        view.solved = true;
        view.position_m = out.chosen.estimate.position_m[i];
        view.covariance_m2 = confidence.covariance_m2[i];
        view.reliability_m = confidence.reliability_m[i];
        // "Converged" promises the node within disputed_m wherever the maps about as good as this
        // one place it.
        view.disputed = solved.disputed[i] != 0 || (job.refresh && job.was_disputed[i] != 0) ||
                        disputedByOtherMaps(regionSemiAxisM(view.covariance_m2), solved.rival_apart_m[i],
                                            other_model_reach_m[i], solve.disputed_m);
        view.main_part = confidence.main_part[i] != 0;
    }
    if (job.check_structure) {
        std::vector<StructureNode> nodes = job.nodes;
        for (uint32_t i = 0; i < problem.nodeCount(); ++i) {
            nodes[i].solve = out.views[i];
        }
        out.structure = check.run(solved_problem, out.chosen.estimate, nodes);
    }
    return out;
}

GlobalStep::GlobalStep(const EngineParams &params, const StructureCheck &check)
    : params_(params), likelihood_(mapLikelihood(params.likelihood)), check_(check)
{
    solve_.range_offsets = params.solve.range_offsets;
    solve_.connectivity = params.solve.connectivity;
    solve_.threads =
        params.solve.threads > 0 ? params.solve.threads : std::max(std::thread::hardware_concurrency(), 1U);
}

bool GlobalStep::enabled() const { return params_.solve.enabled; }

void GlobalStep::markSolved(MapState &map)
{
    for (LinkState &link : map.links) {
        link.solved_range_m = link.representative_m;
    }
}

bool GlobalStep::dueAfterRange(const MapState &map, bool new_link, uint64_t ranges_taken)
{
    const SolveParams &solve = params_.solve;
    if (!enabled()) {
        return false;
    }
    const auto links = static_cast<double>(map.links.size());
    if (map.links.size() < solve.min_links) {
        return false;
    }
    if (new_link) {
        schedule_.ranges_since_new_link = 0;
        if (links >= solve.link_growth * static_cast<double>(schedule_.links_at_last)) {
            return true;
        }
    } else {
        ++schedule_.ranges_since_new_link;
        // The network seems complete: once more on every link it has.
        if (map.links.size() != schedule_.links_at_last &&
            static_cast<double>(schedule_.ranges_since_new_link) >= solve.quiet_ranges_per_link * links) {
            return true;
        }
    }
    // No new link since the last solve, yet other nodes to solve: one settled after a carry or
    // started moving, and the map the last full solve found is of other nodes. (A node that joins
    // brings links: the growth rules above see it.) Looked at kSolvableChecksPerSweep times a
    // sweep, at fixed points of the range stream.
    const uint64_t check_every = std::max<uint64_t>(map.links.size() / kSolvableChecksPerSweep, 1U);
    if (ranges_taken % check_every == 0 && map.links.size() == schedule_.links_at_last &&
        solvableNodes(map) != schedule_.nodes_at_full) {
        return true;
    }
    // The ranges have grown: solve again if they changed the links, looked at once a sweep of
    // the network (at fixed points of the range stream, so a resumed engine looks when this one did).
    if (static_cast<double>(ranges_taken) < solve.link_growth * static_cast<double>(schedule_.ranges_at_last) ||
        static_cast<double>(ranges_taken - schedule_.ranges_at_check) < links) {
        return false;
    }
    schedule_.ranges_at_check = ranges_taken;
    return matured(ranges_taken) || linksChanged(map, kChangedSigmas * params_.range.sigma_m);
}

bool GlobalStep::matured(uint64_t ranges_taken) const
{
    // Only while the links' windows were not yet full at that solve (on average): once they were,
    // more ranges only make their medians flicker.
    const double full_windows_ranges =
        static_cast<double>(schedule_.links_at_full) * static_cast<double>(params_.range.window);
    const auto at_full = static_cast<double>(schedule_.ranges_at_full);
    return schedule_.ranges_at_full > 0 && at_full < full_windows_ranges &&
           static_cast<double>(ranges_taken) >= kMaturedRanges * at_full;
}

bool GlobalStep::dueAtSettle(const MapState &map, uint64_t ranges_taken) const
{
    return enabled() && ranges_taken != schedule_.ranges_at_full && map.links.size() >= params_.solve.min_links;
}

void GlobalStep::start(const MapState &map, uint64_t ranges_taken, bool settling)
{
    schedule_.links_at_last = map.links.size();
    schedule_.ranges_at_last = ranges_taken;

    ++counters_.solves;
    auto job = std::make_shared<PendingSolve>();
    job->built = mapProblemOf(map, params_, ranges_taken);
    const MapProblem &problem = job->built.problem;
    job->settling = settling;
    job->refresh = !settling && problem.links.size() == schedule_.links_at_full &&
                   problem.nodeCount() == schedule_.nodes_at_full && !matured(ranges_taken);
    if (job->refresh) {
        ++counters_.solve_refreshes;
    } else {
        schedule_.links_at_full = problem.links.size();
        schedule_.nodes_at_full = problem.nodeCount();
        schedule_.ranges_at_full = ranges_taken;
    }
    GlobalSolveParams solve = solve_;
    solve.only_current = job->refresh;
    job->current = filterMapOf(map, job->built);
    const double lag_ranges = params_.solve.adopt_after_sweeps * static_cast<double>(map.links.size());
    const bool background = !settling && lag_ranges >= 1.0;
    adopt_in_ranges_ = background ? static_cast<uint64_t>(lag_ranges) : 0U;
    job->background = background;
    // The worker reads only what the job owns (the problem, the start) and copies of the model and
    // the parameters: nothing the caller goes on changing. It holds the job by a plain pointer: the
    // future's shared state keeps the callable, so a shared_ptr in it would keep the job alive
    // forever. The job outlives the worker: `result` is its last member, destroyed first, and that
    // waits for the worker to finish.
    job->height_unknown.resize(problem.nodeCount());
    job->was_disputed.resize(problem.nodeCount());
    job->nodes.resize(problem.nodeCount());
    for (uint32_t i = 0; i < problem.nodeCount(); ++i) {
        const NodeState &state = map.nodes[job->built.node_of[i]];
        job->height_unknown[i] = state.height_m ? 0 : 1;
        job->was_disputed[i] = state.solve.solved && state.solve.disputed ? 1 : 0;
        job->nodes[i].free = state.free();
        job->nodes[i].anchored = state.fixed();
        job->nodes[i].covariance_m2 = state.covariance_m2;
    }
    job->check_structure = params_.refinement.enabled;
    const PendingSolve *owned = job.get();
    const RangeLikelihood likelihood = likelihood_;
    const double min_gain_nats = params_.solve.min_gain_nats;
    MapModelError model_error;
    model_error.common_excess_m = params_.convergence.common_excess_m;
    model_error.room_excess_m = params_.convergence.room_excess_m;
    model_error.height_spread_m = params_.range.unknown_height_spread_m;
    const StructureCheck check = check_;
    job->result =
        std::async(background ? std::launch::async : std::launch::deferred, [owned, likelihood, solve, min_gain_nats,
                                                                             model_error, check]() {
            if (owned->background) {
                lowerThisThreadsPriority(); // the ranges first (worker_priority.hpp)
            }
            return solveAndAssess(*owned, likelihood, solve, min_gain_nats, model_error, check);
        }).share();
    pending_ = std::move(job);
}

bool GlobalStep::finished() const
{
    return pending_ != nullptr && pending_->background &&
           pending_->result.wait_for(std::chrono::seconds(0)) == std::future_status::ready;
}

GlobalStep::Outcome GlobalStep::adopt(MapState &map, uint32_t fixed_frame_nodes, const Trace &trace)
{
    Outcome outcome;
    const std::shared_ptr<const PendingSolve> job = std::move(pending_);
    pending_.reset();
    const SolvedMap &result = job->result.get();
    const GlobalSolveResult &solved = result.solved;
    const StateProblem &built = job->built;
    const MapProblem &problem = built.problem;
    // The filter's map now (the solve started from `job->current`; ranges may have moved it since).
    MapEstimate current = filterMapOf(map, built);
    counters_.solve_starts += solved.counters.starts;
    counters_.solve_escapes += solved.counters.escapes;
    if (solved.best.estimate.placedCount() < 3) {
        return outcome;
    }
    const MapHypothesis *chosen = &result.chosen;
    outcome.adopted = chosen->origin != "current";
    counters_.solves_adopted += outcome.adopted ? 1U : 0U;
    MapEstimate map_estimate = chosen->estimate;
    // Seen from the current frame: the rigid fit of the solve's map onto the filter's.
    RigidTransform transform;
    if (fixed_frame_nodes < 2) {
        std::vector<Vector2> source;
        std::vector<Vector2> target;
        for (uint32_t i = 0; i < problem.nodeCount(); ++i) {
            if (map_estimate.placed[i] != 0 && current.placed[i] != 0) {
                source.push_back(map_estimate.position_m[i]);
                target.push_back(current.position_m[i]);
            }
        }
        if (source.size() >= 2) {
            transform = fitRigid(source, target, true);
        }
    } else if (fixed_frame_nodes == 2) {
        // Two fixed nodes fix the frame up to the mirror image through them: keep the side the
        // filter's map is on (its handedness rule), by the nodes both place.
        Vector2 a = Vector2::Zero();
        Vector2 b = Vector2::Zero();
        int seen = 0;
        for (uint32_t i = 0; i < problem.nodeCount() && seen < 2; ++i) {
            if (problem.fixed[i] != 0 && map.nodes[built.node_of[i]].fixed()) {
                (seen == 0 ? a : b) = problem.fixed_position_m[i];
                ++seen;
            }
        }
        const Vector2 axis = (b - a).normalized();
        double agree = 0.0;
        double disagree = 0.0;
        for (uint32_t i = 0; i < problem.nodeCount(); ++i) {
            if (problem.fixed[i] != 0 || map_estimate.placed[i] == 0 || current.placed[i] == 0) {
                continue;
            }
            auto side = [&](const Vector2 &p) {
                const Vector2 d = p - a;
                return axis.x() * d.y() - axis.y() * d.x();
            };
            const double s_new = side(map_estimate.position_m[i]);
            const double s_old = side(current.position_m[i]);
            (s_new * s_old >= 0.0 ? agree : disagree) += std::abs(s_old);
        }
        if (disagree > agree) {
            // Reflect across the line through the two fixed nodes.
            const Matrix2 reflection = 2.0 * axis * axis.transpose() - Matrix2::Identity();
            transform.rotation = reflection;
            transform.translation_m = a - reflection * a;
            transform.reflected = true;
        }
    }
    const bool offsets = result.offsets;
    for (uint32_t i = 0; i < problem.nodeCount(); ++i) {
        map.nodes[built.node_of[i]].range_offset_m = offsets ? solved.offsets.offset_m[i] : 0.0;
    }
    counters_.offsets_adopted += offsets ? 1U : 0U;
    for (uint32_t i = 0; i < problem.nodeCount(); ++i) {
        const uint32_t node = built.node_of[i];
        NodeState &state = map.nodes[node];
        if (!solvable(state)) {
            continue; // it started moving after the solve started: its track is its estimate
        }
        NodeSolveView &view = state.solve;
        view = result.views[i];
        if (!view.solved) {
            continue;
        }
        const Vector2 position = transform.apply(view.position_m);
        view.position_m = position;
        view.covariance_m2 = transform.applyToCovariance(view.covariance_m2);
        if (!state.free()) {
            view.position_m = state.position_m;
            continue;
        }
        if (!state.placed()) {
            // One range says how far a node is from one neighbour, not where: the solve's
            // position for it is one point of a circle, not a placement.
            uint32_t placed_links = 0;
            for (uint32_t link : problem.node_links[i]) {
                placed_links += map_estimate.placed[problem.other(link, i)] != 0 ? 1U : 0U;
            }
            if (placed_links < 2) {
                view = NodeSolveView{};
                continue;
            }
            outcome.placed.push_back(node);
            outcome.placed_covariance_m2.push_back(view.covariance_m2 -
                                                   transform.applyToCovariance(result.shared_excess_m2[i]));
            state.position_m = position;
            ++counters_.solve_placed;
            continue;
        }
        if (!params_.refinement.enabled) {
            // The paper's filter: the merged SoG is the estimate of a placed node; the solve only
            // places the nodes the filter could not.
            view.position_m = state.position_m;
            continue;
        }
        const Vector2 delta = position - state.position_m;
        if (delta.squaredNorm() > 0.0) {
            outcome.shifted.emplace_back(node, delta);
        }
        state.position_m = position;
    }
    if (job->check_structure) {
        outcome.structure = result.structure;
        outcome.structure_nodes = built.node_of;
    }
    if (trace) {
        trace("global solve on " + std::to_string(problem.links.size()) + " links: " + chosen->origin + ", cost " +
              std::to_string(chosen->cost) + " nats (NLOS share " + std::to_string(chosen->nlos_fraction) +
              ", mean excess " + std::to_string(chosen->nlos_mean_excess_m) + " m), " +
              std::to_string(outcome.placed.size()) + " placed, " + std::to_string(outcome.shifted.size()) +
              " moved, " + std::to_string(solved.rivals.size()) + " rival maps");
    }
    return outcome;
}

} // namespace cdro::engine
