#include "cdro/service/config.hpp"

#include <cmath>
#include <fstream>
#include <limits>
#include <set>
#include <sstream>
#include <type_traits>

#include <yaml-cpp/yaml.h>

#include "cdro/frames.h"

namespace cdro::service {

namespace {

std::string where(const YAML::Node &node, const std::string &origin)
{
    const YAML::Mark mark = node.Mark();
    if (mark.line < 0) {
        return origin;
    }
    return origin + ":" + std::to_string(mark.line + 1);
}

// One section (a YAML map): typed reads by key, and a final check that every key was known.
class Section {
public:
    Section(const YAML::Node &node, std::string name, std::string origin)
        : node_(node), name_(std::move(name)), origin_(std::move(origin))
    {
        if (node_ && !node_.IsNull() && !node_.IsMap()) {
            throw ConfigError(where(node_, origin_) + ": section '" + name_ + "' must be a map of keys");
        }
    }

    // Integers are read as int64 and floats as double, then range-checked, so that a small
    // type never wraps (yaml-cpp would read uint8_t as a character).
    template <typename T> void read(const char *key, T &value, T minimum, T maximum)
    {
        using Wide = std::conditional_t<std::is_floating_point_v<T>, double, int64_t>;
        const YAML::Node item = lookup(key);
        if (!item) {
            return;
        }
        Wide parsed{};
        try {
            parsed = item.as<Wide>();
        } catch (const YAML::Exception &) {
            fail(item, key, std::string("expected ") + (std::is_floating_point_v<T> ? "a number" : "an integer") +
                                ", got '" + scalarText(item) + "'");
        }
        if constexpr (std::is_floating_point_v<T>) {
            if (!std::isfinite(parsed)) {
                fail(item, key, "must be a finite number");
            }
        }
        if (parsed < static_cast<Wide>(minimum) || parsed > static_cast<Wide>(maximum)) {
            std::ostringstream message;
            message << "must be between " << static_cast<Wide>(minimum) << " and " << static_cast<Wide>(maximum)
                    << ", got " << parsed;
            fail(item, key, message.str());
        }
        value = static_cast<T>(parsed);
    }

    void readString(const char *key, std::string &value)
    {
        const YAML::Node item = lookup(key);
        if (!item) {
            return;
        }
        if (item.IsNull()) {
            value.clear();
            return;
        }
        if (!item.IsScalar()) {
            fail(item, key, "expected a string");
        }
        value = item.Scalar();
    }

    void readIds(const char *key, std::vector<uint16_t> &ids)
    {
        const YAML::Node item = lookup(key);
        if (!item) {
            return;
        }
        ids.clear();
        if (item.IsNull()) {
            return;
        }
        if (!item.IsSequence()) {
            fail(item, key, "expected a list of node ids, e.g. [0x6069, 0x6A11]");
        }
        std::set<uint16_t> seen;
        for (const YAML::Node &element : item) {
            int64_t id = 0;
            try {
                id = element.as<int64_t>();
            } catch (const YAML::Exception &) {
                fail(element, key, "node id '" + scalarText(element) + "' is not an integer");
            }
            if (id < 1 || id > 65535) {
                fail(element, key, "node id " + std::to_string(id) + " is outside 1..65535");
            }
            if (!seen.insert(static_cast<uint16_t>(id)).second) {
                fail(element, key, "node id " + std::to_string(id) + " is listed twice");
            }
            ids.push_back(static_cast<uint16_t>(id));
        }
        if (ids.size() > CDRO_MAX_NODES) {
            fail(item, key, std::to_string(ids.size()) + " ids, the protocol carries at most " +
                                std::to_string(CDRO_MAX_NODES));
        }
    }

    // A string key with a fixed set of values; returns the index of the value.
    void readChoice(const char *key, const std::vector<std::string> &choices, size_t &index)
    {
        std::string text;
        if (!lookup(key)) {
            return;
        }
        readString(key, text);
        for (size_t i = 0; i < choices.size(); ++i) {
            if (choices[i] == text) {
                index = i;
                return;
            }
        }
        std::string allowed;
        for (const std::string &choice : choices) {
            allowed += (allowed.empty() ? "" : ", ") + choice;
        }
        fail(lookup(key), key, "'" + text + "' is not one of: " + allowed);
    }

