// service.hpp: cdro_service put together. One object owns the event loop, the serial link (or
// the replay source), the intake, the device session, the capture, the JSON Lines writer, the
// MQTT publisher, the live map and the checkpoints; the estimator plugs in through ServiceHooks.
//
// cdro-hostd's main (host/hostd/src/main.cpp) does, in this order:
//     ServiceConfig config = ...;                      // config.hpp / config_cli.hpp
//     setupLogging(config.logging);
//     EngineAdapter adapter(...);                      // FrameConsumer + MapSource + CheckpointProvider
//                                                      // + OdometryConsumer
//     SystemClock clock;
//     Service service(config, run_options, {&adapter, &adapter, &adapter, &adapter}, clock);
//     service.setCaptureContext(...);                  // what a replay needs (before start())
//     service.start();                                 // throws on a startup problem: exit non-zero
//     std::cerr << "live map: " << service.liveMapUrl() << "\n";
//     return service.run();                            // 0 after SIGTERM/SIGINT or the replay's end
//
// Data flow on the loop thread, per frame: link bytes (or a replay record) -> FrameIntake ->
// capture record -> hooks.consumer (the engine) -> if hooks.map->revision() moved: JSON Lines
// and MQTT get the new estimates (event time decides the rate, so replays write the same
// lines). Per odometry message: a UDP datagram or MQTT payload (or a replayed odometry
// record) -> OdometryIntake -> capture record -> hooks.odometry -> the same outputs. Timers publish health (output.health_period_s), push the live map
// (http.update_period_s) and write checkpoints (checkpoint.period_s).
//
// Under systemd (systemd_notify.hpp): READY=1 at the end of start(), STATUS= every health
// period, WATCHDOG=1 from a loop timer, STOPPING=1 when the shutdown begins.
//
// On SIGTERM/SIGINT (through the self-pipe), the replay's end or requestStop(): the input
// stops, the last estimates and a health line are written, a final checkpoint is written,
// outputs are flushed, the capture is closed (fsync), MQTT says "offline", the HTTP server
// stops, and run() returns 0.
//
// Threading: construct, start() and run() on one thread, which becomes the loop thread; the
// hooks are called only on it. requestStop() is the one call allowed from anywhere.
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "cdro/service/capture.hpp"
#include "cdro/service/checkpoint.hpp"
#include "cdro/service/clock.hpp"
#include "cdro/service/config.hpp"
#include "cdro/service/config_cli.hpp"
#include "cdro/service/consumer.hpp"
#include "cdro/service/event_loop.hpp"
#include "cdro/service/http_server.hpp"
#include "cdro/service/intake.hpp"
#include "cdro/service/json_output.hpp"
#include "cdro/service/map_state.hpp"
#include "cdro/service/mqtt_publisher.hpp"
#include "cdro/service/odometry.hpp"
#include "cdro/service/odometry_intake.hpp"
#include "cdro/service/odometry_udp.hpp"
#include "cdro/service/replay.hpp"
#include "cdro/service/serial_link.hpp"
#include "cdro/service/session.hpp"
#include "cdro/service/systemd_notify.hpp"

namespace cdro::service {

struct ServiceHooks {
    FrameConsumer *consumer = nullptr;        // required: the estimator's input
    MapSource *map = nullptr;                 // optional: without it, outputs carry health only
    CheckpointProvider *checkpoint = nullptr; // optional: without it, no checkpoints, no --resume
    OdometryConsumer *odometry = nullptr;     // optional: the robot's odometry (without it the
                                              // messages are still checked, counted and captured)
};

class Service final : private SerialLink::Listener, private CommandSink, private SessionListener {
public:
    // clock: SystemClock in production; must outlive the service.
    Service(const ServiceConfig &config, const RunOptions &run, ServiceHooks hooks, const Clock &clock);
    ~Service() override;
    Service(const Service &) = delete;
    Service &operator=(const Service &) = delete;

    // Opens everything (capture, outputs, HTTP, MQTT, the port or the replay file, --resume).
    // Throws ConfigError, CaptureError or CheckpointError with a message for the user.
    void start();
    int run(); // until stopped; returns the exit code (0)
    // What a replay of this run's capture needs to reach the same result (cdro-hostd: the map's
    // heights, fixed nodes and settings, as JSON), written into every capture file's header.
    // Call before start().
    void setCaptureContext(std::string context) { capture_context_ = std::move(context); }
    void requestStop(); // thread-safe

