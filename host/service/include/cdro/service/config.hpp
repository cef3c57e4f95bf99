// config.hpp: the service's sections of the one YAML configuration file of cdro-hostd.
//
// Owned by cdro_service. The loader reads only the sections below; `engine:` belongs to the
// engine library and is ignored here, as is any other top-level section this layer does not
// know (so that each layer can grow its own). Inside the service's sections, an unknown key
// is an error that names the key and its section: a typo must not silently fall back to a
// default. Every key, its default and unit are documented in docs/service.md.
//
// Values are plain fields, so that the CLI (config_cli.hpp) or a test can set them directly.
#pragma once

#include <cstdint>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace cdro::service {

// A configuration that cannot be used; what() names the section, key and the reason.
class ConfigError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

enum class UnknownNodePolicy { Learn, Reject };

struct SerialConfig {
    std::string device = "/dev/ttyACM0"; // path of the serial device (a symlink is fine)
    uint32_t baud = 115200;              // bit/s, raw 8N1
    double reconnect_min_s = 0.5;        // s, first retry after the device vanished
    double reconnect_max_s = 30.0;       // s, the backoff doubles up to this
    double hello_timeout_s = 2.0;        // s, wait for HELLO before (re)sending HELLO_REQUEST
    uint32_t hello_retries = 5;          // HELLO_REQUESTs before the port is reopened
    double command_timeout_s = 1.0;      // s, wait for the ACK/NACK of a command
    uint32_t command_retries = 3;        // resends of a command before re-handshaking
    double keepalive_period_s = 2.0;     // s between PINGs while running; 0 = off
    uint32_t keepalive_misses = 3;       // unanswered PINGs in a row before re-handshaking
};

struct NodesConfig {
    std::vector<uint16_t> ids; // remote node ids for SET_NODES; empty = keep the
                               // device's discovered list
    UnknownNodePolicy unknown = UnknownNodePolicy::Learn;
};

struct ScheduleConfig {               // the SET_SCHEDULE fields (docs/protocol.md)
    uint16_t slot_period_ms = 0;      // ms between ranging slots; 0 = back to back
    uint8_t mode = 1;                 // 0 = direct_only, 1 = all_pairs
    uint16_t motion_poll_ms = 200;    // ms between accelerometer polls; 0 = off
    uint8_t moving_boost = 2;         // 1..8
    uint16_t status_period_ms = 1000; // ms, 100..60000
    uint8_t max_retries = 1;          // 0..10
};

struct CaptureConfig {
    std::string path = "capture.cdrocap"; // "" = no capture
    double rotate_mib = 64.0;             // MiB; a file is rotated before it grows past this
    uint32_t keep = 5;                    // rotated files kept: path.1 .. path.<keep>
};

// The `jsonl:` section: what keeps a long-running JSON Lines file bounded. A file is appended
// to across restarts (never truncated) and rotated like the capture.
struct JsonlLimits {
    double rotate_mib = 64.0;      // MiB; a file is rotated before it grows past this
    uint32_t keep = 5;             // rotated files kept: path.1 .. path.<keep>
    double max_node_rate_hz = 2.0; // Hz of event time, most lines per node (and robot)
                                   // when output.rate_hz is 0; 0 = a line per update
};

struct OutputConfig {
    std::string jsonl = "-";      // JSON Lines path, "-" = stdout, "" = off
    double rate_hz = 0.0;         // Hz, all nodes at this rate; 0 = a line per update
    double health_period_s = 1.0; // s of event time between health lines; 0 = off
    JsonlLimits limits;           // the `jsonl:` section
};

// The `mqtt_auth:` section: credentials and TLS for the broker of mqtt.url.
struct MqttAuthConfig {
    std::string username;      // "" = connect without credentials
    std::string password_file; // first line is the password; "" = none (needs username)
    std::string ca_file;       // PEM CA certificate(s) to check the broker with (mqtts://);
                               // "" = the system's (/etc/ssl/certs)
    std::string cert_file;     // PEM client certificate, for brokers that ask for one
    std::string key_file;      // its PEM private key (unencrypted)
};

struct MqttConfig {
    std::string url; // mqtt://host[:port]; "" = off
    std::string topic_prefix = "cdro";
    int qos = 0; // 0, 1 or 2
    std::string client_id = "cdro-hostd";
    uint32_t keepalive_s = 30;     // s, MQTT keepalive
    double rate_hz = 10.0;         // Hz, most publishes per node per second; 0 = every update
    double reconnect_min_s = 1.0;  // s
    double reconnect_max_s = 30.0; // s
    MqttAuthConfig auth;           // the `mqtt_auth:` section
};

