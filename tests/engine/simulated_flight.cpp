#include "simulated_flight.hpp"

#include <cmath>

#include "support.hpp"

namespace cdro::enginetest {

const std::array<engine::Vector3, 6> kFlightAnchorPositionsM = {
    engine::Vector3(0.0, 0.0, 1.60), engine::Vector3(4.0, 0.0, 1.90),  engine::Vector3(4.0, 4.0, 1.70),
    engine::Vector3(0.0, 4.0, 1.85), engine::Vector3(2.0, -0.2, 1.75), engine::Vector3(2.0, 4.2, 1.65)};

engine::Vector3 flightTagPositionM(size_t k, double t_s)
{
    const double phase = 2.1 * static_cast<double>(k); // rad
    const double w = 0.45;                             // rad/s
    return {2.0 + 1.4 * std::cos(w * t_s + phase), 2.0 + 1.4 * std::sin(0.8 * w * t_s + 1.3 * phase),
            0.8 + 0.5 * std::sin(0.5 * w * t_s + phase)};
}

std::vector<FlightRange> simulateFlight(uint64_t seed, const std::vector<engine::NodeId> &tags,
                                        const FlightSchedule &schedule)
{
    Random random(seed);
    std::vector<FlightRange> out;
    const size_t tag_count = tags.size();
    size_t anchor_slots = 0;
    size_t pairs = 0;
    for (size_t slot = 0; static_cast<double>(slot) * schedule.slot_s < schedule.duration_s; ++slot) {
        const double t_s = static_cast<double>(slot) * schedule.slot_s;
        const double noise_m = schedule.noise_m * random.normal();
        if (slot % schedule.slots_per_cycle == schedule.slots_per_cycle - 1) {
            if (schedule.tag_to_tag && tag_count >= 2) {
                const size_t ring = tag_count == 2 ? 1 : tag_count; // the distinct pairs (k, k + 1)
                const size_t a = pairs % ring;
                const size_t b = (a + 1) % tag_count;
                ++pairs;
                const double d_m = (flightTagPositionM(a, t_s) - flightTagPositionM(b, t_s)).norm();
                out.push_back({t_s, tags[a], tags[b], d_m + noise_m});
            }
            continue;
        }
        const size_t k = anchor_slots % tag_count;
        const size_t a = (anchor_slots / tag_count) % kFlightAnchors.size();
        ++anchor_slots;
        const double d_m = (flightTagPositionM(k, t_s) - kFlightAnchorPositionsM[a]).norm();
        out.push_back({t_s, tags[k], kFlightAnchors[a], d_m + noise_m});
    }
    return out;
}

void fixFlightAnchors(engine::Engine &engine)
{
    for (size_t a = 0; a < kFlightAnchors.size(); ++a) {
        engine.setFixed(kFlightAnchors[a], kFlightAnchorPositionsM[a].head<2>());
        engine.setHeight(kFlightAnchors[a], kFlightAnchorPositionsM[a].z());
    }
}

} // namespace cdro::enginetest
