// mqtt_publisher.hpp: publishes the estimates and the service's health to an MQTT broker
// through libmosquitto, the way RTLS systems hand positions to other machines.
//
// Topics (prefix = mqtt.topic_prefix), payloads are the JSON objects of docs/outputs.md:
//   <prefix>/nodes/<id>  a node line, retained          (<id> as 0x6001, as in the logs)
//   <prefix>/robot       the robot line, retained
//   <prefix>/health      the health line, retained
//   <prefix>/status      "online" (retained) once connected; "offline" (retained) on a clean
//                        shutdown, and as the broker's last will if the service dies
//
// libmosquitto runs without its own thread: its socket sits in the service's poll loop
// (loop_read when readable, loop_write when it wants to write, loop_misc every second), so
// its callbacks run on the loop thread and no lock is needed. Only the broker host name
// resolution in connect may block: use an IP address (mqtt://127.0.0.1:1883) to avoid it.
// When the broker is lost, the publisher keeps the latest retained payload of every topic,
// retries with backoff, and publishes them all again when the broker is back. Publishing while
// disconnected counts mqtt_dropped and never blocks the loop.
//
// The same client also subscribes (subscribe(): the robot's odometry topic, odometry.hpp):
// the subscriptions are sent on every connect (the session is clean, so a reconnect forgets
// them), and each message arrives in a callback on the loop thread, counted in mqtt_received.
// Retained messages are ignored: a retained odometry step is an old one, replayed by the
// broker to every new subscriber.
//
// Credentials and TLS (the mqtt_auth: section): a user name and a password read from a file
// (mosquitto_username_pw_set), and for an mqtts:// URL a TLS connection that checks the broker's
// certificate against mqtt_auth.ca_file (or the system's CAs) and the URL's host name, with an
// optional client certificate (mosquitto_tls_set). Refused credentials are logged as an error
// once per outage; the service keeps running and retrying like for a broker that is away.
//
// Threading: loop thread only.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "cdro/service/config.hpp"
#include "cdro/service/event_loop.hpp"
#include "cdro/service/map_state.hpp"

struct mosquitto;
struct mosquitto_message;

namespace cdro::service {

class MqttPublisher {
public:
    MqttPublisher(EventLoop &loop, const MqttConfig &config, ServiceCounters &counters);
    ~MqttPublisher();
    MqttPublisher(const MqttPublisher &) = delete;
    MqttPublisher &operator=(const MqttPublisher &) = delete;

    void start();    // throws ConfigError for a bad URL; connecting itself never throws
    void shutdown(); // "offline", clean disconnect (bounded wait), release
    bool connected() const { return connected_; }
    // Connected, and fewer than kMaxInFlight messages handed to libmosquitto are still waiting
    // to go out: a replay feeds more input only then, so that publishing keeps up with it.
    bool readyForMore() const { return connected_ && in_flight_ < kMaxInFlight; }
    static constexpr uint64_t kMaxInFlight = 1000;
    // Connection attempts so far (the first and every retry), for a replay deciding how long
    // to wait for the broker.
    uint64_t connectAttempts() const { return connect_attempts_; }
    // Connected and nothing queued for the socket (tests, and a clean shutdown).
    bool flushed() const;

    // After an update at event time event_us: the nodes (and robot) that changed, at most
    // rate_hz per node.
    // changed: the positions in map.nodes of the nodes the update may have changed
    // (MapSource::updateEstimates); the nodes waiting for their period are looked at again.
    // Without `changed`, every node is looked at.
    void onUpdate(const MapState &map, const std::vector<size_t> &changed, int64_t event_us);
    void onUpdate(const MapState &map, int64_t event_us) { onUpdate(map, allNodes(map), event_us); }
    void publishHealth(const Health &health, OutputTime time);

    // Subscribes to topic (an exact topic, no wildcards) on every connect; handler gets each
    // message's payload on the loop thread. Call before start().
    using MessageHandler = std::function<void(const std::string &topic, const char *payload, size_t len)>;
    void subscribe(const std::string &topic, MessageHandler handler);
    // Subscriptions the broker acknowledged since the last connect (tests).
    uint64_t subscriptionsAcknowledged() const { return subscriptions_acknowledged_; }

    std::string topic(const std::string &suffix) const { return config_.topic_prefix + "/" + suffix; }

private:
    void connect();
    void configureSecurity(bool tls); // mqtt_auth: user name and password, TLS; throws ConfigError
    void scheduleReconnect();
    void onSocketEvents(short revents);
    void updateInterest();
    void onConnected(int rc);
    void onLost(const std::string &reason);
    void publish(const std::string &topic, const std::string &payload, bool retain);
    void tick();

    static void connectCallback(struct mosquitto *, void *self, int rc);
    static void disconnectCallback(struct mosquitto *, void *self, int rc);
    static void messageCallback(struct mosquitto *, void *self, const ::mosquitto_message *message);
    static void subscribeCallback(struct mosquitto *, void *self, int mid, int qos_count, const int *granted_qos);
    static void publishCallback(struct mosquitto *, void *self, int mid);
    void dropInFlight(const std::string &why);
    void settleInFlight(bool want_write);

    EventLoop &loop_;
    MqttConfig config_;
    ServiceCounters &counters_;
    struct mosquitto *mosq_ = nullptr;
    std::string host_;
    uint16_t port_ = 1883;
    int fd_ = -1;
    bool connected_ = false;
    bool first_connect_ = true;
    bool outage_logged_ = false;
    bool auth_error_logged_ = false;
    bool stopping_ = false;
    int64_t backoff_us_ = 0;
    EventLoop::TimerId retry_timer_ = 0;
    EventLoop::TimerId misc_timer_ = 0;
    std::map<std::string, std::string> retained_; // topic -> latest payload
    std::map<uint16_t, NodeEstimate> last_node_;  // id -> the estimate last published
    std::map<uint16_t, int64_t> next_due_us_;     // id -> event time of the next publish
    std::vector<uint16_t> waiting_ids_;           // changed, waiting for their next publish (sorted)
    std::optional<RobotPose> last_robot_;
    std::map<std::string, MessageHandler> subscriptions_; // topic -> handler
    std::map<int, std::string> pending_subscriptions_;    // message id -> topic, until the SUBACK
    uint64_t subscriptions_acknowledged_ = 0;
    bool retained_warned_ = false;
    uint64_t connect_attempts_ = 0;
    uint64_t in_flight_ = 0; // published, not yet written to the socket (QoS 0) or acknowledged
    std::string last_loss_;  // why messages were last dropped, for the summary at the end
};

} // namespace cdro::service
