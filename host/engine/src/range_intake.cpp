#include "cdro/engine/range_intake.hpp"

#include <cmath>

#include "cdro/engine/range_model.hpp"

namespace cdro::engine {

const char *rangeVerdictName(RangeVerdict verdict)
{
    switch (verdict) {
    case RangeVerdict::Used: return "used";
    case RangeVerdict::Stored: return "stored";
    case RangeVerdict::RejectedSelf: return "rejected: a node ranging itself";
    case RangeVerdict::RejectedValue: return "rejected: not a plausible range";
    }
    return "unknown";
}

uint32_t RangeIntake::node(MapState &map, NodeId id)
{
    const size_t before = map.nodes.size();
    const uint32_t index = map.addNode(id);
    if (map.nodes.size() != before) {
        map.nodes[index].first_range = counters_.taken();
    }
    return index;
}

TakenRange RangeIntake::take(MapState &map, NodeId from, NodeId to, double range_m, double t_s)
{
    TakenRange taken;
    ++counters_.ranges_received;
    if (std::isfinite(t_s)) {
        map.last_time_s = std::max(map.last_time_s, t_s);
    }
    if (from == to) {
        ++counters_.rejected_self;
        taken.verdict = RangeVerdict::RejectedSelf;
        return taken;
    }
    if (!std::isfinite(range_m) || range_m <= 0.0 || range_m > params_.max_range_m) {
        ++counters_.rejected_value;
        taken.verdict = RangeVerdict::RejectedValue;
        return taken;
    }
    taken.a = node(map, from);
    taken.b = node(map, to);
    taken.planar_m = range_m;
    const NodeState &a = map.nodes[taken.a];
    const NodeState &b = map.nodes[taken.b];
    if (a.height_m && b.height_m) {
        bool clamped = false;
        taken.planar_m = projectRange(range_m, *a.height_m - *b.height_m, &clamped);
        counters_.projection_clamped += clamped ? 1U : 0U;
    }
    const size_t links_before = map.links.size();
    taken.link = map.addLink(taken.a, taken.b, params_.window);
    taken.new_link = map.links.size() != links_before;
    LinkState &link = map.links[taken.link];
    // How far this range is from the link's own recent ranges (a static NLOS link reads long
    // but consistently; a node that moves reads differently from before).
    taken.jump_m = link.window.size() > 0 ? taken.planar_m - link.window.median() : 0.0;
    link.window.push(taken.planar_m);
    // The window keeps the ranges as read; what the filter uses is corrected by the ends' offsets.
    taken.planar_m -= a.range_offset_m + b.range_offset_m;
    link.last_range_m = range_m;
    ++link.range_count;
    return taken;
}

void RangeIntake::refreshLinkRange(MapState &map, uint32_t link, bool tracking_motion) const
{
    LinkState &state = map.links[link];
    const bool moving = map.nodes[state.node_a].moving() || map.nodes[state.node_b].moving();
    state.representative_m = (tracking_motion && moving ? state.window.newest() : state.window.median()) -
                             map.nodes[state.node_a].range_offset_m - map.nodes[state.node_b].range_offset_m;
}

} // namespace cdro::engine