    // Every key of the section must have been read by name.
    void rejectUnknownKeys() const
    {
        if (!node_ || !node_.IsMap()) {
            return;
        }
        for (const auto &entry : node_) {
            const std::string key = entry.first.as<std::string>();
            if (known_.count(key) == 0) {
                std::string allowed;
                for (const std::string &name : known_) {
                    allowed += (allowed.empty() ? "" : ", ") + name;
                }
                throw ConfigError(where(entry.first, origin_) + ": unknown key '" + key + "' in section '" +
                                  name_ + "' (known keys: " + allowed + ")");
            }
        }
    }

private:
    YAML::Node lookup(const char *key)
    {
        known_.insert(key);
        if (!node_ || !node_.IsMap()) {
            return YAML::Node(YAML::NodeType::Undefined);
        }
        for (const auto &entry : node_) {
            if (entry.first.as<std::string>() == key) {
                return entry.second;
            }
        }
        return YAML::Node(YAML::NodeType::Undefined);
    }

    static std::string scalarText(const YAML::Node &item)
    {
        return item.IsScalar() ? item.Scalar() : std::string("(not a scalar)");
    }

    [[noreturn]] void fail(const YAML::Node &item, const char *key, const std::string &why) const
    {
        throw ConfigError(where(item, origin_) + ": " + name_ + "." + key + ": " + why);
    }

    YAML::Node node_;
    std::string name_;
    std::string origin_;
    std::set<std::string> known_;
};

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

template <typename Parse, typename Value>
void section(const YAML::Node &root, const char *name, const std::string &origin, Parse parse, Value &value)
{
    const YAML::Node node = root[name];
    Section s(node, name, origin);
    parse(s, value);
    s.rejectUnknownKeys();
}

} // namespace

const char *unknownNodePolicyName(UnknownNodePolicy policy)
{
    return policy == UnknownNodePolicy::Learn ? "learn" : "reject";
}

const char *scheduleModeName(uint8_t mode) { return mode == CDRO_SCHEDULE_DIRECT_ONLY ? "direct_only" : "all_pairs"; }

MqttUrl parseMqttUrl(const std::string &url)
{
    const std::string scheme = "mqtt://";
    if (url.compare(0, scheme.size(), scheme) != 0) {
        throw ConfigError("mqtt.url: '" + url + "' must look like mqtt://host[:port] (TLS is not supported)");
    }
    std::string rest = url.substr(scheme.size());
    while (!rest.empty() && rest.back() == '/') {
        rest.pop_back();
    }
    MqttUrl out;
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
        throw ConfigError("mqtt.url: no host in '" + url + "' (expected mqtt://host[:port])");
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
    frame.as.set_schedule = {c.schedule.slot_period_ms, c.schedule.mode,         c.schedule.motion_poll_ms,
                             c.schedule.moving_boost,   c.schedule.status_period_ms, c.schedule.max_retries};
    if (cdro_frame_validate(&frame) != CDRO_OK) {
        throw ConfigError("schedule: the values are outside the ranges of SET_SCHEDULE (docs/protocol.md)");
    }
    if (!c.mqtt.url.empty()) {
        parseMqttUrl(c.mqtt.url);
        if (c.mqtt.topic_prefix.empty() || c.mqtt.topic_prefix.find_first_of("#+") != std::string::npos) {
            throw ConfigError("mqtt.topic_prefix '" + c.mqtt.topic_prefix + "' must be non-empty, without # or +");
        }
    }
    if (c.http.port != 0 && c.http.bind.empty()) {
        throw ConfigError("http.bind is empty");
    }
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
    section(root, "mqtt", origin, parseMqtt, config.mqtt);
    section(root, "http", origin, parseHttp, config.http);
    section(root, "checkpoint", origin, parseCheckpoint, config.checkpoint);
    section(root, "logging", origin, parseLogging, config.logging);
    validateServiceConfig(config);
    return config;
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
