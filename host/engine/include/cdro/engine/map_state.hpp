// map_state.hpp: the state of stage 1 as a plain value: the nodes (each with its role and one
// lifecycle), the links with their range windows, the rings (the SoGs) and the frame. No
// behaviour beyond queries: the steps of the pipeline (engine.hpp) read and change it, and the
// global solve reads it without cloning anything.
//
// Storage is sparse and ordered: nodes and links live in vectors in the order they first
// appeared (every loop over them is deterministic), hash maps serve lookups by id only, a link
// exists only once two nodes have ranged, so memory grows with the links, not with M^2.
#pragma once

#include <array>
#include <cstdint>
#include <limits>
#include <optional>
#include <unordered_map>
#include <vector>

#include "cdro/engine/alignment.hpp"
#include "cdro/engine/motion_track.hpp"
#include "cdro/engine/ring_sog.hpp"
#include "cdro/engine/types.hpp"

namespace cdro::engine {

constexpr uint32_t kNoIndex = std::numeric_limits<uint32_t>::max();

// Who decides where a node is.
enum class NodeRole : uint8_t {
    Free,   // the filter estimates it
    Fixed,  // known coordinates (setFixed), never moved
    Pinned, // the movement stage's EKF owns its position: an anchor here until unpinned
};

// Where a node is in its life, one state at a time.
enum class NodeLifecycle : uint8_t {
    Unplaced,  // no position yet
    Placed,    // a position, not (yet) one the ranges determine
    Converged, // the ranges determine it (Convergence: every check passed)
    Moving,    // reported or found moving: tracked, anchor for nobody (paper Fig. 4)
    Settling,  // stopped, but not every link has a range from where it stopped
};

// Why a placed node is not converged (None when it is, or while it is not placed).
enum class NodeDoubt : uint8_t {
    None,
    TooFewLinks, // fewer than three links to placed nodes: its ranges cannot fix it
    Ambiguous,   // another position fits its links about as well (a mirror image), or a rival
                 // map that explains the links almost as well places it elsewhere
    Foldable,    // its part hangs on one or two nodes (`hinge`) and can fold about them
    Flexible,    // it hangs on links that nothing checks: one error in them, too small to be
                 // noticed, or the map's own flexibility, could move it by a metre or more
    Unsettled,   // its estimate still moves (eq. 16) or the global solve has not seen it yet
};

const char *nodeRoleName(NodeRole role);
const char *nodeLifecycleName(NodeLifecycle lifecycle);
const char *nodeDoubtName(NodeDoubt doubt);

// The last ranges of a link (projected to the plane), for a robust summary: their median.
class RangeWindow {
public:
    static constexpr uint32_t kCapacity = 32;
    void push(double range_m);
    void clear();
    uint32_t size() const { return size_; }
    double median() const; // m; 0 when empty
    double newest() const; // m; 0 when empty
    // Oldest first (for checkpoints).
    std::vector<double> values() const;
    void setCapacityLimit(uint32_t limit); // how many of kCapacity are used, 1..kCapacity

private:
    std::array<double, kCapacity> values_{};
    uint32_t size_ = 0;
    uint32_t next_ = 0;
    uint32_t limit_ = 15;
};

// What the global solve said about a node when its map was last adopted (global_step.hpp).
struct NodeSolveView {
    bool solved = false;                     // the solve placed it
    Vector2 position_m = Vector2::Zero();    // m, engine frame, as adopted
    Matrix2 covariance_m2 = Matrix2::Zero(); // m^2, the map's (correlations across it included)
    double reliability_m = 0.0;              // m, the most one unnoticed link error moves it
    bool disputed = false;                   // a rival map places it a metre or more away
    bool main_part = false;                  // in the part joined by checked links
};

// The fallback motion detector's memory: the node's last ranges (when, on which link, how far
// from the map); and the reports.
struct MotionMemory {
    static constexpr uint32_t kRecentRanges = 16;
    bool reports = false;         // the node sends motion reports: the detector leaves it alone
    bool reported_moving = false; // the last report said moving (kept while not placed)
    bool inferred = false;        // the current motion was found by the detector
    std::array<uint32_t, kRecentRanges> recent_links{};
    std::array<double, kRecentRanges> recent_t_s{};        // s (NaN: the range had no time)
    std::array<double, kRecentRanges> recent_residual_m{}; // m, from the map and the link's history
    uint32_t recent_count = 0;
    uint32_t recent_next = 0;
    double walk_nats = 0.0;                   // the start test's last log-likelihood ratio (motion_tracker.cpp)
    Vector2 still_anchor_m = Vector2::Zero(); // m, where an inferred-moving node was N updates ago
    uint32_t still_updates = 0;
    // An inferred-moving node's last ranges to anchors, for the test that it stands still again.
    static constexpr uint32_t kStillRanges = 8;
    std::array<uint32_t, kStillRanges> still_anchor{}; // node indices
    std::array<double, kStillRanges> still_range_m{};  // m
    std::array<double, kStillRanges> still_t_s{};      // s
    // What the track knew when each came (its prediction, before the range): the range's log
    // predictive density (log 1/m), where it put the node (m) and how sure it was (m^2), and
    // whether it had taken enough ranges to be a walk worth testing against.
    std::array<double, kStillRanges> still_track_log_density{};
    std::array<Vector2, kStillRanges> still_track_position_m{};
    std::array<Matrix2, kStillRanges> still_track_covariance_m2{};
    std::array<uint8_t, kStillRanges> still_track_warm{};
    uint32_t still_count = 0;
    uint32_t still_next = 0;
};

struct NodeState {
    NodeId id = 0;
    NodeRole role = NodeRole::Free;
    NodeLifecycle lifecycle = NodeLifecycle::Unplaced;
    NodeDoubt doubt = NodeDoubt::None;
    std::array<uint32_t, 2> hinge{kNoIndex, kNoIndex}; // Foldable: the nodes it hangs on (indices)
    std::optional<double> height_m;                    // m, when known
    Vector2 position_m = Vector2::Zero();              // m, engine frame
    Matrix2 covariance_m2 = Matrix2::Identity();       // m^2, the local (refinement) covariance
    Vector2 average_m = Vector2::Zero();               // m, convergence moving average (eq. 16)
    uint32_t still_updates = 0;                        // consecutive updates with the average's step under threshold
    uint32_t update_count = 0;                         // merges/refinements since placed (saturating)
    uint32_t placements = 0;                           // times placed (re-placements after an inconsistency count)
    uint32_t waiting_ranges = 0;                       // ranges seen while not placed (placement's patience)
    uint64_t first_range = 0;                          // ranges the engine had taken when the node appeared
    double range_offset_m = 0.0; // m, its radio reads this much long (range_offsets.hpp; the global solve's)
    std::vector<uint32_t> links; // indices into MapState::links, in order of appearance
    MotionMemory motion;
    std::optional<MotionTrack> track; // while moving or settling: the constant-velocity track
    NodeSolveView solve;

