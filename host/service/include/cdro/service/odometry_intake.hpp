// odometry_intake.hpp: the robot's odometry messages in, checked steps out (odometry.hpp).
//
// Every message (a UDP datagram or an MQTT payload; several may come in one, one per line)
// is parsed as JSON, checked field by field, converted to a step when it carries velocities,
// checked against the messages before it, and then appended to the capture (flag
// CDRO_CAPTURE_FLAG_ODOMETRY, its normalised JSON, the receive time) and handed to the
// OdometryConsumer. Anything else is counted by reason (odometry_rejected_* in
// ServiceCounters), logged at a limited rate with what was dropped and why, and dropped; the
// service keeps running. The rules are in docs/service.md, "Odometry input".
//
// Replay (pushRecorded) feeds a capture's odometry records: they are the accepted steps
// already, so only the per-message checks run again (a damaged file must not hand the
// consumer absurd values) and the consumer sees the same messages with the same values in
// the same place among the frames; ordering, velocity clocks and the receive-time default do
// not run again, so their state cannot make a replay differ from the live run.
//
// Nothing here reads a clock except the log rate limiter; times come from the caller.
// Threading: loop thread only.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <string>
#include <string_view>

#include "cdro/service/clock.hpp"
#include "cdro/service/config.hpp"
#include "cdro/service/counters.hpp"
#include "cdro/service/log.hpp"
#include "cdro/service/odometry.hpp"

namespace cdro::service {

class CaptureWriter;

// Bounds of a plausible message (documented in docs/service.md); beyond them: rejected, absurd.
constexpr double kOdometryMaxStepM = 10.0;                     // m per message, |distance_m|
constexpr double kOdometryMaxStepRad = 3.14159265358979323846; // rad per message, |dheading_rad|
constexpr double kOdometryMaxSpeedMps = 20.0;                  // m/s, |v_mps|
constexpr double kOdometryMaxTurnRadps = 10.0;                 // rad/s, |omega_radps|
constexpr double kOdometryMinT = 946684800.0;                  // s since the epoch, 2000-01-01T00:00Z
constexpr double kOdometryMaxT = 4102444800.0;                 // s since the epoch, 2100-01-01T00:00Z
constexpr double kOdometryBackstepS = 1.0;                     // s; further back is a clock step
constexpr size_t kOdometryMaxMessageBytes = 1024;              // bytes of one message (one line)

enum class OdometryReject { NotJson, NotObject, Field, BothForms, Absurd, OutOfOrder, TooLong };
const char *odometryRejectName(OdometryReject reason); // "not_json", ... as in the counter names

// One message as sent, after the checks that need nothing but its text.
struct ParsedOdometry {
    enum class Form { Step, Velocity };
    Form form = Form::Step;
    bool has_t = false;
    double t_s = 0.0;          // s since the epoch (when has_t)
    double distance_m = 0.0;   // Step: m
    double dheading_rad = 0.0; // Step: rad
    double v_mps = 0.0;        // Velocity: m/s
    double omega_radps = 0.0;  // Velocity: rad/s
};

// Parses one message. On failure returns false with the reason and a sentence for the log.
bool parseOdometry(std::string_view text, ParsedOdometry *out, OdometryReject *reason, std::string *why);

// The capture record's data for an accepted step: compact JSON, keys t, distance_m,
// dheading_rad, source, numbers in their shortest round-trip form (so the replay reads back
// the same doubles bit for bit).
std::string normaliseOdometry(const OdometryMessage &message, const std::string &source);

class OdometryIntake {
public:
    // clock: only for rate-limiting log lines (never for anything the consumer sees).
    OdometryIntake(const OdometryConfig &config, double drop_log_per_s, ServiceCounters &counters, const Clock &clock);

    void setConsumer(OdometryConsumer *consumer) { consumer_ = consumer; }
    void setCapture(CaptureWriter *capture) { capture_ = capture; }
    // Called after each message handed to the consumer, with its event time (us since the
    // epoch: the receive time live, the record's time on replay).
    void setAfterDelivery(std::function<void(int64_t event_unix_us)> after) { after_delivery_ = std::move(after); }

    // A datagram or payload from source (e.g. "udp:127.0.0.1:40312", "mqtt:cdro/odometry"),
    // received at receive_unix_us. One message, or several separated by newlines.
    void push(const std::string &source, const char *data, size_t len, int64_t receive_unix_us);
    // One odometry record of a capture (replay), with the record's time.
    void pushRecorded(const uint8_t *data, size_t len, int64_t record_unix_us);

    int64_t lastEventUnixUs() const { return last_event_unix_us_; }

    static constexpr size_t kMaxSources = 64; // velocity clocks kept; more sources restart them all

private:
    struct VelocityClock {
        bool running = false;
        double t_s = 0.0;
        double v_mps = 0.0;
        double omega_radps = 0.0;
    };
    void takeLive(std::string_view text, const std::string &source, int64_t receive_unix_us);
    void deliver(const OdometryMessage &message, const std::string &source, int64_t event_unix_us, bool live);
    void reject(OdometryReject reason, const std::string &source, std::string_view text, const std::string &why);

    OdometryConfig config_;
    ServiceCounters &counters_;
    const Clock &clock_;
    RateLimiter log_limit_;
    OdometryConsumer *consumer_ = nullptr;
    CaptureWriter *capture_ = nullptr;
    std::function<void(int64_t)> after_delivery_;

    bool have_last_ = false;
    double last_t_s_ = 0.0;                       // t of the last message taken (delivered or clock start)
    std::map<std::string, VelocityClock> clocks_; // by source
    int64_t last_event_unix_us_ = 0;
};

} // namespace cdro::service
