// engine_config.hpp: the `engine:` section of cdro-hostd's YAML configuration, and the
// command-line settings of the engine.
//
// Every engine parameter (host/engine/include/cdro/engine/params.hpp, docs/engine.md) has a
// key `engine.<group>.<name>`; an unknown key is an error naming file, line and the known keys
// (yaml_section.hpp). The command line sets any of them with `--set engine.<group>.<name>=VALUE`
// (repeatable, applied over the file, checked the same way), and has switches for the
// ablations: --no-weight-transfer, --no-cooperative, --no-refinement (the paper's filter
// alone: the merged SoG is the estimate) and --no-motion-reset (moving nodes handled as static).
#pragma once

#include <string>
#include <vector>

#include <yaml-cpp/yaml.h>

#include "cdro/engine/movement.hpp"
#include "cdro/engine/moving_calibration.hpp"
#include "cdro/engine/params.hpp"

namespace CLI {
class App;
}

namespace cdro::hostd {

struct EngineOverrides {
    std::vector<std::string> sets; // --set KEY=VALUE, in order
    bool no_weight_transfer = false;
    bool no_cooperative = false;
    bool no_refinement = false;
    bool no_motion_reset = false;
};

void addEngineOptions(CLI::App &app, EngineOverrides &overrides);
// The switches (--no-...) applied to parameters.
void applySwitches(engine::EngineParams &params, const EngineOverrides &overrides);

// The engine section of a YAML document (root: the whole document); defaults where absent.
// Throws cdro::service::ConfigError.
engine::EngineParams parseEngineParams(const YAML::Node &root, const std::string &origin);

// The YAML document of --config (or none: "" gives an empty one) with the --set settings
// applied, and the text the service's parser reads (the file's own text when nothing was set, so
// that its messages name real lines). A section no layer knows, in the file or in a --set, is an
// error naming it and the known ones. Throws cdro::service::ConfigError.
struct ConfigDocument {
    YAML::Node root;
    std::string service_text;
    std::string origin; // the file's path, "<defaults>", + " + --set"
};
ConfigDocument loadConfigDocument(const std::string &path, const std::vector<std::string> &sets);

// The engine's parameters from loadConfigDocument, with the switches applied.
// Throws cdro::service::ConfigError.
engine::EngineParams loadEngineParams(const std::string &config_path, const EngineOverrides &overrides);

// The `movement:` section (the movement stage, movement.hpp); defaults where absent.
engine::MovementParams parseMovementParams(const YAML::Node &root, const std::string &origin);

// The `calibration:` section: the anchors' calibration from moving nodes' ranges (offline
// --moving without --fixed-csv; moving_calibration.hpp). Defaults where absent, except
// calibration.range_sigma_m, which is engine.range.sigma_m (of `engine`) unless set.
// Throws cdro::service::ConfigError naming the key for a value out of its range.
engine::MovingCalibrationParams parseCalibrationParams(const YAML::Node &root, const std::string &origin,
                                                       const engine::EngineParams &engine);

// Applies `section.key=value` settings to a YAML document (creating maps as needed).
// Throws cdro::service::ConfigError for a malformed setting.
void applySettings(YAML::Node &root, const std::vector<std::string> &settings);

// Every engine key with its current value, as YAML (for --print-config and the docs test).
std::string engineParamsYaml(const engine::EngineParams &params);
std::string movementParamsYaml(const engine::MovementParams &params);
std::string calibrationParamsYaml(const engine::MovingCalibrationParams &params);

// Every key, as "engine.<group>.<name>", "movement.[<group>.]<name>" and "calibration.<name>"
// (docs/engine.md lists them).
std::vector<std::string> configurationKeys();

} // namespace cdro::hostd
