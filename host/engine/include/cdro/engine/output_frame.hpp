// output_frame.hpp: where the outputs are. Fixed nodes (known coordinates, given before the first
// range): two or more define the engine frame and never move; a single one only says where the
// map sits (the outputs are shifted so that it is at its coordinates). Otherwise the named frame
// (params.frame: origin at (0, 0), x-axis node on +x, a third on the +y side), else the frame
// triangle's nodes play those roles, so the output frame stays put while the map is refined.
// A node known to move (the robot's tag) is never one of the triangle's; when a node of the
// triangle starts moving, another is picked and the outputs stay where they were (an offset,
// map.frame_offset). When a solve adopts a map without one of them, another is picked and the
// outputs move with it: nothing ties the replaced map's frame to the new one.
#pragma once

#include <cstdint>
#include <optional>
#include <utility>
#include <vector>

#include "cdro/engine/alignment.hpp"
#include "cdro/engine/map_state.hpp"
#include "cdro/engine/params.hpp"

namespace cdro::engine {

class OutputFrame {
public:
    explicit OutputFrame(const FrameParams &named) : named_(named) {}

    // Before the first range (throws std::logic_error after).
    void setFixed(NodeId id, const Vector2 &position_m);
    // At the first placement: the fixed nodes take their coordinates (two or more), or the single
    // one is remembered for the output shift.
    void apply(MapState &map);
    bool applied() const { return applied_; }
    uint32_t fixedFrameNodes() const { return fixed_frame_nodes_; }
    const std::vector<std::pair<NodeId, Vector2>> &fixedPositions() const { return fixed_; }
    // Engine frame -> output frame.
    RigidTransform transform(const MapState &map) const;
    // The single fixed node, if there is exactly one.
    const std::optional<std::pair<NodeId, Vector2>> &singleFixed() const { return single_; }
    // A node never to be one of the frame triangle's (Engine::excludeFromFrame).
    void exclude(NodeId id);
    bool excluded(NodeId id) const;
    // Per node of the map: may it be one of the frame triangle's (not excluded, and with
    // `anchors_only` placed and still).
    std::vector<bool> eligible(const MapState &map, bool anchors_only) const;
    // The frame triangle is all placed and still, or picked again among the placed, still nodes:
    // after a node of it started moving, the outputs kept where they were (map.frame_offset takes
    // the difference); after one was unplaced, in the new triangle's frame (no offset).
    void ensureFrameNodes(MapState &map, const PlacementParams &placement) const;
    // Whether the frame triangle needs picking again (a node of it unplaced, moving or settling).
    bool frameNodesLost(const MapState &map) const;
    // After a restore: the state as it was.
    void restored(const MapState &map);

private:
    FrameParams named_;
    std::vector<std::pair<NodeId, Vector2>> fixed_;
    std::optional<std::pair<NodeId, Vector2>> single_;
    std::vector<NodeId> excluded_; // sorted
    uint32_t fixed_frame_nodes_ = 0;
    bool applied_ = false;
};

} // namespace cdro::engine
