#include "cdro/engine/output_frame.hpp"

#include <algorithm>
#include <stdexcept>

#include "cdro/engine/placement.hpp"
#include "cdro/engine/range_model.hpp"

namespace cdro::engine {

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

void OutputFrame::ensureFrameNodes(MapState &map, const PlacementParams &placement) const
{
    // The output frame needs three placed nodes that ranged to each other (a map adopted from
    // the global solve may have placed a triangle of its own): pick them as the first is picked.
    if (fixed_frame_nodes_ >= 2) {
        return;
    }
    if (map.frame_nodes && std::all_of(map.frame_nodes->begin(), map.frame_nodes->end(),
                                       [&](uint32_t n) { return map.nodes[n].placed(); })) {
        return;
    }
    const std::optional<FrameTriangle> triangle =
        chooseFrameTriangle(map, placement, eligible(map, true), std::nullopt);
    if (triangle) {
        map.frame_nodes = std::array<uint32_t, 3>{triangle->origin, triangle->x_axis, triangle->positive_y};
    }
}

RigidTransform OutputFrame::transform(const MapState &map) const
{
    RigidTransform transform;
    if (fixed_frame_nodes_ >= 2) {
        return transform;
    }
    std::optional<std::array<uint32_t, 3>> frame;
    if (named_.origin != 0 && named_.x_axis != 0 && named_.positive_y != 0) {
        const std::array<uint32_t, 3> ids{map.findNode(named_.origin), map.findNode(named_.x_axis),
                                          map.findNode(named_.positive_y)};
        if (std::all_of(ids.begin(), ids.end(), [&](uint32_t n) { return n != kNoIndex && map.nodes[n].placed(); })) {
            frame = ids;
        }
    } else if (map.frame_nodes && std::all_of(map.frame_nodes->begin(), map.frame_nodes->end(),
                                              [&](uint32_t n) { return map.nodes[n].placed(); })) {
        frame = map.frame_nodes;
    }
    if (frame) {
        const Vector2 origin = map.nodes[(*frame)[0]].position_m;
        const Vector2 axis = map.nodes[(*frame)[1]].position_m - origin;
        if (axis.norm() > kSingularDistanceM) {
            const Vector2 unit_x = axis.normalized();
            Matrix2 rotation;
            rotation << unit_x.x(), unit_x.y(), -unit_x.y(), unit_x.x();
            const Vector2 third = rotation * (map.nodes[(*frame)[2]].position_m - origin);
            if (third.y() < 0.0) {
                rotation.row(1) *= -1.0;
                transform.reflected = true;
            }
            transform.rotation = rotation;
            transform.translation_m = -rotation * origin;
        }
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
