// cdro-service-harness: the service exactly as cdro-hostd will run it, with the harness
// engine (harness_map.hpp) in place of the SLAM engine. Not installed; driven by the pytest
// end-to-end tests. Options: every service option (config_cli.hpp) plus --received FILE.
#include <cstdio>

#include <CLI/CLI.hpp>

#include "cdro/service/config_cli.hpp"
#include "cdro/service/log.hpp"
#include "cdro/service/service.hpp"
#include "harness_map.hpp"

int main(int argc, char **argv)
{
    using namespace cdro::service;
    try {
        CLI::App app{"cdro-service-harness: the cdro-hostd service with a recording consumer"};
        ServiceOverrides overrides;
        addServiceOptions(app, overrides);
        std::string received;
        app.add_option("--received", received,
                       "write every frame and odometry message the consumer receives, one JSON line each");
        CLI11_PARSE(app, argc, argv);
        ServiceConfig config =
            overrides.config_path.empty() ? ServiceConfig{} : loadServiceConfig(overrides.config_path);
        applyOverrides(config, overrides);
        setupLogging(config.logging);
        HarnessEngine engine(received);
        SystemClock clock;
        Service service(config, overrides.run, {&engine, &engine, &engine, &engine}, clock);
        service.start();
        if (!service.liveMapUrl().empty()) {
            std::fprintf(stderr, "live map: %s\n", service.liveMapUrl().c_str());
        }
        if (service.odometryUdpPort() != 0) {
            std::fprintf(stderr, "odometry: udp port %u\n", static_cast<unsigned>(service.odometryUdpPort()));
        }
        return service.run();
    } catch (const std::exception &error) {
        std::fprintf(stderr, "cdro-service-harness: %s\n", error.what());
        return 2;
    }
}
