// sog_bank.hpp: steps 3 and 4a of a range, the paper's filter (eq. 5-15): for every link between
// placed nodes the two SoGs that describe each end as seen from the other (ring_sog.hpp), their
// EKF updates with the link's ranges, their weights from every other node that ranged to the
// target (the cooperative part, eq. 8-11), the weight transfer (eq. 15), and the moment match of
// all SoGs that describe a node (eq. 12-14). A range to a moving node resets the SoG around the
// ranging neighbour (Fig. 4). The rings live in MapState::rings; this step owns their life.
#pragma once

#include <cstdint>
#include <vector>

#include "cdro/engine/map_state.hpp"
#include "cdro/engine/params.hpp"
#include "cdro/engine/range_likelihood.hpp"

namespace cdro::engine {

struct SogBankCounters {
    uint64_t ekf_component_updates = 0;
    uint64_t ekf_gated = 0;                 // component updates refused by the innovation gate
    uint64_t weight_terms = 0;              // (ring, other node) likelihood terms applied
    uint64_t weight_terms_downweighted = 0; // ... where the ring's best component read NLOS
    uint64_t weight_collapses = 0;          // rings reset to the evidence (all weights at floor)
    uint64_t weight_transfers = 0;
    uint64_t motion_resets = 0;           // SoGs reset by a range to a moving node (Fig. 4)
    uint64_t weight_updates_deferred = 0; // ranges to a converged node whose ring was not re-weighted
};

class SogBank {
public:
    SogBank(const EngineParams &params, const RangeLikelihood &likelihood);

    // Generates the missing SoGs on the node's links to placed nodes, both directions (none
    // describes a fixed node: its position is known), each weighted at once by the other nodes'
    // ranges (Algorithm 1: a ring of equal weights would merge into its own centre).
    void ensureRings(MapState &map, uint32_t node);
    // Drops the SoGs on the node's links: those centred on it (`centred_only`) or all of them.
    void dropRings(MapState &map, uint32_t node, bool centred_only);
    // The EKF update of the SoG centred on `center` of `link` with a range, then its weights.
    void update(MapState &map, uint32_t link, uint32_t center, double range_m);
    // Weights from the other nodes' ranges (full: every component, else the active set).
    void reweight(MapState &map, uint32_t link, uint32_t center, double own_range_m, bool full);
    // Eq. 12-14 over every SoG describing the node; ring_count says how many took part.
    Gaussian2 merge(const MapState &map, uint32_t node, uint32_t *ring_count) const;
    // The SoGs centred on the node move with its estimate (O(1) each), where rings follow.
    void follow(MapState &map, uint32_t node, const Vector2 &delta_m) const;
    // The same always: the node was moved from outside the filter (a map adopted, a pin).
    void translate(MapState &map, uint32_t node, const Vector2 &delta_m) const;
    // Whether rings follow their centre (sog.rings_follow_center with refinement: without it the
    // merged SoG is the estimate, and relative rings would feed back into their own merge).
    bool ringsFollow() const { return follow_; }

    const SogBankCounters &counters() const { return counters_; }
    void restoreCounters(const SogBankCounters &counters) { counters_ = counters; }

private:
    uint32_t newSlot(MapState &map) const;

    RingSogParams ring_;
    SogUpdateParams sog_;
    double range_sigma_m_;
    bool motion_reset_;
    bool follow_;
    RangeLikelihood likelihood_;
    SogBankCounters counters_;
    std::vector<RangeWitness> scratch_;
};

} // namespace cdro::engine
