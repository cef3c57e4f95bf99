// The robot's odometry: parsing and every rejection reason, velocities converted to steps,
// ordering and clock steps, the capture record, the replay path, and the two live sources on
// real sockets (UDP on loopback inside a real EventLoop; MQTT through a real mosquitto).
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <fstream>
#include <mutex>
#include <system_error>

#include <gtest/gtest.h>
#include <mosquitto.h>
#include <nlohmann/json.hpp>

#include "cdro/service/capture.hpp"
#include "cdro/service/mqtt_publisher.hpp"
#include "cdro/service/odometry_intake.hpp"
#include "cdro/service/odometry_udp.hpp"
#include "cdro/service/replay.hpp"
#include "cdro/service/service.hpp"
#include "support.hpp"

using namespace cdro::service;
using cdro::test::encode;
using cdro::test::helloFrame;
using cdro::test::rangeFrame;

namespace {

constexpr int64_t kT0Us = 1'764'600'000'000'000; // us since the epoch, 2025-12-01T14:40Z
constexpr double kT0 = 1764600000.0;             // s, the same instant

std::string step(double t_s, double distance_m, double dheading_rad)
{
    char text[160];
    std::snprintf(text, sizeof text, "{\"t\": %.17g, \"distance_m\": %.17g, \"dheading_rad\": %.17g}", t_s, distance_m,
                  dheading_rad);
    return text;
}

std::string velocity(double t_s, double v_mps, double omega_radps)
{
    char text[160];
    std::snprintf(text, sizeof text, "{\"t\": %.17g, \"v_mps\": %.17g, \"omega_radps\": %.17g}", t_s, v_mps,
                  omega_radps);
    return text;
}

uint64_t rejectedSum(const ServiceCounters &c)
{
    return c.odometry_rejected_not_json + c.odometry_rejected_not_object + c.odometry_rejected_field +
           c.odometry_rejected_both_forms + c.odometry_rejected_absurd + c.odometry_rejected_out_of_order +
           c.odometry_rejected_too_long;
}

OdometryConfig withGap(double max_velocity_gap_s)
{
    OdometryConfig config;
    config.max_velocity_gap_s = max_velocity_gap_s;
    return config;
}

struct Fixture {
    explicit Fixture(double max_velocity_gap_s = 1.0)
        : config(withGap(max_velocity_gap_s)), intake(config, 1000.0, counters, clock)
    {
        intake.setConsumer(&consumer);
    }
    void push(const std::string &text, int64_t receive_us = kT0Us, const std::string &source = "udp:test")
    {
        intake.push(source, text.data(), text.size(), receive_us);
    }
    std::vector<OdometryMessage> messages() const
    {
        std::vector<OdometryMessage> out;
        for (const auto &r : consumer.received) {
            out.push_back(r.odometry);
        }
        return out;
    }
    // Every message is accounted for exactly once.
    void expectBalanced() const
    {
        EXPECT_EQ(counters.odometry_received,
                  counters.odometry_accepted + counters.odometry_clock_starts + rejectedSum(counters));
        EXPECT_EQ(counters.odometry_accepted, consumer.received.size());
    }
    OdometryConfig config;
    ManualClock clock;
    ServiceCounters counters;
    cdro::test::RecordingConsumer consumer;
    OdometryIntake intake;
};

template <typename Done> void runUntil(EventLoop &loop, Done done)
{
    // Each iteration blocks in poll; the count is a deadlock guard, not a speed assumption.
    for (int i = 0; i < 4000 && !done(); ++i) {
        loop.runOnce(5'000);
    }
    ASSERT_TRUE(done());
}

std::vector<CaptureRecord> readCapture(const std::string &path)
{
    CaptureReader reader(path);
    std::vector<CaptureRecord> records;
    CaptureRecord record;
    while (reader.next(record)) {
        records.push_back(record);
    }
    return records;
}

// A UDP sender on loopback, as the robot's drive software would be.
class UdpSender {
public:
    UdpSender() : fd_(::socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0))
    {
        sockaddr_in self{};
        self.sin_family = AF_INET;
        self.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
        if (::bind(fd_, reinterpret_cast<sockaddr *>(&self), sizeof self) != 0) {
            throw std::system_error(errno, std::generic_category(), "UdpSender: bind");
        }
        socklen_t len = sizeof self;
        ::getsockname(fd_, reinterpret_cast<sockaddr *>(&self), &len);
        port_ = ntohs(self.sin_port);
    }
    ~UdpSender() { ::close(fd_); }
    void send(uint16_t port, const std::string &text) const
    {
        sockaddr_in to{};
        to.sin_family = AF_INET;
        to.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
        to.sin_port = htons(port);
        ASSERT_EQ(::sendto(fd_, text.data(), text.size(), 0, reinterpret_cast<sockaddr *>(&to), sizeof to),
                  static_cast<ssize_t>(text.size()));
    }
    uint16_t port() const { return port_; }

private:
    int fd_;
    uint16_t port_ = 0;
};

} // namespace

// ---- parsing ---------------------------------------------------------------------------------

