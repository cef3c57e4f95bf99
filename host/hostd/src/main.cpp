// cdro-hostd: the CDRO-SLAM service next to the robot.
//
//   cdro-hostd [--config FILE] [service options]           serial link (or --replay FILE)
//   cdro-hostd --ranges-csv FILE ... --out-csv OUT          offline (offline.hpp)
//   cdro-hostd --print-config [--config FILE] [options]     the whole configuration in effect
//   cdro-hostd --version                                    release, protocol, layout hashes
//
// docs/service.md documents the service, docs/engine.md the engine and its parameters.
#include <algorithm>
#include <cstdio>
#include <exception>
#include <string>
#include <vector>

#include <unistd.h>

#include <CLI/CLI.hpp>
#include <yaml-cpp/yaml.h>

#include "cdro/csv/reader.hpp"
#include "cdro/engine/engine.hpp"
#include "cdro/hostd/engine_adapter.hpp"
#include "cdro/hostd/engine_config.hpp"
#include "cdro/hostd/known_geometry.hpp"
#include "cdro/hostd/memory.hpp"
#include "cdro/hostd/offline.hpp"
#include "cdro/hostd/progress.hpp"
#include "cdro/service/capture.hpp"
#include "cdro/service/config.hpp"
#include "cdro/service/config_cli.hpp"
#include "cdro/service/log.hpp"
#include "cdro/service/service.hpp"
#include "cdro/service/version.hpp"
#include "cdro/service/yaml_section.hpp"

namespace {

// A replay reaches the live run's map only with what the map depended on: the heights and fixed
// nodes and the settings, which the live run recorded in its capture's header. Whatever the
// replay's own command line and configuration do not give is taken from there; what they give
// is used, with a warning when it differs from the live run's. Returns whether the live run
// recorded where it adopted its global solves (the replay then adopts them there).
bool takeRunContext(const std::string &capture, bool gave_geometry, bool gave_settings, cdro::hostd::KnownRows &rows,
                    cdro::engine::EngineParams &params, cdro::engine::MovementParams &movement,
                    std::vector<uint16_t> &moving)
{
    cdro::service::CaptureReader reader(capture);
    if (reader.context().empty()) {
        cdro::service::log()->warn(
            "replay: {} does not record what the map depends on (a capture written before cdro-hostd recorded "
            "it): the replay uses the heights, fixed nodes and settings given now ({} heights, {} fixed nodes, {} "
            "settings) and reaches the live run's map only if they are the live run's",
            capture, rows.heights.size(), rows.fixed.size(), gave_settings ? "the configured" : "the default");
        return false;
    }
    const cdro::hostd::RunContext recorded = cdro::hostd::decodeRunContext(reader.context(), capture);
    if (!gave_geometry) {
        rows = recorded.rows;
        cdro::service::log()->info("replay: the live run's {} known heights and {} fixed nodes, from the capture",
                                   rows.heights.size(), rows.fixed.size());
    } else if (!(rows == recorded.rows)) {
        cdro::service::log()->warn("replay: the heights or fixed nodes given differ from the live run's (recorded in "
                                   "the capture: {} heights, {} fixed nodes); the map will differ from the live one",
                                   recorded.rows.heights.size(), recorded.rows.fixed.size());
    }
    if (moving.empty()) {
        moving = recorded.moving;
        if (!moving.empty()) {
            cdro::service::log()->info("replay: the live run's {} nodes tracked in 3D (map.moving), from the capture",
                                       moving.size());
        }
    } else if (moving != recorded.moving) {
        cdro::service::log()->warn("replay: the nodes tracked in 3D given (map.moving, --moving) differ from the live "
                                   "run's ({} recorded in the capture); the outputs will differ from the live ones",
                                   recorded.moving.size());
    }
    const std::string now = cdro::hostd::engineParamsYaml(params) + cdro::hostd::movementParamsYaml(movement);
    if (!gave_settings) {
        const YAML::Node root = YAML::Load(recorded.settings);
        params = cdro::hostd::parseEngineParams(root, capture + " (the live run's settings)");
        movement = cdro::hostd::parseMovementParams(root, capture + " (the live run's settings)");
        cdro::service::log()->info("replay: the live run's engine settings, from the capture");
    } else if (now != recorded.settings) {
        cdro::service::log()->warn("replay: the engine settings given differ from the live run's (recorded in the "
                                   "capture; cdro-hostd --print-config shows these); the map will differ from the "
                                   "live one");
    }
    return recorded.solve_adoption_recorded;
}

} // namespace

