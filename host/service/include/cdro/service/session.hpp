// session.hpp: the conversation with the device (docs/protocol.md, "Conversation" and
// "Device behaviour"), as a state machine driven by frames and by time read from a Clock.
//
//   disconnected --link up--> await HELLO --HELLO ok--> configuring --START acked--> running
//        ^                      |  no HELLO: HELLO_REQUEST every hello_timeout_s;   |
//        |                      |  after hello_retries of them: ask for a reopen    |
//        +------link down-------+<------ reset / command or keepalive failure ------+
//   any state --HELLO or frames of another protocol build--> incompatible (HELLO_REQUEST after
//   hello_timeout_s, doubling up to serial.reconnect_max_s, until a compatible HELLO)
//
// A HELLO configures the device only while awaiting one (or while incompatible): a device
// reset reaches the session first as onDeviceReset, which starts the wait; any other HELLO is
// the late answer to an earlier HELLO_REQUEST and changes nothing.
//
// Configuring sends SET_NODES (if nodes.ids is set), SET_SCHEDULE and START, each awaiting its
// ACK (matched by type and sequence) for command_timeout_s, resent up to command_retries times;
// then the handshake starts over. A NACK is logged with its reason and counted; a NACKed
// SET_NODES or SET_SCHEDULE leaves the device's setting as it was and configuration goes on, a
// NACKed START is retried like a timeout. While running, a PING every keepalive_period_s must be
// answered (ACK echoing the nonce); keepalive_misses in a row start the handshake over.
//
// Threading: loop thread only. Time: clock.monotonicUs() for every timeout; the owner calls
// onTick() at nextDeadlineUs() (or later).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "cdro/frames.h"
#include "cdro/service/clock.hpp"
#include "cdro/service/config.hpp"
#include "cdro/service/counters.hpp"
#include "cdro/service/intake.hpp"
#include "cdro/service/map_state.hpp"

namespace cdro::service {

// Where the session's frames go: the owner assigns the host sequence number, encodes, writes
// to the link and to the capture. Returns false if the frame could not be sent.
class CommandSink {
public:
    virtual ~CommandSink() = default;
    virtual bool sendCommand(cdro_frame_t &frame) = 0; // sets frame.sequence
};

class SessionListener {
public:
    virtual ~SessionListener() = default;
    virtual void onSessionState(LinkState state, const std::string &detail) = 0;
    // The device does not answer at all: close and reopen the port (with backoff).
    virtual void onReopenRequested(const std::string &reason) = 0;
};

class DeviceSession final : public IntakeObserver {
public:
    enum class Phase { Disconnected, AwaitHello, Configuring, Running, Incompatible };

    DeviceSession(const ServiceConfig &config, const Clock &clock, CommandSink &sink, SessionListener &listener,
                  ServiceCounters &counters);

    void onLinkUp();
    void onLinkDown();
    void onTick();
    int64_t nextDeadlineUs() const { return deadline_us_; } // monotonic; INT64_MAX = none

    // IntakeObserver
    void onDeviceFrame(const cdro_frame_t &frame, int64_t host_unix_us) override;
    void onDeviceReset(DeviceResetReason reason, int64_t host_unix_us) override;
    void onIncompatible(const std::string &message) override;

    Phase phase() const { return phase_; }
    LinkState linkState() const;
    const std::string &detail() const { return detail_; }
    static const char *phaseName(Phase phase);

private:
    void setPhase(Phase phase, const std::string &detail);
    void startAwaitHello(bool request_now);
    void sendHelloRequest();
    void startConfiguring();
    void sendCurrentStep();
    void stepDone();
    void commandFailed(const std::string &why);
    void sendPing();

    ServiceConfig config_;
    const Clock &clock_;
    CommandSink &sink_;
    SessionListener &listener_;
    ServiceCounters &counters_;

    Phase phase_ = Phase::Disconnected;
    std::string detail_;
    int64_t deadline_us_ = INT64_MAX;
    uint32_t hello_requests_ = 0;         // in this wait for HELLO
    int64_t incompatible_backoff_us_ = 0; // us until the next HELLO_REQUEST while incompatible

    std::vector<cdro_frame_t> steps_; // the configuration commands, in order
    size_t step_ = 0;
    uint32_t step_attempts_ = 0;
    uint16_t step_sequence_ = 0; // sequence of the command awaiting its answer

    bool ping_outstanding_ = false;
    uint32_t ping_nonce_ = 0;
    uint32_t ping_misses_ = 0;
};

} // namespace cdro::service
