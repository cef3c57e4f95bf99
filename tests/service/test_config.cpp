// The service's sections of the YAML config: defaults, every key, strictness, CLI overrides.
#include <fstream>

#include <CLI/CLI.hpp>
#include <gtest/gtest.h>

#include "cdro/service/config.hpp"
#include "cdro/service/config_cli.hpp"
#include "support.hpp"

using namespace cdro::service;

namespace {
std::string errorOf(const std::string &yaml)
{
    try {
        parseServiceConfig(yaml, "test.yaml");
    } catch (const ConfigError &error) {
        return error.what();
    }
    return "";
}
} // namespace

TEST(Config, EmptyTextGivesTheDocumentedDefaults)
{
    const ServiceConfig c = parseServiceConfig("", "empty");
    EXPECT_EQ(c.serial.device, "/dev/ttyACM0");
    EXPECT_EQ(c.serial.baud, 115200U);
    EXPECT_DOUBLE_EQ(c.serial.reconnect_min_s, 0.5);
    EXPECT_DOUBLE_EQ(c.serial.reconnect_max_s, 30.0);
    EXPECT_TRUE(c.nodes.ids.empty());
    EXPECT_EQ(c.nodes.unknown, UnknownNodePolicy::Learn);
    EXPECT_EQ(c.schedule.mode, 1);
    EXPECT_EQ(c.schedule.status_period_ms, 1000);
    EXPECT_EQ(c.capture.path, "capture.cdrocap");
    EXPECT_EQ(c.output.jsonl, "-");
    EXPECT_TRUE(c.mqtt.url.empty());
    EXPECT_EQ(c.http.bind, "127.0.0.1");
    EXPECT_EQ(c.http.port, 8080);
    EXPECT_EQ(c.checkpoint.path, "checkpoint.cdrosog");
    EXPECT_EQ(c.logging.level, "info");
}

TEST(Config, TheExampleFileParsesAndSetsEveryKey)
{
    const ServiceConfig c = loadServiceConfig(std::string(CDRO_SOURCE_DIR) + "/config/cdro-hostd.example.yaml");
    EXPECT_FALSE(c.serial.device.empty());
    EXPECT_EQ(c.nodes.ids.size(), 7U);
    EXPECT_EQ(c.mqtt.url, "mqtt://127.0.0.1:1883");
    EXPECT_EQ(odometryMqttTopic(c), "cdro/odometry");
    EXPECT_EQ(c.odometry.udp_port, 0);
}

