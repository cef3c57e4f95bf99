#include "cdro/service/odometry_intake.hpp"

#include <cmath>
#include <cstdio>

#include <nlohmann/json.hpp>

#include "cdro/capture.h"
#include "cdro/service/capture.hpp"

namespace cdro::service {

namespace {

// What the log shows of a dropped message: enough to recognise it, never a flood.
constexpr size_t kLogSnippetBytes = 120;

std::string snippet(std::string_view text)
{
    std::string out;
    for (const char c : text.substr(0, kLogSnippetBytes)) {
        out += (c >= 0x20 && c < 0x7F) ? c : '?';
    }
    if (text.size() > kLogSnippetBytes) {
        out += "...";
    }
    return out;
}

std::string number(double value)
{
    char text[40];
    std::snprintf(text, sizeof text, "%.9g", value);
    return text;
}

const char *jsonTypeName(const nlohmann::json &j)
{
    return j.type_name(); // "array", "string", "number", "boolean", "null"
}

// Reads key as a finite number if it is there; false (with *why) if it is there but unusable.
bool readNumber(const nlohmann::json &object, const char *key, bool *present, double *value, std::string *why)
{
    const auto it = object.find(key);
    *present = it != object.end();
    if (!*present) {
        return true;
    }
    if (!it->is_number()) {
        *why = std::string("'") + key + "' is " + (it->is_null() ? "null" : std::string("a ") + jsonTypeName(*it)) +
               ", not a number";
        return false;
    }
    *value = it->get<double>();
    if (!std::isfinite(*value)) {
        *why = std::string("'") + key + "' is not a finite number";
        return false;
    }
    return true;
}

bool fail(OdometryReject r, std::string text, OdometryReject *reason, std::string *why)
{
    *reason = r;
    *why = std::move(text);
    return false;
}

} // namespace

const char *odometryRejectName(OdometryReject reason)
{
    switch (reason) {
    case OdometryReject::NotJson: return "not_json";
    case OdometryReject::NotObject: return "not_object";
    case OdometryReject::Field: return "field";
    case OdometryReject::BothForms: return "both_forms";
    case OdometryReject::Absurd: return "absurd";
    case OdometryReject::OutOfOrder: return "out_of_order";
    case OdometryReject::TooLong: return "too_long";
    }
    return "rejected";
}

bool parseOdometry(std::string_view text, ParsedOdometry *out, OdometryReject *reason, std::string *why)
{
    if (text.size() > kOdometryMaxMessageBytes) {
        return fail(OdometryReject::TooLong,
                    std::to_string(text.size()) + " bytes, longer than " + std::to_string(kOdometryMaxMessageBytes),
                    reason, why);
    }
    const nlohmann::json j = nlohmann::json::parse(text.begin(), text.end(), nullptr, false);
    if (j.is_discarded()) {
        return fail(OdometryReject::NotJson, "not JSON", reason, why);
    }
    if (!j.is_object()) {
        return fail(OdometryReject::NotObject, std::string("a JSON ") + jsonTypeName(j) + ", not an object", reason,
                    why);
    }
    ParsedOdometry p;
    bool has_distance = false, has_dheading = false, has_v = false, has_omega = false;
    std::string problem;
    if (!readNumber(j, "t", &p.has_t, &p.t_s, &problem) ||
        !readNumber(j, "distance_m", &has_distance, &p.distance_m, &problem) ||
        !readNumber(j, "dheading_rad", &has_dheading, &p.dheading_rad, &problem) ||
        !readNumber(j, "v_mps", &has_v, &p.v_mps, &problem) ||
        !readNumber(j, "omega_radps", &has_omega, &p.omega_radps, &problem)) {
        return fail(OdometryReject::Field, problem, reason, why);
    }
    const bool step = has_distance || has_dheading;
    const bool velocity = has_v || has_omega;
    if (step && velocity) {
        return fail(OdometryReject::BothForms,
                    "a step (distance_m, dheading_rad) and velocities (v_mps, omega_radps) in one message", reason,
                    why);
    }
    if (!step && !velocity) {
        return fail(OdometryReject::Field,
                    "neither a step (distance_m, dheading_rad) nor velocities (v_mps, omega_radps)", reason, why);
    }
    if (step && !(has_distance && has_dheading)) {
        return fail(OdometryReject::Field, has_distance ? "'dheading_rad' is missing" : "'distance_m' is missing",
                    reason, why);
    }
    if (velocity && !(has_v && has_omega)) {
        return fail(OdometryReject::Field, has_v ? "'omega_radps' is missing" : "'v_mps' is missing", reason, why);
    }
    p.form = step ? ParsedOdometry::Form::Step : ParsedOdometry::Form::Velocity;
    if (p.has_t && (p.t_s < kOdometryMinT || p.t_s > kOdometryMaxT)) {
        return fail(OdometryReject::Absurd,
                    "t " + number(p.t_s) +
                        " s is not Unix time between 2000 and 2100 (a sender that does not know the time omits t)",
                    reason, why);
    }
    if (step && std::fabs(p.distance_m) > kOdometryMaxStepM) {
        return fail(OdometryReject::Absurd, "distance_m " + number(p.distance_m) + " is beyond +-10 m per message",
                    reason, why);
    }
    if (step && std::fabs(p.dheading_rad) > kOdometryMaxStepRad) {
        return fail(OdometryReject::Absurd, "dheading_rad " + number(p.dheading_rad) + " is beyond +-pi per message",
                    reason, why);
    }
    if (velocity && std::fabs(p.v_mps) > kOdometryMaxSpeedMps) {
        return fail(OdometryReject::Absurd, "v_mps " + number(p.v_mps) + " is beyond +-20 m/s", reason, why);
    }
    if (velocity && std::fabs(p.omega_radps) > kOdometryMaxTurnRadps) {
        return fail(OdometryReject::Absurd, "omega_radps " + number(p.omega_radps) + " is beyond +-10 rad/s", reason,
                    why);
    }
    *out = p;
    return true;
}

std::string normaliseOdometry(const OdometryMessage &message, const std::string &source)
{
    nlohmann::ordered_json j = nlohmann::ordered_json::object();
    j["t"] = message.t_s;
    j["distance_m"] = message.distance_m;
    j["dheading_rad"] = message.dheading_rad;
    j["source"] = source;
    // (nlohmann writes doubles in their shortest round-trip form, and replaces invalid UTF-8
    // in the source rather than throwing.)
    return j.dump(-1, ' ', false, nlohmann::ordered_json::error_handler_t::replace);
}

OdometryIntake::OdometryIntake(const OdometryConfig &config, double drop_log_per_s, ServiceCounters &counters,
                               const Clock &clock)
    : config_(config), counters_(counters), clock_(clock), log_limit_(drop_log_per_s)
{
}

void OdometryIntake::push(const std::string &source, const char *data, size_t len, int64_t receive_unix_us)
{
    const std::string_view all(data, len);
    bool any = false;
    size_t begin = 0;
    while (begin <= all.size()) {
        size_t end = all.find('\n', begin);
        if (end == std::string_view::npos) {
            end = all.size();
        }
        std::string_view line = all.substr(begin, end - begin);
        while (!line.empty() && (line.back() == '\r' || line.back() == ' ' || line.back() == '\t')) {
            line.remove_suffix(1);
        }
        while (!line.empty() && (line.front() == ' ' || line.front() == '\t')) {
            line.remove_prefix(1);
        }
        if (!line.empty()) {
            any = true;
            ++counters_.odometry_received;
            takeLive(line, source, receive_unix_us);
        }
        begin = end + 1;
    }
    if (!any) {
        ++counters_.odometry_received;
        reject(OdometryReject::NotJson, source, all, "an empty message");
    }
}

void OdometryIntake::takeLive(std::string_view text, const std::string &source, int64_t receive_unix_us)
{
    ParsedOdometry p;
    OdometryReject reason = OdometryReject::NotJson;
    std::string why;
    if (!parseOdometry(text, &p, &reason, &why)) {
        reject(reason, source, text, why);
        return;
    }
    // Without t, the receive time stands in (and is what the capture records).
    const double t_s = p.has_t ? p.t_s : static_cast<double>(receive_unix_us) / 1e6;
    bool clock_step = false;
    if (have_last_ && t_s < last_t_s_) {
        if (last_t_s_ - t_s <= kOdometryBackstepS) {
            reject(OdometryReject::OutOfOrder, source, text,
                   "t " + number(t_s) + " is " + number(last_t_s_ - t_s) + " s before the last message taken (" +
                       number(last_t_s_) + ")");
            return;
        }
        // The sender's clock stepped back (set by hand or by NTP, or a restart with another
        // clock). Dropping everything until it caught up could lose the odometry for hours;
        // taking it, and measuring from it, loses nothing.
        clock_step = true;
        ++counters_.odometry_clock_steps;
        clocks_.clear();
        uint64_t suppressed = 0;
        if (log_limit_.allow("odometry_clock_step", clock_.monotonicUs(), &suppressed)) {
            log()->warn("odometry: the clock of {} stepped back by {} s (t {} after {}); taken, velocity clocks "
                        "restarted; check the robot's time",
                        source, number(last_t_s_ - t_s), number(t_s), number(last_t_s_));
        }
    }
    OdometryMessage message{t_s, 0.0, 0.0};
    if (p.form == ParsedOdometry::Form::Step) {
        // A step covers the time up to its t: a velocity interval must not count it again.
        const auto it = clocks_.find(source);
        if (it != clocks_.end()) {
            it->second.running = false;
        }
        message.distance_m = p.distance_m;
        message.dheading_rad = p.dheading_rad;
    } else {
        if (clocks_.size() >= kMaxSources && clocks_.count(source) == 0) {
            clocks_.clear(); // senders that come and go (new UDP ports); the cost is one restart each
        }
        VelocityClock &clock = clocks_[source];
        const double gap_s = t_s - clock.t_s; // >= 0: clocks hold taken times, and t_s is not before them
        const VelocityClock previous = clock;
        clock = {true, t_s, p.v_mps, p.omega_radps};
        have_last_ = true;
        last_t_s_ = t_s;
        if (!previous.running || clock_step || gap_s > config_.max_velocity_gap_s) {
            ++counters_.odometry_clock_starts;
            log()->debug("odometry: {}: velocity clock {} at t {}", source,
                         previous.running ? "restarted after " + number(gap_s) + " s" : std::string("started"),
                         number(t_s));
            return;
        }
        // Trapezoid: the mean of the velocities at both ends of the interval (exact for
        // velocities that change linearly between messages).
        message.distance_m = 0.5 * (previous.v_mps + p.v_mps) * gap_s;
        message.dheading_rad = 0.5 * (previous.omega_radps + p.omega_radps) * gap_s;
        if (std::fabs(message.distance_m) > kOdometryMaxStepM ||
            std::fabs(message.dheading_rad) > kOdometryMaxStepRad) {
            reject(OdometryReject::Absurd, source, text,
                   "the velocities over " + number(gap_s) + " s make a step of " + number(message.distance_m) + " m, " +
                       number(message.dheading_rad) + " rad (beyond +-10 m, +-pi)");
            return;
        }
    }
    deliver(message, source, receive_unix_us, true);
}

void OdometryIntake::pushRecorded(const uint8_t *data, size_t len, int64_t record_unix_us)
{
    ++counters_.odometry_received;
    const std::string_view text(reinterpret_cast<const char *>(data), len);
    ParsedOdometry p;
    OdometryReject reason = OdometryReject::NotJson;
    std::string why;
    if (!parseOdometry(text, &p, &reason, &why)) {
        reject(reason, "the capture", text, why);
        return;
    }
    if (p.form != ParsedOdometry::Form::Step || !p.has_t) {
        reject(OdometryReject::Field, "the capture", text, "a recorded odometry message must be a step with t");
        return;
    }
    deliver({p.t_s, p.distance_m, p.dheading_rad}, "replay", record_unix_us, false);
}

void OdometryIntake::deliver(const OdometryMessage &message, const std::string &source, int64_t event_unix_us,
                             bool live)
{
    have_last_ = true;
    last_t_s_ = message.t_s;
    last_event_unix_us_ = event_unix_us;
    ++counters_.odometry_accepted;
    if (live && capture_ != nullptr) {
        const std::string record = normaliseOdometry(message, source);
        capture_->append(CDRO_CAPTURE_FLAG_ODOMETRY, event_unix_us, reinterpret_cast<const uint8_t *>(record.data()),
                         record.size());
    }
    if (consumer_ != nullptr) {
        consumer_->onOdometry(message);
    }
    if (after_delivery_) {
        after_delivery_(event_unix_us);
    }
}

void OdometryIntake::reject(OdometryReject reason, const std::string &source, std::string_view text,
                            const std::string &why)
{
    switch (reason) {
    case OdometryReject::NotJson: ++counters_.odometry_rejected_not_json; break;
    case OdometryReject::NotObject: ++counters_.odometry_rejected_not_object; break;
    case OdometryReject::Field: ++counters_.odometry_rejected_field; break;
    case OdometryReject::BothForms: ++counters_.odometry_rejected_both_forms; break;
    case OdometryReject::Absurd: ++counters_.odometry_rejected_absurd; break;
    case OdometryReject::OutOfOrder: ++counters_.odometry_rejected_out_of_order; break;
    case OdometryReject::TooLong: ++counters_.odometry_rejected_too_long; break;
    }
    uint64_t suppressed = 0;
    const std::string key = std::string("odometry_") + odometryRejectName(reason);
    if (!log_limit_.allow(key, clock_.monotonicUs(), &suppressed)) {
        return;
    }
    if (suppressed > 0) {
        log()->warn("odometry: dropped a message from {}: {}: '{}' ({} more like it not logged)", source, why,
                    snippet(text), suppressed);
    } else {
        log()->warn("odometry: dropped a message from {}: {}: '{}'", source, why, snippet(text));
    }
}

} // namespace cdro::service
