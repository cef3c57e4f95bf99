#include "cdro/service/config.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>
#include <set>
#include <sstream>
#include <type_traits>

#include <sys/stat.h>

#include <yaml-cpp/yaml.h>

#include "cdro/frames.h"
#include "cdro/service/yaml_section.hpp"

namespace cdro::service {

namespace {

constexpr double kMaxSeconds = 86400.0; // s; a day is more than any timeout needs

void parseSerial(Section &s, SerialConfig &c)
{
    s.readString("device", c.device);
    s.read<uint32_t>("baud", c.baud, 50, 4000000);
    s.read<double>("reconnect_min_s", c.reconnect_min_s, 0.001, kMaxSeconds);
    s.read<double>("reconnect_max_s", c.reconnect_max_s, 0.001, kMaxSeconds);
    s.read<double>("hello_timeout_s", c.hello_timeout_s, 0.001, kMaxSeconds);
    s.read<uint32_t>("hello_retries", c.hello_retries, 1, 1000);
    s.read<double>("command_timeout_s", c.command_timeout_s, 0.001, kMaxSeconds);
    s.read<uint32_t>("command_retries", c.command_retries, 0, 1000);
    s.read<double>("keepalive_period_s", c.keepalive_period_s, 0.0, kMaxSeconds);
    s.read<uint32_t>("keepalive_misses", c.keepalive_misses, 1, 1000);
}

void parseNodes(Section &s, NodesConfig &c)
{
    s.readIds("ids", c.ids);
    size_t policy = c.unknown == UnknownNodePolicy::Learn ? 0 : 1;
    s.readChoice("unknown", {"learn", "reject"}, policy);
    c.unknown = policy == 0 ? UnknownNodePolicy::Learn : UnknownNodePolicy::Reject;
}

void parseSchedule(Section &s, ScheduleConfig &c)
{
    s.read<uint16_t>("slot_period_ms", c.slot_period_ms, 0, 60000);
    size_t mode = c.mode;
    s.readChoice("mode", {"direct_only", "all_pairs"}, mode);
    c.mode = static_cast<uint8_t>(mode);
    s.read<uint16_t>("motion_poll_ms", c.motion_poll_ms, 0, 60000);
    s.read<uint8_t>("moving_boost", c.moving_boost, 1, 8);
    s.read<uint16_t>("status_period_ms", c.status_period_ms, 100, 60000);
    s.read<uint8_t>("max_retries", c.max_retries, 0, 10);
}

void parseCapture(Section &s, CaptureConfig &c)
{
    s.readString("path", c.path);
    s.read<double>("rotate_mib", c.rotate_mib, 0.01, 1024.0 * 1024.0);
    s.read<uint32_t>("keep", c.keep, 0, 10000);
}

void parseOutput(Section &s, OutputConfig &c)
{
    s.readString("jsonl", c.jsonl);
    s.read<double>("rate_hz", c.rate_hz, 0.0, 1000.0);
    s.read<double>("health_period_s", c.health_period_s, 0.0, kMaxSeconds);
}

void parseJsonl(Section &s, JsonlLimits &c)
{
    s.read<double>("rotate_mib", c.rotate_mib, 0.01, 1024.0 * 1024.0);
    s.read<uint32_t>("keep", c.keep, 0, 10000);
    s.read<double>("max_node_rate_hz", c.max_node_rate_hz, 0.0, 1000.0);
}

void parseMqttAuth(Section &s, MqttAuthConfig &c)
{
    s.readString("username", c.username);
    s.readString("password_file", c.password_file);
    s.readString("ca_file", c.ca_file);
    s.readString("cert_file", c.cert_file);
    s.readString("key_file", c.key_file);
}

void parseMqtt(Section &s, MqttConfig &c)
{
    s.readString("url", c.url);
    s.readString("topic_prefix", c.topic_prefix);
    s.read<int>("qos", c.qos, 0, 2);
    s.readString("client_id", c.client_id);
    s.read<uint32_t>("keepalive_s", c.keepalive_s, 5, 65535);
    s.read<double>("rate_hz", c.rate_hz, 0.0, 1000.0);
    s.read<double>("reconnect_min_s", c.reconnect_min_s, 0.01, kMaxSeconds);
    s.read<double>("reconnect_max_s", c.reconnect_max_s, 0.01, kMaxSeconds);
}

void parseHttp(Section &s, HttpConfig &c)
{
    s.readString("bind", c.bind);
    s.read<uint16_t>("port", c.port, 0, 65535);
    s.read<double>("update_period_s", c.update_period_s, 0.0, kMaxSeconds);
    s.read<uint32_t>("max_event_clients", c.max_event_clients, 1, 64);
}

void parseCheckpoint(Section &s, CheckpointConfig &c)
{
    s.readString("path", c.path);
    s.read<double>("period_s", c.period_s, 0.0, kMaxSeconds);
}

void parseOdometry(Section &s, OdometryConfig &c)
{
    s.readString("udp_bind", c.udp_bind);
    s.read<uint16_t>("udp_port", c.udp_port, 0, 65535);
    if (s.child("mqtt_topic")) {
        std::string topic;
        s.readString("mqtt_topic", topic);
        c.mqtt_topic = topic;
    }
    s.read<double>("max_velocity_gap_s", c.max_velocity_gap_s, 0.001, 3600.0);
}

void parseLogging(Section &s, LoggingConfig &c)
{
    size_t level = 2;
    const std::vector<std::string> levels = {"trace", "debug", "info", "warn", "error", "critical", "off"};
    for (size_t i = 0; i < levels.size(); ++i) {
        if (levels[i] == c.level) {
            level = i;
        }
    }
    s.readChoice("level", levels, level);
    c.level = levels[level];
    s.readString("file", c.file);
    s.read<double>("drop_log_per_s", c.drop_log_per_s, 0.0, 1e6);
}

void parseWeb(Section &s, WebConfig &c)
{
    const YAML::Node node = s.child("floor_plan");
    Section plan(node, s.name() + ".floor_plan", s.origin());
    plan.readString("path", c.floor_plan.path);
    plan.read<double>("metres_per_pixel", c.floor_plan.metres_per_pixel, 1e-6, 1e3);
    plan.read<double>("origin_x_m", c.floor_plan.origin_x_m, -1e6, 1e6);
    plan.read<double>("origin_y_m", c.floor_plan.origin_y_m, -1e6, 1e6);
    plan.read<double>("rotation_rad", c.floor_plan.rotation_rad, -7.0, 7.0);
    plan.rejectUnknownKeys();
}

// The PNG signature and the IHDR chunk that must follow it (ISO/IEC 15948, 5.2 and 11.2.2).
constexpr unsigned char kPngSignature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'};
constexpr size_t kPngHeaderBytes = 24;                  // signature, IHDR length and type, width, height
constexpr uint32_t kMaxFloorPlanPixels = 16384;         // px per side; a browser draws no more
constexpr std::streamoff kMaxFloorPlanBytes = 64 << 20; // bytes; the server keeps the file in memory

FloorPlanImage floorPlan(const std::string &path, bool whole)
{
    const std::string key = "web.floor_plan.path: ";
    struct stat status {};
    if (::stat(path.c_str(), &status) == 0 && !S_ISREG(status.st_mode)) {
        throw ConfigError(key + "'" + path + "' is not a file (a PNG image is needed)");
    }
    std::ifstream in(path, std::ios::binary);
    if (!in) {
        throw ConfigError(key + "cannot read '" + path + "' (missing, or not readable by this user?)");
    }
    in.seekg(0, std::ios::end);
    const std::streamoff size = in.tellg();
    in.seekg(0, std::ios::beg);
    if (size > kMaxFloorPlanBytes) {
        throw ConfigError(key + "'" + path + "' is " + std::to_string(size) + " bytes; at most " +
                          std::to_string(kMaxFloorPlanBytes) + " (scale the image down)");
    }
    std::string bytes(whole ? static_cast<size_t>(std::max<std::streamoff>(size, 0)) : kPngHeaderBytes, '\0');
    in.read(bytes.data(), static_cast<std::streamsize>(bytes.size()));
    bytes.resize(static_cast<size_t>(in.gcount()));
    const auto u8 = [&bytes](size_t i) { return static_cast<unsigned char>(bytes[i]); };
    const auto u32 = [&u8](size_t i) {
        return static_cast<uint32_t>(u8(i)) << 24 | static_cast<uint32_t>(u8(i + 1)) << 16 |
               static_cast<uint32_t>(u8(i + 2)) << 8 | static_cast<uint32_t>(u8(i + 3));
    };
    if (bytes.size() < kPngHeaderBytes || std::memcmp(bytes.data(), kPngSignature, sizeof kPngSignature) != 0 ||
        bytes.compare(12, 4, "IHDR") != 0) {
        throw ConfigError(key + "'" + path + "' is not a PNG image (the floor plan must be a PNG)");
    }
    FloorPlanImage image;
    image.width_px = u32(16);
    image.height_px = u32(20);
    if (image.width_px == 0 || image.height_px == 0 || image.width_px > kMaxFloorPlanPixels ||
        image.height_px > kMaxFloorPlanPixels) {
        throw ConfigError(key + "'" + path + "' is " + std::to_string(image.width_px) + " x " +
                          std::to_string(image.height_px) + " px; each side must be 1.." +
                          std::to_string(kMaxFloorPlanPixels));
    }
    if (whole) {
        image.png = std::move(bytes);
    }
    return image;
}

template <typename Parse, typename Value>
void section(const YAML::Node &root, const char *name, const std::string &origin, Parse parse, Value &value)
{
    const YAML::Node node = root[name];
    Section s(node, name, origin);
    parse(s, value);
    s.rejectUnknownKeys();
}

} // namespace

const std::vector<std::string> &serviceSectionNames()
{
    static const std::vector<std::string> names = {"serial",   "nodes",   "schedule",  "capture", "output",
                                                   "jsonl",    "mqtt",    "mqtt_auth", "http",    "checkpoint",
                                                   "odometry", "logging", "web"};
    return names;
}

FloorPlanImage readFloorPlanHeader(const std::string &path) { return floorPlan(path, false); }

FloorPlanImage readFloorPlan(const std::string &path) { return floorPlan(path, true); }

const char *unknownNodePolicyName(UnknownNodePolicy policy)
{
    return policy == UnknownNodePolicy::Learn ? "learn" : "reject";
}

const char *scheduleModeName(uint8_t mode) { return mode == CDRO_SCHEDULE_DIRECT_ONLY ? "direct_only" : "all_pairs"; }

MqttUrl parseMqttUrl(const std::string &url)
{
    MqttUrl out;
    std::string rest;
    if (url.compare(0, 7, "mqtt://") == 0) {
        rest = url.substr(7);
    } else if (url.compare(0, 8, "mqtts://") == 0) {
        rest = url.substr(8);
        out.tls = true;
        out.port = 8883;
    } else {
        throw ConfigError("mqtt.url: '" + url +
                          "' must look like mqtt://host[:port] or, with TLS, mqtts://host[:port]");
    }
    while (!rest.empty() && rest.back() == '/') {
        rest.pop_back();
    }
    const size_t colon = rest.rfind(':');
    if (colon != std::string::npos && rest.find(']') == std::string::npos) {
        const std::string port_text = rest.substr(colon + 1);
        rest = rest.substr(0, colon);
        char *end = nullptr;
        const long port = std::strtol(port_text.c_str(), &end, 10);
        if (port_text.empty() || *end != '\0' || port < 1 || port > 65535) {
            throw ConfigError("mqtt.url: port '" + port_text + "' in '" + url + "' is not 1..65535");
        }
        out.port = static_cast<uint16_t>(port);
    }
    if (rest.empty() || rest.find('/') != std::string::npos) {
        throw ConfigError("mqtt.url: no host in '" + url + "' (expected mqtt://host[:port] or mqtts://host[:port])");
    }
    out.host = rest;
    return out;
}

void validateServiceConfig(const ServiceConfig &c)
{
    if (c.serial.reconnect_min_s > c.serial.reconnect_max_s) {
        throw ConfigError("serial.reconnect_min_s (" + std::to_string(c.serial.reconnect_min_s) +
                          ") is larger than serial.reconnect_max_s (" + std::to_string(c.serial.reconnect_max_s) + ")");
    }
    if (c.mqtt.reconnect_min_s > c.mqtt.reconnect_max_s) {
        throw ConfigError("mqtt.reconnect_min_s is larger than mqtt.reconnect_max_s");
    }
    if (c.serial.device.empty()) {
        throw ConfigError("serial.device is empty");
    }
    cdro_frame_t frame{};
    frame.type = CDRO_FRAME_SET_SCHEDULE;
    frame.as.set_schedule = {c.schedule.slot_period_ms,   c.schedule.mode,
                             c.schedule.motion_poll_ms,   c.schedule.moving_boost,
                             c.schedule.status_period_ms, c.schedule.max_retries};
    if (cdro_frame_validate(&frame) != CDRO_OK) {
        throw ConfigError("schedule: the values are outside the ranges of SET_SCHEDULE (docs/protocol.md)");
    }
    if (!c.mqtt.url.empty()) {
        parseMqttUrl(c.mqtt.url);
        if (c.mqtt.topic_prefix.empty() || c.mqtt.topic_prefix.find_first_of("#+") != std::string::npos) {
            throw ConfigError("mqtt.topic_prefix '" + c.mqtt.topic_prefix + "' must be non-empty, without # or +");
        }
    }
    const MqttAuthConfig &auth = c.mqtt.auth;
    if (!auth.password_file.empty() && auth.username.empty()) {
        throw ConfigError("mqtt_auth.password_file is set but mqtt_auth.username is empty (a broker takes a password "
                          "only with a user name)");
    }
    if (auth.cert_file.empty() != auth.key_file.empty()) {
        throw ConfigError("mqtt_auth.cert_file and mqtt_auth.key_file go together: a client certificate needs its key");
    }
    if (!c.mqtt.url.empty() && !parseMqttUrl(c.mqtt.url).tls && !(auth.ca_file.empty() && auth.cert_file.empty())) {
        throw ConfigError("mqtt_auth: ca_file or cert_file is set, but mqtt.url '" + c.mqtt.url +
                          "' is not TLS; use mqtts://host[:port]");
    }
    if (c.http.port != 0 && c.http.bind.empty()) {
        throw ConfigError("http.bind is empty");
    }
    if (c.odometry.udp_port != 0 && c.odometry.udp_bind.empty()) {
        throw ConfigError("odometry.udp_bind is empty");
    }
    if (c.odometry.mqtt_topic && c.odometry.mqtt_topic->find_first_of("#+") != std::string::npos) {
        // A filter could match the service's own topics (cdro/#) and feed it its own output.
        throw ConfigError("odometry.mqtt_topic '" + *c.odometry.mqtt_topic +
                          "' must be a topic, not a filter (no # or +)");
    }
    if (!(c.odometry.max_velocity_gap_s > 0.0)) {
        throw ConfigError("odometry.max_velocity_gap_s must be > 0 s");
    }
    if (!c.web.floor_plan.path.empty()) {
        readFloorPlanHeader(c.web.floor_plan.path);
    }
}

std::string odometryMqttTopic(const ServiceConfig &c)
{
    if (c.mqtt.url.empty()) {
        return "";
    }
    return c.odometry.mqtt_topic ? *c.odometry.mqtt_topic : c.mqtt.topic_prefix + "/odometry";
}

ServiceConfig parseServiceConfig(const std::string &yaml_text, const std::string &origin)
{
    YAML::Node root;
    try {
        root = YAML::Load(yaml_text);
    } catch (const YAML::Exception &error) {
        throw ConfigError(origin + ": not valid YAML: " + error.what());
    }
    ServiceConfig config;
    if (!root || root.IsNull()) {
        validateServiceConfig(config);
        return config;
    }
    if (!root.IsMap()) {
        throw ConfigError(origin + ": the configuration must be a map of sections (serial:, nodes:, ...)");
    }
    // engine: and any other section are other layers' business.
    section(root, "serial", origin, parseSerial, config.serial);
    section(root, "nodes", origin, parseNodes, config.nodes);
    section(root, "schedule", origin, parseSchedule, config.schedule);
    section(root, "capture", origin, parseCapture, config.capture);
    section(root, "output", origin, parseOutput, config.output);
    section(root, "jsonl", origin, parseJsonl, config.output.limits);
    section(root, "mqtt", origin, parseMqtt, config.mqtt);
    section(root, "mqtt_auth", origin, parseMqttAuth, config.mqtt.auth);
    section(root, "http", origin, parseHttp, config.http);
    section(root, "checkpoint", origin, parseCheckpoint, config.checkpoint);
    section(root, "odometry", origin, parseOdometry, config.odometry);
    section(root, "logging", origin, parseLogging, config.logging);
    section(root, "web", origin, parseWeb, config.web);
    validateServiceConfig(config);
    return config;
}

std::string serviceConfigYaml(const ServiceConfig &c)
{
    YAML::Emitter out;
    out << YAML::BeginMap;
    const auto begin = [&out](const char *name) { out << YAML::Key << name << YAML::Value << YAML::BeginMap; };
    const auto end = [&out] { out << YAML::EndMap; };
    const auto key = [&out](const char *name, const auto &value) { out << YAML::Key << name << YAML::Value << value; };
    const auto number = [&out](const char *name, double value) {
        // The shortest text that reads back as the same double: 0.1, not 0.10000000000000001.
        char text[32];
        const std::to_chars_result written = std::to_chars(text, text + sizeof text, value);
        out << YAML::Key << name << YAML::Value << std::string(text, written.ptr);
    };
    const auto integer = [&out](const char *name, uint64_t value) { out << YAML::Key << name << YAML::Value << value; };

    begin("serial");
    key("device", c.serial.device);
    integer("baud", c.serial.baud);
    number("reconnect_min_s", c.serial.reconnect_min_s);
    number("reconnect_max_s", c.serial.reconnect_max_s);
    number("hello_timeout_s", c.serial.hello_timeout_s);
    integer("hello_retries", c.serial.hello_retries);
    number("command_timeout_s", c.serial.command_timeout_s);
    integer("command_retries", c.serial.command_retries);
    number("keepalive_period_s", c.serial.keepalive_period_s);
    integer("keepalive_misses", c.serial.keepalive_misses);
    end();
    begin("nodes");
    out << YAML::Key << "ids" << YAML::Value << YAML::Flow << YAML::BeginSeq;
    for (uint16_t id : c.nodes.ids) {
        out << id;
    }
    out << YAML::EndSeq;
    key("unknown", std::string(unknownNodePolicyName(c.nodes.unknown)));
    end();
    begin("schedule");
    integer("slot_period_ms", c.schedule.slot_period_ms);
    key("mode", std::string(scheduleModeName(c.schedule.mode)));
    integer("motion_poll_ms", c.schedule.motion_poll_ms);
    integer("moving_boost", c.schedule.moving_boost);
    integer("status_period_ms", c.schedule.status_period_ms);
    integer("max_retries", c.schedule.max_retries);
    end();
    begin("capture");
    key("path", c.capture.path);
    number("rotate_mib", c.capture.rotate_mib);
    integer("keep", c.capture.keep);
    end();
    begin("output");
    key("jsonl", c.output.jsonl);
    number("rate_hz", c.output.rate_hz);
    number("health_period_s", c.output.health_period_s);
    end();
    begin("jsonl");
    number("rotate_mib", c.output.limits.rotate_mib);
    integer("keep", c.output.limits.keep);
    number("max_node_rate_hz", c.output.limits.max_node_rate_hz);
    end();
    begin("mqtt");
    key("url", c.mqtt.url);
    key("topic_prefix", c.mqtt.topic_prefix);
    integer("qos", static_cast<uint64_t>(c.mqtt.qos));
    key("client_id", c.mqtt.client_id);
    integer("keepalive_s", c.mqtt.keepalive_s);
    number("rate_hz", c.mqtt.rate_hz);
    number("reconnect_min_s", c.mqtt.reconnect_min_s);
    number("reconnect_max_s", c.mqtt.reconnect_max_s);
    end();
    begin("mqtt_auth");
    key("username", c.mqtt.auth.username);
    key("password_file", c.mqtt.auth.password_file);
    key("ca_file", c.mqtt.auth.ca_file);
    key("cert_file", c.mqtt.auth.cert_file);
    key("key_file", c.mqtt.auth.key_file);
    end();
    begin("http");
    key("bind", c.http.bind);
    integer("port", c.http.port);
    number("update_period_s", c.http.update_period_s);
    integer("max_event_clients", c.http.max_event_clients);
    end();
    begin("checkpoint");
    key("path", c.checkpoint.path);
    number("period_s", c.checkpoint.period_s);
    end();
    begin("odometry");
    key("udp_bind", c.odometry.udp_bind);
    integer("udp_port", c.odometry.udp_port);
    // Unset means "<topic_prefix>/odometry": printed as what it stands for.
    key("mqtt_topic", c.odometry.mqtt_topic ? *c.odometry.mqtt_topic : c.mqtt.topic_prefix + "/odometry");
    number("max_velocity_gap_s", c.odometry.max_velocity_gap_s);
    end();
    begin("logging");
    key("level", c.logging.level);
    key("file", c.logging.file);
    number("drop_log_per_s", c.logging.drop_log_per_s);
    end();
    begin("web");
    begin("floor_plan");
    key("path", c.web.floor_plan.path);
    number("metres_per_pixel", c.web.floor_plan.metres_per_pixel);
    number("origin_x_m", c.web.floor_plan.origin_x_m);
    number("origin_y_m", c.web.floor_plan.origin_y_m);
    number("rotation_rad", c.web.floor_plan.rotation_rad);
    end();
    end();
    out << YAML::EndMap;
    return std::string(out.c_str()) + "\n";
}

ServiceConfig loadServiceConfig(const std::string &path)
{
    std::ifstream in(path, std::ios::binary);
    if (!in) {
        throw ConfigError(path + ": cannot read the configuration file");
    }
    std::ostringstream text;
    text << in.rdbuf();
    return parseServiceConfig(text.str(), path);
}

} // namespace cdro::service