TEST(Config, ReadsEveryKeyOfEverySection)
{
    const ServiceConfig c = parseServiceConfig(R"(
serial: {device: /dev/ttyUSB3, baud: 230400, reconnect_min_s: 0.25, reconnect_max_s: 8,
         hello_timeout_s: 1.5, hello_retries: 4, command_timeout_s: 0.5, command_retries: 2,
         keepalive_period_s: 0, keepalive_misses: 5}
nodes: {ids: [0x6069, 24593, 0x6A11], unknown: reject}
schedule: {slot_period_ms: 20, mode: direct_only, motion_poll_ms: 0, moving_boost: 4,
           status_period_ms: 500, max_retries: 3}
capture: {path: run.cdrocap, rotate_mib: 2.5, keep: 9}
output: {jsonl: out.jsonl, rate_hz: 5, health_period_s: 2}
mqtt: {url: "mqtt://10.1.2.3:1884", topic_prefix: lab/cdro, qos: 1, client_id: robot-7, keepalive_s: 15,
       rate_hz: 2, reconnect_min_s: 0.1, reconnect_max_s: 3}
http: {bind: 0.0.0.0, port: 0, update_period_s: 0.5, max_event_clients: 3}
checkpoint: {path: state.cdrosog, period_s: 12}
logging: {level: debug, file: service.log, drop_log_per_s: 1}
)",
                                               "all");
    EXPECT_EQ(c.serial.device, "/dev/ttyUSB3");
    EXPECT_EQ(c.serial.baud, 230400U);
    EXPECT_DOUBLE_EQ(c.serial.reconnect_min_s, 0.25);
    EXPECT_EQ(c.serial.hello_retries, 4U);
    EXPECT_EQ(c.serial.command_retries, 2U);
    EXPECT_DOUBLE_EQ(c.serial.keepalive_period_s, 0.0);
    EXPECT_EQ(c.serial.keepalive_misses, 5U);
    EXPECT_EQ(c.nodes.ids, (std::vector<uint16_t>{0x6069, 24593, 0x6A11}));
    EXPECT_EQ(c.nodes.unknown, UnknownNodePolicy::Reject);
    EXPECT_EQ(c.schedule.slot_period_ms, 20);
    EXPECT_EQ(c.schedule.mode, 0);
    EXPECT_EQ(c.schedule.moving_boost, 4);
    EXPECT_EQ(c.schedule.max_retries, 3);
    EXPECT_DOUBLE_EQ(c.capture.rotate_mib, 2.5);
    EXPECT_EQ(c.capture.keep, 9U);
    EXPECT_EQ(c.output.jsonl, "out.jsonl");
    EXPECT_DOUBLE_EQ(c.output.rate_hz, 5.0);
    EXPECT_EQ(c.mqtt.topic_prefix, "lab/cdro");
    EXPECT_EQ(c.mqtt.qos, 1);
    EXPECT_EQ(c.mqtt.client_id, "robot-7");
    EXPECT_EQ(c.http.bind, "0.0.0.0");
    EXPECT_EQ(c.http.port, 0);
    EXPECT_EQ(c.http.max_event_clients, 3U);
    EXPECT_EQ(c.checkpoint.path, "state.cdrosog");
    EXPECT_DOUBLE_EQ(c.checkpoint.period_s, 12.0);
    EXPECT_EQ(c.logging.level, "debug");
    EXPECT_EQ(c.logging.file, "service.log");
}

TEST(Config, UnknownKeyIsRejectedNamingKeyAndSection)
{
    const std::string message = errorOf("serial:\n  device: /dev/x\n  buad: 9600\n");
    EXPECT_NE(message.find("unknown key 'buad'"), std::string::npos) << message;
    EXPECT_NE(message.find("section 'serial'"), std::string::npos) << message;
    EXPECT_NE(message.find("test.yaml:3"), std::string::npos) << message;
}

TEST(Config, EngineAndOtherTopLevelSectionsAreLeftToOtherLayers)
{
    const ServiceConfig c =
        parseServiceConfig("engine: {whatever: 1, nested: {a: b}}\nsimulator: [1, 2]\nserial: {baud: 9600}\n", "x");
    EXPECT_EQ(c.serial.baud, 9600U);
}

TEST(Config, BadValuesAreClearErrors)
{
    EXPECT_NE(errorOf("serial: {baud: fast}").find("serial.baud: expected an integer, got 'fast'"), std::string::npos);
    EXPECT_NE(errorOf("schedule: {moving_boost: 9}").find("schedule.moving_boost: must be between 1 and 8, got 9"),
              std::string::npos);
    // uint8 fields must not wrap (300 would be 44 in a byte).
    EXPECT_NE(errorOf("schedule: {max_retries: 300}").find("max_retries"), std::string::npos);
    EXPECT_NE(errorOf("nodes: {ids: [1, 2, 1]}").find("listed twice"), std::string::npos);
    EXPECT_NE(errorOf("nodes: {ids: [0]}").find("outside 1..65535"), std::string::npos);
    EXPECT_NE(errorOf("nodes: {unknown: maybe}").find("'maybe' is not one of: learn, reject"), std::string::npos);
    EXPECT_NE(errorOf("serial: {reconnect_min_s: 5, reconnect_max_s: 1}").find("reconnect_min_s"), std::string::npos);
    EXPECT_NE(errorOf("mqtt: {url: 'http://x'}").find("mqtt://host[:port]"), std::string::npos);
    EXPECT_NE(errorOf("serial: 3").find("section 'serial' must be a map"), std::string::npos);
    EXPECT_NE(errorOf("serial: {baud: [1").find("not valid YAML"), std::string::npos);
    EXPECT_NE(errorOf("- a\n- b\n").find("map of sections"), std::string::npos);
}