    bool replaying() const { return replay_ != nullptr; }
    LinkState linkState() const;
    const ServiceCounters &counters() const { return counters_; }
    std::string liveMapUrl() const; // "" when http.port is 0
    int httpPort() const;
    int64_t runStartUnixUs() const { return run_start_unix_us_; }
    EventLoop &loop() { return loop_; }
    // The UDP port odometry is read from (0 = none), e.g. for a test that let the kernel choose.
    uint16_t odometryUdpPort() const { return odometry_udp_ ? odometry_udp_->port() : 0; }

    // The current map with health (loop thread).
    MapState currentMap() const;
    // Writes a checkpoint now (loop thread); false if there is no provider or it failed.
    bool writeCheckpointNow();

private:
    // SerialLink::Listener
    void onLinkUp() override;
    void onLinkBytes(const uint8_t *bytes, size_t len, int64_t received_unix_us) override;
    void onLinkDown(const std::string &reason) override;
    // CommandSink
    bool sendCommand(cdro_frame_t &frame) override;
    // SessionListener
    void onSessionState(LinkState state, const std::string &detail) override;
    void onReopenRequested(const std::string &reason) override;

    class ConsumerTap;
    void afterFrame(int64_t event_unix_us);
    void noteUpdates(const MapState &map, const std::vector<size_t> &changed, int64_t event_unix_us);
    void stampUpdates(MapState &map) const;
    void afterBatch();
    void rearmSession();
    Health health(int64_t now_event_unix_us) const;
    int64_t nowEventUnixUs() const;
    double tSeconds(int64_t event_unix_us) const;
    OutputTime outputTime(int64_t event_unix_us) const;
    void healthTick();
    void httpTick();
    void checkpointTick();
    void watchdogTick();
    // Live: between frames too (a pause, the last frame), the consumer's own-timed work is
    // taken in within kHostEventPollUs and recorded (consumer.hpp, host events).
    void hostEventTick();
    std::string statusLine() const; // systemd's STATUS=: link, frames, nodes, the live map
    bool replayMayGoOn();
    void shutdown(const std::string &why);

    ServiceConfig config_;
    RunOptions run_;
    ServiceHooks hooks_;
    const Clock &clock_;
    ServiceCounters counters_;
    EventLoop loop_;
    std::unique_ptr<ConsumerTap> tap_;
    FrameIntake intake_;
    OdometryIntake odometry_;
    std::unique_ptr<OdometryUdpSource> odometry_udp_;
    std::unique_ptr<CaptureWriter> capture_;
    std::unique_ptr<SerialLink> link_;
    std::unique_ptr<DeviceSession> session_;
    std::unique_ptr<ReplaySource> replay_;
    JsonLinesWriter jsonl_;
    MqttPublisher mqtt_;
    MapSnapshotStore store_;
    std::unique_ptr<HttpServer> http_;
    SystemdNotifier systemd_;

    std::string capture_context_;
    int64_t run_start_unix_us_ = 0;
    int64_t resumed_run_start_unix_us_ = 0; // the resumed run's start (us), from its checkpoint
    uint16_t host_sequence_ = 0;
    uint64_t last_map_revision_ = 0;
    // The nodes and robot as of the last update, kept up to date by the map source update by
    // update (MapSource::updateEstimates), with the positions the last one changed.
    MapState updated_map_;
    std::vector<size_t> changed_nodes_;
    bool map_dirty_ = false;
    std::string last_published_map_;
    // Per node: the estimate last seen and the event time (us since the epoch) it changed at,
    // for the live map's `t_updated_unix_s`.
    std::map<uint16_t, std::pair<NodeEstimate, int64_t>> node_updates_;
    EventLoop::TimerId session_timer_ = 0;
    int64_t session_timer_deadline_us_ = INT64_MAX;
    bool checkpoint_warned_ = false;
    int64_t broker_wait_since_us_ = 0;  // monotonic us when a replay began to wait for MQTT (0 = not)
    uint64_t broker_wait_attempts_ = 0; // MQTT connection attempts when that wait began
    bool broker_gave_up_logged_ = false;
    bool shut_down_ = false;
    bool started_ = false;
};

} // namespace cdro::service
