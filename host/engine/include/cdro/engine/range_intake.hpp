// range_intake.hpp: step 1 of a range. Refuses what is not a range (counted, never stored),
// projects it to the plane when both heights are known (sqrt(r^2 - dz^2); shorter than |dz|:
// 0, counted), and keeps it in its link's window (the link's range is the window's median; a
// moving end makes old ranges wrong, so there its newest range).
#pragma once

#include <cstdint>

#include "cdro/engine/map_state.hpp"
#include "cdro/engine/params.hpp"

namespace cdro::engine {

enum class RangeVerdict {
    Used,          // both ends placed: the filter took it
    Stored,        // kept on its link; an end is not placed yet
    RejectedSelf,  // a node ranging itself
    RejectedValue, // not finite, not positive, or beyond range.max_range_m
};
const char *rangeVerdictName(RangeVerdict verdict);

struct RangeIntakeCounters {
    uint64_t ranges_received = 0;
    uint64_t rejected_self = 0;
    uint64_t rejected_value = 0;
    uint64_t projection_clamped = 0; // 3D range shorter than the height difference
    // The ranges taken (received, not rejected): what the global solve's schedule counts, so
    // that a rejected range changes nothing at all.
    uint64_t taken() const { return ranges_received - rejected_self - rejected_value; }
};

struct TakenRange {
    RangeVerdict verdict = RangeVerdict::Stored; // RejectedSelf / RejectedValue: nothing else is set
    uint32_t a = kNoIndex;                       // node indices of `from` and `to`
    uint32_t b = kNoIndex;
    uint32_t link = kNoIndex;
    bool new_link = false;
    double planar_m = 0.0; // m, the range in the plane
    double jump_m = 0.0;   // m, how far it is from its link's median before it (0 for a new link)
};

class RangeIntake {
public:
    explicit RangeIntake(const RangeParams &params) : params_(params) {}

    TakenRange take(MapState &map, NodeId from, NodeId to, double range_m, double t_s);
    // The link's range: the median of its window, or its newest range while an end moves.
    void refreshLinkRange(MapState &map, uint32_t link, bool tracking_motion) const;
    // The node's index, adding it (with its first-seen range) when new.
    uint32_t node(MapState &map, NodeId id);

    const RangeIntakeCounters &counters() const { return counters_; }
    void restoreCounters(const RangeIntakeCounters &counters) { counters_ = counters; }

private:
    RangeParams params_;
    RangeIntakeCounters counters_;
};

} // namespace cdro::engine