TEST(Config, MqttUrls)
{
    EXPECT_EQ(parseMqttUrl("mqtt://127.0.0.1:1884").port, 1884);
    EXPECT_EQ(parseMqttUrl("mqtt://broker.local").host, "broker.local");
    EXPECT_EQ(parseMqttUrl("mqtt://broker.local").port, 1883);
    EXPECT_THROW(parseMqttUrl("mqtt://:80"), ConfigError);
    EXPECT_THROW(parseMqttUrl("mqtt://host:99999"), ConfigError);
    EXPECT_EQ(parseMqttUrl("mqtts://host").port, 8883); // TLS, mqtt_auth: for its files
    EXPECT_TRUE(parseMqttUrl("mqtts://host:8884").tls);
    EXPECT_FALSE(parseMqttUrl("mqtt://host").tls);
    EXPECT_THROW(parseMqttUrl("ssl://host"), ConfigError);
    EXPECT_THROW(parseMqttUrl("mqtts://"), ConfigError);
}

TEST(Config, MqttAuthNeedsAUserForAPasswordAndTlsForCertificates)
{
    const auto errorOf = [](const std::string &yaml) {
        try {
            parseServiceConfig(yaml, "c.yaml");
        } catch (const ConfigError &error) {
            return std::string(error.what());
        }
        return std::string();
    };
    EXPECT_NE(errorOf("mqtt_auth: {password_file: pw}\n").find("username is empty"), std::string::npos);
    EXPECT_NE(errorOf("mqtt_auth: {cert_file: c.pem}\n").find("go together"), std::string::npos);
    EXPECT_NE(errorOf("mqtt: {url: 'mqtt://b'}\nmqtt_auth: {ca_file: ca.pem}\n").find("mqtts://"), std::string::npos);
    EXPECT_NE(errorOf("mqtt_auth: {usename: x}\n").find("unknown key 'usename'"), std::string::npos);
    EXPECT_EQ(errorOf("mqtt: {url: 'mqtts://b'}\nmqtt_auth: {username: u, password_file: pw, ca_file: ca.pem}\n"), "");
}

TEST(Config, CommandLineOverridesTheFile)
{
    cdro::test::TempDir dir;
    const std::string path = dir.file("c.yaml");
    std::ofstream(path) << "serial: {device: /dev/a, baud: 9600}\nhttp: {port: 9000}\n";
    CLI::App app{"test"};
    ServiceOverrides overrides;
    addServiceOptions(app, overrides);
    const char *argv[] = {"test",     "--config",   path.c_str(), "--device", "/dev/b", "--http-port",          "0",
                          "--replay", path.c_str(), "--speed",    "max",      "--mqtt", "mqtt://127.0.0.1:1999"};
    app.parse(static_cast<int>(std::size(argv)), argv);
    ServiceConfig config = loadServiceConfig(overrides.config_path);
    applyOverrides(config, overrides);
    EXPECT_EQ(config.serial.device, "/dev/b");
    EXPECT_EQ(config.serial.baud, 9600U); // from the file
    EXPECT_EQ(config.http.port, 0);
    EXPECT_EQ(config.mqtt.url, "mqtt://127.0.0.1:1999");
    EXPECT_EQ(overrides.run.replay_path, path);
    EXPECT_DOUBLE_EQ(overrides.run.replay_speed, 0.0);
    EXPECT_DOUBLE_EQ(parseReplaySpeed("2.5"), 2.5);
    EXPECT_THROW(parseReplaySpeed("fast"), ConfigError);
    EXPECT_THROW(parseReplaySpeed("0"), ConfigError);
}