struct HttpConfig {
    std::string bind = "127.0.0.1"; // address the live map listens on
    uint16_t port = 8080;           // TCP port; 0 = off
    double update_period_s = 0.2;   // s, shortest interval between pushed map updates
    uint32_t max_event_clients = 8; // concurrent server-sent-event streams
};

struct CheckpointConfig {
    std::string path = "checkpoint.cdrosog"; // "" = no checkpoints
    double period_s = 30.0;                  // s between periodic checkpoints; 0 = only at exit
};

struct OdometryConfig {                    // the robot's odometry input (docs/service.md)
    std::string udp_bind = "127.0.0.1";    // address the UDP socket binds to (loopback by default)
    uint16_t udp_port = 0;                 // UDP port; 0 = no UDP input
    std::optional<std::string> mqtt_topic; // MQTT topic subscribed to when mqtt.url is set;
                                           // unset = "<mqtt.topic_prefix>/odometry", "" = none
    double max_velocity_gap_s = 1.0;       // s; a velocity message later than this after its
                                           // source's previous one only restarts the clock
};

struct LoggingConfig {
    std::string level = "info";  // trace, debug, info, warn, error, critical, off
    std::string file;            // "" = stderr (never stdout: it may carry JSON Lines)
    double drop_log_per_s = 5.0; // most "dropped frame" log lines per second per reason
};

struct FloorPlanConfig {            // web.floor_plan: an image under the live map
    std::string path;               // PNG file; "" = none
    double metres_per_pixel = 0.05; // m on the map per image pixel
    double origin_x_m = 0.0;        // m, where the image's bottom-left corner lies on the map
    double origin_y_m = 0.0;        // m
    double rotation_rad = 0.0;      // rad, counter-clockwise about that corner
};

struct WebConfig { // the live map page (the server is http:)
    FloorPlanConfig floor_plan;
};

struct ServiceConfig {
    SerialConfig serial;
    NodesConfig nodes;
    ScheduleConfig schedule;
    CaptureConfig capture;
    OutputConfig output;
    MqttConfig mqtt;
    HttpConfig http;
    CheckpointConfig checkpoint;
    OdometryConfig odometry;
    LoggingConfig logging;
    WebConfig web;
};

// The odometry topic the service subscribes to: odometry.mqtt_topic, or its default under
// mqtt.topic_prefix; "" when there is none (no mqtt.url, or the topic set to "").
std::string odometryMqttTopic(const ServiceConfig &config);

// The top-level sections this layer reads (serial, nodes, ...), in the order of the docs.
const std::vector<std::string> &serviceSectionNames();

// Parses YAML text (origin names it in messages, e.g. the file path). Throws ConfigError.
ServiceConfig parseServiceConfig(const std::string &yaml_text, const std::string &origin = "<config>");

// The whole configuration as YAML, every key of every section with its value (defaults
// included), in the order of the docs; parseServiceConfig reads it back to the same values.
std::string serviceConfigYaml(const ServiceConfig &config);

// Reads and parses a file. Throws ConfigError (also when the file cannot be read).
ServiceConfig loadServiceConfig(const std::string &path);

// Checks cross-field rules (ranges, min <= max, a parseable MQTT URL). parse/load call it;
// call it again after changing fields (e.g. from the CLI). Throws ConfigError.
void validateServiceConfig(const ServiceConfig &config);

// Names used in the YAML and the docs.
const char *unknownNodePolicyName(UnknownNodePolicy policy);
const char *scheduleModeName(uint8_t mode);

// A floor-plan image as the live map serves it: the PNG's bytes and its size.
struct FloorPlanImage {
    std::string png; // the file's bytes
    uint32_t width_px = 0;
    uint32_t height_px = 0;
};
// The size of the PNG at `path` from its header, checked to be a PNG; throws ConfigError naming
// web.floor_plan.path and what is wrong (missing, unreadable, not a PNG, too large).
FloorPlanImage readFloorPlanHeader(const std::string &path);
// The whole file, checked as above.
FloorPlanImage readFloorPlan(const std::string &path);

// mqtt://host[:port] (plain, port 1883) or mqtts://host[:port] (TLS, port 8883) split into
// its parts; throws ConfigError for anything else.
struct MqttUrl {
    std::string host;
    uint16_t port = 1883;
    bool tls = false;
};
MqttUrl parseMqttUrl(const std::string &url);

} // namespace cdro::service
