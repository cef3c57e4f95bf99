#include "cdro/engine/motion_tracker.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>
#include <vector>

#include <Eigen/LU>

#include "cdro/engine/point_solver.hpp"

namespace cdro::engine {

namespace {

// An inferred-moving node stands still again when one position explains its last
// kStillFitRanges ranges to anchors, taken over at least kStillSpanS on at least kStillMinAnchors
// anchors: each within kStillSigmas of its noise (and its anchor's uncertainty along it), all of
// them together within the 99 % point of their chi-square, that position determined to within
// kStillSigmaM; and standing explains the ranges since some time t1 better than the moving track
// did, by the Bayes factor below. One NLOS range fails the test, and then the track's speed
// decides, as without it (once the track has taken kStillWarmUpdates ranges). The sizes were
// chosen on simulated carries (docs/results.md, "How late the fallback detector sees the
// motion"): 6 ranges instead of 8 see the stop about 0.3 s sooner, and the Bayes factor, not a
// comparison of chi-squares, keeps them from calling a carried node still.
//
// The Bayes factor: the ranges since t1 (at least kStillFactorRanges, on kStillFactorAnchors
// anchors), each predicted by the track (its innovation and variance when it came, under the
// robust range likelihood) against the same ranges predicted by a node standing since t1 where the
// track then put it (a position-only filter started from the track's position and covariance at
// t1, widened by kStillStartSigmaM). Both start from what the track knew at t1, so a track that
// is still unsure where the node is makes standing no likelier; a track that keeps walking while
// the ranges stay put loses by more with every range. t1 is one of the remembered ranges' times
// at which the track had taken at least kStillWarmUpdates ranges (a young track's walk is a
// guess, and standing beats a guess).
constexpr uint32_t kStillFitRanges = 6;
constexpr uint32_t kStillMinAnchors = 4;
constexpr double kStillSpanS = 0.5; // s
constexpr double kStillSigmas = 3.0;
constexpr double kStillChiSquare = 13.28; // chi-square, 4 degrees of freedom (6 ranges, 2 unknowns), 99 %
constexpr double kStillSigmaM = 0.3;      // m
constexpr uint32_t kStillFactorRanges = 3;
constexpr uint32_t kStillFactorAnchors = 3;
constexpr double kStillStartSigmaM = 0.1; // m
constexpr uint32_t kStillWarmUpdates = 8;
constexpr double kStillNats = 3.0; // log Bayes factor of standing over the track

// The remembered ranges in the order they came (the ring's oldest first).
uint32_t stillSlot(const MotionMemory &memory, uint32_t i)
{
    constexpr uint32_t kRanges = MotionMemory::kStillRanges;
    return (memory.still_next + kRanges - memory.still_count + i) % kRanges;
}

double standingFactor(const MapState &map, const MotionMemory &memory, const RangeLikelihood &likelihood,
                      double sigma_m)
{
    const uint32_t n = memory.still_count;
    double best = -std::numeric_limits<double>::infinity();
    for (uint32_t j = 0; j + kStillFactorRanges <= n; ++j) {
        const uint32_t first = stillSlot(memory, j);
        if (!memory.still_track_warm[first]) {
            continue;
        }
        std::array<uint32_t, MotionMemory::kStillRanges> anchors{};
        uint32_t distinct = 0;
        for (uint32_t i = j; i < n; ++i) {
            const uint32_t anchor = memory.still_anchor[stillSlot(memory, i)];
            if (std::find(anchors.begin(), anchors.begin() + distinct, anchor) == anchors.begin() + distinct) {
                anchors[distinct++] = anchor;
            }
        }
        if (distinct < kStillFactorAnchors) {
            continue;
        }
        Vector2 position_m = memory.still_track_position_m[first];
        Matrix2 covariance_m2 =
            memory.still_track_covariance_m2[first] + kStillStartSigmaM * kStillStartSigmaM * Matrix2::Identity();
        double factor = 0.0;
        for (uint32_t i = j; i < n; ++i) {
            const uint32_t slot = stillSlot(memory, i);
            const NodeState &anchor = map.nodes[memory.still_anchor[slot]];
            const Vector2 along = position_m - anchor.position_m;
            const double distance_m = along.norm();
            if (distance_m < 1e-9) {
                return -std::numeric_limits<double>::infinity();
            }
            const Vector2 u = along / distance_m;
            const Matrix2 anchor_covariance = anchor.fixed() ? Matrix2::Zero() : anchor.covariance_m2;
            const double noise = sigma_m * sigma_m + u.dot(anchor_covariance * u);
            const Vector2 pu = covariance_m2 * u;
            const double variance = u.dot(pu) + noise;
            const double innovation_m = memory.still_range_m[slot] - distance_m;
            const RangeLikelihood::DensityWithInlier at = likelihood.densityWithInlier(innovation_m, variance);
            factor += std::log(at.density_per_m) - memory.still_track_log_density[slot];
            // As the track takes a range: an NLOS-looking one counts for less.
            const double widened = u.dot(pu) + noise / std::max(at.inlier_probability, 0.05);
            position_m += pu / widened * innovation_m;
            covariance_m2 = symmetricPart(covariance_m2 - pu * pu.transpose() / widened);
        }
        best = std::max(best, factor);
    }
    return best;
}

bool standsStill(const MapState &map, const NodeState &state, const RangeLikelihood &likelihood, double sigma_m)
{
    const MotionMemory &memory = state.motion;
    if (memory.still_count < kStillFitRanges) {
        return false;
    }
    std::vector<RangeConstraint> constraints;
    std::vector<uint32_t> anchors;
    double earliest_s = std::numeric_limits<double>::infinity();
    double latest_s = -std::numeric_limits<double>::infinity();
    for (uint32_t i = memory.still_count - kStillFitRanges; i < memory.still_count; ++i) {
        const uint32_t slot = stillSlot(memory, i);
        const NodeState &anchor = map.nodes[memory.still_anchor[slot]];
        if (!anchor.anchor()) {
            return false;
        }
        RangeConstraint constraint;
        constraint.anchor_m = anchor.position_m;
        constraint.anchor_covariance_m2 = anchor.fixed() ? Matrix2::Zero() : anchor.covariance_m2;
        constraint.range_m = memory.still_range_m[slot];
        constraints.push_back(constraint);
        if (std::find(anchors.begin(), anchors.end(), memory.still_anchor[slot]) == anchors.end()) {
            anchors.push_back(memory.still_anchor[slot]);
        }
        earliest_s = std::min(earliest_s, memory.still_t_s[slot]);
        latest_s = std::max(latest_s, memory.still_t_s[slot]);
    }
    if (anchors.size() < kStillMinAnchors || !(latest_s - earliest_s >= kStillSpanS)) {
        return false;
    }
    PointSolverParams solver;
    solver.range_sigma_m = sigma_m;
    const Vector2 start_m = state.track ? state.track->position() : state.position_m;
    const PointSolution fit = solvePoint(constraints, start_m, likelihood, solver);
    if (!fit.well_posed || !(std::sqrt(fit.covariance_m2.trace()) < kStillSigmaM)) {
        return false;
    }
    double chi_square = 0.0;
    for (const RangeConstraint &constraint : constraints) {
        const Vector2 along = fit.position_m - constraint.anchor_m;
        const double distance_m = along.norm();
        if (distance_m < 1e-9) {
            return false;
        }
        const Vector2 u = along / distance_m;
        const double variance = sigma_m * sigma_m + u.dot(constraint.anchor_covariance_m2 * u);
        const double residual_m = constraint.range_m - distance_m;
        if (residual_m * residual_m > kStillSigmas * kStillSigmas * variance) {
            return false;
        }
        chi_square += residual_m * residual_m / variance;
    }
    return chi_square <= kStillChiSquare && standingFactor(map, memory, likelihood, sigma_m) > kStillNats;
}

// The start test, for ranges with times. Under "the node stands", each residual e_i of its recent
// ranges (to neighbours that stand: from the map, or from the link's history) is range noise;
// under "it walks at a constant velocity v since t0", e_i = |p + v (t_i - t0) - a_i| - |p - a_i|
// plus that noise (p: its map position, a_i: the neighbour's). A walk makes the residuals grow
// with time, on each link by the walk's share along it: ranges a few tenths of a metre off on
// several links, growing, tell a walk before any one of them is far off. Both hypotheses take the
// robust range likelihood (range_likelihood.hpp): a reading too long costs what the NLOS model
// says whatever its size, so a few long readings are weak evidence of a walk, and one too short
// is strong evidence. The log-likelihood ratio is maximised over v (Gauss-Newton steps with the
// robust model's IRLS weights, |v| capped at kWalkMaxSpeedMps) and over t0 (after each of the
// recent ranges, with at least kWalkMinRanges ranges on kWalkMinLinks links after it). The
// threshold was chosen on simulated carries and rooms where nothing moves (docs/results.md, "How
// late the fallback detector sees the motion"): at 12 nats a carry at 1.3 m/s is seen about 0.05 s
// sooner than at 15, but 4-5 of 400 still nodes (90 s each) are called moving; at 15, none.
constexpr uint32_t kWalkMinRanges = 3;
constexpr uint32_t kWalkMinLinks = 2;
constexpr uint32_t kWalkIterations = 4;
constexpr double kWalkMaxSpeedMps = 2.0; // m/s, a brisk walk: a faster carry still fits well enough
constexpr double kWalkNats = 15.0;       // log-likelihood ratio over which the node walks
// The test runs again only after a residual beyond this many sigmas, or while the ratio is above
// half its threshold: a small residual cannot take it from there over the threshold.
constexpr double kWalkGateSigmas = 2.0;

double walkEvidence(const MapState &map, uint32_t node, const MotionMemory &memory, const RangeLikelihood &likelihood,
                    double variance_m2)
{
    constexpr uint32_t kRanges = MotionMemory::kRecentRanges;
    // The newest ranges with times, oldest first.
    std::array<uint32_t, kRanges> order{};
    uint32_t n = 0;
    for (uint32_t back = 0; back < memory.recent_count; ++back) {
        const uint32_t slot = (memory.recent_next + kRanges - 1 - back) % kRanges;
        if (!std::isfinite(memory.recent_t_s[slot])) {
            break;
        }
        order[n++] = slot;
    }
    std::reverse(order.begin(), order.begin() + n);
    if (n < kWalkMinRanges + 1) {
        return 0.0;
    }
    const Vector2 position_m = map.nodes[node].position_m;
    std::array<Vector2, kRanges> offset_m{}; // m, from the neighbour to the node
    std::array<double, kRanges> distance_m{};
    std::array<double, kRanges> still_log{}; // log p(e_i) under standing
    std::array<double, kRanges> still_weight{};
    for (uint32_t i = 0; i < n; ++i) {
        const uint32_t slot = order[i];
        offset_m[i] = position_m - map.nodes[map.otherNode(memory.recent_links[slot], node)].position_m;
        distance_m[i] = offset_m[i].norm();
        const double e_m = memory.recent_residual_m[slot];
        const ResidualEvaluation at = likelihood.evaluate(e_m, variance_m2);
        still_log[i] = at.log_density;
        still_weight[i] = likelihood.irlsWeight(e_m, variance_m2, at);
    }
    double best = 0.0;
    std::array<double, kRanges> weight{};
    std::array<uint32_t, kRanges> links{};
    for (uint32_t j = n - kWalkMinRanges; j >= 1; --j) {
        const double t0_s = memory.recent_t_s[order[j - 1]];
        uint32_t distinct = 0;
        for (uint32_t i = j; i < n; ++i) {
            const uint32_t link = memory.recent_links[order[i]];
            if (std::find(links.begin(), links.begin() + distinct, link) == links.begin() + distinct) {
                links[distinct++] = link;
            }
        }
        if (distinct < kWalkMinLinks) {
            continue;
        }
        std::copy(still_weight.begin() + j, still_weight.begin() + n, weight.begin() + j);
        Vector2 velocity_mps = Vector2::Zero();
        double walk_log = 0.0;
        for (uint32_t iteration = 0; iteration < kWalkIterations; ++iteration) {
            // A negligible ridge: every range after t0 may lie along one line.
            Matrix2 normal = 1e-9 * Matrix2::Identity();
            Vector2 gradient = Vector2::Zero();
            for (uint32_t i = j; i < n; ++i) {
                const double dt_s = std::max(memory.recent_t_s[order[i]] - t0_s, 0.0);
                const Vector2 walked = offset_m[i] + velocity_mps * dt_s;
                const double reach_m = walked.norm();
                const Vector2 jacobian = reach_m > 1e-9 ? Vector2(walked / reach_m * dt_s) : Vector2::Zero();
                const double misfit_m = memory.recent_residual_m[order[i]] - (reach_m - distance_m[i]);
                normal += weight[i] * jacobian * jacobian.transpose();
                gradient += weight[i] * misfit_m * jacobian;
            }
            velocity_mps += normal.inverse() * gradient;
            const double speed_mps = velocity_mps.norm();
            if (speed_mps > kWalkMaxSpeedMps) {
                velocity_mps *= kWalkMaxSpeedMps / speed_mps;
            }
            walk_log = 0.0;
            for (uint32_t i = j; i < n; ++i) {
                const double dt_s = std::max(memory.recent_t_s[order[i]] - t0_s, 0.0);
                const double reach_m = (offset_m[i] + velocity_mps * dt_s).norm();
                const double misfit_m = memory.recent_residual_m[order[i]] - (reach_m - distance_m[i]);
                const ResidualEvaluation at = likelihood.evaluate(misfit_m, variance_m2);
                walk_log += at.log_density - still_log[i];
                weight[i] = likelihood.irlsWeight(misfit_m, variance_m2, at);
            }
        }
        best = std::max(best, walk_log);
    }
    return best;
}

} // namespace

MotionTracker::MotionTracker(const EngineParams &params, const RangeLikelihood &likelihood)
    : params_(params.motion), range_sigma_m_(params.range.sigma_m), gate_sigma_(params.sog.gate_sigma),
      likelihood_(likelihood)
{
}

bool MotionTracker::trackIsEstimate(const NodeState &state) const
{
    return (state.moving() || state.settling()) && state.track && state.track->updates() >= params_.track_warmup;
}

bool MotionTracker::report(MapState &map, SogBank &sogs, uint32_t node, bool moving, const Trace &trace)
{
    NodeState &state = map.nodes[node];
    state.motion.reports = true;
    state.motion.reported_moving = moving;
    return change(map, sogs, node, moving, trace);
}

bool MotionTracker::change(MapState &map, SogBank &sogs, uint32_t node, bool moving, const Trace &trace)
{
    NodeState &state = map.nodes[node];
    const bool was_moving = state.moving();
    if (!state.placed() || was_moving == moving || (!moving && state.settling())) {
        return false;
    }
    state.motion.inferred = false;
    if (!params_.reset) {
        // The ablation: the motion is shown, the node is handled as a static one.
        state.lifecycle = moving ? NodeLifecycle::Moving : NodeLifecycle::Placed;
        return true;
    }
    moving ? ++counters_.motion_starts : ++counters_.motion_stops;
    if (trace) {
        trace("node " + std::to_string(state.id) + (moving ? " moves" : " stopped"));
    }
    state.still_updates = 0;
    state.motion.still_anchor_m = state.position_m;
    state.motion.still_updates = 0;
    state.motion.recent_count = 0;
    state.motion.walk_nats = 0.0;
    state.motion.still_count = 0;
    // Stopping: the track, at rest, stays the estimate until every link has a range again (the
    // links start afresh below, and a median of nothing is no range).
    if (!moving && state.track && params_.track) {
        state.track->stop();
        state.position_m = state.track->position();
        state.lifecycle = NodeLifecycle::Settling;
    } else {
        state.track.reset();
        state.lifecycle = moving ? NodeLifecycle::Moving : NodeLifecycle::Placed;
    }
    for (uint32_t link : state.links) {
        // Ranges from before the change describe another place: start the links afresh.
        map.links[link].window.clear();
    }
    // The SoGs centred on the node describe its neighbours from where it was.
    sogs.dropRings(map, node, true);
    if (!moving) {
        sogs.ensureRings(map, node); // generated again around where it stopped
    }
    return true;
}

bool MotionTracker::watch(MapState &map, SogBank &sogs, uint32_t node, uint32_t link, double residual_m, double t_s,
                          const Trace &trace)
{
    // The fallback detector, for a node without motion reports: with range times, the start test
    // above (its recent ranges fit a walk far better than standing); without, several of its
    // recent ranges, on different links, read far from the map (one NLOS link reads far on one
    // link).
    NodeState &state = map.nodes[node];
    if (!params_.reset || !params_.infer_from_ranges || state.motion.reports || state.moving() || state.fixed()) {
        return false;
    }
    MotionMemory &memory = state.motion;
    constexpr uint32_t kRanges = MotionMemory::kRecentRanges;
    memory.recent_links[memory.recent_next] = link;
    memory.recent_t_s[memory.recent_next] = t_s;
    memory.recent_residual_m[memory.recent_next] = residual_m;
    memory.recent_next = (memory.recent_next + 1) % kRanges;
    memory.recent_count = std::min(memory.recent_count + 1, kRanges);
    std::string why;
    if (std::isfinite(t_s)) {
        if (std::abs(residual_m) > kWalkGateSigmas * range_sigma_m_ || memory.walk_nats > 0.5 * kWalkNats) {
            memory.walk_nats = walkEvidence(map, node, memory, likelihood_, range_sigma_m_ * range_sigma_m_);
        }
        if (!(memory.walk_nats > kWalkNats)) {
            return false;
        }
        char nats[32];
        std::snprintf(nats, sizeof nats, "%.1f", memory.walk_nats);
        why = "its last ranges fit a walk better than standing (log-likelihood ratio " + std::string(nats) + ")";
    } else {
        const uint32_t window = std::clamp<uint32_t>(params_.inferred_window, 1U, kRanges);
        // Large means beyond both the configured distance and four standard deviations of the noise.
        const double large_m = std::max(params_.inferred_residual_m, 4.0 * range_sigma_m_);
        const uint32_t seen = std::min(memory.recent_count, window);
        uint32_t large = 0;
        std::vector<uint32_t> large_links;
        for (uint32_t back = 0; back < seen; ++back) {
            const uint32_t slot = (memory.recent_next + kRanges - 1 - back) % kRanges;
            if (std::abs(memory.recent_residual_m[slot]) > large_m) {
                ++large;
                if (std::find(large_links.begin(), large_links.end(), memory.recent_links[slot]) == large_links.end()) {
                    large_links.push_back(memory.recent_links[slot]);
                }
            }
        }
        if (large < params_.inferred_min_large || large_links.size() < params_.inferred_min_links) {
            return false;
        }
        why = std::to_string(large) + " of its last " + std::to_string(seen) + " ranges read far from the map";
    }
    ++counters_.motion_inferred;
    if (trace) {
        trace("node " + std::to_string(state.id) + ": " + why + ": taken as moving");
    }
    const bool changed = change(map, sogs, node, true, trace);
    state.motion.inferred = true;
    return changed;
}

void MotionTracker::track(MapState &map, uint32_t moving_node, uint32_t anchor_node, double range_m, double t_s)
{
    NodeState &state = map.nodes[moving_node];
    const NodeState &anchor = map.nodes[anchor_node];
    if (!params_.reset || !params_.track || !(state.moving() || state.settling()) || !anchor.anchor()) {
        return;
    }

    if (!state.track) {
        // An inferred motion is found late: the node is already somewhere else, by metres.
        const double position_sigma = state.motion.inferred ? 2.0 : 0.3;
        state.track = MotionTrack(state.position_m, position_sigma, params_.track_speed_sigma_mps);
    }
    // At rest (settling) only a little jitter is allowed, not walking.
    state.track->predict(t_s, state.settling() ? 0.05 : params_.track_accel_sigma_mps2);
    const Matrix2 anchor_covariance = anchor.fixed() ? Matrix2::Zero() : anchor.covariance_m2;
    if (state.moving() && state.motion.inferred) {
        // The range and how well the moving track predicted it, for the test that it stopped.
        MotionMemory &memory = state.motion;
        const Vector2 along = state.track->position() - anchor.position_m;
        const double distance_m = along.norm();
        const Vector2 u = distance_m > 1e-9 ? Vector2(along / distance_m) : Vector2::UnitX();
        const double variance =
            range_sigma_m_ * range_sigma_m_ + u.dot((state.track->positionCovariance() + anchor_covariance) * u);
        memory.still_anchor[memory.still_next] = anchor_node;
        memory.still_range_m[memory.still_next] = range_m;
        memory.still_t_s[memory.still_next] = t_s;
        memory.still_track_log_density[memory.still_next] = likelihood_.logDensity(range_m - distance_m, variance);
        memory.still_track_position_m[memory.still_next] = state.track->position();
        memory.still_track_covariance_m2[memory.still_next] = state.track->positionCovariance();
        memory.still_track_warm[memory.still_next] = state.track->updates() >= kStillWarmUpdates ? 1 : 0;
        memory.still_next = (memory.still_next + 1) % MotionMemory::kStillRanges;
        memory.still_count = std::min(memory.still_count + 1, MotionMemory::kStillRanges);
    }
    if (state.track->updateRange(anchor.position_m, anchor_covariance, range_m, range_sigma_m_, likelihood_,
                                 gate_sigma_)) {
        state.track->limitSpeed(params_.track_max_speed_mps);
        ++counters_.track_updates;
    } else {
        ++counters_.track_refused;
    }
}

bool MotionTracker::afterUpdate(MapState &map, SogBank &sogs, uint32_t node, const Trace &trace)
{
    NodeState &state = map.nodes[node];
    if (state.settling()) {
        bool fresh = true;
        for (uint32_t link : state.links) {
            const NodeState &other = map.nodes[map.otherNode(link, node)];
            fresh = fresh && (!other.placed() || other.moving() || map.links[link].window.size() > 0);
        }
        if (fresh) {
            state.track.reset();
            state.lifecycle = NodeLifecycle::Placed;
            return true;
        }
        return false;
    }
    if (!state.moving() || !state.motion.inferred) {
        return false;
    }
    // An inferred motion ends when the track's speed stayed low for a while (or, without a track,
    // the estimate stayed within inferred_still_m).
    MotionMemory &memory = state.motion;
    if (standsStill(map, state, likelihood_, range_sigma_m_)) {
        return change(map, sogs, node, false, trace);
    }
    // A young track's speed is its prior's (it starts at rest): it says nothing yet.
    const bool slow = state.track ? state.track->updates() >= kStillWarmUpdates &&
                                        state.track->velocity().norm() < params_.inferred_still_speed_mps
                                  : (state.position_m - memory.still_anchor_m).norm() < params_.inferred_still_m;
    memory.still_updates = slow ? memory.still_updates + 1 : 0;
    if (!slow) {
        memory.still_anchor_m = state.position_m;
    }
    if (memory.still_updates >= params_.inferred_still_updates) {
        return change(map, sogs, node, false, trace);
    }
    return false;
}

} // namespace cdro::engine
