#include "cdro/engine/output_changes.hpp"

#include <algorithm>

namespace cdro::engine {

void OutputChangeLog::nodeUpdated(uint32_t node, bool bumped)
{
    bumps_from_updates_ += bumped ? 1U : 0U;
    if (overflowed_) {
        return;
    }
    if (touched_.size() >= kMaxTouched) {
        overflowed_ = true;
        touched_.clear();
        return;
    }
    touched_.push_back(node);
}

void OutputChangeLog::rangeTaken(uint32_t a, uint32_t b)
{
    nodeUpdated(a, true);
    nodeUpdated(b, false);
}

OutputChanges OutputChangeLog::take(const MapState &map, uint64_t revision, const RigidTransform &transform)
{
    OutputChanges out;
    const bool same_nodes = position_of_.size() == map.nodes.size();
    const bool same_frame = transform.rotation == transform_at_take_.rotation &&
                            transform.translation_m == transform_at_take_.translation_m &&
                            transform.reflected == transform_at_take_.reflected;
    out.all =
        !taken_ || overflowed_ || !same_nodes || !same_frame || revision - revision_at_take_ != bumps_from_updates_;
    if (!same_nodes) {
        const std::vector<uint32_t> &by_id = map.nodesById();
        position_of_.assign(map.nodes.size(), 0);
        for (uint32_t position = 0; position < by_id.size(); ++position) {
            position_of_[by_id[position]] = position;
        }
    }
    if (!out.all) {
        out.positions.reserve(touched_.size());
        for (const uint32_t node : touched_) {
            out.positions.push_back(position_of_[node]);
        }
        for (uint32_t node = 0; node < map.nodes.size(); ++node) {
            if (map.nodes[node].moving()) {
                out.positions.push_back(position_of_[node]);
            }
        }
        std::sort(out.positions.begin(), out.positions.end());
        out.positions.erase(std::unique(out.positions.begin(), out.positions.end()), out.positions.end());
    }
    touched_.clear();
    overflowed_ = false;
    bumps_from_updates_ = 0;
    taken_ = true;
    revision_at_take_ = revision;
    transform_at_take_ = transform;
    return out;
}

} // namespace cdro::engine
