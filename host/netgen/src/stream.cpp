#include "cdro/netgen/stream.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace cdro::netgen {

const char *streamOrderName(StreamOrder order)
{
    switch (order) {
    case StreamOrder::Sweeps: return "sweeps";
    case StreamOrder::Staggered: return "staggered";
    case StreamOrder::Late: return "late";
    }
    return "unknown";
}

std::optional<StreamOrder> parseStreamOrder(const std::string &name)
{
    for (StreamOrder order : {StreamOrder::Sweeps, StreamOrder::Staggered, StreamOrder::Late}) {
        if (name == streamOrderName(order)) {
            return order;
        }
    }
    return std::nullopt;
}

GeneratedStream generateStream(const World &world, const StreamOptions &options)
{
    GeneratedStream stream;
    Random random(mixSeed(options.seed ^ 0x73747265616DULL)); // "stream"
    std::vector<double> power_on_s(world.nodes.size(), 0.0);
    const double dt_s = 1.0 / std::max(options.range_rate_hz, 1e-6);
    if (options.order == StreamOrder::Staggered) {
        for (size_t i = 0; i < power_on_s.size(); ++i) {
            power_on_s[i] = random.uniform(0.0, options.stagger_s);
        }
    }
    uint32_t late = std::numeric_limits<uint32_t>::max();
    if (options.order == StreamOrder::Late && !world.nodes.empty()) {
        late = static_cast<uint32_t>(random.below(world.nodes.size()));
        stream.late_node = world.nodes[late].id;
        power_on_s[late] = std::numeric_limits<double>::infinity(); // set when its turn comes
    }
    std::vector<size_t> order(world.links.size());
    for (size_t i = 0; i < order.size(); ++i) {
        order[i] = i;
    }
    double t_s = 0.0;
    uint32_t full_sweeps = 0;
    const uint32_t wanted = options.sweeps + (late != std::numeric_limits<uint32_t>::max() ? options.late_sweeps : 0U);
    while (full_sweeps < wanted) {
        if (late != std::numeric_limits<uint32_t>::max() && full_sweeps == options.sweeps) {
            power_on_s[late] = t_s;
        }
        random.shuffle(order);
        bool all_on = true;
        size_t ranged = 0;
        for (size_t k : order) {
            const WorldLink &link = world.links[k];
            if (power_on_s[link.a] > t_s || power_on_s[link.b] > t_s) {
                all_on = false;
                continue;
            }
            const bool flip = random.chance(0.5);
            GeneratedRange range;
            range.from = world.nodes[flip ? link.b : link.a].id;
            range.to = world.nodes[flip ? link.a : link.b].id;
            range.range_m = world.measureM(link, random);
            range.t_s = t_s;
            stream.ranges.push_back(range);
            t_s += dt_s;
            ++ranged;
        }
        if (ranged == 0) {
            // Nothing on yet: on to the next node switched on.
            double next = std::numeric_limits<double>::infinity();
            for (double on : power_on_s) {
                if (on > t_s) {
                    next = std::min(next, on);
                }
            }
            t_s = std::isfinite(next) ? next : t_s + dt_s;
            continue;
        }
        // A sweep counts once every node is on (the late node: before its turn, without it).
        const bool late_pending = late != std::numeric_limits<uint32_t>::max() && full_sweeps < options.sweeps;
        if (all_on || late_pending) {
            ++full_sweeps;
        }
    }
    return stream;
}

std::vector<GeneratedRange> shuffledStream(const std::vector<GeneratedRange> &ranges, uint64_t seed)
{
    std::vector<GeneratedRange> out = ranges;
    Random random(mixSeed(seed ^ 0x73687566666CULL)); // "shuffl"
    random.shuffle(out);
    const double dt_s =
        out.size() > 1 ? (ranges.back().t_s - ranges.front().t_s) / static_cast<double>(out.size() - 1) : 0.0;
    for (size_t i = 0; i < out.size(); ++i) {
        out[i].t_s = static_cast<double>(i) * dt_s;
    }
    return out;
}

} // namespace cdro::netgen