    bool placed() const { return lifecycle != NodeLifecycle::Unplaced; }
    bool converged() const { return lifecycle == NodeLifecycle::Converged; }
    bool moving() const { return lifecycle == NodeLifecycle::Moving; }
    bool settling() const { return lifecycle == NodeLifecycle::Settling; }
    bool fixed() const { return role == NodeRole::Fixed; }
    bool pinned() const { return role == NodeRole::Pinned; }
    // An anchor for the others: placed, still (not moving or settling).
    bool anchor() const { return placed() && !moving() && !settling(); }
    // Estimated by stage 1's filter (not fixed, not pinned).
    bool free() const { return role == NodeRole::Free; }
};

struct LinkState {
    uint32_t node_a = kNoIndex; // index of the node with the smaller id
    uint32_t node_b = kNoIndex;
    RangeWindow window;        // recent projected ranges, m
    uint32_t range_count = 0;  // ranges seen on this link
    double last_range_m = 0.0; // m, last measured range (3D, as reported)
    double representative_m =
        0.0;                     // m, median of the window (projected), less its ends' range offsets: the link's range
    double solved_range_m = 0.0; // m, the link's range when the global solve last saw it (0: never)
    uint32_t ring_from_a = kNoIndex; // SoG centred on node_a describing node_b (index into rings)
    uint32_t ring_from_b = kNoIndex;
    double inlier_probability = 1.0; // line-of-sight probability at the last refinement
};

class MapState {
public:
    uint32_t findNode(NodeId id) const;
    uint32_t addNode(NodeId id); // returns the existing index when known
    uint32_t findLink(uint32_t node_a, uint32_t node_b) const;
    uint32_t addLink(uint32_t node_x, uint32_t node_y, uint32_t window_limit); // either order

    uint32_t otherNode(uint32_t link, uint32_t node) const
    {
        const LinkState &state = links[link];
        return state.node_a == node ? state.node_b : state.node_a;
    }
    // The ring centred on `center_node` of `link` (kNoIndex when none).
    uint32_t &ringSlot(uint32_t link, uint32_t center_node)
    {
        LinkState &state = links[link];
        return state.node_a == center_node ? state.ring_from_a : state.ring_from_b;
    }
    uint32_t ringSlot(uint32_t link, uint32_t center_node) const
    {
        const LinkState &state = links[link];
        return state.node_a == center_node ? state.ring_from_a : state.ring_from_b;
    }
    uint32_t placedCount() const;
    // Node and link indices in the order the outputs list them (nodes by id, links by (a, b)),
    // kept as nodes and links are added, so that no output sorts the map.
    const std::vector<uint32_t> &nodesById() const { return nodes_by_id_; }
    const std::vector<uint32_t> &linksById() const { return links_by_id_; }

    std::vector<NodeState> nodes;
    std::vector<LinkState> links;
    std::vector<RingSog> rings;                         // the SoGs, by slot (sog_bank.hpp owns their life)
    std::vector<uint32_t> free_rings;                   // slots to reuse
    std::optional<std::array<uint32_t, 3>> frame_nodes; // the frame triangle (node indices)
    RigidTransform frame_offset; // the output frame from the triangle's (identity until it is picked again)
    double last_time_s = -std::numeric_limits<double>::infinity(); // s, latest range time seen

private:
    static uint32_t linkKey(NodeId a, NodeId b) { return (static_cast<uint32_t>(a) << 16) | b; }
    std::unordered_map<NodeId, uint32_t> node_index_;
    std::unordered_map<uint32_t, uint32_t> link_index_;
    std::vector<uint32_t> nodes_by_id_;
    std::vector<uint32_t> links_by_id_;
};

} // namespace cdro::engine