TEST(OdometryParse, TheTwoFormsAndAnOptionalTime)
{
    ParsedOdometry p;
    OdometryReject reason = OdometryReject::NotJson;
    std::string why;
    ASSERT_TRUE(
        parseOdometry(R"({"t": 1764600000.125, "distance_m": 0.012, "dheading_rad": -0.001})", &p, &reason, &why));
    EXPECT_EQ(p.form, ParsedOdometry::Form::Step);
    EXPECT_TRUE(p.has_t);
    EXPECT_EQ(p.t_s, 1764600000.125);
    EXPECT_EQ(p.distance_m, 0.012);
    EXPECT_EQ(p.dheading_rad, -0.001);
    ASSERT_TRUE(parseOdometry(R"({"v_mps": 0.5, "omega_radps": 0.1, "frame": "base_link"})", &p, &reason, &why));
    EXPECT_EQ(p.form, ParsedOdometry::Form::Velocity);
    EXPECT_FALSE(p.has_t); // (and unknown keys are left alone)
    EXPECT_EQ(p.v_mps, 0.5);
    EXPECT_EQ(p.omega_radps, 0.1);
    // The bounds themselves are plausible; integers are numbers too.
    EXPECT_TRUE(parseOdometry(R"({"distance_m": -10, "dheading_rad": 3.141592653589793})", &p, &reason, &why));
    EXPECT_TRUE(parseOdometry(R"({"v_mps": 20, "omega_radps": -10})", &p, &reason, &why));
}

TEST(OdometryParse, EveryRejectionReasonWithASentence)
{
    struct Case {
        std::string text;
        OdometryReject reason;
        const char *says;
    };
    const std::string padded = R"({"distance_m": 0.1, "dheading_rad": 0, "pad": ")" + std::string(1000, 'x') + "\"}";
    const std::vector<Case> cases = {
        {"hello", OdometryReject::NotJson, "not JSON"},
        {"{\"distance_m\": 0.1,", OdometryReject::NotJson, "not JSON"},
        {R"({"t": 1e999, "distance_m": 0, "dheading_rad": 0})", OdometryReject::NotJson, "not JSON"},
        {"[0.1, 0.0]", OdometryReject::NotObject, "array, not an object"},
        {"42", OdometryReject::NotObject, "number, not an object"},
        {"\"step\"", OdometryReject::NotObject, "string, not an object"},
        {"null", OdometryReject::NotObject, "null, not an object"},
        {R"({"distance_m": "0.1", "dheading_rad": 0})", OdometryReject::Field, "'distance_m' is a string"},
        {R"({"distance_m": 0.1})", OdometryReject::Field, "'dheading_rad' is missing"},
        {R"({"dheading_rad": 0.1})", OdometryReject::Field, "'distance_m' is missing"},
        {R"({"v_mps": 0.5})", OdometryReject::Field, "'omega_radps' is missing"},
        {R"({"omega_radps": 0.5})", OdometryReject::Field, "'v_mps' is missing"},
        {R"({"t": null, "distance_m": 0, "dheading_rad": 0})", OdometryReject::Field, "'t' is null"},
        {R"({"t": "now", "distance_m": 0, "dheading_rad": 0})", OdometryReject::Field, "'t' is a string"},
        {R"({"v_mps": true, "omega_radps": 0})", OdometryReject::Field, "'v_mps' is a boolean"},
        {R"({"distance_m": [1], "dheading_rad": 0})", OdometryReject::Field, "'distance_m' is a array"},
        {"{}", OdometryReject::Field, "neither a step"},
        {R"({"speed": 1})", OdometryReject::Field, "neither a step"},
        {R"({"distance_m": 0.1, "dheading_rad": 0, "v_mps": 1, "omega_radps": 0})", OdometryReject::BothForms,
         "a step (distance_m, dheading_rad) and velocities"},
        {R"({"distance_m": 0.1, "dheading_rad": 0, "v_mps": 1})", OdometryReject::BothForms, "in one message"},
        {R"({"distance_m": 10.001, "dheading_rad": 0})", OdometryReject::Absurd, "beyond +-10 m"},
        {R"({"distance_m": -12, "dheading_rad": 0})", OdometryReject::Absurd, "beyond +-10 m"},
        {R"({"distance_m": 0, "dheading_rad": 3.2})", OdometryReject::Absurd, "beyond +-pi"},
        {R"({"distance_m": 0, "dheading_rad": -3.15})", OdometryReject::Absurd, "beyond +-pi"},
        {R"({"v_mps": 20.5, "omega_radps": 0})", OdometryReject::Absurd, "beyond +-20 m/s"},
        {R"({"v_mps": 0, "omega_radps": -10.5})", OdometryReject::Absurd, "beyond +-10 rad/s"},
        {R"({"t": 12.5, "distance_m": 0, "dheading_rad": 0})", OdometryReject::Absurd, "not Unix time"},
        {R"({"t": 5e9, "distance_m": 0, "dheading_rad": 0})", OdometryReject::Absurd, "not Unix time"},
        {padded, OdometryReject::TooLong, "longer than 1024"},
    };
    for (const Case &c : cases) {
        ParsedOdometry p;
        OdometryReject reason = OdometryReject::NotJson;
        std::string why;
        EXPECT_FALSE(parseOdometry(c.text, &p, &reason, &why)) << c.text;
        EXPECT_EQ(odometryRejectName(reason), std::string(odometryRejectName(c.reason))) << c.text;
        EXPECT_NE(why.find(c.says), std::string::npos) << c.text << " -> " << why;
    }
}

// ---- the intake ------------------------------------------------------------------------------

