#include "cdro/service/session.hpp"

#include <algorithm>
#include <climits>

#include "cdro/service/log.hpp"

namespace cdro::service {

namespace {
const char *nackReasonName(uint8_t reason)
{
    switch (reason) {
    case CDRO_NACK_MALFORMED: return "MALFORMED";
    case CDRO_NACK_BAD_VALUE: return "BAD_VALUE";
    case CDRO_NACK_TOO_MANY_NODES: return "TOO_MANY_NODES";
    case CDRO_NACK_UNKNOWN_TYPE: return "UNKNOWN_TYPE";
    case CDRO_NACK_WRONG_STATE: return "WRONG_STATE";
    default: return "unknown reason";
    }
}

const char *typeName(uint8_t type)
{
    const char *name = cdro_frame_type_name(type);
    return name != nullptr ? name : "?";
}
} // namespace

DeviceSession::DeviceSession(const ServiceConfig &config, const Clock &clock, CommandSink &sink,
                             SessionListener &listener, ServiceCounters &counters)
    : config_(config), clock_(clock), sink_(sink), listener_(listener), counters_(counters)
{
}

const char *DeviceSession::phaseName(Phase phase)
{
    switch (phase) {
    case Phase::Disconnected: return "disconnected";
    case Phase::AwaitHello: return "awaiting HELLO";
    case Phase::Configuring: return "configuring";
    case Phase::Running: return "running";
    case Phase::Incompatible: return "incompatible";
    }
    return "?";
}

LinkState DeviceSession::linkState() const
{
    switch (phase_) {
    case Phase::Disconnected: return LinkState::Disconnected;
    case Phase::AwaitHello:
    case Phase::Configuring: return LinkState::Handshaking;
    case Phase::Running: return LinkState::Connected;
    case Phase::Incompatible: return LinkState::Incompatible;
    }
    return LinkState::Disconnected;
}

void DeviceSession::setPhase(Phase phase, const std::string &detail)
{
    const bool changed = phase != phase_ || detail != detail_;
    phase_ = phase;
    detail_ = detail;
    if (changed) {
        listener_.onSessionState(linkState(), detail_);
    }
}

void DeviceSession::onLinkUp()
{
    ping_outstanding_ = false;
    ping_misses_ = 0;
    startAwaitHello(false); // the device may be booting and about to say HELLO by itself
}

void DeviceSession::onLinkDown()
{
    deadline_us_ = INT64_MAX;
    steps_.clear();
    setPhase(Phase::Disconnected, "device link lost");
}

void DeviceSession::startAwaitHello(bool request_now)
{
    hello_requests_ = 0;
    steps_.clear();
    ping_outstanding_ = false;
    setPhase(Phase::AwaitHello, "waiting for HELLO");
    if (request_now) {
        sendHelloRequest();
    } else {
        deadline_us_ = clock_.monotonicUs() + secondsToUs(config_.serial.hello_timeout_s);
    }
}

void DeviceSession::sendHelloRequest()
{
    ++hello_requests_;
    ++counters_.hello_requests;
    cdro_frame_t frame{};
    frame.type = CDRO_FRAME_HELLO_REQUEST;
    sink_.sendCommand(frame);
    deadline_us_ = clock_.monotonicUs() + secondsToUs(config_.serial.hello_timeout_s);
}

void DeviceSession::startConfiguring()
{
    steps_.clear();
    if (!config_.nodes.ids.empty()) {
        cdro_frame_t set_nodes{};
        set_nodes.type = CDRO_FRAME_SET_NODES;
        set_nodes.as.set_nodes.node_ids_count = static_cast<uint8_t>(config_.nodes.ids.size());
        for (size_t i = 0; i < config_.nodes.ids.size(); ++i) {
            set_nodes.as.set_nodes.node_ids[i] = config_.nodes.ids[i];
        }
        steps_.push_back(set_nodes);
    }
    cdro_frame_t schedule{};
    schedule.type = CDRO_FRAME_SET_SCHEDULE;
    const ScheduleConfig &s = config_.schedule;
    schedule.as.set_schedule = {s.slot_period_ms,   s.mode,       s.motion_poll_ms, s.moving_boost,
                                s.status_period_ms, s.max_retries};
    steps_.push_back(schedule);
    cdro_frame_t start{};
    start.type = CDRO_FRAME_START;
    steps_.push_back(start);
    step_ = 0;
    step_attempts_ = 0;
    setPhase(Phase::Configuring, "configuring the device");
    sendCurrentStep();
}

void DeviceSession::sendCurrentStep()
{
    cdro_frame_t frame = steps_[step_];
    ++step_attempts_;
    if (!sink_.sendCommand(frame)) {
        log()->warn("session: could not send {}", typeName(frame.type));
    }
    step_sequence_ = frame.sequence;
    deadline_us_ = clock_.monotonicUs() + secondsToUs(config_.serial.command_timeout_s);
}

void DeviceSession::stepDone()
{
    ++step_;
    step_attempts_ = 0;
    if (step_ < steps_.size()) {
        sendCurrentStep();
        return;
    }
    steps_.clear();
    ++counters_.handshakes;
    ping_outstanding_ = false;
    ping_misses_ = 0;
    log()->info("session: device configured and ranging (handshake {})", counters_.handshakes);
    setPhase(Phase::Running, "running");
    deadline_us_ = config_.serial.keepalive_period_s > 0.0
                       ? clock_.monotonicUs() + secondsToUs(config_.serial.keepalive_period_s)
                       : INT64_MAX;
}

void DeviceSession::commandFailed(const std::string &why)
{
    const uint8_t type = steps_[step_].type;
    if (step_attempts_ <= config_.serial.command_retries) {
        log()->warn("session: {} {}; resending ({} of {} retries)", typeName(type), why, step_attempts_,
                    config_.serial.command_retries);
        sendCurrentStep();
        return;
    }
    log()->error("session: {} {} after {} retries; starting the handshake over", typeName(type), why,
                 config_.serial.command_retries);
    startAwaitHello(true);
}

void DeviceSession::sendPing()
{
    cdro_frame_t frame{};
    frame.type = CDRO_FRAME_PING;
    frame.as.ping.nonce = ++ping_nonce_;
    sink_.sendCommand(frame);
    ping_outstanding_ = true;
    deadline_us_ = clock_.monotonicUs() + secondsToUs(config_.serial.command_timeout_s);
}

void DeviceSession::onTick()
{
    if (clock_.monotonicUs() < deadline_us_) {
        return;
    }
    switch (phase_) {
    case Phase::Disconnected: deadline_us_ = INT64_MAX; return;
    case Phase::Incompatible: {
        // Ask again, ever less often: the HELLO may have been a corruption, or the device
        // reflashed; a device that really speaks another version costs one frame per period.
        ++counters_.hello_requests;
        cdro_frame_t frame{};
        frame.type = CDRO_FRAME_HELLO_REQUEST;
        sink_.sendCommand(frame);
        deadline_us_ = clock_.monotonicUs() + incompatible_backoff_us_;
        incompatible_backoff_us_ = std::min(incompatible_backoff_us_ * 2, secondsToUs(config_.serial.reconnect_max_s));
        return;
    }
    case Phase::AwaitHello:
        if (hello_requests_ >= config_.serial.hello_retries) {
            deadline_us_ = INT64_MAX;
            const std::string reason = "no HELLO after " + std::to_string(hello_requests_) + " HELLO_REQUESTs";
            log()->warn("session: {}; reopening the port", reason);
            listener_.onReopenRequested(reason);
            return;
        }
        if (hello_requests_ == 0) {
            log()->info("session: no HELLO yet; sending HELLO_REQUEST");
        }
        sendHelloRequest();
        return;
    case Phase::Configuring:
        ++counters_.command_timeouts;
        commandFailed("got no ACK within " + std::to_string(config_.serial.command_timeout_s) + " s");
        return;
    case Phase::Running:
        if (ping_outstanding_) {
            ++counters_.pings_missed;
            ++ping_misses_;
            ping_outstanding_ = false;
            if (ping_misses_ >= config_.serial.keepalive_misses) {
                log()->warn("session: {} keepalive PINGs unanswered; starting the handshake over", ping_misses_);
                startAwaitHello(true);
                return;
            }
        }
        sendPing();
        return;
    }
}

void DeviceSession::onDeviceFrame(const cdro_frame_t &f, int64_t /*host_unix_us*/)
{
    if (phase_ == Phase::Disconnected) {
        return; // bytes from a replay, or after the link went down
    }
    switch (f.type) {
    case CDRO_FRAME_HELLO: {
        const cdro_hello_t &h = f.as.hello;
        if (h.protocol_version != CDRO_PROTOCOL_VERSION || h.layout_hash != CDRO_LAYOUT_HASH) {
            return; // onIncompatible has been called
        }
        if (phase_ == Phase::Configuring || phase_ == Phase::Running) {
            // The answer to an earlier HELLO_REQUEST that a slow link delivered late: the
            // device did not reset (the intake would have said so first, and the phase would
            // be awaiting HELLO), so the configuration in place or under way stands.
            log()->debug("session: HELLO while {} (a late answer); nothing to do", phaseName(phase_));
            return;
        }
        log()->info("session: HELLO from node 0x{:04X}, firmware {}.{}, protocol {}, layout 0x{:04X}, "
                    "max_nodes {}, reset_cause 0x{:02X}",
                    h.node_id, h.firmware_version >> 8, h.firmware_version & 0xFF, h.protocol_version, h.layout_hash,
                    h.max_nodes, h.reset_cause);
        startConfiguring();
        return;
    }
    case CDRO_FRAME_ACK: {
        const cdro_ack_t &a = f.as.ack;
        if (phase_ == Phase::Configuring && a.acked_type == steps_[step_].type && a.acked_sequence == step_sequence_) {
            stepDone();
        } else if (phase_ == Phase::Running && ping_outstanding_ && a.acked_type == CDRO_FRAME_PING &&
                   a.value == ping_nonce_) {
            ping_outstanding_ = false;
            ping_misses_ = 0;
            deadline_us_ = clock_.monotonicUs() + secondsToUs(config_.serial.keepalive_period_s);
        }
        return;
    }
    case CDRO_FRAME_NACK: {
        const cdro_nack_t &n = f.as.nack;
        ++counters_.nacks;
        log()->error("session: the device NACKed {} seq {}: {}", typeName(n.nacked_type), n.nacked_sequence,
                     nackReasonName(n.reason));
        if (phase_ != Phase::Configuring || n.nacked_type != steps_[step_].type ||
            n.nacked_sequence != step_sequence_) {
            return;
        }
        if (n.nacked_type == CDRO_FRAME_START) {
            commandFailed(std::string("was NACKed (") + nackReasonName(n.reason) + ")");
        } else {
            log()->error("session: the device keeps its previous {} setting; check the configuration",
                         typeName(n.nacked_type));
            stepDone();
        }
        return;
    }
    case CDRO_FRAME_STATUS:
        if (phase_ == Phase::Running && f.as.status.running == 0) {
            log()->warn("session: the device reports it stopped ranging; configuring it again");
            startConfiguring();
        }
        return;
    default: return;
    }
}

void DeviceSession::onDeviceReset(DeviceResetReason reason, int64_t /*host_unix_us*/)
{
    if (phase_ == Phase::Disconnected || phase_ == Phase::Incompatible) {
        return;
    }
    // The device is stopped after a reset; its boot HELLO usually follows at once and starts
    // the configuration. If that HELLO was lost, HELLO_REQUEST goes out after the timeout.
    log()->warn("session: device reset ({}); re-handshaking", deviceResetReasonName(reason));
    startAwaitHello(false);
}

void DeviceSession::onIncompatible(const std::string &message)
{
    if (phase_ == Phase::Disconnected) {
        return;
    }
    steps_.clear();
    incompatible_backoff_us_ = secondsToUs(config_.serial.hello_timeout_s);
    deadline_us_ = clock_.monotonicUs() + incompatible_backoff_us_;
    incompatible_backoff_us_ = std::min(incompatible_backoff_us_ * 2, secondsToUs(config_.serial.reconnect_max_s));
    setPhase(Phase::Incompatible, message);
}

} // namespace cdro::service
