#include "cdro/service/service.hpp"

#include <algorithm>
#include <csignal>

#include <nlohmann/json.hpp>

#include "cdro/service/log.hpp"
#include "cdro/service/output_file.hpp"

namespace cdro::service {

namespace {

// us: how soon, live, work the consumer finished between frames is taken in (a global solve's
// map after the last frame of a burst); well under a frame's period at the firmware's ~14 frames/s.
constexpr int64_t kHostEventPollUs = 20'000;

} // namespace

// Forwards every frame to the engine, then lets the service publish what changed, so that the
// outputs follow the frames one by one (and a replay reproduces them exactly).
class Service::ConsumerTap final : public FrameConsumer {
public:
    ConsumerTap(Service &service, FrameConsumer &inner) : service_(service), inner_(inner) {}
    void onRange(const cdro_range_t &range, const FrameContext &context) override
    {
        inner_.onRange(range, context);
        service_.afterFrame(context.host_unix_us);
    }
    void onMotion(const cdro_motion_t &motion, const FrameContext &context) override
    {
        inner_.onMotion(motion, context);
        service_.afterFrame(context.host_unix_us);
    }
    void onHello(const cdro_hello_t &hello, const FrameContext &context) override
    {
        inner_.onHello(hello, context);
        service_.afterFrame(context.host_unix_us);
    }
    void onStatus(const cdro_status_t &status, const FrameContext &context) override
    {
        inner_.onStatus(status, context);
        service_.afterFrame(context.host_unix_us);
    }
    void onNodeList(const cdro_node_list_t &list, const FrameContext &context) override
    {
        inner_.onNodeList(list, context);
        service_.afterFrame(context.host_unix_us);
    }
    void onDeviceError(const cdro_error_t &error, const FrameContext &context) override
    {
        inner_.onDeviceError(error, context);
        service_.afterFrame(context.host_unix_us);
    }
    void onDeviceReset(DeviceResetReason reason, const FrameContext &context) override
    {
        inner_.onDeviceReset(reason, context);
        service_.afterFrame(context.host_unix_us);
    }
    void onHostEvent(const uint8_t *data, size_t len, const FrameContext &context) override
    {
        inner_.onHostEvent(data, len, context);
        service_.afterFrame(context.host_unix_us);
    }

private:
    Service &service_;
    FrameConsumer &inner_;
};

Service::Service(const ServiceConfig &config, const RunOptions &run, ServiceHooks hooks, const Clock &clock)
    : config_(config), run_(run), hooks_(hooks), clock_(clock), loop_(clock),
      intake_(config.nodes, config.logging.drop_log_per_s, counters_, clock),
      odometry_(config.odometry, config.logging.drop_log_per_s, counters_, clock), jsonl_(config.output, counters_),
      mqtt_(loop_, config.mqtt, counters_)
{
    if (hooks_.consumer == nullptr) {
        throw ConfigError("service: a FrameConsumer is required");
    }
    tap_ = std::make_unique<ConsumerTap>(*this, *hooks_.consumer);
    intake_.setConsumer(tap_.get());
    odometry_.setConsumer(hooks_.odometry);
    // Odometry moves the robot's estimate: the outputs follow it message by message, as they
    // follow the frames.
    odometry_.setAfterDelivery([this](int64_t event_unix_us) { afterFrame(event_unix_us); });
}

Service::~Service() { shutdown("service destroyed"); }

void Service::start()
{
    // --resume first: a bad checkpoint must stop the start before anything is opened.
    if (!run_.resume_path.empty()) {
        if (hooks_.checkpoint == nullptr) {
            throw ConfigError("--resume: this build has no checkpoint provider");
        }
        const SogSnapshot snapshot = loadCheckpointFile(run_.resume_path);
        hooks_.checkpoint->restore(snapshot);
        std::vector<uint16_t> mapped;
        for (const cdro_sog_node_t &node : snapshot.nodes) {
            mapped.push_back(node.id);
        }
        for (const uint16_t id : hooks_.checkpoint->restoredNodes()) {
            mapped.push_back(id);
        }
        intake_.addKnownNodes(mapped);
        ServiceCheckpointInfo info;
        const SogSnapshot::Extension *own = snapshot.findExtension(kServiceExtensionTag);
        if (own != nullptr && decodeServiceInfo(own->bytes, &info)) {
            resumed_run_start_unix_us_ = info.run_start_unix_us; // t_s goes on from the run resumed
            log()->info("resume: {} ({} nodes, {} pairs; the run had delivered {} frames)", run_.resume_path,
                        snapshot.nodes.size(), snapshot.pairs.size(), info.frames_delivered);
        } else {
            log()->info("resume: {} ({} nodes, {} pairs)", run_.resume_path, snapshot.nodes.size(),
                        snapshot.pairs.size());
        }
    }

    // Output paths are checked before anything is opened, so that a link or a world-writable
    // directory stops the start with its reason (docs/service.md, "Security model").
    if (hooks_.checkpoint != nullptr && !config_.checkpoint.path.empty()) {
        checkOutputPath(config_.checkpoint.path, "checkpoint.path");
    }
    if (!config_.output.jsonl.empty() && config_.output.jsonl != "-") {
        checkOutputPath(config_.output.jsonl, "output.jsonl");
    }

    std::string source;
    if (!run_.replay_path.empty()) {
        replay_ = std::make_unique<ReplaySource>(loop_, std::vector<std::string>{run_.replay_path}, run_.replay_speed,
                                                 intake_, counters_);
        replay_->setOdometryIntake(&odometry_);
        replay_->open();
        run_start_unix_us_ = resumed_run_start_unix_us_ != 0 ? resumed_run_start_unix_us_ : replay_->runStartUnixUs();
        source = replay_->source();
        log()->info("replay: writes JSON Lines to {}, {}, {}, {} (each only when its option is given)",
                    config_.output.jsonl.empty()  ? "nowhere"
                    : config_.output.jsonl == "-" ? "stdout"
                                                  : config_.output.jsonl,
                    config_.checkpoint.path.empty() ? "no checkpoint (--checkpoint FILE)"
                                                    : "a checkpoint to " + config_.checkpoint.path,
                    config_.http.port == 0 ? "no live map (--http-port N)"
                                           : "a live map on port " + std::to_string(config_.http.port),
                    config_.mqtt.url.empty() ? "no MQTT (--mqtt URL)" : "MQTT to " + config_.mqtt.url);
    } else {
        run_start_unix_us_ = resumed_run_start_unix_us_ != 0 ? resumed_run_start_unix_us_ : clock_.unixUs();
        SerialLink::Listener &link_listener = *this;
        link_ = std::make_unique<SerialLink>(loop_, config_.serial, link_listener, counters_);
        source = link_->description();
        CommandSink &sink = *this;
        SessionListener &session_listener = *this;
        session_ = std::make_unique<DeviceSession>(config_, clock_, sink, session_listener, counters_);
        intake_.setObserver(session_.get());
        if (!config_.capture.path.empty()) {
            capture_ = std::make_unique<CaptureWriter>(config_.capture, source, counters_, capture_context_);
            capture_->open(run_start_unix_us_);
            intake_.setCapture(capture_.get());
            odometry_.setCapture(capture_.get());
            log()->info("capture: {} (rotated at {} MiB, {} kept)", config_.capture.path, config_.capture.rotate_mib,
                        config_.capture.keep);
        }
        // Live odometry only: on --replay it comes from the capture, and a live sender mixed in
        // would make the replay differ from the run it replays.
        if (config_.odometry.udp_port != 0) {
            odometry_udp_ = std::make_unique<OdometryUdpSource>(loop_, config_.odometry.udp_bind,
                                                                config_.odometry.udp_port, odometry_);
            odometry_udp_->setAfterBurst([this] { afterBatch(); });
            odometry_udp_->start();
        }
        const std::string topic = odometryMqttTopic(config_);
        if (!topic.empty()) {
            mqtt_.subscribe(topic, [this](const std::string &name, const char *payload, size_t len) {
                if (shut_down_) {
                    return;
                }
                odometry_.push("mqtt:" + name, payload, len, clock_.unixUs());
                afterBatch();
            });
        }
    }

    jsonl_.open();
    mqtt_.start();
    if (config_.http.port != 0) {
        http_ = std::make_unique<HttpServer>(loop_, config_.http, store_,
                                             [this](uint16_t id) -> std::optional<std::string> {
                                                 if (hooks_.map == nullptr) {
                                                     return std::nullopt;
                                                 }
                                                 const std::optional<NodeComponents> components =
                                                     hooks_.map->components(id);
                                                 if (!components) {
                                                     return std::nullopt;
                                                 }
                                                 return componentsJson(*components).dump();
                                             });
        http_->setFloorPlan(config_.web.floor_plan);
        http_->start();
    }

    loop_.handleSignals({SIGTERM, SIGINT}, [this](int signo) {
        shutdown(signo == SIGTERM ? "SIGTERM" : signo == SIGINT ? "SIGINT" : "signal");
    });

    if (config_.output.health_period_s > 0.0) {
        loop_.addTimerAfter(secondsToUs(config_.output.health_period_s), [this] { healthTick(); });
    }
    if (http_) {
        loop_.addTimerAfter(0, [this] { httpTick(); });
    }
    if (hooks_.checkpoint != nullptr && !config_.checkpoint.path.empty() && config_.checkpoint.period_s > 0.0) {
        loop_.addTimerAfter(secondsToUs(config_.checkpoint.period_s), [this] { checkpointTick(); });
    }

    if (systemd_.watchdogPeriodUs() > 0) {
        loop_.addTimerAfter(systemd_.watchdogPeriodUs(), [this] { watchdogTick(); });
    }
    if (!replay_) {
        loop_.addTimerAfter(kHostEventPollUs, [this] { hostEventTick(); });
    }

    started_ = true;
    systemd_.ready(statusLine());
    if (replay_) {
        if (!config_.mqtt.url.empty()) {
            replay_->setGate([this] { return replayMayGoOn(); });
        }
        replay_->start([this] { afterBatch(); }, [this] { shutdown("the replay is complete"); });
    } else {
        link_->start();
        rearmSession();
    }
}

int Service::run()
{
    if (!started_) {
        start();
    }
    loop_.run();
    return 0;
}

void Service::requestStop()
{
    loop_.post([this] { shutdown("stop requested"); });
}

LinkState Service::linkState() const
{
    if (replay_) {
        return LinkState::Replay;
    }
    return session_ ? session_->linkState() : LinkState::Disconnected;
}

std::string Service::liveMapUrl() const { return http_ ? http_->url() : std::string(); }
int Service::httpPort() const { return http_ ? http_->port() : 0; }

int64_t Service::nowEventUnixUs() const
{
    // Live: the wall clock (frames are stamped with it too). Replay: the last record's time.
    if (replay_) {
        const int64_t last_us = std::max(intake_.lastEventUnixUs(), odometry_.lastEventUnixUs());
        return last_us != 0 ? last_us : run_start_unix_us_;
    }
    return clock_.unixUs();
}

double Service::tSeconds(int64_t event_unix_us) const
{
    return static_cast<double>(event_unix_us - run_start_unix_us_) * 1e-6;
}

OutputTime Service::outputTime(int64_t event_unix_us) const
{
    // Divided rather than multiplied by 1e-6: the correctly rounded quotient prints as the
    // microseconds it came from.
    return {tSeconds(event_unix_us), static_cast<double>(event_unix_us) / 1e6};
}

Health Service::health(int64_t now_event_unix_us) const
{
    Health h;
    h.link = linkState();
    h.device = replay_ ? replay_->source() : (link_ ? link_->description() : std::string());
    if (intake_.incompatible()) {
        h.detail = intake_.incompatibleMessage();
    } else if (session_) {
        h.detail = session_->detail();
    } else if (replay_) {
        h.detail = replay_->finished() ? "replay complete" : "replaying";
    }
    h.device_node_id = intake_.deviceNodeId();
    h.device_firmware = intake_.deviceFirmware();
    h.counters = counters_;
    if (http_) {
        const HttpStats http = http_->stats();
        h.counters.http_requests = http.requests;
        h.counters.http_refused = http.refused;
    }
    h.rates = intake_.rates(now_event_unix_us);
    return h;
}

MapState Service::currentMap() const
{
    MapState map;
    const int64_t now_us = nowEventUnixUs();
    if (hooks_.map != nullptr) {
        hooks_.map->fill(map);
    }
    map.t_s = tSeconds(now_us);
    map.t_unix_s = outputTime(now_us).t_unix_s;
    map.health = health(now_us);
    stampUpdates(map);
    return map;
}

void Service::noteUpdates(const MapState &map, const std::vector<size_t> &changed, int64_t event_unix_us)
{
    for (const size_t position : changed) {
        const NodeEstimate &node = map.nodes[position];
        const auto it = node_updates_.find(node.id);
        if (it == node_updates_.end() || !sameEstimate(it->second.first, node)) {
            node_updates_[node.id] = {node, event_unix_us};
        }
    }
}

void Service::stampUpdates(MapState &map) const
{
    for (const NodeEstimate &node : map.nodes) {
        const auto it = node_updates_.find(node.id);
        if (it != node_updates_.end()) {
            map.updated_unix_s[node.id] = outputTime(it->second.second).t_unix_s;
        }
    }
}

void Service::afterFrame(int64_t event_unix_us)
{
    if (shut_down_) {
        return;
    }
    if (!replaying()) {
        // Live: the estimator's own-timed work, recorded right after the frame it followed.
        const std::vector<uint8_t> event = hooks_.consumer->hostEventAfterFrame(FrameContext{event_unix_us, 0});
        if (!event.empty()) {
            ++counters_.host_events;
            if (capture_ != nullptr) {
                capture_->append(CDRO_CAPTURE_FLAG_HOST_EVENT, event_unix_us, event.data(), event.size());
            }
        }
    }
    if (hooks_.map == nullptr) {
        return;
    }
    const uint64_t revision = hooks_.map->revision();
    if (revision == last_map_revision_) {
        return;
    }
    last_map_revision_ = revision;
    map_dirty_ = true;
    hooks_.map->updateEstimates(updated_map_, changed_nodes_);
    updated_map_.t_s = tSeconds(event_unix_us);
    updated_map_.t_unix_s = outputTime(event_unix_us).t_unix_s;
    noteUpdates(updated_map_, changed_nodes_, event_unix_us);
    jsonl_.onUpdate(updated_map_, changed_nodes_, event_unix_us);
    mqtt_.onUpdate(updated_map_, changed_nodes_, event_unix_us);
}

void Service::afterBatch()
{
    jsonl_.flush();
    rearmSession();
}

// ---- link, session, commands -------------------------------------------------------------------

void Service::onLinkUp()
{
    session_->onLinkUp();
    rearmSession();
}

void Service::onLinkBytes(const uint8_t *bytes, size_t len, int64_t received_unix_us)
{
    intake_.push(bytes, len, received_unix_us);
    afterBatch();
}

void Service::onLinkDown(const std::string &)
{
    intake_.endOfStream(clock_.unixUs());
    session_->onLinkDown();
    afterBatch();
}

bool Service::sendCommand(cdro_frame_t &frame)
{
    frame.sequence = host_sequence_++;
    uint8_t bytes[CDRO_MAX_ENCODED_FRAME];
    const size_t size = cdro_frame_encode(&frame, bytes, sizeof bytes);
    if (size == 0 || link_ == nullptr || !link_->send(bytes, size)) {
        return false;
    }
    ++counters_.commands_sent;
    if (capture_) {
        capture_->append(CDRO_CAPTURE_FLAG_TO_DEVICE, clock_.unixUs(), bytes, size - 1); // without the 0x00
    }
    intake_.noteSentFrame(frame.type);
    return true;
}

void Service::onSessionState(LinkState state, const std::string &detail)
{
    log()->info("link: {} ({})", linkStateName(state), detail);
    systemd_.status(statusLine());
    if (state == LinkState::Connected && link_) {
        link_->resetBackoff();
    }
}

void Service::onReopenRequested(const std::string &reason)
{
    if (link_) {
        link_->reopen(reason);
    }
}

void Service::rearmSession()
{
    if (!session_ || shut_down_) {
        return;
    }
    const int64_t deadline_us = session_->nextDeadlineUs();
    if (deadline_us == session_timer_deadline_us_) {
        return;
    }
    if (session_timer_ != 0) {
        loop_.cancelTimer(session_timer_);
        session_timer_ = 0;
    }
    session_timer_deadline_us_ = deadline_us;
    if (deadline_us == INT64_MAX) {
        return;
    }
    session_timer_ = loop_.addTimerAt(deadline_us, [this] {
        session_timer_ = 0;
        session_timer_deadline_us_ = INT64_MAX;
        session_->onTick();
        afterBatch();
    });
}

// ---- timers ------------------------------------------------------------------------------------

void Service::healthTick()
{
    if (shut_down_) {
        return;
    }
    const int64_t now_us = nowEventUnixUs();
    const Health h = health(now_us);
    jsonl_.writeHealth(h, outputTime(now_us));
    jsonl_.flush();
    mqtt_.publishHealth(h, outputTime(now_us));
    systemd_.status(statusLine());
    loop_.addTimerAfter(secondsToUs(config_.output.health_period_s), [this] { healthTick(); });
}

void Service::hostEventTick()
{
    if (shut_down_) {
        return;
    }
    afterFrame(nowEventUnixUs()); // records a host event if the consumer has one; then the outputs
    jsonl_.flush();
    loop_.addTimerAfter(kHostEventPollUs, [this] { hostEventTick(); });
}

void Service::watchdogTick()
{
    if (shut_down_) {
        return;
    }
    // From the loop itself: if the loop hangs, the pings stop and systemd restarts the service.
    systemd_.watchdog();
    loop_.addTimerAfter(systemd_.watchdogPeriodUs(), [this] { watchdogTick(); });
}

std::string Service::statusLine() const
{
    std::string line = std::string(linkStateName(linkState()));
    if (replay_) {
        line += " " + replay_->source();
    } else if (link_) {
        line += " " + link_->description();
    }
    line += ", " + std::to_string(counters_.frames_delivered) + " frames";
    if (counters_.chunks_rejected > 0) {
        line += ", " + std::to_string(counters_.chunks_rejected) + " rejected";
    }
    if (http_) {
        line += "; live map " + http_->url();
    }
    return line;
}

void Service::httpTick()
{
    if (shut_down_ || !http_) {
        return;
    }
    const MapState map = currentMap();
    nlohmann::ordered_json comparable = mapJson(map);
    std::string map_json = comparable.dump();
    // Rates and wall time move on their own; publish when the picture (less t_s) changed.
    comparable.erase("t_s");
    comparable.erase("t_unix_s");
    comparable["health"].erase("t_s");
    comparable["health"].erase("t_unix_s");
    std::string key = comparable.dump();
    if (key != last_published_map_) {
        last_published_map_ = std::move(key);
        store_.publish(std::move(map_json), healthJson(map.health, outputTimeOf(map)).dump());
    }
    map_dirty_ = false;
    loop_.addTimerAfter(std::max<int64_t>(secondsToUs(config_.http.update_period_s), 10'000), [this] { httpTick(); });
}

bool Service::replayMayGoOn()
{
    // A replay runs as fast as its outputs take it: MQTT must be connected and keeping up. A
    // broker that is not there is given kBrokerAttempts connection attempts (the first one and
    // the retries of mqtt.reconnect_min_s, doubling); one that is connected but stops taking
    // messages, kStallUs. Then the replay goes on without it, and what cannot be published is
    // dropped, counted and summed up at the end.
    constexpr uint64_t kBrokerAttempts = 4;
    constexpr int64_t kStallUs = 10'000'000;
    if (mqtt_.readyForMore()) {
        broker_wait_since_us_ = 0;
        return true;
    }
    const int64_t now_us = clock_.monotonicUs();
    if (broker_wait_since_us_ == 0) {
        broker_wait_since_us_ = now_us;
        broker_wait_attempts_ = mqtt_.connectAttempts();
    }
    const bool gave_up = mqtt_.connected() ? now_us - broker_wait_since_us_ >= kStallUs
                                           : mqtt_.connectAttempts() >= broker_wait_attempts_ + kBrokerAttempts;
    if (!gave_up) {
        return false;
    }
    if (!broker_gave_up_logged_) {
        broker_gave_up_logged_ = true;
        log()->warn("mqtt: the broker {} is {}; the replay goes on without it (what cannot be published is counted "
                    "in mqtt_dropped)",
                    config_.mqtt.url, mqtt_.connected() ? "not taking messages" : "not reachable");
    }
    return true;
}

bool Service::writeCheckpointNow()
{
    if (hooks_.checkpoint == nullptr || config_.checkpoint.path.empty()) {
        if (!checkpoint_warned_) {
            checkpoint_warned_ = true;
            log()->info("checkpoint: none written ({})",
                        hooks_.checkpoint == nullptr ? "no provider" : "checkpoint.path is empty");
        }
        return false;
    }
    try {
        SogSnapshot snapshot = hooks_.checkpoint->snapshot();
        snapshot.header.created_unix_us = nowEventUnixUs();
        ServiceCheckpointInfo info;
        info.run_start_unix_us = run_start_unix_us_;
        info.last_event_unix_us = intake_.lastEventUnixUs();
        info.frames_delivered = counters_.frames_delivered;
        snapshot.extensions.push_back({kServiceExtensionTag, encodeServiceInfo(info)});
        writeCheckpointFile(config_.checkpoint.path, snapshot);
        ++counters_.checkpoints_written;
        log()->debug("checkpoint: wrote {} ({} nodes)", config_.checkpoint.path, snapshot.nodes.size());
        return true;
    } catch (const std::exception &error) {
        ++counters_.checkpoint_errors;
        log()->error("{} (the previous checkpoint is intact)", error.what());
        return false;
    }
}

void Service::checkpointTick()
{
    if (shut_down_) {
        return;
    }
    writeCheckpointNow();
    loop_.addTimerAfter(secondsToUs(config_.checkpoint.period_s), [this] { checkpointTick(); });
}

void Service::shutdown(const std::string &why)
{
    if (shut_down_) {
        return;
    }
    if (started_) {
        log()->info("stopping ({}): final checkpoint, flushing outputs, closing the capture", why);
        systemd_.stopping("stopping (" + why + ")");
    }
    // 1. No more input.
    if (link_) {
        link_->shutdown();
    }
    if (replay_) {
        replay_->stop();
    }
    if (odometry_udp_) {
        odometry_udp_->stop();
    }
    if (session_timer_ != 0) {
        loop_.cancelTimer(session_timer_);
        session_timer_ = 0;
    }
    if (started_) {
        // 2. The last estimates and health, then the checkpoint.
        const MapState map = currentMap();
        jsonl_.finish(map);
        if (config_.output.health_period_s > 0.0) {
            jsonl_.writeHealth(map.health, outputTimeOf(map));
        }
        writeCheckpointNow();
        if (http_) {
            store_.publish(mapJson(map).dump(), healthJson(map.health, outputTimeOf(map)).dump());
        }
        mqtt_.onUpdate(map, nowEventUnixUs());
        mqtt_.publishHealth(map.health, outputTimeOf(map));
    }
    shut_down_ = true;
    // 3. Outputs flushed and closed.
    jsonl_.close();
    if (capture_) {
        capture_->close();
    }
    mqtt_.shutdown();
    if (http_) {
        http_->stop();
    }
    loop_.stop();
    if (started_) {
        log()->info("stopped: {} frames delivered, {} chunks rejected, {} device resets", counters_.frames_delivered,
                    counters_.chunks_rejected, counters_.device_resets);
    }
}

} // namespace cdro::service
