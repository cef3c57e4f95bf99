// engine.hpp: the CDRO-SLAM initialization stage as a streaming filter, one range at a time.
//
// Per range r_ij (Algorithm 1 of the paper, streaming; docs/engine.md):
//   1. project to the plane with the known heights; keep it in the link's window (the link's
//      range is the window's median);
//   2. place what can be placed (placement.hpp): the frame triangle first, then every node
//      whose placed neighbours decide its position;
//   3. if both ends are placed: EKF-update SoG_ij and SoG_ji with the range, update their
//      weights with every other node m that ranged to the target (cooperative, eq. 8-11),
//      transfer the weights (eq. 15);
//   4. merge every SoG that describes i, and j (eq. 12-14), refine the merged estimate against
//      the links (robust Gauss-Newton, beyond the paper: needed for NLOS data), update the
//      convergence average (eq. 16);
//   5. update a bounded number of neighbours of nodes that moved, so that information spreads
//      even when the ranges of a region stopped arriving.
// settle() runs step 5 until nothing moves (the end of a file, or idle time).
//
// Determinism: no clock, no randomness, no iteration over hash maps; the same calls in the same
// order give the same estimates, bit for bit. Threads: none; call from one thread.
#pragma once

#include <array>
#include <cstdint>
#include <deque>
#include <functional>
#include <limits>
#include <memory>
#include <string>
#include <optional>
#include <vector>

#include "cdro/engine/alignment.hpp"
#include "cdro/engine/foldable.hpp"
#include "cdro/engine/network.hpp"
#include "cdro/engine/params.hpp"
#include "cdro/engine/point_solver.hpp"
#include "cdro/engine/range_likelihood.hpp"
#include "cdro/engine/ring_sog.hpp"

namespace cdro::engine {

enum class RangeVerdict {
    Used,          // both ends placed: the filter took it
    Stored,        // kept on its link; an end is not placed yet
    RejectedSelf,  // a node ranging itself
    RejectedValue, // not finite, not positive, or beyond range.max_range_m
};
const char *rangeVerdictName(RangeVerdict verdict);

struct EngineCounters {
    uint64_t ranges_received = 0;
    uint64_t ranges_used = 0;
    uint64_t ranges_stored = 0;
    uint64_t rejected_self = 0;
    uint64_t rejected_value = 0;
    uint64_t projection_clamped = 0;         // 3D range shorter than the height difference
    uint64_t ekf_component_updates = 0;
    uint64_t ekf_gated = 0;                  // component updates refused by the innovation gate
    uint64_t weight_terms = 0;               // (ring, other node) likelihood terms applied
    uint64_t weight_terms_downweighted = 0;  // ... where the ring's best component read NLOS
    uint64_t weight_collapses = 0;           // rings reset to the evidence (all weights at floor)
    uint64_t weight_transfers = 0;
    uint64_t placements = 0;                 // nodes placed (frame triangle included)
    uint64_t placements_by_tie_break = 0;    // ... decided by the MDS layout
    uint64_t placement_ambiguous = 0;        // evaluations that could not decide (waited)
    uint64_t placements_forced = 0;          // placed at the best candidate after patience ran out
    uint64_t mds_layouts = 0;
    uint64_t replacements = 0;               // placed nodes found inconsistent, placed again
    uint64_t refinements = 0;
    uint64_t refinement_links_downweighted = 0; // links with inlier probability < 0.5, summed
    uint64_t hypothesis_switches = 0;        // the merged SoG won over the previous estimate
    uint64_t node_updates = 0;               // merges (after a range or as a neighbour)
    uint64_t relaxations = 0;                // neighbour updates (step 5)
    uint64_t reinitializations = 0;          // initializations run again on all links
    uint64_t reinitializations_adopted = 0;  // ... whose map replaced the current one
    uint64_t joint_solves = 0;               // maps solved all nodes at once (joint_solver.hpp)
    uint64_t ambiguous_nodes = 0;            // nodes found ambiguous at the last check
    uint64_t motion_starts = 0;              // nodes that started moving (reported or inferred)
    uint64_t motion_stops = 0;
    uint64_t motion_inferred = 0;            // ... of the starts, found by the range detector
    uint64_t motion_resets = 0;              // SoGs reset by a range to a moving node (Fig. 4)
    uint64_t track_updates = 0;              // ranges taken by a moving node's track
    uint64_t track_refused = 0;              // ... refused as outliers
};

// A node's estimate in the output frame.
struct NodeOutput {
    NodeId id = 0;
    bool placed = false;
    bool converged = false;
    bool moving = false;
    bool fixed = false;
    bool ambiguous = false;                        // its links fit another position about as well
    // In a part of the network that hangs on at most two other nodes (foldable.hpp): the part
    // can fold over them without changing a range, so the node is not called converged.
    bool foldable = false;
    std::array<NodeId, 2> hinge{};                 // the nodes it hangs on (hinge_nodes of them, by id)
    uint8_t hinge_nodes = 0;
    bool height_known = false;
    double height_m = 0.0;                         // m
    uint32_t link_count = 0;                       // links to other nodes
    Vector2 position_m = Vector2::Zero();          // m
    Matrix2 covariance_m2 = Matrix2::Zero();       // m^2
};

struct LinkOutput {
    NodeId a = 0;                  // smaller id
    NodeId b = 0;
    double last_range_m = 0.0;     // m, as measured (3D)
    double range_m = 0.0;          // m, the link's range: median of its window, projected
    uint32_t range_count = 0;
    double inlier_probability = 1.0; // line-of-sight probability at the last refinement
};

// One SoG describing a node (output frame).
struct RingOutput {
    NodeId center = 0;
    NodeId target = 0;
    std::vector<SogComponentState> components;
};

class Engine {
public:
    explicit Engine(const EngineParams &params = {});

