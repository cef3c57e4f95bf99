// network.hpp: the engine's sparse storage. Nodes and links live in vectors in the order they
// first appeared (so every loop over them is deterministic), with hash maps only for lookup by
// id. A link exists only once two nodes have ranged, and a node's adjacency lists only its own
// links, so memory grows with the links that exist, not with M^2.
#pragma once

#include <array>
#include <cstdint>
#include <limits>
#include <unordered_map>
#include <vector>

#include "cdro/engine/motion_track.hpp"
#include "cdro/engine/types.hpp"

namespace cdro::engine {

constexpr uint32_t kNoIndex = std::numeric_limits<uint32_t>::max();

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

struct NodeState {
    NodeId id = 0;
    bool placed = false;            // has a position in the engine frame
    bool fixed = false;             // known coordinates, never updated
    bool height_known = false;
    bool moving = false;            // moving: tracked, not an anchor for others (paper Fig. 4)
    bool motion_reported = false;   // motion comes from reports (MOTION frames, the motion CSV)
    bool motion_inferred = false;   // moving because its ranges jumped (no reports for it)
    bool pinned = false;            // position owned by the movement stage's EKF: an anchor here
    bool converged = false;
    bool ambiguous = false;         // another position fits its links about as well (a mirror
                                    // image across nearly collinear neighbours): not converged
    double height_m = 0.0;          // m, meaningful when height_known
    Vector2 position_m = Vector2::Zero();        // m, engine frame
    Matrix2 covariance_m2 = Matrix2::Identity(); // m^2
    Vector2 average_m = Vector2::Zero();         // m, convergence moving average (eq. 16)
    uint32_t still_updates = 0;     // consecutive updates with the average's step under threshold
    uint32_t update_count = 0;      // merges/refinements since placed (saturating)
    uint32_t placements = 0;        // times placed (re-placements after an inconsistency count)
    uint32_t ambiguous_ranges = 0;  // ranges seen while not placed (placement's patience)
    std::vector<uint32_t> links;    // indices into Network::links, in order of appearance
    // The fallback motion detector's memory: the last ranges of this node, whether each read
    // far from the map, and on which link.
    static constexpr uint32_t kRecentRanges = 16;
    std::array<uint32_t, kRecentRanges> recent_links{};
    std::array<bool, kRecentRanges> recent_large{};
    uint32_t recent_count = 0;
    uint32_t recent_next = 0;
    Vector2 track_anchor_m = Vector2::Zero(); // m, where an inferred-moving node was N updates ago
    uint32_t track_updates = 0;
    bool has_track = false;          // while moving: the constant-velocity track (motion_track.hpp)
    bool settling = false;           // stopped, but not every link has a range since: the track
                                     // (at rest) is still the estimate
    MotionTrack track;
};

struct LinkState {
    uint32_t node_a = kNoIndex;     // index of the node with the smaller id
    uint32_t node_b = kNoIndex;
    RangeWindow window;             // recent projected ranges, m
    uint32_t range_count = 0;       // ranges seen on this link
    double last_range_m = 0.0;      // m, last measured range (3D, as reported)
    double representative_m = 0.0; // m, median of the window (projected): the link's range
    uint32_t ring_from_a = kNoIndex; // SoG centred on node_a describing node_b (index into rings)
    uint32_t ring_from_b = kNoIndex;
    double inlier_probability = 1.0; // line-of-sight probability at the last refinement
};

class Network {
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

    std::vector<NodeState> nodes;
    std::vector<LinkState> links;

private:
    static uint32_t linkKey(NodeId a, NodeId b) { return (static_cast<uint32_t>(a) << 16) | b; }
    std::unordered_map<NodeId, uint32_t> node_index_;
    std::unordered_map<uint32_t, uint32_t> link_index_;
};

} // namespace cdro::engine