TEST(Config, OdometryDefaultsKeysAndTopic)
{
    const ServiceConfig defaults = parseServiceConfig("", "empty");
    EXPECT_EQ(defaults.odometry.udp_bind, "127.0.0.1");
    EXPECT_EQ(defaults.odometry.udp_port, 0);
    EXPECT_FALSE(defaults.odometry.mqtt_topic.has_value());
    EXPECT_DOUBLE_EQ(defaults.odometry.max_velocity_gap_s, 1.0);
    EXPECT_EQ(odometryMqttTopic(defaults), ""); // no MQTT at all

    const ServiceConfig c = parseServiceConfig(
        "odometry: {udp_bind: '::1', udp_port: 5005, mqtt_topic: robot/7/odom, max_velocity_gap_s: 0.25}\n"
        "mqtt: {url: 'mqtt://127.0.0.1:1883', topic_prefix: lab}\n",
        "odo");
    EXPECT_EQ(c.odometry.udp_bind, "::1");
    EXPECT_EQ(c.odometry.udp_port, 5005);
    EXPECT_EQ(c.odometry.mqtt_topic.value_or("?"), "robot/7/odom");
    EXPECT_DOUBLE_EQ(c.odometry.max_velocity_gap_s, 0.25);
    EXPECT_EQ(odometryMqttTopic(c), "robot/7/odom");

    // Unset: under the prefix; "" (or null): no subscription.
    EXPECT_EQ(odometryMqttTopic(parseServiceConfig("mqtt: {url: 'mqtt://127.0.0.1', topic_prefix: lab}", "x")),
              "lab/odometry");
    EXPECT_EQ(odometryMqttTopic(parseServiceConfig("mqtt: {url: 'mqtt://127.0.0.1'}\nodometry: {mqtt_topic: ''}", "x")),
              "");
    EXPECT_EQ(odometryMqttTopic(parseServiceConfig("mqtt: {url: 'mqtt://127.0.0.1'}\nodometry: {mqtt_topic: ~}", "x")),
              "");
}

TEST(Config, OdometryErrors)
{
    const std::string unknown = errorOf("odometry:\n  udp_prot: 5005\n");
    EXPECT_NE(unknown.find("unknown key 'udp_prot' in section 'odometry'"), std::string::npos) << unknown;
    EXPECT_NE(unknown.find("udp_port"), std::string::npos) << unknown; // the known keys are listed
    EXPECT_NE(errorOf("odometry: {udp_port: 70000}").find("odometry.udp_port: must be between 0 and 65535"),
              std::string::npos);
    EXPECT_NE(errorOf("odometry: {mqtt_topic: 'robots/+/odom'}").find("not a filter"), std::string::npos);
    EXPECT_NE(errorOf("odometry: {mqtt_topic: 'robots/#'}").find("not a filter"), std::string::npos);
    EXPECT_NE(errorOf("odometry: {max_velocity_gap_s: 0}").find("odometry.max_velocity_gap_s"), std::string::npos);
    EXPECT_NE(errorOf("odometry: {udp_port: 5005, udp_bind: ''}").find("odometry.udp_bind is empty"),
              std::string::npos);
    EXPECT_NE(errorOf("odometry: [1]").find("section 'odometry' must be a map"), std::string::npos);
}

TEST(Config, OdometryCommandLine)
{
    CLI::App app{"test"};
    ServiceOverrides overrides;
    addServiceOptions(app, overrides);
    const char *argv[] = {"test",   "--odometry-udp-port",  "5006", "--odometry-mqtt-topic", "robot/odom",
                          "--mqtt", "mqtt://127.0.0.1:1999"};
    app.parse(static_cast<int>(std::size(argv)), argv);
    ServiceConfig config;
    applyOverrides(config, overrides);
    EXPECT_EQ(config.odometry.udp_port, 5006);
    EXPECT_EQ(odometryMqttTopic(config), "robot/odom");

    CLI::App off{"test"};
    ServiceOverrides none;
    addServiceOptions(off, none);
    const char *argv_off[] = {"test", "--odometry-mqtt-topic", "", "--mqtt", "mqtt://127.0.0.1:1999"};
    off.parse(static_cast<int>(std::size(argv_off)), argv_off);
    ServiceConfig quiet;
    applyOverrides(quiet, none);
    EXPECT_EQ(odometryMqttTopic(quiet), "");

    CLI::App bad{"test"};
    ServiceOverrides wild;
    addServiceOptions(bad, wild);
    const char *argv_bad[] = {"test", "--odometry-mqtt-topic", "a/#"};
    bad.parse(static_cast<int>(std::size(argv_bad)), argv_bad);
    ServiceConfig config_bad;
    EXPECT_THROW(applyOverrides(config_bad, wild), ConfigError);
}

