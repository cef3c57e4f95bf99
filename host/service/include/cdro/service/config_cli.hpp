// config_cli.hpp: CLI11 options for the service's settings, for cdro-hostd's main (host/hostd/src/main.cpp).
//
// The command line overrides the configuration file. Because the file is named on the same
// command line (--config), options are parsed first into ServiceOverrides (each one optional)
// and applied after the file is loaded:
//
//     CLI::App app{"cdro-hostd"};
//     cdro::service::ServiceOverrides overrides;
//     cdro::service::addServiceOptions(app, overrides);   // adds --config, --device, ...
//     CLI11_PARSE(app, argc, argv);
//     ServiceConfig config = overrides.config_path.empty() ? ServiceConfig{}
//                                                         : loadServiceConfig(overrides.config_path);
//     applyOverrides(config, overrides);                  // validates again; throws ConfigError
//
// Run options that are not configuration (--replay, --speed, --resume) land in RunOptions.
#pragma once

#include <optional>
#include <string>

#include "cdro/service/config.hpp"

namespace CLI {
class App;
}

namespace cdro::service {

struct RunOptions {
    std::string replay_path;   // --replay FILE: feed this capture instead of the serial port
    double replay_speed = 0.0; // --speed X|max: 0 = as fast as possible, else X times real time
    std::string resume_path;   // --resume FILE: start from this checkpoint
};

struct ServiceOverrides {
    std::string config_path; // --config FILE
    RunOptions run;
    std::optional<std::string> device;              // --device PATH
    std::optional<uint32_t> baud;                   // --baud N
    std::optional<std::string> capture_path;        // --capture FILE ("" = off)
    std::optional<std::string> jsonl;               // --jsonl FILE|-
    std::optional<double> output_rate_hz;           // --rate HZ
    std::optional<std::string> mqtt_url;            // --mqtt URL
    std::optional<std::string> http_bind;           // --http-bind ADDR
    std::optional<uint16_t> http_port;              // --http-port N (0 = off)
    std::optional<std::string> checkpoint_path;     // --checkpoint FILE
    std::optional<double> checkpoint_period_s;      // --checkpoint-period S
    std::optional<std::string> log_level;           // --log-level LEVEL
    std::optional<uint16_t> odometry_udp_port;      // --odometry-udp-port N (0 = off)
    std::optional<std::string> odometry_mqtt_topic; // --odometry-mqtt-topic TOPIC ("" = none)
};

// Adds the options above to app (option names are documented in docs/service.md).
void addServiceOptions(CLI::App &app, ServiceOverrides &overrides);

// Copies every set override into config, then validates. Throws ConfigError.
void applyOverrides(ServiceConfig &config, const ServiceOverrides &overrides);

// "max" -> 0, "2.5" -> 2.5; throws ConfigError for anything else or a speed <= 0.
double parseReplaySpeed(const std::string &text);

} // namespace cdro::service