    // Known facts, before the ranges that need them: a node's height (m), a node with known
    // coordinates (m, output frame) that stays fixed (before the first range; throws
    // std::logic_error after). Two or more fixed nodes define the frame; a single one only
    // says where the map sits.
    void setHeight(NodeId id, double height_m);
    void setFixed(NodeId id, const Vector2 &position_m);

    // One range between two nodes, as measured (3D, m), at time t_s (s; NaN when unknown: the
    // initialization does not need it, tracking a moving node does).
    RangeVerdict addRange(NodeId from, NodeId to, double range_m, double t_s = std::numeric_limits<double>::quiet_NaN());

    // A motion report (MOTION frame, motion CSV): the node is moving or still (params.motion).
    void setMoving(NodeId id, bool moving);

    // The movement stage's EKF owns this node's position: here it is an anchor at that position
    // (not refined, not placed again) until unpinned.
    void pinNode(NodeId id, const Vector2 &position_m, const Matrix2 &covariance_m2);
    void unpinNode(NodeId id);
    // While held, no frame triangle is placed: nodes are placed only from fixed or pinned ones
    // (the movement stage's own frame).
    void holdFrame(bool held) { frame_held_ = held; }

    // Updates neighbours until no node moves more than refinement.relax_threshold_m, or
    // max_updates were made (after running the initialization again if links appeared since
    // it last ran). Returns the updates made.
    uint64_t settle(uint64_t max_updates);

    // The map's robust cost (nats): -log p(e) over every link with both ends placed, plus the
    // price of an unexplained range (the likelihood's gross-error floor) for every link with an
    // end not placed, so that a map placing more nodes consistently costs less.
    double mapCost() const;

    // Runs the initialization again on all links and adopts its map if it costs at least
    // reinitialization.min_gain_nats less (aligned onto the current frame). Returns whether
    // it was adopted.
    bool reinitialize();

    // Outputs, in the output frame (see outputTransform()).
    std::vector<NodeOutput> estimates() const;                 // every known node, by id
    std::optional<NodeOutput> estimate(NodeId id) const;
    uint32_t foldableCount() const;                            // placed nodes that can fold
    std::vector<LinkOutput> links() const;                     // by (a, b)
    std::vector<RingOutput> ringsDescribing(NodeId id) const;  // SoG_ij for every neighbour i
    // Engine frame -> output frame: the named frame (params.frame), else the frame triangle's
    // (origin, x-axis, +y) nodes, then shifted so a single fixed node sits at its coordinates.
    // With two or more fixed nodes the engine frame is theirs and this is the identity.
    RigidTransform outputTransform() const;

    // Decisions worth explaining (placements, tie breaks, re-placements) as one-line messages,
    // for the service's debug log and for investigations. Off when empty.
    void setTrace(std::function<void(const std::string &)> sink) { trace_ = std::move(sink); }

    uint64_t revision() const { return revision_; }
    const EngineCounters &counters() const { return counters_; }
    const EngineParams &params() const { return params_; }
    const Network &network() const { return network_; }
    const std::vector<RingSog> &rings() const { return rings_; }
    // The frame triangle's nodes (ids), once placed.
    std::optional<std::array<NodeId, 3>> frameNodes() const;

