#include "cdro/netgen/track.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

namespace cdro::netgen {

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kOneGMg = 1000.0; // mg
// s: stretches meet when one starts where the previous ends; the end is a sum of leg times, so
// it may come out a rounding error later than the start written for the next.
constexpr double kMeetToleranceS = 1e-9;

// Component by component, so that a length is the same to the bit wherever it is computed.
double distanceM(const Vector3 &a, const Vector3 &b)
{
    const double dx = a.x() - b.x();
    const double dy = a.y() - b.y();
    const double dz = a.z() - b.z();
    return std::sqrt(dx * dx + dy * dy + dz * dz);
}

std::string stretchName(const Stretch &stretch)
{
    return "track: the stretch at " + std::to_string(stretch.start_s) + " s";
}

std::vector<Vector3> points(const Vector3 &start_m, const Stretch &stretch)
{
    if (stretch.waypoints.empty()) {
        throw std::invalid_argument(stretchName(stretch) + " has no waypoints");
    }
    std::vector<Vector3> out;
    for (const Waypoint &w : stretch.waypoints) {
        const Vector3 p(w.x_m, w.y_m, w.z_m.value_or(start_m.z()));
        if (!p.allFinite()) {
            throw std::invalid_argument(stretchName(stretch) + " has a waypoint that is not finite");
        }
        out.push_back(p);
    }
    return out;
}

} // namespace

Track::Track(const Vector3 &start_m) : start_m_(start_m)
{
    if (!start_m.allFinite()) {
        throw std::invalid_argument("track: the start position is not finite");
    }
}

Track::Track(const Vector3 &start_m, std::vector<Stretch> stretches, const Gait &gait) : Track(start_m)
{
    gait_ = gait;
    std::stable_sort(stretches.begin(), stretches.end(),
                     [](const Stretch &a, const Stretch &b) { return a.start_s < b.start_s; });
    Vector3 at = start_m;
    double free_s = -std::numeric_limits<double>::infinity(); // s: when the previous stretch ends
    for (const Stretch &stretch : stretches) {
        if (!std::isfinite(stretch.start_s)) {
            throw std::invalid_argument("track: a stretch starts at a time that is not finite");
        }
        if (stretch.start_s < free_s - kMeetToleranceS) {
            throw std::invalid_argument(stretchName(stretch) + " starts before the previous one ends at " +
                                        std::to_string(free_s) + " s");
        }
        const std::vector<Vector3> path = points(start_m, stretch);
        double speed_mps = stretch.speed_mps;
        if (speed_mps == 0.0) {
            if (!(stretch.end_s > stretch.start_s)) {
                throw std::invalid_argument(stretchName(stretch) + " has no speed and ends at " +
                                            std::to_string(stretch.end_s) + " s, not after it starts");
            }
            double length_m = 0.0;
            Vector3 from = at;
            for (const Vector3 &p : path) {
                length_m += distanceM(p, from);
                from = p;
            }
            speed_mps = length_m / (stretch.end_s - stretch.start_s);
        }
        if (!(speed_mps > 0.0) || !std::isfinite(speed_mps)) {
            throw std::invalid_argument(stretchName(stretch) + " has the speed " + std::to_string(speed_mps) +
                                        " m/s: it must be positive (a path of length 0 with an end time has none)");
        }
        double t_s = stretch.start_s;
        for (const Vector3 &p : path) {
            const double leg_s = distanceM(at, p) / speed_mps;
            if (leg_s > 0.0) {
                legs_.push_back({t_s, t_s + leg_s, at, p, stretch.start_s});
            }
            t_s += leg_s;
            at = p;
        }
        free_s = t_s;
    }
}

const Track::Leg *Track::legAt(double t_s) const
{
    for (const Leg &leg : legs_) {
        if (t_s >= leg.t0_s && t_s < leg.t1_s) {
            return &leg;
        }
    }
    return nullptr;
}

Vector3 Track::positionM(double t_s) const
{
    Vector3 at = start_m_;
    for (const Leg &leg : legs_) {
        if (t_s < leg.t0_s) {
            break;
        }
        if (t_s >= leg.t1_s) {
            at = leg.to_m;
            continue;
        }
        const double f = (t_s - leg.t0_s) / (leg.t1_s - leg.t0_s);
        const Vector3 &a = leg.from_m;
        const Vector3 &b = leg.to_m;
        return {a.x() + f * (b.x() - a.x()), a.y() + f * (b.y() - a.y()), a.z() + f * (b.z() - a.z())};
    }
    return at;
}

// The firmware's detector (deviation above 80 mg -> moving, below 40 mg for 16 samples -> still)
// is to see the node move exactly while it is carried: at rest the trace is exactly 1 g.
Vector3 Track::accelMg(double t_s) const
{
    const Leg *leg = legAt(t_s);
    if (leg == nullptr) {
        return {0.0, 0.0, kOneGMg};
    }
    const double phase = 2.0 * kPi * gait_.frequency_hz * (t_s - leg->stretch_start_s);
    double dx = leg->to_m.x() - leg->from_m.x();
    double dy = leg->to_m.y() - leg->from_m.y();
    const double horizontal_m = std::sqrt(dx * dx + dy * dy);
    if (horizontal_m > 0.0) {
        dx /= horizontal_m;
        dy /= horizontal_m;
    } else {
        dx = 1.0; // a vertical leg: any horizontal axis will do
        dy = 0.0;
    }
    const double amplitude = gait_.amplitude_mg;
    const double surge = 0.3 * amplitude * std::sin(phase + kPi / 2.0);
    const double sway = 0.2 * amplitude * std::sin(0.5 * phase);
    return {surge * dx - sway * dy, surge * dy + sway * dx, kOneGMg + amplitude * std::sin(phase)};
}

std::vector<Track::Span> Track::spans() const
{
    std::vector<Span> out;
    for (size_t l = 0; l < legs_.size();) {
        size_t last = l;
        while (last + 1 < legs_.size() && legs_[last + 1].t0_s <= legs_[last].t1_s) {
            ++last;
        }
        double length_m = 0.0;
        for (size_t k = l; k <= last; ++k) {
            length_m += distanceM(legs_[k].from_m, legs_[k].to_m);
        }
        out.push_back({legs_[l].t0_s, legs_[last].t1_s, length_m});
        l = last + 1;
    }
    return out;
}

} // namespace cdro::netgen