namespace {
// A PNG's first 24 bytes (signature, IHDR length and type, width, height) and a little more.
void writePngHeader(const std::string &path, uint32_t width_px, uint32_t height_px)
{
    std::string bytes = std::string("\x89PNG\r\n\x1A\n", 8) + std::string("\0\0\0\x0DIHDR", 8);
    for (const uint32_t v : {width_px, height_px}) {
        for (int shift = 24; shift >= 0; shift -= 8) {
            bytes.push_back(static_cast<char>((v >> shift) & 0xFFU));
        }
    }
    bytes += std::string("\x08\x02\0\0\0", 5);
    std::ofstream(path, std::ios::binary) << bytes;
}
} // namespace

TEST(Config, WebFloorPlanKeysAndItsImage)
{
    cdro::test::TempDir dir;
    const std::string png = dir.file("plan.png");
    writePngHeader(png, 640, 480);
    const ServiceConfig defaults = parseServiceConfig("", "empty");
    EXPECT_TRUE(defaults.web.floor_plan.path.empty());
    EXPECT_DOUBLE_EQ(defaults.web.floor_plan.metres_per_pixel, 0.05);
    const ServiceConfig c = parseServiceConfig("web:\n  floor_plan: {path: " + png +
                                                   ", metres_per_pixel: 0.02, origin_x_m: -3.5, origin_y_m: 2,"
                                                   " rotation_rad: 0.5}\n",
                                               "web.yaml");
    EXPECT_EQ(c.web.floor_plan.path, png);
    EXPECT_DOUBLE_EQ(c.web.floor_plan.metres_per_pixel, 0.02);
    EXPECT_DOUBLE_EQ(c.web.floor_plan.origin_x_m, -3.5);
    EXPECT_DOUBLE_EQ(c.web.floor_plan.origin_y_m, 2.0);
    EXPECT_DOUBLE_EQ(c.web.floor_plan.rotation_rad, 0.5);
    const FloorPlanImage image = readFloorPlan(png);
    EXPECT_EQ(image.width_px, 640U);
    EXPECT_EQ(image.height_px, 480U);
    EXPECT_EQ(image.png.size(), 29U);
}

TEST(Config, AFloorPlanThatCannotBeUsedIsAnErrorNamingTheKey)
{
    cdro::test::TempDir dir;
    const auto errorWith = [&](const std::string &path) { return errorOf("web: {floor_plan: {path: " + path + "}}"); };
    EXPECT_NE(errorWith(dir.file("missing.png")).find("web.floor_plan.path: cannot read '" + dir.file("missing.png")),
              std::string::npos);
    std::ofstream(dir.file("text.png")) << "just some text, more than twenty-four bytes of it";
    EXPECT_NE(errorWith(dir.file("text.png")).find("is not a PNG image"), std::string::npos);
    std::ofstream(dir.file("short.png"), std::ios::binary) << std::string("\x89PNG\r\n\x1A\n", 8);
    EXPECT_NE(errorWith(dir.file("short.png")).find("is not a PNG image"), std::string::npos);
    writePngHeader(dir.file("huge.png"), 20000, 10);
    EXPECT_NE(errorWith(dir.file("huge.png")).find("20000 x 10 px"), std::string::npos);
    writePngHeader(dir.file("empty.png"), 0, 10);
    EXPECT_NE(errorWith(dir.file("empty.png")).find("0 x 10 px"), std::string::npos);
    EXPECT_NE(errorWith(dir.path()).find("web.floor_plan.path"), std::string::npos); // a directory
    EXPECT_NE(errorOf("web: {floor_plan: {pth: x.png}}").find("unknown key 'pth' in section 'web.floor_plan'"),
              std::string::npos);
    EXPECT_NE(errorOf("web: {floorplan: {}}").find("unknown key 'floorplan' in section 'web'"), std::string::npos);
    EXPECT_NE(errorOf("web: {floor_plan: {metres_per_pixel: 0}}").find("web.floor_plan.metres_per_pixel"),
              std::string::npos);
}
