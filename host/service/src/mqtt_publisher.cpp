#include "cdro/service/mqtt_publisher.hpp"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <fstream>
#include <mutex>

#include <mosquitto.h>
#include <nlohmann/json.hpp>
#include <poll.h>

#include "cdro/service/json_output.hpp"
#include "cdro/service/log.hpp"

namespace cdro::service {

namespace {
std::once_flag g_mosquitto_init;
constexpr int64_t kMiscPeriodUs = 1'000'000; // libmosquitto wants loop_misc about once a second
constexpr int kFlushPolls = 500;             // 20 ms polls at the stop: what is queued gets 10 s
} // namespace

MqttPublisher::MqttPublisher(EventLoop &loop, const MqttConfig &config, ServiceCounters &counters)
    : loop_(loop), config_(config), counters_(counters), backoff_us_(secondsToUs(config.reconnect_min_s))
{
}

MqttPublisher::~MqttPublisher() { shutdown(); }

void MqttPublisher::start()
{
    if (config_.url.empty()) {
        return;
    }
    const MqttUrl url = parseMqttUrl(config_.url);
    host_ = url.host;
    port_ = url.port;
    std::call_once(g_mosquitto_init, [] { mosquitto_lib_init(); });
    mosq_ = mosquitto_new(config_.client_id.c_str(), true, this);
    if (mosq_ == nullptr) {
        throw ConfigError("mqtt: cannot create a client (client_id '" + config_.client_id + "')");
    }
    configureSecurity(url.tls);
    const std::string will_topic = topic("status");
    mosquitto_will_set(mosq_, will_topic.c_str(), 7, "offline", config_.qos, true);
    mosquitto_connect_callback_set(mosq_, &MqttPublisher::connectCallback);
    mosquitto_disconnect_callback_set(mosq_, &MqttPublisher::disconnectCallback);
    mosquitto_message_callback_set(mosq_, &MqttPublisher::messageCallback);
    mosquitto_subscribe_callback_set(mosq_, &MqttPublisher::subscribeCallback);
    mosquitto_publish_callback_set(mosq_, &MqttPublisher::publishCallback);
    connect();
}

void MqttPublisher::configureSecurity(bool tls)
{
    const MqttAuthConfig &auth = config_.auth;
    if (!auth.username.empty()) {
        std::string password;
        if (!auth.password_file.empty()) {
            std::ifstream in(auth.password_file);
            if (!in) {
                throw ConfigError("mqtt_auth.password_file: cannot read '" + auth.password_file +
                                  "': " + std::strerror(errno));
            }
            std::getline(in, password);
            if (!password.empty() && password.back() == '\r') {
                password.pop_back();
            }
        }
        const int rc = mosquitto_username_pw_set(mosq_, auth.username.c_str(),
                                                 auth.password_file.empty() ? nullptr : password.c_str());
        if (rc != MOSQ_ERR_SUCCESS) {
            throw ConfigError(std::string("mqtt_auth.username: ") + mosquitto_strerror(rc));
        }
    }
    if (!tls) {
        return;
    }
    // Without a CA file, the system's certificates (a broker with a certificate from a public CA).
    const char *ca_file = auth.ca_file.empty() ? nullptr : auth.ca_file.c_str();
    const char *ca_path = auth.ca_file.empty() ? "/etc/ssl/certs" : nullptr;
    const int rc = mosquitto_tls_set(mosq_, ca_file, ca_path, auth.cert_file.empty() ? nullptr : auth.cert_file.c_str(),
                                     auth.key_file.empty() ? nullptr : auth.key_file.c_str(), nullptr);
    if (rc != MOSQ_ERR_SUCCESS) {
        throw ConfigError("mqtt_auth: cannot use the TLS files (ca_file '" + auth.ca_file + "', cert_file '" +
                          auth.cert_file + "', key_file '" + auth.key_file +
                          "'): " + (rc == MOSQ_ERR_ERRNO ? std::strerror(errno) : mosquitto_strerror(rc)));
    }
    // The broker's certificate must name the host of mqtt.url (never switched off here).
    mosquitto_tls_insecure_set(mosq_, false);
}

void MqttPublisher::connect()
{
    retry_timer_ = 0;
    if (stopping_ || mosq_ == nullptr) {
        return;
    }
    ++connect_attempts_;
    const int keepalive_s = static_cast<int>(config_.keepalive_s);
    const int rc = first_connect_ ? mosquitto_connect_async(mosq_, host_.c_str(), port_, keepalive_s)
                                  : mosquitto_reconnect_async(mosq_);
    first_connect_ = first_connect_ && rc != MOSQ_ERR_SUCCESS;
    if (rc != MOSQ_ERR_SUCCESS) {
        onLost(std::string("cannot connect: ") +
               (rc == MOSQ_ERR_ERRNO ? std::strerror(errno) : mosquitto_strerror(rc)));
        return;
    }
    fd_ = mosquitto_socket(mosq_);
    if (fd_ < 0) {
        onLost("no socket after connect");
        return;
    }
    loop_.watchFd(fd_, POLLIN, [this](short revents) { onSocketEvents(revents); });
    updateInterest();
    if (misc_timer_ == 0) {
        misc_timer_ = loop_.addTimerAfter(kMiscPeriodUs, [this] { tick(); });
    }
}

void MqttPublisher::tick()
{
    misc_timer_ = 0;
    if (mosq_ == nullptr || stopping_) {
        return;
    }
    if (fd_ >= 0) {
        const int rc = mosquitto_loop_misc(mosq_);
        if (rc != MOSQ_ERR_SUCCESS && rc != MOSQ_ERR_NO_CONN) {
            onLost(std::string("keepalive failed: ") + mosquitto_strerror(rc));
        } else {
            updateInterest();
        }
    }
    misc_timer_ = loop_.addTimerAfter(kMiscPeriodUs, [this] { tick(); });
}

void MqttPublisher::updateInterest()
{
    if (fd_ < 0 || mosq_ == nullptr) {
        return;
    }
    const bool want_write = mosquitto_want_write(mosq_);
    settleInFlight(want_write);
    loop_.setFdEvents(fd_, static_cast<short>(want_write ? (POLLIN | POLLOUT) : POLLIN));
}

// QoS 0 has no acknowledgement: a message is done once libmosquitto has nothing left to write
// (its on_publish callback does not come for every one of them). QoS 1 and 2 messages are done
// when the broker acknowledges them (publishCallback).
void MqttPublisher::settleInFlight(bool want_write)
{
    if (config_.qos == 0 && !want_write) {
        in_flight_ = 0;
    }
}

void MqttPublisher::onSocketEvents(short revents)
{
    if (revents & (POLLIN | POLLHUP | POLLERR)) {
        const int rc = mosquitto_loop_read(mosq_, 16);
        if (rc != MOSQ_ERR_SUCCESS) {
            onLost(std::string("read: ") + (rc == MOSQ_ERR_ERRNO ? std::strerror(errno) : mosquitto_strerror(rc)));
            return;
        }
    }
    if (fd_ >= 0 && (revents & POLLOUT)) {
        const int rc = mosquitto_loop_write(mosq_, 16);
        if (rc != MOSQ_ERR_SUCCESS) {
            onLost(std::string("write: ") + (rc == MOSQ_ERR_ERRNO ? std::strerror(errno) : mosquitto_strerror(rc)));
            return;
        }
    }
    updateInterest();
}

void MqttPublisher::connectCallback(struct mosquitto *, void *self, int rc)
{
    static_cast<MqttPublisher *>(self)->onConnected(rc);
}

void MqttPublisher::disconnectCallback(struct mosquitto *, void *self, int rc)
{
    auto *publisher = static_cast<MqttPublisher *>(self);
    if (!publisher->stopping_) {
        publisher->onLost(std::string("disconnected: ") + mosquitto_strerror(rc));
    }
}

void MqttPublisher::subscribe(const std::string &topic, MessageHandler handler)
{
    subscriptions_[topic] = std::move(handler);
}

void MqttPublisher::messageCallback(struct mosquitto *, void *self, const ::mosquitto_message *message)
{
    auto *publisher = static_cast<MqttPublisher *>(self);
    ++publisher->counters_.mqtt_received;
    const auto it = publisher->subscriptions_.find(message->topic != nullptr ? message->topic : "");
    if (it == publisher->subscriptions_.end()) {
        return;
    }
    if (message->retain) {
        if (!publisher->retained_warned_) {
            publisher->retained_warned_ = true;
            log()->warn("mqtt: ignoring the retained message on '{}' (the broker keeps an old one for new "
                        "subscribers; publish odometry without retain)",
                        it->first);
        }
        return;
    }
    const std::string topic = it->first;
    const MessageHandler handler = it->second; // a copy: the handler may subscribe or stop
    handler(topic, static_cast<const char *>(message->payload), static_cast<size_t>(std::max(0, message->payloadlen)));
}

void MqttPublisher::subscribeCallback(struct mosquitto *, void *self, int mid, int qos_count, const int *granted_qos)
{
    auto *publisher = static_cast<MqttPublisher *>(self);
    const auto it = publisher->pending_subscriptions_.find(mid);
    const std::string name = it != publisher->pending_subscriptions_.end() ? it->second : std::string("?");
    if (it != publisher->pending_subscriptions_.end()) {
        publisher->pending_subscriptions_.erase(it);
    }
    for (int i = 0; i < qos_count; ++i) {
        if (granted_qos[i] > 2) { // 0x80: the broker refused the subscription
            log()->error("mqtt: the broker refused the subscription to '{}' (its messages will not arrive)", name);
            continue;
        }
        ++publisher->subscriptions_acknowledged_;
        log()->info("mqtt: subscribed to '{}' (QoS {})", name, granted_qos[i]);
    }
}

void MqttPublisher::publishCallback(struct mosquitto *, void *self, int)
{
    auto *publisher = static_cast<MqttPublisher *>(self);
    if (publisher->in_flight_ > 0) {
        --publisher->in_flight_;
    }
}

// Messages libmosquitto still held when the connection went (or the service stops) never
// reached the broker: they are counted as dropped, not as published-and-forgotten.
void MqttPublisher::dropInFlight(const std::string &why)
{
    if (in_flight_ == 0) {
        return;
    }
    counters_.mqtt_dropped += in_flight_;
    counters_.mqtt_published -= std::min(counters_.mqtt_published, in_flight_);
    last_loss_ = why;
    in_flight_ = 0;
}

void MqttPublisher::onConnected(int rc)
{
    if (rc != 0) {
        // 4: bad user name or password, 5: not authorised. Retrying will not fix credentials, but
        // the broker's password file may be fixed meanwhile: an error (not the outage warning),
        // once, naming the settings to check, and the retries go on.
        if ((rc == 4 || rc == 5) && !auth_error_logged_) {
            auth_error_logged_ = true;
            log()->error("mqtt: the broker {}:{} refused the credentials: {} (check mqtt_auth.username and "
                         "mqtt_auth.password_file); retrying with backoff, estimates keep flowing elsewhere",
                         host_, port_, mosquitto_connack_string(rc));
        }
        onLost(std::string("the broker refused the connection: ") + mosquitto_connack_string(rc));
        return;
    }
    auth_error_logged_ = false;
    connected_ = true;
    outage_logged_ = false;
    backoff_us_ = secondsToUs(config_.reconnect_min_s);
    ++counters_.mqtt_connects;
    log()->info("mqtt: connected to {}:{}, publishing under '{}/'", host_, port_, config_.topic_prefix);
    publish(topic("status"), "online", true);
    // The session is clean: a reconnect has forgotten the subscriptions.
    subscriptions_acknowledged_ = 0;
    pending_subscriptions_.clear();
    for (const auto &[name, handler] : subscriptions_) {
        int mid = 0;
        const int sub_rc = mosquitto_subscribe(mosq_, &mid, name.c_str(), config_.qos);
        if (sub_rc != MOSQ_ERR_SUCCESS) {
            log()->error("mqtt: cannot subscribe to '{}': {}", name, mosquitto_strerror(sub_rc));
        } else {
            pending_subscriptions_[mid] = name;
        }
    }
    // Everything retained goes out again: a subscriber that connects later, or a broker that
    // restarted without persistence, gets the current picture.
    const std::map<std::string, std::string> retained = retained_;
    for (const auto &[name, payload] : retained) {
        if (name != topic("status")) {
            publish(name, payload, true);
        }
    }
}

void MqttPublisher::onLost(const std::string &reason)
{
    dropInFlight("the connection to the broker was lost: " + reason);
    last_loss_ = "broker " + host_ + ":" + std::to_string(port_) + " unavailable: " + reason;
    if (fd_ >= 0) {
        loop_.unwatchFd(fd_); // before anything can reuse the descriptor number
        fd_ = -1;
    }
    if (connected_) {
        ++counters_.mqtt_disconnects;
        connected_ = false;
    }
    if (!outage_logged_) {
        outage_logged_ = true;
        log()->warn("mqtt: broker {}:{} unavailable ({}); retrying with backoff, estimates keep flowing elsewhere",
                    host_, port_, reason);
    }
    scheduleReconnect();
}

void MqttPublisher::scheduleReconnect()
{
    if (stopping_ || retry_timer_ != 0) {
        return;
    }
    const int64_t delay_us = backoff_us_;
    backoff_us_ = std::min(backoff_us_ * 2, secondsToUs(config_.reconnect_max_s));
    retry_timer_ = loop_.addTimerAfter(delay_us, [this] { connect(); });
}

void MqttPublisher::publish(const std::string &name, const std::string &payload, bool retain)
{
    if (retain) {
        retained_[name] = payload;
    }
    if (!connected_ || mosq_ == nullptr) {
        ++counters_.mqtt_dropped;
        if (last_loss_.empty()) {
            last_loss_ = "not connected to the broker yet";
        }
        return;
    }
    const int rc = mosquitto_publish(mosq_, nullptr, name.c_str(), static_cast<int>(payload.size()), payload.data(),
                                     config_.qos, retain);
    if (rc == MOSQ_ERR_SUCCESS) {
        ++counters_.mqtt_published;
        ++in_flight_;
    } else {
        ++counters_.mqtt_dropped;
        last_loss_ = mosquitto_strerror(rc);
        if (rc == MOSQ_ERR_NO_CONN || rc == MOSQ_ERR_CONN_LOST) {
            onLost(mosquitto_strerror(rc));
            return;
        }
    }
    updateInterest();
}

void MqttPublisher::onUpdate(const MapState &map, const std::vector<size_t> &changed, int64_t event_us)
{
    if (mosq_ == nullptr) {
        return;
    }
    const int64_t period_us = config_.rate_hz > 0.0 ? static_cast<int64_t>(std::llround(1e6 / config_.rate_hz)) : 0;
    const std::vector<size_t> positions = nodesToLookAt(map, changed, waiting_ids_);
    waiting_ids_.clear();
    for (const size_t position : positions) {
        const NodeEstimate &node = map.nodes[position];
        auto last = last_node_.find(node.id);
        if (last != last_node_.end() && sameEstimate(last->second, node)) {
            continue;
        }
        auto due = next_due_us_.find(node.id);
        if (period_us > 0 && due != next_due_us_.end() && event_us < due->second) {
            waiting_ids_.push_back(node.id);
            continue;
        }
        next_due_us_[node.id] = event_us + period_us;
        last_node_[node.id] = node;
        publish(topic("nodes/" + nodeIdHex(node.id)), JsonLinesWriter::line(nodeJson(node, outputTimeOf(map))), true);
    }
    if (map.robot && !(last_robot_ && sameEstimate(*last_robot_, *map.robot))) {
        last_robot_ = map.robot;
        publish(topic("robot"), JsonLinesWriter::line(robotJson(*map.robot, outputTimeOf(map))), true);
    }
}

void MqttPublisher::publishHealth(const Health &health, OutputTime time)
{
    if (mosq_ == nullptr) {
        return;
    }
    publish(topic("health"), JsonLinesWriter::line(healthJson(health, time)), true);
}

bool MqttPublisher::flushed() const { return connected_ && mosq_ != nullptr && !mosquitto_want_write(mosq_); }

void MqttPublisher::shutdown()
{
    if (mosq_ == nullptr) {
        return;
    }
    if (connected_) {
        publish(topic("status"), "offline", true);
        stopping_ = true;
        // Bounded flush of what is queued (a replay at full speed may have much: it all goes out,
        // then the offline status and the DISCONNECT).
        for (int i = 0; i < kFlushPolls && fd_ >= 0 && (mosquitto_want_write(mosq_) || in_flight_ > 0); ++i) {
            settleInFlight(mosquitto_want_write(mosq_));
            if (in_flight_ == 0 && !mosquitto_want_write(mosq_)) {
                break;
            }
            pollfd p{fd_, static_cast<short>(POLLIN | (mosquitto_want_write(mosq_) ? POLLOUT : 0)), 0};
            if (::poll(&p, 1, 20) <= 0) {
                continue;
            }
            // Reads too: with QoS 1 and 2 a message is done when the broker acknowledges it.
            if ((p.revents & (POLLIN | POLLHUP | POLLERR)) != 0 && mosquitto_loop_read(mosq_, 64) != MOSQ_ERR_SUCCESS) {
                break;
            }
            if ((p.revents & POLLOUT) != 0 && mosquitto_loop_write(mosq_, 64) != MOSQ_ERR_SUCCESS) {
                break;
            }
        }
        mosquitto_disconnect(mosq_);
        for (int i = 0; i < 50 && fd_ >= 0 && mosquitto_want_write(mosq_); ++i) {
            pollfd p{fd_, POLLOUT, 0};
            if (::poll(&p, 1, 20) > 0 && mosquitto_loop_write(mosq_, 16) != MOSQ_ERR_SUCCESS) {
                break;
            }
        }
        dropInFlight("still queued when the service stopped");
    }
    if (counters_.mqtt_dropped > 0) {
        log()->warn("mqtt: {} messages not published ({}); {} published", counters_.mqtt_dropped,
                    last_loss_.empty() ? "the broker was not reachable" : last_loss_, counters_.mqtt_published);
    }
    stopping_ = true;
    if (fd_ >= 0) {
        loop_.unwatchFd(fd_);
        fd_ = -1;
    }
    if (retry_timer_ != 0) {
        loop_.cancelTimer(retry_timer_);
        retry_timer_ = 0;
    }
    if (misc_timer_ != 0) {
        loop_.cancelTimer(misc_timer_);
        misc_timer_ = 0;
    }
    mosquitto_destroy(mosq_);
    mosq_ = nullptr;
    connected_ = false;
}

} // namespace cdro::service
