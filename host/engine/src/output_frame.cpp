#include "cdro/engine/output_frame.hpp"

#include <algorithm>
#include <stdexcept>

#include "cdro/engine/placement.hpp"
#include "cdro/engine/range_model.hpp"

namespace cdro::engine {

namespace {

// Origin node at (0, 0), the x-axis node on +x, the third on the +y side.
RigidTransform triangleFrame(const MapState &map, const std::array<uint32_t, 3> &frame)
{
    RigidTransform transform;
    const Vector2 origin = map.nodes[frame[0]].position_m;
    const Vector2 axis = map.nodes[frame[1]].position_m - origin;
    if (axis.norm() > kSingularDistanceM) {
        const Vector2 unit_x = axis.normalized();
        Matrix2 rotation;
        rotation << unit_x.x(), unit_x.y(), -unit_x.y(), unit_x.x();
        const Vector2 third = rotation * (map.nodes[frame[2]].position_m - origin);
        if (third.y() < 0.0) {
            rotation.row(1) *= -1.0;
            transform.reflected = true;
        }
        transform.rotation = rotation;
        transform.translation_m = -rotation * origin;
    }
    return transform;
}

// outer after inner.
RigidTransform compose(const RigidTransform &outer, const RigidTransform &inner)
{
    RigidTransform out;
    out.rotation = outer.rotation * inner.rotation;
    out.translation_m = outer.rotation * inner.translation_m + outer.translation_m;
    out.reflected = outer.reflected != inner.reflected;
    return out;
}

RigidTransform inverse(const RigidTransform &transform)
{
    RigidTransform out;
    out.rotation = transform.rotation.transpose();
    out.translation_m = -(out.rotation * transform.translation_m);
    out.reflected = transform.reflected;
    return out;
}

} // namespace

void OutputFrame::setFixed(NodeId id, const Vector2 &position_m)
{
    if (applied_) {
        throw std::logic_error("fixed nodes must be given before the first range");
    }
    for (auto &entry : fixed_) {
        if (entry.first == id) {
            entry.second = position_m;
            return;
        }
    }
    fixed_.emplace_back(id, position_m);
}

void OutputFrame::exclude(NodeId id)
{
    const auto at = std::lower_bound(excluded_.begin(), excluded_.end(), id);
    if (at == excluded_.end() || *at != id) {
        excluded_.insert(at, id);
    }
}

bool OutputFrame::excluded(NodeId id) const { return std::binary_search(excluded_.begin(), excluded_.end(), id); }

std::vector<bool> OutputFrame::eligible(const MapState &map, bool anchors_only) const
{
    std::vector<bool> out(map.nodes.size(), false);
    for (uint32_t node = 0; node < map.nodes.size(); ++node) {
        out[node] = (!anchors_only || map.nodes[node].anchor()) && !excluded(map.nodes[node].id);
    }
    return out;
}

void OutputFrame::apply(MapState &map)
{
    applied_ = true;
    if (fixed_.size() == 1) {
        // One known node fixes only where the map sits: it is estimated like any other and the
        // output is shifted onto its coordinates.
        single_ = fixed_.front();
        return;
    }
    for (const auto &[id, position_m] : fixed_) {
        const uint32_t index = map.findNode(id);
        if (index == kNoIndex) {
            continue;
        }
        NodeState &state = map.nodes[index];
        state.role = NodeRole::Fixed;
        state.lifecycle = NodeLifecycle::Converged;
        state.doubt = NodeDoubt::None;
        state.position_m = position_m;
        state.average_m = position_m;
        state.covariance_m2.setZero();
        ++fixed_frame_nodes_;
    }
}

void OutputFrame::restored(const MapState &map)
{
    applied_ = true;
    fixed_frame_nodes_ = 0;
    for (const NodeState &node : map.nodes) {
        fixed_frame_nodes_ += node.fixed() ? 1U : 0U;
    }
    if (fixed_.size() == 1) {
        single_ = fixed_.front();
    }
}

bool OutputFrame::frameNodesLost(const MapState &map) const
{
    return fixed_frame_nodes_ < 2 && map.frame_nodes &&
           !std::all_of(map.frame_nodes->begin(), map.frame_nodes->end(),
                        [&](uint32_t n) { return map.nodes[n].anchor(); });
}

void OutputFrame::ensureFrameNodes(MapState &map, const PlacementParams &placement) const
{
    // The output frame needs three placed, still nodes that ranged to each other (a map adopted
    // from the global solve may have placed a triangle of its own; a node of it may start moving):
    // pick them as the first is picked.
    if (fixed_frame_nodes_ >= 2) {
        return;
    }
    if (map.frame_nodes && !frameNodesLost(map)) {
        return;
    }
    const std::optional<FrameTriangle> triangle =
        chooseFrameTriangle(map, placement, eligible(map, true), std::nullopt);
    if (!triangle) {
        return;
    }
    const std::array<uint32_t, 3> picked{triangle->origin, triangle->x_axis, triangle->positive_y};
    if (map.frame_nodes && std::all_of(map.frame_nodes->begin(), map.frame_nodes->end(),
                                       [&](uint32_t n) { return map.nodes[n].placed(); })) {
        // A node of the triangle started moving: the outputs stay where they were, the old
        // triangle's frame (where its nodes are now) composed with the offset so far, seen from
        // the new triangle's.
        const RigidTransform before = compose(map.frame_offset, triangleFrame(map, *map.frame_nodes));
        map.frame_offset = compose(before, inverse(triangleFrame(map, picked)));
    } else {
        // A node of it unplaced by a solve: its last position is in the frame of the map the
        // solve replaced, so nothing ties the two frames together; the new triangle's frame.
        map.frame_offset = RigidTransform{};
    }
    map.frame_nodes = picked;
}

RigidTransform OutputFrame::transform(const MapState &map) const
{
    RigidTransform transform;
    if (fixed_frame_nodes_ >= 2) {
        return transform;
    }
    if (named_.origin != 0 && named_.x_axis != 0 && named_.positive_y != 0) {
        const std::array<uint32_t, 3> ids{map.findNode(named_.origin), map.findNode(named_.x_axis),
                                          map.findNode(named_.positive_y)};
        if (std::all_of(ids.begin(), ids.end(), [&](uint32_t n) { return n != kNoIndex && map.nodes[n].placed(); })) {
            transform = triangleFrame(map, ids);
        }
    } else if (map.frame_nodes && std::all_of(map.frame_nodes->begin(), map.frame_nodes->end(),
                                              [&](uint32_t n) { return map.nodes[n].placed(); })) {
        transform = compose(map.frame_offset, triangleFrame(map, *map.frame_nodes));
    }
    if (single_) {
        const uint32_t node = map.findNode(single_->first);
        if (node != kNoIndex && map.nodes[node].placed()) {
            // The fixed node's output is its known coordinates.
            transform.translation_m += single_->second - transform.apply(map.nodes[node].position_m);
        }
    }
    return transform;
}

} // namespace cdro::engine