TEST(OdometryIntake, AStepIsDeliveredWithItsOwnTime)
{
    Fixture f;
    f.push(R"({"t": 1764600000.125, "distance_m": 0.012, "dheading_rad": -0.001})", kT0Us + 300'000);
    ASSERT_EQ(f.consumer.received.size(), 1U);
    EXPECT_EQ(f.consumer.received[0].kind, "odometry");
    EXPECT_EQ(f.messages()[0].t_s, 1764600000.125);
    EXPECT_EQ(f.messages()[0].distance_m, 0.012);
    EXPECT_EQ(f.messages()[0].dheading_rad, -0.001);
    EXPECT_EQ(f.counters.odometry_received, 1U);
    EXPECT_EQ(f.counters.odometry_accepted, 1U);
    EXPECT_EQ(f.intake.lastEventUnixUs(), kT0Us + 300'000); // event time: when it arrived
    f.expectBalanced();
}

TEST(OdometryIntake, WithoutTTheReceiveTimeIsUsed)
{
    Fixture f;
    const int64_t receive_us = kT0Us + 123'457;
    f.push(R"({"distance_m": 0.1, "dheading_rad": 0.02})", receive_us);
    ASSERT_EQ(f.consumer.received.size(), 1U);
    EXPECT_EQ(f.messages()[0].t_s, static_cast<double>(receive_us) / 1e6); // FrameContext's clock, in s
}

TEST(OdometryIntake, EveryRejectionIsCountedByReasonAndTheIntakeGoesOn)
{
    Fixture f;
    using Counter = uint64_t ServiceCounters::*;
    const std::vector<std::pair<std::string, Counter>> cases = {
        {"not json at all", &ServiceCounters::odometry_rejected_not_json},
        {"", &ServiceCounters::odometry_rejected_not_json},          // an empty datagram
        {" \r\n\n\t", &ServiceCounters::odometry_rejected_not_json}, // nothing but blank lines
        {"[1, 2]", &ServiceCounters::odometry_rejected_not_object},
        {R"({"distance_m": 0.1})", &ServiceCounters::odometry_rejected_field},
        {R"({"v_mps": "fast", "omega_radps": 0})", &ServiceCounters::odometry_rejected_field},
        {R"({"distance_m": 0.1, "dheading_rad": 0, "omega_radps": 0})", &ServiceCounters::odometry_rejected_both_forms},
        {R"({"distance_m": 11, "dheading_rad": 0})", &ServiceCounters::odometry_rejected_absurd},
        {R"({"v_mps": 25, "omega_radps": 0})", &ServiceCounters::odometry_rejected_absurd},
        {R"({"distance_m": 0, "dheading_rad": 0, "x": ")" + std::string(1100, 'y') + "\"}",
         &ServiceCounters::odometry_rejected_too_long},
    };
    for (const auto &[text, counter] : cases) {
        const uint64_t before = f.counters.*counter;
        f.push(text);
        EXPECT_EQ(f.counters.*counter, before + 1) << "'" << text.substr(0, 60) << "'";
        EXPECT_TRUE(f.consumer.received.empty()) << text;
    }
    f.push(step(kT0 + 1.0, 0.1, 0.0));
    EXPECT_EQ(f.consumer.received.size(), 1U); // still taking good messages
    EXPECT_EQ(f.counters.odometry_received, cases.size() + 1);
    f.expectBalanced();
}

TEST(OdometryIntake, AMessageUpTo1sOlderThanTheLastIsDroppedFurtherBackIsAClockStep)
{
    Fixture f;
    f.push(step(kT0 + 10.0, 0.1, 0.0));
    f.push(step(kT0 + 9.5, 0.1, 0.0)); // a late datagram
    f.push(step(kT0 + 9.0, 0.1, 0.0)); // exactly 1 s back: still late, not a clock step
    EXPECT_EQ(f.counters.odometry_rejected_out_of_order, 2U);
    EXPECT_EQ(f.consumer.received.size(), 1U);
    f.push(step(kT0 + 10.0, 0.2, 0.0)); // the same time as the last: taken
    EXPECT_EQ(f.consumer.received.size(), 2U);
    f.push(step(kT0 + 4.0, 0.3, 0.0)); // the robot's clock was set back 6 s
    EXPECT_EQ(f.counters.odometry_clock_steps, 1U);
    ASSERT_EQ(f.consumer.received.size(), 3U);
    EXPECT_EQ(f.messages()[2].t_s, kT0 + 4.0);
    f.push(step(kT0 + 4.5, 0.4, 0.0)); // and from there on, time is measured from it
    EXPECT_EQ(f.consumer.received.size(), 4U);
    f.push(step(kT0 + 4.25, 0.4, 0.0));
    EXPECT_EQ(f.counters.odometry_rejected_out_of_order, 3U);
    f.expectBalanced();
}

TEST(OdometryIntake, VelocitiesBecomeTrapezoidStepsAndTheFirstOnlyStartsTheClock)
{
    Fixture f;
    const double t1 = kT0 + 0.25, t2 = kT0 + 0.375, t3 = kT0 + 1.625, t4 = kT0 + 1.75;
    f.push(velocity(t1, 0.5, 0.1));
    EXPECT_TRUE(f.consumer.received.empty());
    EXPECT_EQ(f.counters.odometry_clock_starts, 1U);
    f.push(velocity(t2, 0.7, 0.3));
    ASSERT_EQ(f.consumer.received.size(), 1U);
    EXPECT_EQ(f.messages()[0].t_s, t2);
    EXPECT_DOUBLE_EQ(f.messages()[0].distance_m, 0.5 * (0.5 + 0.7) * (t2 - t1));
    EXPECT_DOUBLE_EQ(f.messages()[0].dheading_rad, 0.5 * (0.1 + 0.3) * (t2 - t1));
    // 1.25 s of silence (more than max_velocity_gap_s): the velocities over it are unknown.
    f.push(velocity(t3, -0.4, 0.0));
    EXPECT_EQ(f.consumer.received.size(), 1U);
    EXPECT_EQ(f.counters.odometry_clock_starts, 2U);
    f.push(velocity(t4, -0.6, -0.2));
    ASSERT_EQ(f.consumer.received.size(), 2U);
    EXPECT_DOUBLE_EQ(f.messages()[1].distance_m, 0.5 * (-0.4 - 0.6) * (t4 - t3));
    EXPECT_DOUBLE_EQ(f.messages()[1].dheading_rad, 0.5 * (0.0 - 0.2) * (t4 - t3));
    f.expectBalanced();
}

TEST(OdometryIntake, VelocityClocksArePerSourceAndAStepEndsTheInterval)
{
    Fixture f;
    f.push(velocity(kT0 + 0.0, 1.0, 0.0), kT0Us, "udp:a");
    f.push(velocity(kT0 + 0.1, 2.0, 0.0), kT0Us, "udp:b"); // another sender: its own clock
    EXPECT_EQ(f.counters.odometry_clock_starts, 2U);
    f.push(velocity(kT0 + 0.5, 1.0, 0.0), kT0Us, "udp:a");
    ASSERT_EQ(f.consumer.received.size(), 1U);
    EXPECT_DOUBLE_EQ(f.messages()[0].distance_m, 0.5);     // 1 m/s over 0.5 s
    f.push(step(kT0 + 0.6, 0.1, 0.0), kT0Us, "udp:a");     // a step covers up to its t ...
    f.push(velocity(kT0 + 0.7, 1.0, 0.0), kT0Us, "udp:a"); // ... so this only starts the clock again
    EXPECT_EQ(f.consumer.received.size(), 2U);
    EXPECT_EQ(f.counters.odometry_clock_starts, 3U);
    f.push(velocity(kT0 + 0.9, 2.0, 0.0), kT0Us, "udp:b");
    ASSERT_EQ(f.consumer.received.size(), 3U);
    EXPECT_DOUBLE_EQ(f.messages()[2].distance_m, 0.5 * (2.0 + 2.0) * ((kT0 + 0.9) - (kT0 + 0.1)));
    f.expectBalanced();
}

TEST(OdometryIntake, AClockStepRestartsTheVelocityClocks)
{
    Fixture f;
    f.push(velocity(kT0 + 10.0, 1.0, 0.0));
    f.push(velocity(kT0 + 10.5, 1.0, 0.0));
    EXPECT_EQ(f.consumer.received.size(), 1U);
    f.push(velocity(kT0 + 2.0, 1.0, 0.0)); // set back 8.5 s: no interval can be measured across it
    EXPECT_EQ(f.counters.odometry_clock_steps, 1U);
    EXPECT_EQ(f.counters.odometry_clock_starts, 2U);
    EXPECT_EQ(f.consumer.received.size(), 1U);
    f.push(velocity(kT0 + 2.5, 1.0, 0.0));
    ASSERT_EQ(f.consumer.received.size(), 2U);
    EXPECT_DOUBLE_EQ(f.messages()[1].distance_m, 0.5);
    f.expectBalanced();
}

TEST(OdometryIntake, AConvertedStepBeyondTheBoundsIsAbsurdAndTheClockMovesOn)
{
    Fixture f(2.0);
    f.push(velocity(kT0, 19.0, 0.0));
    f.push(velocity(kT0 + 0.75, 19.0, 0.0)); // 14.25 m in one message
    EXPECT_EQ(f.counters.odometry_rejected_absurd, 1U);
    EXPECT_TRUE(f.consumer.received.empty());
    f.push(velocity(kT0 + 0.875, 1.0, 0.0)); // measured from the rejected one
    ASSERT_EQ(f.consumer.received.size(), 1U);
    EXPECT_DOUBLE_EQ(f.messages()[0].distance_m, 0.5 * (19.0 + 1.0) * 0.125);
    f.expectBalanced();
}

TEST(OdometryIntake, SeveralMessagesInOneDatagramOneALine)
{
    Fixture f;
    f.push(step(kT0 + 1, 0.1, 0.0) + "\n" + step(kT0 + 2, 0.2, 0.0) + "\r\n\n  {broken\n");
    EXPECT_EQ(f.counters.odometry_received, 3U);
    EXPECT_EQ(f.counters.odometry_rejected_not_json, 1U);
    ASSERT_EQ(f.consumer.received.size(), 2U);
    EXPECT_EQ(f.messages()[1].distance_m, 0.2);
    f.expectBalanced();
}

TEST(OdometryIntake, AcceptedMessagesAreCapturedAsNormalisedStepsWithTheReceiveTime)
{
    cdro::test::TempDir dir;
    Fixture f;
    CaptureConfig config;
    config.path = dir.file("odo.cdrocap");
    CaptureWriter capture(config, "test", f.counters);
    capture.open(kT0Us);
    f.intake.setCapture(&capture);
    f.push(step(kT0 + 0.5, 0.012, -0.001), kT0Us + 500'100, "udp:127.0.0.1:40000");
    f.push("garbage", kT0Us + 600'000);
    f.push(velocity(kT0 + 0.75, 0.5, 0.0), kT0Us + 750'100, "mqtt:cdro/odometry");
    f.push(velocity(kT0 + 1.0, 0.5, 0.2), kT0Us + 1'000'100, "mqtt:cdro/odometry");
    f.push(R"({"distance_m": 0.25, "dheading_rad": 0})", kT0Us + 1'250'000, "udp:127.0.0.1:40000");
    capture.close();

    const auto records = readCapture(config.path);
    ASSERT_EQ(records.size(), 3U); // neither the garbage nor the clock start
    for (const CaptureRecord &r : records) {
        EXPECT_EQ(r.flags, CDRO_CAPTURE_FLAG_ODOMETRY);
        EXPECT_TRUE(r.odometry());
        EXPECT_FALSE(r.toDevice());
    }
    EXPECT_EQ(records[0].host_time_us, kT0Us + 500'100);
    EXPECT_EQ(std::string(records[0].data.begin(), records[0].data.end()),
              R"({"t":1764600000.5,"distance_m":0.012,"dheading_rad":-0.001,"source":"udp:127.0.0.1:40000"})");
    const auto converted = nlohmann::json::parse(records[1].data);
    EXPECT_EQ(converted["t"].get<double>(), kT0 + 1.0);
    EXPECT_EQ(converted["distance_m"].get<double>(), f.messages()[1].distance_m); // the step, bit for bit
    EXPECT_EQ(converted["dheading_rad"].get<double>(), f.messages()[1].dheading_rad);
    EXPECT_EQ(converted["source"], "mqtt:cdro/odometry");
    const auto defaulted = nlohmann::json::parse(records[2].data);
    EXPECT_EQ(defaulted["t"].get<double>(), static_cast<double>(kT0Us + 1'250'000) / 1e6); // recorded, not re-derived
}

TEST(OdometryIntake, TheNormalisedTextIsTheGoldenVectorsOne)
{
    // tests/golden/vectors.json holds it for the Python codec and cdro-decode.
    std::ifstream in(std::string(CDRO_SOURCE_DIR) + "/tests/golden/vectors.json");
    const nlohmann::json vectors = nlohmann::json::parse(in);
    const auto &capture = vectors["capture"];
    const std::string hex = capture["records"][capture["odometry"]["record"].get<size_t>()]["data"];
    std::string golden;
    for (size_t i = 0; i + 1 < hex.size(); i += 2) {
        golden += static_cast<char>(std::stoi(hex.substr(i, 2), nullptr, 16));
    }
    EXPECT_EQ(normaliseOdometry({1795046400.225, 0.012, -0.001}, "udp:127.0.0.1:40000"), golden);
}

TEST(OdometryIntake, RecordedMessagesAreDeliveredAsRecorded)
{
    Fixture f;
    const std::string first = normaliseOdometry({kT0 + 5.0, 0.1, 0.01}, "udp:x");
    const std::string earlier = normaliseOdometry({kT0 + 4.5, 0.2, 0.02}, "udp:x");
    f.intake.pushRecorded(reinterpret_cast<const uint8_t *>(first.data()), first.size(), kT0Us + 5'000'000);
    // A replay does not judge the order again: the capture holds what the live run accepted.
    f.intake.pushRecorded(reinterpret_cast<const uint8_t *>(earlier.data()), earlier.size(), kT0Us + 5'100'000);
    ASSERT_EQ(f.consumer.received.size(), 2U);
    EXPECT_EQ(f.messages()[1].t_s, kT0 + 4.5);
    EXPECT_EQ(f.messages()[1].distance_m, 0.2);
    EXPECT_EQ(f.intake.lastEventUnixUs(), kT0Us + 5'100'000);
    // A damaged or hand-made record never hands the consumer something it could not get live.
    const std::string bad[] = {"{\"t\":1764600000,\"v_mps\":1,\"omega_radps\":0}",
                               "{\"distance_m\":0.1,\"dheading_rad\":0}",
                               "{\"t\":1764600000,\"distance_m\":99,"
                               "\"dheading_rad\":0}",
                               "\x01\x02"};
    for (const std::string &text : bad) {
        f.intake.pushRecorded(reinterpret_cast<const uint8_t *>(text.data()), text.size(), kT0Us + 6'000'000);
    }
    EXPECT_EQ(f.consumer.received.size(), 2U);
    EXPECT_EQ(f.counters.odometry_rejected_field, 2U);
    EXPECT_EQ(f.counters.odometry_rejected_absurd, 1U);
    EXPECT_EQ(f.counters.odometry_rejected_not_json, 1U);
    f.expectBalanced();
}

// ---- UDP on a real loopback socket -----------------------------------------------------------

TEST(OdometryUdp, DatagramsOnLoopbackReachTheConsumerWithTheReceiveTime)
{
    SystemClock clock;
    EventLoop loop(clock);
    ServiceCounters counters;
    OdometryConfig config;
    OdometryIntake intake(config, 1000.0, counters, clock);
    cdro::test::RecordingConsumer consumer;
    intake.setConsumer(&consumer);
    cdro::test::TempDir dir;
    CaptureConfig capture_config;
    capture_config.path = dir.file("udp.cdrocap");
    CaptureWriter capture(capture_config, "test", counters);
    capture.open(clock.unixUs());
    intake.setCapture(&capture);
    OdometryUdpSource source(loop, "127.0.0.1", 0, intake);
    int bursts = 0;
    source.setAfterBurst([&] { ++bursts; });
    source.start();
    ASSERT_NE(source.port(), 0);
    EXPECT_EQ(source.description(), "udp:127.0.0.1:" + std::to_string(source.port()));

    UdpSender sender;
    const int64_t before_us = clock.unixUs();
    sender.send(source.port(), R"({"distance_m": 0.05, "dheading_rad": 0.01})");
    sender.send(source.port(), "no json");
    sender.send(source.port(), R"({"distance_m": 0.07, "dheading_rad": -0.01})");
    runUntil(loop, [&] { return counters.odometry_received == 3; });
    const int64_t after_us = clock.unixUs();
    ASSERT_EQ(consumer.received.size(), 2U);
    EXPECT_EQ(counters.odometry_rejected_not_json, 1U);
    EXPECT_GE(consumer.received[0].odometry.t_s, static_cast<double>(before_us) / 1e6);
    EXPECT_LE(consumer.received[1].odometry.t_s, static_cast<double>(after_us) / 1e6);
    EXPECT_LE(consumer.received[0].odometry.t_s, consumer.received[1].odometry.t_s);
    EXPECT_EQ(consumer.received[1].odometry.distance_m, 0.07);
    EXPECT_GE(bursts, 1);
    capture.close();
    const auto records = readCapture(capture_config.path);
    ASSERT_EQ(records.size(), 2U);
    EXPECT_EQ(nlohmann::json::parse(records[0].data)["source"], "udp:127.0.0.1:" + std::to_string(sender.port()));
}

TEST(OdometryUdp, AFloodIsDrainedInBoundedBursts)
{
    SystemClock clock;
    EventLoop loop(clock);
    ServiceCounters counters;
    OdometryIntake intake(OdometryConfig{}, 1000.0, counters, clock);
    OdometryUdpSource source(loop, "127.0.0.1", 0, intake);
    source.start();
    UdpSender sender;
    constexpr int kSent = 80; // small datagrams: all fit in the socket's default buffer
    for (int i = 0; i < kSent; ++i) {
        sender.send(source.port(), R"({"distance_m": 0.01, "dheading_rad": 0})");
    }
    // Loopback delivery is synchronous: all of them are queued before the loop looks.
    loop.runOnce(1'000'000);
    EXPECT_EQ(source.datagrams(), static_cast<uint64_t>(OdometryUdpSource::kBurstDatagrams));
    runUntil(loop, [&] { return source.datagrams() == static_cast<uint64_t>(kSent); });
    EXPECT_EQ(counters.odometry_accepted, static_cast<uint64_t>(kSent));
}

TEST(OdometryUdp, ABusyPortOrABadAddressIsAClearError)
{
    SystemClock clock;
    EventLoop loop(clock);
    ServiceCounters counters;
    OdometryIntake intake(OdometryConfig{}, 1000.0, counters, clock);
    OdometryUdpSource first(loop, "127.0.0.1", 0, intake);
    first.start();
    OdometryUdpSource second(loop, "127.0.0.1", first.port(), intake);
    try {
        second.start();
        FAIL() << "a second socket on the same port";
    } catch (const ConfigError &error) {
        const std::string message = error.what();
        EXPECT_NE(message.find("cannot listen for UDP on 127.0.0.1:" + std::to_string(first.port())), std::string::npos)
            << message;
        EXPECT_NE(message.find("in use"), std::string::npos) << message;
    }
    OdometryUdpSource named(loop, "localhost", 0, intake);
    try {
        named.start();
        FAIL() << "a host name";
    } catch (const ConfigError &error) {
        EXPECT_NE(std::string(error.what()).find("not a numeric IPv4 or IPv6 address"), std::string::npos);
    }
}

// ---- MQTT through a real broker --------------------------------------------------------------

namespace {

// Publishes like the robot's software would, on libmosquitto's own thread.
class MqttSender {
public:
    explicit MqttSender(uint16_t port)
    {
        mosquitto_lib_init();
        mosq_ = mosquitto_new(nullptr, true, this);
        mosquitto_connect_callback_set(mosq_, [](struct mosquitto *, void *self, int rc) {
            auto *s = static_cast<MqttSender *>(self);
            std::lock_guard<std::mutex> lock(s->mutex_);
            s->connected_ = rc == 0;
            s->changed_.notify_all();
        });
        mosquitto_publish_callback_set(mosq_, [](struct mosquitto *, void *self, int) {
            auto *s = static_cast<MqttSender *>(self);
            std::lock_guard<std::mutex> lock(s->mutex_);
            ++s->published_;
            s->changed_.notify_all();
        });
        mosquitto_connect(mosq_, "127.0.0.1", port, 30);
        mosquitto_loop_start(mosq_);
        std::unique_lock<std::mutex> lock(mutex_);
        changed_.wait_for(lock, std::chrono::seconds(20), [&] { return connected_; });
    }
    ~MqttSender()
    {
        mosquitto_disconnect(mosq_);
        mosquitto_loop_stop(mosq_, false);
        mosquitto_destroy(mosq_);
    }
    // Waits (deadlock guard) until the broker acknowledged it (QoS 1).
    bool publish(const std::string &topic, const std::string &payload, bool retain)
    {
        std::unique_lock<std::mutex> lock(mutex_);
        const int before = published_;
        if (mosquitto_publish(mosq_, nullptr, topic.c_str(), static_cast<int>(payload.size()), payload.data(), 1,
                              retain) != MOSQ_ERR_SUCCESS) {
            return false;
        }
        return changed_.wait_for(lock, std::chrono::seconds(20), [&] { return published_ > before; });
    }

private:
    struct mosquitto *mosq_ = nullptr;
    std::mutex mutex_;
    std::condition_variable changed_;
    bool connected_ = false;
    int published_ = 0;
};

} // namespace

TEST(OdometryMqtt, TheTopicIsSubscribedAndResubscribedAfterTheBrokerReturns)
{
    const uint16_t port = cdro::test::freeLoopbackPort();
    auto broker = std::make_unique<cdro::test::Broker>(port);
    const std::string topic = "lab/odometry";
    {
        // Left on the broker before the service comes: an old step it must not take.
        MqttSender early(port);
        ASSERT_TRUE(early.publish(topic, step(kT0, 5.0, 0.0), true));
    }
    SystemClock clock;
    EventLoop loop(clock);
    ServiceCounters counters;
    MqttConfig config;
    config.url = "mqtt://127.0.0.1:" + std::to_string(port);
    config.topic_prefix = "lab";
    config.qos = 1;
    config.reconnect_min_s = 0.05;
    config.reconnect_max_s = 0.2;
    OdometryIntake intake(OdometryConfig{}, 1000.0, counters, clock);
    cdro::test::RecordingConsumer consumer;
    intake.setConsumer(&consumer);
    MqttPublisher client(loop, config, counters);
    std::vector<std::string> sources;
    client.subscribe(topic, [&](const std::string &name, const char *payload, size_t len) {
        sources.push_back(name);
        intake.push("mqtt:" + name, payload, len, clock.unixUs());
    });
    client.start();
    runUntil(loop, [&] { return client.connected() && client.subscriptionsAcknowledged() == 1; });
    runUntil(loop, [&] { return counters.mqtt_received >= 1; }); // the retained one arrives first
    EXPECT_TRUE(consumer.received.empty());
    EXPECT_EQ(counters.odometry_received, 0U);

    MqttSender robot(port);
    ASSERT_TRUE(robot.publish(topic, step(kT0 + 1.0, 0.25, 0.0), false));
    ASSERT_TRUE(robot.publish("lab/other", step(kT0 + 1.5, 9.0, 0.0), false)); // not subscribed
    runUntil(loop, [&] { return consumer.received.size() == 1; });
    EXPECT_EQ(consumer.received[0].odometry.distance_m, 0.25);
    EXPECT_EQ(sources, std::vector<std::string>{topic});

    broker->kill();
    runUntil(loop, [&] { return !client.connected(); });
    broker = std::make_unique<cdro::test::Broker>(port); // back, without the old session
    runUntil(loop, [&] { return client.connected() && client.subscriptionsAcknowledged() == 1; });
    MqttSender again(port);
    ASSERT_TRUE(again.publish(topic, step(kT0 + 2.0, 0.5, 0.1) + "\n" + "{\"v_mps\": 1}", false));
    runUntil(loop, [&] { return counters.odometry_received == 3; });
    ASSERT_EQ(consumer.received.size(), 2U);
    EXPECT_EQ(consumer.received[1].odometry.t_s, kT0 + 2.0);
    EXPECT_EQ(counters.odometry_rejected_field, 1U);
    EXPECT_EQ(counters.mqtt_connects, 2U);
    client.shutdown();
}

// ---- the service: live capture, then replay ---------------------------------------------------

namespace {

ServiceConfig quietConfig(const cdro::test::TempDir &dir)
{
    ServiceConfig config;
    config.serial.device = dir.file("ttyPOZYX");
    config.serial.reconnect_min_s = 0.05;
    config.serial.reconnect_max_s = 0.2;
    config.nodes.ids = {0x6069, 0x6A11}; // the device's list: the frames below name these
    config.capture.path = dir.file("live.cdrocap");
    config.output.jsonl = "";
    config.output.health_period_s = 0.0;
    config.http.port = 0;
    config.checkpoint.path = "";
    return config;
}

} // namespace

TEST(OdometryService, ALiveRunReplaysWithFramesAndOdometryInTheSameOrderWithTheSameValues)
{
    cdro::test::TempDir dir;
    ServiceConfig config = quietConfig(dir);
    config.odometry.udp_port = cdro::test::freeLoopbackUdpPort();
    cdro::test::FakeDevicePty device(config.serial.device);
    SystemClock clock;
    cdro::test::RecordingConsumer live;
    {
        Service service(config, RunOptions{}, {&live, nullptr, nullptr, &live}, clock);
        service.start();
        ASSERT_EQ(service.odometryUdpPort(), config.odometry.udp_port);
        UdpSender robot;
        runUntil(service.loop(), [&] { return service.counters().link_connects == 1; });
        // Frames and odometry alternate; each waits for the one before to be taken, so the
        // order of arrival is the order written here.
        uint16_t sequence = 0;
        const auto frame = [&](const cdro_frame_t &f) {
            const size_t before = live.received.size();
            device.write(encode(f));
            runUntil(service.loop(), [&] { return live.received.size() == before + 1; });
        };
        const auto range = [&] {
            ++sequence;
            frame(rangeFrame(sequence, 10U + 20U * sequence, 0x6000, 0x6069, 3000U + sequence));
        };
        const auto odometry = [&](const std::string &text) {
            const uint64_t before = service.counters().odometry_received;
            robot.send(config.odometry.udp_port, text);
            runUntil(service.loop(), [&] { return service.counters().odometry_received == before + 1; });
        };
        // Explicit times from 10 minutes after now (longer than any deadlock guard): later than
        // the first message's receive time however slowly it is read.
        const double base_s = static_cast<double>(clock.unixUs()) / 1e6 + 600.0;
        frame(helloFrame(0, 10));
        range();
        odometry(R"({"distance_m": 0.02, "dheading_rad": 0.003})"); // t: the receive time
        range();
        odometry(velocity(base_s, 0.3, 0.05)); // starts the clock only
        range();
        odometry(velocity(base_s + 0.5, 0.5, 0.05));
        range();
        odometry(step(base_s + 0.75, 0.125, -0.01));
        range();
        range();
        odometry("{\"distance_m\": \"far\"}"); // dropped, not captured
        range();
        odometry(step(base_s + 1.0, 0.25, 0.0));
        range();
        EXPECT_EQ(service.counters().odometry_accepted, 4U);
        EXPECT_EQ(service.counters().odometry_clock_starts, 1U);
        EXPECT_EQ(service.counters().odometry_rejected_field, 1U);
    }
    std::vector<std::string> kinds;
    for (const auto &r : live.received) {
        kinds.push_back(r.kind);
    }
    ASSERT_EQ(std::count(kinds.begin(), kinds.end(), "odometry"), 4);
    ASSERT_EQ(std::count(kinds.begin(), kinds.end(), "range"), 8);

    // The capture holds the odometry records between the frames, in delivery order.
    const auto records = readCapture(config.capture.path);
    EXPECT_EQ(std::count_if(records.begin(), records.end(), [](const CaptureRecord &r) { return r.odometry(); }), 4);

    ServiceConfig replay_config = quietConfig(dir);
    replay_config.capture.path = dir.file("not-written.cdrocap");
    RunOptions run;
    run.replay_path = config.capture.path;
    cdro::test::RecordingConsumer replayed;
    {
        Service service(replay_config, run, {&replayed, nullptr, nullptr, &replayed}, clock);
        service.start();
        EXPECT_EQ(service.odometryUdpPort(), 0); // no live input during a replay
        service.run();                           // returns at the end of the capture
        EXPECT_EQ(service.counters().replay_odometry_records, 4U);
        EXPECT_EQ(service.counters().odometry_accepted, 4U);
    }
    ASSERT_EQ(replayed.received.size(), live.received.size());
    for (size_t i = 0; i < live.received.size(); ++i) {
        const auto &a = live.received[i];
        const auto &b = replayed.received[i];
        ASSERT_EQ(a.kind, b.kind) << i;
        EXPECT_EQ(a.context.host_unix_us, b.context.host_unix_us) << i;
        EXPECT_EQ(a.context.sequence, b.context.sequence) << i;
        // Bit for bit: compare the doubles with ==, not with a tolerance.
        EXPECT_EQ(a.odometry.t_s, b.odometry.t_s) << i;
        EXPECT_EQ(a.odometry.distance_m, b.odometry.distance_m) << i;
        EXPECT_EQ(a.odometry.dheading_rad, b.odometry.dheading_rad) << i;
        if (a.kind == "range") {
            EXPECT_EQ(a.frame.as.range.distance_mm, b.frame.as.range.distance_mm) << i;
        }
    }
}

TEST(OdometryService, AReplayInterleavesOdometryRecordsExactlyAsCaptured)
{
    cdro::test::TempDir dir;
    const std::string path = dir.file("hand.cdrocap");
    ServiceCounters counters;
    {
        CaptureConfig config;
        config.path = path;
        CaptureWriter writer(config, "test", counters);
        writer.open(kT0Us);
        const auto chunk = [](const cdro_frame_t &frame) {
            std::vector<uint8_t> bytes = encode(frame);
            bytes.pop_back(); // records hold the chunk without its delimiter
            return bytes;
        };
        const auto odometry = [&](int64_t t_us, double d) {
            const std::string text = normaliseOdometry({static_cast<double>(t_us) / 1e6, d, 0.0}, "udp:x");
            writer.append(CDRO_CAPTURE_FLAG_ODOMETRY, t_us, reinterpret_cast<const uint8_t *>(text.data()),
                          text.size());
        };
        auto hello = chunk(helloFrame(0, 5));
        writer.append(0, kT0Us + 1000, hello.data(), hello.size());
        odometry(kT0Us + 2000, 0.1);
        auto r1 = chunk(rangeFrame(1, 10, 0x6000, 0x6069, 2000));
        writer.append(0, kT0Us + 3000, r1.data(), r1.size());
        odometry(kT0Us + 3000, 0.2); // the same time as the frame before: order is the file's
        odometry(kT0Us + 4000, 0.3);
        auto r2 = chunk(rangeFrame(2, 20, 0x6000, 0x6069, 2100));
        writer.append(0, kT0Us + 5000, r2.data(), r2.size());
        odometry(kT0Us + 6000, 0.4);
        writer.close();
    }
    ServiceConfig config = quietConfig(dir);
    RunOptions run;
    run.replay_path = path;
    run.replay_speed = 50.0; // paced: the order must not depend on the speed
    cdro::test::RecordingConsumer consumer;
    SystemClock clock;
    Service service(config, run, {&consumer, nullptr, nullptr, &consumer}, clock);
    service.start();
    service.run();
    std::vector<std::string> kinds;
    std::vector<double> distances;
    for (const auto &r : consumer.received) {
        kinds.push_back(r.kind);
        if (r.kind == "odometry") {
            distances.push_back(r.odometry.distance_m);
        }
    }
    EXPECT_EQ(kinds,
              (std::vector<std::string>{"hello", "odometry", "range", "odometry", "odometry", "range", "odometry"}));
    EXPECT_EQ(distances, (std::vector<double>{0.1, 0.2, 0.3, 0.4}));
    EXPECT_EQ(consumer.received[3].odometry.t_s, static_cast<double>(kT0Us + 3000) / 1e6);
}

TEST(OdometryService, AVersion1CaptureStillReplays)
{
    // Written as the service wrote captures before odometry records existed.
    cdro::test::TempDir dir;
    const std::string path = dir.file("old.cdrocap");
    std::vector<uint8_t> file(CDRO_CAPTURE_HEADER_FIXED + CDRO_CAPTURE_MAX_SOURCE);
    cdro_capture_header_t header{};
    header.format_version = 1;
    header.created_unix_us = kT0Us;
    file.resize(cdro_capture_header_encode(&header, file.data(), file.size()));
    ASSERT_GT(file.size(), 0U);
    int64_t t_us = kT0Us;
    for (const cdro_frame_t &frame : {helloFrame(0, 5), rangeFrame(1, 10, 0x6000, 0x6069, 2000)}) {
        std::vector<uint8_t> chunk = encode(frame);
        chunk.pop_back();
        t_us += 1000;
        const cdro_capture_record_t record{0, t_us, static_cast<uint16_t>(chunk.size()), chunk.data()};
        uint8_t bytes[CDRO_CAPTURE_RECORD_OVERHEAD + CDRO_MAX_ENCODED_FRAME];
        const size_t size = cdro_capture_record_encode(&record, bytes, sizeof bytes);
        file.insert(file.end(), bytes, bytes + size);
    }
    std::ofstream(path, std::ios::binary)
        .write(reinterpret_cast<const char *>(file.data()), static_cast<std::streamsize>(file.size()));
    EXPECT_EQ(CaptureReader(path).header().format_version, 1U);

    RunOptions run;
    run.replay_path = path;
    cdro::test::RecordingConsumer consumer;
    SystemClock clock;
    Service service(quietConfig(dir), run, {&consumer, nullptr, nullptr, &consumer}, clock);
    service.start();
    service.run();
    ASSERT_EQ(consumer.received.size(), 2U);
    EXPECT_EQ(consumer.received[1].kind, "range");
    EXPECT_EQ(consumer.received[1].context.host_unix_us, kT0Us + 2000);
    EXPECT_EQ(service.counters().replay_odometry_records, 0U);
}
