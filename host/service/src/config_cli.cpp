#include "cdro/service/config_cli.hpp"

#include <cmath>

#include <CLI/CLI.hpp>

namespace cdro::service {

double parseReplaySpeed(const std::string &text)
{
    if (text == "max") {
        return 0.0;
    }
    char *end = nullptr;
    const double speed = std::strtod(text.c_str(), &end);
    if (text.empty() || *end != '\0' || !std::isfinite(speed) || !(speed > 0.0)) {
        throw ConfigError("--speed: '" + text + "' is neither 'max' nor a positive factor such as 1 or 10");
    }
    return speed;
}

void addServiceOptions(CLI::App &app, ServiceOverrides &o)
{
    app.add_option("-c,--config", o.config_path, "YAML configuration file")->check(CLI::ExistingFile);
    app.add_option("--replay", o.run.replay_path, "feed this capture file instead of the serial port")
        ->check(CLI::ExistingFile);
    app.add_option_function<std::string>(
           "--speed", [&o](const std::string &text) { o.run.replay_speed = parseReplaySpeed(text); },
           "replay pace: a factor of real time (1 = as recorded) or 'max' (default)")
        ->needs("--replay");
    app.add_option("--resume", o.run.resume_path, "continue from this checkpoint (.cdrosog)")->check(CLI::ExistingFile);
    app.add_option("--device", o.device, "serial device path (serial.device)");
    app.add_option("--baud", o.baud, "bit/s (serial.baud)");
    app.add_option("--capture", o.capture_path, "capture file, '' = off (capture.path)");
    app.add_option("--jsonl", o.jsonl, "JSON Lines output file, '-' = stdout, '' = off (output.jsonl)");
    app.add_option("--rate", o.output_rate_hz, "Hz of JSON lines, 0 = one per update (output.rate_hz)");
    app.add_option("--mqtt", o.mqtt_url, "MQTT broker, mqtt://host[:port] (mqtt.url)");
    app.add_option("--http-bind", o.http_bind, "live map address (http.bind)");
    app.add_option("--http-port", o.http_port, "live map port, 0 = off (http.port)");
    app.add_option("--checkpoint", o.checkpoint_path, "checkpoint file, '' = off (checkpoint.path)");
    app.add_option("--checkpoint-period", o.checkpoint_period_s, "s between checkpoints (checkpoint.period_s)");
    app.add_option("--log-level", o.log_level, "trace, debug, info, warn, error, critical, off (logging.level)");
    app.add_option("--odometry-udp-port", o.odometry_udp_port,
                   "UDP port for the robot's odometry JSON, 0 = off (odometry.udp_port)");
    app.add_option("--odometry-mqtt-topic", o.odometry_mqtt_topic,
                   "MQTT topic of the robot's odometry, '' = none (odometry.mqtt_topic)");
}

void applyOverrides(ServiceConfig &c, const ServiceOverrides &o)
{
    if (o.device)
        c.serial.device = *o.device;
    if (o.baud)
        c.serial.baud = *o.baud;
    if (o.capture_path)
        c.capture.path = *o.capture_path;
    if (o.jsonl)
        c.output.jsonl = *o.jsonl;
    if (o.output_rate_hz) {
        if (!(*o.output_rate_hz >= 0.0) || *o.output_rate_hz > 1000.0) {
            throw ConfigError("--rate: must be between 0 and 1000 Hz");
        }
        c.output.rate_hz = *o.output_rate_hz;
    }
    if (o.mqtt_url)
        c.mqtt.url = *o.mqtt_url;
    if (o.http_bind)
        c.http.bind = *o.http_bind;
    if (o.http_port)
        c.http.port = *o.http_port;
    if (o.checkpoint_path)
        c.checkpoint.path = *o.checkpoint_path;
    if (o.checkpoint_period_s) {
        if (!(*o.checkpoint_period_s >= 0.0)) {
            throw ConfigError("--checkpoint-period: must be >= 0 s");
        }
        c.checkpoint.period_s = *o.checkpoint_period_s;
    }
    if (!o.run.replay_path.empty()) {
        // A replay writes what its command line asks for and nothing else: the configuration
        // file describes the live service (its checkpoint, its live map's port, its broker, its
        // JSON Lines file), which a replay must neither overwrite nor compete with.
        c.output.jsonl = o.jsonl.value_or("-");
        c.checkpoint.path = o.checkpoint_path.value_or("");
        c.http.port = o.http_port.value_or(0);
        c.mqtt.url = o.mqtt_url.value_or("");
    }
    if (o.odometry_udp_port)
        c.odometry.udp_port = *o.odometry_udp_port;
    if (o.odometry_mqtt_topic)
        c.odometry.mqtt_topic = *o.odometry_mqtt_topic;
    if (o.log_level) {
        static const char *const levels[] = {"trace", "debug", "info", "warn", "error", "critical", "off"};
        bool known = false;
        for (const char *level : levels) {
            known = known || *o.log_level == level;
        }
        if (!known) {
            throw ConfigError("--log-level: '" + *o.log_level + "' is not a level (trace ... off)");
        }
        c.logging.level = *o.log_level;
    }
    validateServiceConfig(c);
}

} // namespace cdro::service
