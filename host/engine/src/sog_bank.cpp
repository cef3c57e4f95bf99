#include "cdro/engine/sog_bank.hpp"

#include <algorithm>

namespace cdro::engine {

namespace {
constexpr uint32_t kSettledReweightEvery = 4;
constexpr uint32_t kSettledRingUpdates = 64;
// A settled ring's full updates come this many times less often: its floor components have had
// 64 ranges to gain weight and did not; the full updates were 80 % of the weight terms of the
// steady state at PLANT's size (docs/bench.md), for the rare ring whose evidence turns, which
// a collapse still finds within a few dozen ranges.
constexpr uint32_t kSettledFullUpdateFactor = 4;
} // namespace

SogBank::SogBank(const EngineParams &params, const RangeLikelihood &likelihood)
    : ring_(params.ring), sog_(params.sog), range_sigma_m_(params.range.sigma_m), motion_reset_(params.motion.reset),
      follow_(params.sog.rings_follow_center && params.refinement.enabled), likelihood_(likelihood)
{
    ring_.radial_sigma_m = params.range.sigma_m;
    ring_.min_tangential_sigma_m = params.range.sigma_m;
}

uint32_t SogBank::newSlot(MapState &map) const
{
    if (!map.free_rings.empty()) {
        const uint32_t slot = map.free_rings.back();
        map.free_rings.pop_back();
        return slot;
    }
    map.rings.emplace_back();
    return static_cast<uint32_t>(map.rings.size() - 1);
}

void SogBank::ensureRings(MapState &map, uint32_t node)
{
    for (uint32_t link : map.nodes[node].links) {
        const uint32_t other = map.otherNode(link, node);
        if (!map.nodes[other].placed()) {
            continue;
        }
        for (const auto &[center, target] : {std::pair{node, other}, std::pair{other, node}}) {
            if (map.nodes[target].fixed() || map.ringSlot(link, center) != kNoIndex) {
                continue;
            }
            const uint32_t slot = newSlot(map);
            map.rings[slot] = RingSog::generate(map.nodes[center].id, map.nodes[target].id,
                                                map.nodes[center].position_m, map.links[link].representative_m, ring_);
            map.ringSlot(link, center) = slot;
            reweight(map, link, center, map.links[link].representative_m, true);
        }
    }
}

void SogBank::dropRings(MapState &map, uint32_t node, bool centred_only)
{
    for (uint32_t link : map.nodes[node].links) {
        LinkState &state = map.links[link];
        for (uint32_t *slot : {&state.ring_from_a, &state.ring_from_b}) {
            const bool centred = (slot == &state.ring_from_a) == (state.node_a == node);
            if (*slot != kNoIndex && (centred || !centred_only)) {
                map.rings[*slot] = RingSog{};
                map.free_rings.push_back(*slot);
                *slot = kNoIndex;
            }
        }
    }
}

void SogBank::update(MapState &map, uint32_t link, uint32_t center_node, double range_m)
{
    const uint32_t target_node = map.otherNode(link, center_node);
    const NodeState &center = map.nodes[center_node];
    const NodeState &target = map.nodes[target_node];
    if (!target.free()) {
        return;
    }
    if (motion_reset_ && center.moving()) {
        return; // a moving node describes nobody; its SoGs come back when it stops
    }
    if (motion_reset_ && target.moving()) {
        // Paper Fig. 4(a): the new range resets the SoG around the ranging neighbour; the other
        // neighbours' latest ranges weight it (4(b)).
        uint32_t slot = map.ringSlot(link, center_node);
        if (slot == kNoIndex) {
            slot = newSlot(map);
            map.ringSlot(link, center_node) = slot;
        }
        map.rings[slot] =
            RingSog::generate(center.id, target.id, center.position_m, map.links[link].representative_m, ring_);
        ++counters_.motion_resets;
        reweight(map, link, center_node, range_m, true);
        return;
    }
    if (map.ringSlot(link, center_node) == kNoIndex) {
        ensureRings(map, center_node);
    }
    const uint32_t slot = map.ringSlot(link, center_node);
    if (slot == kNoIndex) {
        return;
    }
    RingSog &ring = map.rings[slot];
    const Matrix2 center_covariance = center.fixed() ? Matrix2::Zero() : center.covariance_m2;
    // full_update_every 1 is the paper's filter: every range updates every component.
    const uint32_t every_k = std::max<uint32_t>(sog_.full_update_every, 1U);
    const uint32_t every =
        every_k > 1U && ring.updateCount() >= kSettledRingUpdates ? every_k * kSettledFullUpdateFactor : every_k;
    const bool full = ring.updateCount() % every == 0;
    ring.countUpdate();
    const RangeUpdateResult result = ring.updateWithRange(center.position_m, center_covariance, range_m, range_sigma_m_,
                                                          sog_.gate_sigma, sog_.process_noise_m2, full);
    counters_.ekf_component_updates += result.updated;
    counters_.ekf_gated += result.gated;
    // A ring that has taken kSettledRingUpdates ranges has settled on one arc (eq. 15 keeps its
    // weights around the heaviest component): the other nodes' ranges re-weigh it on every
    // kSettledReweightEvery-th range of the ring (and on every full update), not on each. The
    // re-weighting was half of the per-range time at PLANT's size (docs/bench.md), for weights
    // that no longer move; a young ring (a new link, or one generated again after its node moved)
    // takes every range.
    if (ring.updateCount() >= kSettledRingUpdates && !full && ring.updateCount() % kSettledReweightEvery != 0) {
        ++counters_.weight_updates_deferred;
        return;
    }
    reweight(map, link, center_node, range_m, full);
}

void SogBank::reweight(MapState &map, uint32_t link, uint32_t center_node, double own_range_m, bool full)
{
    const uint32_t slot = map.ringSlot(link, center_node);
    if (slot == kNoIndex) {
        return;
    }
    const uint32_t target_node = map.otherNode(link, center_node);
    const NodeState &center = map.nodes[center_node];
    const NodeState &target = map.nodes[target_node];
    std::vector<RangeWitness> &witnesses = scratch_;
    witnesses.clear();
    if (sog_.cooperative) {
        // Eq. 8-11: every other node m that ranged to the target says how far the target is
        // from m; the components that agree gain weight.
        for (uint32_t other_link : target.links) {
            const uint32_t other = map.otherNode(other_link, target_node);
            const NodeState &witness = map.nodes[other];
            if (other == center_node || !witness.placed() || witness.moving()) {
                continue;
            }
            witnesses.push_back(RangeWitness{witness.position_m,
                                             witness.fixed() ? Matrix2::Zero() : witness.covariance_m2,
                                             map.links[other_link].representative_m});
        }
    } else {
        // The ablation: the ring's own range only (no other node's opinion).
        witnesses.push_back(
            RangeWitness{center.position_m, center.fixed() ? Matrix2::Zero() : center.covariance_m2, own_range_m});
    }
    if (witnesses.empty()) {
        return;
    }
    RingSog &ring = map.rings[slot];
    const WeightUpdateResult weights =
        ring.updateWeights(witnesses, likelihood_, range_sigma_m_, full, sog_.collapse_reset);
    counters_.weight_terms += witnesses.size();
    counters_.weight_terms_downweighted += weights.downweighted;
    counters_.weight_collapses += weights.collapsed ? 1U : 0U;
    if (sog_.weight_transfer) {
        ring.transferWeights(sog_.transfer_sigma_m);
        ++counters_.weight_transfers;
    }
}

Gaussian2 SogBank::merge(const MapState &map, uint32_t node, uint32_t *ring_count) const
{
    // Eq. 12-14: moment matching of every SoG that describes the node; each ring has total
    // weight 1, so each neighbour counts equally.
    Vector2 first = Vector2::Zero();
    Matrix2 second = Matrix2::Zero();
    double total = 0.0;
    *ring_count = 0;
    for (uint32_t link : map.nodes[node].links) {
        const uint32_t other = map.otherNode(link, node);
        const uint32_t slot = map.ringSlot(link, other);
        if (slot == kNoIndex || map.rings[slot].empty() || map.nodes[other].moving()) {
            continue;
        }
        map.rings[slot].accumulateMoments(&first, &second, &total);
        ++*ring_count;
    }
    Gaussian2 merged;
    if (total <= 0.0) {
        return merged;
    }
    merged.mean_m = first / total;
    merged.covariance_m2 = second / total - merged.mean_m * merged.mean_m.transpose();
    return merged;
}

void SogBank::follow(MapState &map, uint32_t node, const Vector2 &delta_m) const
{
    if (follow_) {
        translate(map, node, delta_m);
    }
}

void SogBank::translate(MapState &map, uint32_t node, const Vector2 &delta_m) const
{
    if (delta_m.squaredNorm() == 0.0) {
        return;
    }
    for (uint32_t link : map.nodes[node].links) {
        const uint32_t slot = map.ringSlot(link, node);
        if (slot != kNoIndex) {
            map.rings[slot].translate(delta_m);
        }
    }
}

} // namespace cdro::engine