    // For checkpoints (the service's adapter writes them in common/'s SoG layout): the whole
    // state, exposed for reading, and rebuilt from parts.
    struct RestoredNode {
        NodeState state;             // links are rebuilt from the restored links
    };
    struct RestoredLink {
        NodeId a = 0;
        NodeId b = 0;
        std::vector<double> window_m;
        uint32_t range_count = 0;
        double last_range_m = 0.0;
        double inlier_probability = 1.0;
    };
    struct RestoredState {
        std::vector<NodeState> nodes;
        std::vector<RestoredLink> links;
        std::vector<RingSog> rings;
        std::optional<std::array<NodeId, 3>> frame_nodes;
        EngineCounters counters;
        uint64_t reinit_link_count = 0;       // links when the initialization last ran
        uint64_t ranges_since_new_link = 0;
    };
    uint64_t reinitLinkCount() const { return reinit_link_count_; }
    uint64_t rangesSinceNewLink() const { return ranges_since_new_link_; }
    void restore(const RestoredState &state); // replaces everything; throws std::invalid_argument

private:
    uint32_t nodeIndex(NodeId id);
    void runPlacement();
    void applyFixedNodes();
    void applyMotion(uint32_t node, bool moving);
    void refreshLinkRange(uint32_t link);
    void watchForMotion(uint32_t node, uint32_t link, double residual_m);
    void updateTrack(uint32_t moving_node, uint32_t anchor_node, double range_m, double t_s);
    std::unique_ptr<Engine> unplacedCopy() const;
    bool placeFromMds();
    void sweep(uint32_t sweeps, bool anneal);
    void updateAllNodes(uint32_t rounds);
    uint32_t escapeLocalMinima();
    uint32_t checkAmbiguity();
    void ensureFrameNodes();
    bool placeByHandedness(const std::vector<uint32_t> &nodes);
    // Rings follow their centre's estimate only when the refinement sets it: with the merged SoG
    // as the estimate, relative rings feed back into their own merge and the map drifts.
    bool ringsFollow() const { return params_.sog.rings_follow_center && params_.refinement.enabled; }
    bool placeFrame();
    void placeNode(uint32_t node, const Vector2 &position_m, const Matrix2 &covariance_m2);
    void unplaceNode(uint32_t node);
    void ensureRings(uint32_t node);
    uint32_t &ringSlot(uint32_t link, uint32_t center_node);
    void updateRing(uint32_t link, uint32_t center_node, double range_m);
    void updateNode(uint32_t node, bool after_range = false);
    void reweightRing(uint32_t link, uint32_t center_node, double own_range_m, bool full);
    Gaussian2 mergeRings(uint32_t node, uint32_t *ring_count) const;
    void updateConvergence(NodeState &state);
    void enqueueNeighbours(uint32_t node);
    void enqueue(uint32_t node);
    void relax(uint64_t budget);
    void markPlacementPending(uint32_t node);
    std::optional<std::vector<Vector2>> alignedMdsLayout(std::vector<uint32_t> *members, double *error_m);

    EngineParams params_;
    RangeLikelihood likelihood_;
    PointSolverParams solver_;        // placement
    PointSolverParams refine_solver_; // refinement
    Network network_;
    std::vector<RingSog> rings_;
    std::vector<uint32_t> free_rings_;
    std::vector<bool> placement_pending_;
    bool any_placement_pending_ = false;
    size_t mds_link_count_ = 0;        // links when MDS last ran (it runs again only on growth)
    size_t mds_node_count_ = 0;
    size_t reinit_link_count_ = 0;     // links when the initialization last ran
    uint64_t ranges_since_new_link_ = 0;
    std::deque<uint32_t> relax_queue_;
    std::vector<bool> in_relax_queue_;
    std::optional<std::array<uint32_t, 3>> frame_nodes_; // node indices
    uint32_t fixed_count_ = 0;        // fixed nodes that define the frame (two or more)
    std::vector<std::pair<NodeId, Vector2>> fixed_positions_;
    std::optional<std::pair<NodeId, Vector2>> single_fixed_; // one fixed node: output shift only
    bool fixed_applied_ = false;
    bool placing_ = false;
    bool frame_held_ = false;
    double last_time_s_ = -std::numeric_limits<double>::infinity(); // s, latest range time seen
    EngineCounters counters_;
    uint64_t revision_ = 0;
    std::vector<RangeWitness> scratch_witnesses_;
    // The foldable parts of the placed, still nodes' link graph, recomputed when the links or
    // the placed set change (the key below), not on every output.
    const Foldable &foldableParts() const;
    mutable Foldable foldable_;
    mutable uint64_t foldable_key_ = 0;
    mutable bool foldable_valid_ = false;
    std::function<void(const std::string &)> trace_;
    void trace(const std::string &message) const
    {
        if (trace_) {
            trace_(message);
        }
    }
};

} // namespace cdro::engine
