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
    EXPECT_THROW(parseMqttUrl("mqtts://host"), ConfigError);
}

TEST(Config, CommandLineOverridesTheFile)
{
    cdro::test::TempDir dir;
    const std::string path = dir.file("c.yaml");
    std::ofstream(path) << "serial: {device: /dev/a, baud: 9600}\nhttp: {port: 9000}\n";
    CLI::App app{"test"};
    ServiceOverrides overrides;
    addServiceOptions(app, overrides);
    const char *argv[] = {"test", "--config", path.c_str(), "--device", "/dev/b", "--http-port", "0", "--replay",
                          path.c_str(), "--speed", "max", "--mqtt", "mqtt://127.0.0.1:1999"};
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