static int runMain(int argc, char **argv)
{
    CLI::App app{"cdro-hostd: cooperative range-only SLAM for Pozyx UWB networks.\n\n"
                 "Live:     cdro-hostd --config config/cdro-hostd.example.yaml --device /dev/ttyACM0\n"
                 "Replay:   cdro-hostd --replay run.cdrocap --speed max --jsonl out/estimates.jsonl\n"
                 "Offline:  cdro-hostd --ranges-csv ../shared/data/plant/ranges.csv \\\n"
                 "              --heights-csv ../shared/data/plant/nodes.csv --out-csv out/plant.csv\n"};
    app.set_version_flag("--version", cdro::service::versionText("cdro-hostd"));
    cdro::service::ServiceOverrides service_overrides;
    cdro::service::addServiceOptions(app, service_overrides);
    cdro::hostd::EngineOverrides engine_overrides;
    cdro::hostd::addEngineOptions(app, engine_overrides);

    cdro::hostd::OfflineOptions offline;
    auto *ranges_option =
        app.add_option("--ranges-csv", offline.ranges_csv, "offline: ranges [t,]from,to,range_m in file order (m)");
    app.add_option("--heights-csv", offline.heights_csv, "known heights id,z (m) (map.heights_csv)");
    app.add_option("--fixed-csv", offline.fixed_csv, "known coordinates id,x,y (m), fixed (map.fixed_csv)");
    app.add_option("--out-csv", offline.out_csv, "offline: estimates id,x,y,var_x,cov_xy,var_y,converged")
        ->needs(ranges_option);
    app.add_option("--trace-csv", offline.trace_csv, "offline: every node's estimate every --trace-every ranges")
        ->needs(ranges_option);
    app.add_option("--trace-every", offline.trace_every, "offline: ranges between trace snapshots (default 10)")
        ->needs(ranges_option);
    app.add_option("--odometry-csv", offline.odometry_csv, "offline movement stage: odometry t,distance_m,dheading_rad")
        ->needs(ranges_option);
    app.add_option("--robot-id", offline.robot_id, "offline movement stage: the robot's node id")->needs(ranges_option);
    app.add_option("--motion-csv", offline.motion_csv, "offline: motion reports t,id,moving")->needs(ranges_option);
    app.add_option("--out-trajectory", offline.out_trajectory,
                   "offline movement stage: causal robot estimate t,x,y,heading_rad,var_x,cov_xy,var_y,frame (odometry "
                   "or map); "
                   "with --moving: the moving nodes' 3D trajectories")
        ->needs(ranges_option);
    app.add_option("--moving", offline.moving,
                   "node ids (comma separated) that move from the start, tracked in 3D against the fixed nodes of "
                   "known height (map.moving). Live and replay: their estimates carry z_m and var_z_m2. Offline: "
                   "without --fixed-csv the static nodes they range are calibrated from their ranges first "
                   "(calibration:, heights from --heights-csv held); with --out-trajectory: "
                   "t,id,x,y,z,var_x,cov_xy,var_y,var_z,cov_xz,cov_yz")
        ->delimiter(',');
    app.add_option("--moving-body", offline.moving_bodies,
                   "offline, with --moving: A:B:SEPARATION_M, moving nodes A and B on one rigid body SEPARATION_M "
                   "(m) apart (repeatable)")
        ->needs(ranges_option);
    app.add_option("--out-anchors", offline.out_anchors,
                   "offline, with --moving and no --fixed-csv: the anchors calibrated from the moving nodes' ranges, "
                   "id,x,y,z,height_given (m, the calibration's own frame)")
        ->needs(ranges_option);
    bool no_settle = false;
    app.add_flag("--no-settle", no_settle, "offline: do not settle the map at the end of the file")
        ->needs(ranges_option);
    app.add_flag("--verbose", offline.verbose, "offline: the engine's decisions (placements, motion, ...) on stderr")
        ->needs(ranges_option);
    bool print_config = false;
    app.add_flag("--print-config", print_config,
                 "print the whole configuration in effect (YAML: every section and key, defaults, the file and "
                 "the options applied) and exit");
    bool progress = false;
    app.add_flag("--progress", progress,
                 "a progress line on stderr every second (link, frames, map); the default when stdout is a "
                 "terminal and no --jsonl is given");
    try {
        app.parse(argc, argv);
    } catch (const CLI::ParseError &error) {
        // --help and --version exit 0; every usage error exits 2, like every other bad input.
        return app.exit(error) == 0 ? 0 : 2;
    }

    try {
        const cdro::hostd::ConfigDocument document =
            cdro::hostd::loadConfigDocument(service_overrides.config_path, engine_overrides.sets);
        cdro::hostd::EngineOverrides switches = engine_overrides;
        switches.sets.clear(); // already in the document
        cdro::engine::EngineParams params = cdro::hostd::parseEngineParams(document.root, document.origin);
        cdro::hostd::applySwitches(params, switches);
        cdro::engine::MovementParams movement = cdro::hostd::parseMovementParams(document.root, document.origin);
        const cdro::engine::MovingCalibrationParams calibration =
            cdro::hostd::parseCalibrationParams(document.root, document.origin, params);
        cdro::hostd::KnownGeometry geometry = cdro::hostd::parseKnownGeometry(document.root, document.origin);
        if (!offline.heights_csv.empty()) {
            geometry.heights_csv = offline.heights_csv;
        }
        if (!offline.fixed_csv.empty()) {
            geometry.fixed_csv = offline.fixed_csv;
        }
        if (!offline.moving.empty() && offline.ranges_csv.empty()) {
            // Offline checks its own list (offline.cpp); here the live run's, as the map section's.
            geometry.moving.clear();
            for (const std::string &text : offline.moving) {
                uint16_t id = 0;
                if (!cdro::csv::parseNodeId(text, &id)) {
                    throw cdro::service::ConfigError("--moving: '" + text +
                                                     "' is not a node id (1..65535, decimal or 0x hex)");
                }
                if (std::find(geometry.moving.begin(), geometry.moving.end(), id) == geometry.moving.end()) {
                    geometry.moving.push_back(id);
                }
            }
        } else if (offline.moving.empty()) {
            for (const uint16_t id : geometry.moving) {
                offline.moving.push_back(std::to_string(id));
            }
        }
        if (print_config) {
            // What a run with these arguments would use, as a file --config reads back.
            cdro::service::ServiceConfig config =
                document.service_text.empty()
                    ? cdro::service::ServiceConfig{}
                    : cdro::service::parseServiceConfig(document.service_text, document.origin);
            cdro::service::applyOverrides(config, service_overrides);
            YAML::Emitter map;
            map << YAML::BeginMap << YAML::Key << "map" << YAML::Value << YAML::BeginMap << YAML::Key << "heights_csv"
                << YAML::Value << geometry.heights_csv << YAML::Key << "fixed_csv" << YAML::Value << geometry.fixed_csv
                << YAML::Key << "moving" << YAML::Value << YAML::Flow << geometry.moving << YAML::EndMap
                << YAML::EndMap;
            std::fputs(cdro::service::serviceConfigYaml(config).c_str(), stdout);
            std::fputs(cdro::hostd::engineParamsYaml(params).c_str(), stdout);
            std::fputs(cdro::hostd::movementParamsYaml(movement).c_str(), stdout);
            std::fputs(cdro::hostd::calibrationParamsYaml(calibration).c_str(), stdout);
            std::fputs(map.c_str(), stdout);
            std::fputs("\n", stdout);
            return 0;
        }
        if (!offline.ranges_csv.empty()) {
            offline.heights_csv = geometry.heights_csv;
            offline.fixed_csv = geometry.fixed_csv;
            if (offline.out_csv.empty()) {
                std::fprintf(stderr, "cdro-hostd: --ranges-csv needs --out-csv\n");
                return 2;
            }
            offline.settle = !no_settle;
            offline.calibration = calibration;
            return cdro::hostd::runOffline(offline, params, movement, stderr);
        }

        cdro::service::ServiceConfig config =
            document.service_text.empty() ? cdro::service::ServiceConfig{}
                                          : cdro::service::parseServiceConfig(document.service_text, document.origin);
        cdro::service::applyOverrides(config, service_overrides);
        // A person at a terminal reads the logs and a progress line there; a thousand JSON lines a
        // minute would bury both. Scripts (stdout a pipe or a file) get JSON Lines as ever, and
        // `--jsonl -` asks for them on a terminal too.
        const bool jsonl_held_back =
            config.output.jsonl == "-" && !service_overrides.jsonl && isatty(STDOUT_FILENO) == 1;
        if (jsonl_held_back) {
            config.output.jsonl.clear();
            progress = true;
        }
        cdro::service::setupLogging(config.logging);
        if (jsonl_held_back) {
            cdro::service::log()->info("output: stdout is a terminal, so it gets a progress line instead of the "
                                       "JSON Lines (--jsonl - writes them here, --jsonl FILE to a file)");
        }
        cdro::hostd::KnownRows rows = cdro::hostd::readKnownGeometry(geometry, 20, stderr);
        // Live, no frame waits for the global solve: its map is adopted between frames once its
        // worker is done, and the capture records where (host events), so that a replay adopts it
        // there. Captures that do not say so (cdro-sim's, older cdro-hostd's) keep the fixed lag.
        bool adoption_recorded = service_overrides.run.replay_path.empty();
        if (!service_overrides.run.replay_path.empty()) {
            const bool gave_geometry = !geometry.heights_csv.empty() || !geometry.fixed_csv.empty();
            const bool gave_settings =
                (document.root && document.root.IsMap() && (document.root["engine"] || document.root["movement"])) ||
                engine_overrides.no_weight_transfer || engine_overrides.no_cooperative ||
                engine_overrides.no_refinement || engine_overrides.no_motion_reset;
            adoption_recorded = takeRunContext(service_overrides.run.replay_path, gave_geometry, gave_settings, rows,
                                               params, movement, geometry.moving);
        }
        if (!geometry.moving.empty() && movement.robot_id != 0) {
            throw cdro::service::ConfigError("map.moving is not for the movement stage: no movement.robot_id with it");
        }
        cdro::engine::Engine engine(params);
        engine.setSolveAdoption(adoption_recorded ? cdro::engine::Engine::SolveAdoption::ByCaller
                                                  : cdro::engine::Engine::SolveAdoption::AfterLag);
        engine.setTrace([](const std::string &message) { cdro::service::log()->debug("engine: {}", message); });
        const cdro::hostd::KnownGeometryCounts known = cdro::hostd::applyKnownRows(engine, rows);
        if (known.heights + known.fixed > 0) {
            cdro::service::log()->info("map: {} known heights, {} fixed nodes", known.heights, known.fixed);
        }
        cdro::hostd::trackMovingNodes(engine, rows, geometry.moving);
        if (!geometry.moving.empty()) {
            cdro::service::log()->info("map: {} nodes tracked in 3D (map.moving)", geometry.moving.size());
        }
        std::unique_ptr<cdro::engine::MovementStage> stage;
        if (movement.robot_id != 0) {
            stage = std::make_unique<cdro::engine::MovementStage>(engine, movement);
            stage->setTrace([](const std::string &message) { cdro::service::log()->debug("movement: {}", message); });
        }
        cdro::hostd::EngineAdapter adapter(engine, stage.get(), geometry.moving);
        cdro::service::SystemClock clock;
        cdro::service::Service service(config, service_overrides.run, {&adapter, &adapter, &adapter, &adapter}, clock);
        service.setCaptureContext(cdro::hostd::encodeRunContext(
            {rows, cdro::hostd::engineParamsYaml(params) + cdro::hostd::movementParamsYaml(movement), geometry.moving,
             adoption_recorded}));
        service.start();
        if (!service.liveMapUrl().empty()) {
            std::fprintf(stderr, "cdro-hostd: live map: %s\n", service.liveMapUrl().c_str());
        }
        std::unique_ptr<cdro::hostd::ProgressLine> line;
        if (progress) {
            line = std::make_unique<cdro::hostd::ProgressLine>(service, engine, stderr);
        }
        const int code = service.run();
        if (adapter.hostEventsMismatched() > 0) {
            cdro::service::log()->warn("replay: {} of the capture's host events did not fit this replay (above): its "
                                       "map parts from the live run's there",
                                       adapter.hostEventsMismatched());
        }
        return code;
    } catch (const std::exception &error) {
        std::fprintf(stderr, "cdro-hostd: %s\n", error.what());
        return 2;
    }
}

// An exception that escapes (from setting up the options, before runMain's own handler) ends the
// run with its message and status 2, not with std::terminate's abort.
int main(int argc, char **argv)
{
    cdro::hostd::returnLargeBuffersToTheSystem();
    try {
        return runMain(argc, argv);
    } catch (const std::exception &error) {
        std::fprintf(stderr, "cdro-hostd: %s\n", error.what());
        return 2;
    }
}
