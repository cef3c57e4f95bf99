// MqttPublisher against a real mosquitto broker on a free loopback port: topics and payloads,
// retained state, a lost broker that comes back, and the last will.
#include <condition_variable>
#include <map>
#include <mutex>

#include <gtest/gtest.h>
#include <mosquitto.h>
#include <nlohmann/json.hpp>

#include "cdro/service/mqtt_publisher.hpp"
#include "support.hpp"

using namespace cdro::service;

namespace {

// A subscriber on libmosquitto's own thread; messages are collected under a mutex.
class Subscriber {
public:
    explicit Subscriber(uint16_t port, const std::string &filter) : filter_(filter)
    {
        mosquitto_lib_init();
        mosq_ = mosquitto_new(nullptr, true, this);
        mosquitto_connect_callback_set(mosq_, [](struct mosquitto *m, void *self, int) {
            mosquitto_subscribe(m, nullptr, static_cast<Subscriber *>(self)->filter_.c_str(), 1);
        });
        mosquitto_message_callback_set(mosq_, [](struct mosquitto *, void *self, const mosquitto_message *msg) {
            auto *s = static_cast<Subscriber *>(self);
            std::lock_guard<std::mutex> lock(s->mutex_);
            s->messages_.emplace_back(msg->topic, std::string(static_cast<const char *>(msg->payload),
                                                              static_cast<size_t>(msg->payloadlen)));
            s->changed_.notify_all();
        });
        mosquitto_connect(mosq_, "127.0.0.1", port, 30);
        mosquitto_loop_start(mosq_);
    }
    ~Subscriber()
    {
        mosquitto_disconnect(mosq_);
        mosquitto_loop_stop(mosq_, false);
        mosquitto_destroy(mosq_);
    }
    // The latest payload of topic, waiting (deadlock guard) until predicate(payload) holds.
    template <typename Pred> std::string waitFor(const std::string &topic, Pred predicate)
    {
        std::unique_lock<std::mutex> lock(mutex_);
        std::string found;
        changed_.wait_for(lock, std::chrono::seconds(20), [&] {
            for (auto it = messages_.rbegin(); it != messages_.rend(); ++it) {
                if (it->first == topic && predicate(it->second)) {
                    found = it->second;
                    return true;
                }
            }
            return false;
        });
        return found;
    }

private:
    std::string filter_;
    struct mosquitto *mosq_ = nullptr;
    std::mutex mutex_;
    std::condition_variable changed_;
    std::vector<std::pair<std::string, std::string>> messages_;
};

MapState mapWith(double x)
{
    MapState map;
    map.t_s = 4.5;
    map.t_unix_s = 1700000004.5;
    map.nodes.push_back(
        {24577, x, 1.0, 0.01, 0.0, 0.02, true, false, true, false, "converged", "", {}, 1.5, {}, {}, {}});
    map.nodes.push_back({24578, 2.0, 3.0, 0.01, 0.0, 0.02, false, true, true, false, "moving", "", {}, {}, {}, {}, {}});
    RobotPose robot;
    robot.id = 24600;
    robot.x_m = 0.5;
    robot.y_m = 0.25;
    robot.heading_rad = 1.0;
    robot.var_x_m2 = 0.01;
    robot.var_y_m2 = 0.01;
    map.robot = robot;
    return map;
}

// A publisher of the tests' broker under test/cdro/, at rate_hz messages per node (0: every change).
MqttConfig configFor(uint16_t port, double rate_hz)
{
    MqttConfig config;
    config.url = "mqtt://127.0.0.1:" + std::to_string(port);
    config.topic_prefix = "test/cdro";
    config.rate_hz = rate_hz;
    return config;
}

template <typename Done> void pump(EventLoop &loop, Done done)
{
    for (int i = 0; i < 4000 && !done(); ++i) {
        loop.runOnce(5'000);
    }
}

} // namespace

TEST(Mqtt, PublishesNodesRobotHealthAndStatusRetained)
{
    cdro::test::Broker broker(cdro::test::freeLoopbackPort());
    SystemClock clock;
    EventLoop loop(clock);
    ServiceCounters counters;
    MqttPublisher publisher(loop, configFor(broker.port(), 0.0), counters);
    publisher.start();
    pump(loop, [&] { return publisher.connected(); });
    ASSERT_TRUE(publisher.connected());
    publisher.onUpdate(mapWith(1.25), 4'500'000);
    Health health;
    health.link = LinkState::Connected;
    health.counters.frames_ok = 42;
    publisher.publishHealth(health, {4.5, 1700000004.5});
    // (libmosquitto writes at once when the socket takes it; anything left goes out when the
    // loop sees the socket writable.)
    pump(loop, [&] { return publisher.flushed(); });
    Subscriber subscriber(broker.port(), "test/cdro/#");
    const auto any = [](const std::string &) { return true; };
    // Topics name a node as the logs and the live map do: 0x6001 is 24577.
    const auto node = nlohmann::json::parse(subscriber.waitFor("test/cdro/nodes/0x6001", any));
    EXPECT_EQ(node["type"], "node");
    EXPECT_EQ(node["x_m"], 1.25);
    EXPECT_EQ(node["z_m"], 1.5);
    EXPECT_EQ(node["t_s"], 4.5);
    EXPECT_EQ(node["t_unix_s"], 1700000004.5);
    EXPECT_EQ(node["id_hex"], "0x6001");
    EXPECT_EQ(nlohmann::json::parse(subscriber.waitFor("test/cdro/nodes/0x6002", any))["moving"], true);
    EXPECT_EQ(nlohmann::json::parse(subscriber.waitFor("test/cdro/robot", any))["heading_rad"], 1.0);
    EXPECT_EQ(nlohmann::json::parse(subscriber.waitFor("test/cdro/health", any))["counters"]["frames_ok"], 42);
    EXPECT_EQ(subscriber.waitFor("test/cdro/status", any), "online");
    EXPECT_GE(counters.mqtt_published, 5U);
    // Retained: a subscriber that comes after the messages were delivered still gets them.
    Subscriber later(broker.port(), "test/cdro/nodes/#");
    EXPECT_EQ(nlohmann::json::parse(later.waitFor("test/cdro/nodes/0x6001", any))["x_m"], 1.25);
    publisher.shutdown();
    EXPECT_EQ(subscriber.waitFor("test/cdro/status", [](const std::string &p) { return p == "offline"; }), "offline");
}

TEST(Mqtt, ALostBrokerIsRetriedAndGetsTheLatestStateWhenBack)
{
    const uint16_t port = cdro::test::freeLoopbackPort();
    auto broker = std::make_unique<cdro::test::Broker>(port);
    SystemClock clock;
    EventLoop loop(clock);
    ServiceCounters counters;
    MqttConfig config;
    config.url = "mqtt://127.0.0.1:" + std::to_string(port);
    config.rate_hz = 0;
    config.reconnect_min_s = 0.05;
    config.reconnect_max_s = 0.2;
    MqttPublisher publisher(loop, config, counters);
    publisher.start();
    pump(loop, [&] { return publisher.connected(); });
    ASSERT_TRUE(publisher.connected());
    broker->kill();
    pump(loop, [&] { return !publisher.connected(); });
    ASSERT_FALSE(publisher.connected());
    EXPECT_EQ(counters.mqtt_disconnects, 1U);
    // Estimates keep coming while the broker is away: counted as dropped, never blocking.
    publisher.onUpdate(mapWith(7.5), 1'000'000);
    EXPECT_GE(counters.mqtt_dropped, 1U);
    broker = std::make_unique<cdro::test::Broker>(port); // back, without persistence
    pump(loop, [&] { return publisher.connected(); });
    ASSERT_TRUE(publisher.connected());
    EXPECT_EQ(counters.mqtt_connects, 2U);
    // What was published from the connect callback is queued; the loop writes it.
    pump(loop, [&] { return publisher.flushed(); });
    Subscriber subscriber(port, "cdro/#");
    const std::string payload = subscriber.waitFor("cdro/nodes/0x6001", [](const std::string &p) {
        return nlohmann::json::parse(p)["x_m"] == 7.5; // the state published while it was away
    });
    ASSERT_FALSE(payload.empty());
}

// The service tells the publisher which nodes an update changed (MapSource::updateEstimates). A
// node that changed before its period was up waits, and goes out with the first update after
// it, even when that update changed another node only.
TEST(Mqtt, ANodeWaitingForItsPeriodGoesOutWithALaterUpdateThatDidNotChangeIt)
{
    cdro::test::Broker broker(cdro::test::freeLoopbackPort());
    SystemClock clock;
    EventLoop loop(clock);
    ServiceCounters counters;
    // A message per node per 0.5 s of event time.
    MqttPublisher publisher(loop, configFor(broker.port(), 2.0), counters);
    publisher.start();
    pump(loop, [&] { return publisher.connected(); });
    ASSERT_TRUE(publisher.connected());
    Subscriber subscriber(broker.port(), "test/cdro/nodes/#");
    MapState map = mapWith(1.25);
    publisher.onUpdate(map, {0, 1}, 0);
    map.nodes[0].x_m = 2.5; // too soon for 0x6001: it waits
    publisher.onUpdate(map, {0}, 100'000);
    map.nodes[1].x_m = 7.0; // only 0x6002 changed, 0.6 s on: both are due
    publisher.onUpdate(map, {1}, 600'000);
    pump(loop, [&] { return publisher.flushed(); });
    const auto x_is = [](double x) {
        return [x](const std::string &payload) { return nlohmann::json::parse(payload)["x_m"] == x; };
    };
    EXPECT_FALSE(subscriber.waitFor("test/cdro/nodes/0x6001", x_is(2.5)).empty());
    EXPECT_FALSE(subscriber.waitFor("test/cdro/nodes/0x6002", x_is(7.0)).empty());
    EXPECT_EQ(counters.mqtt_published, 4U + 2U); // two nodes twice, the robot and the status
    publisher.shutdown();
}
