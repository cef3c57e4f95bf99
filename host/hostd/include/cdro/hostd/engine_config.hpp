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

#include "cdro/engine/movement.hpp"
#include "cdro/engine/params.hpp"

namespace CLI {
class App;
}
namespace YAML {
class Node;
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

// Reads the file (or none: "" gives the defaults), applies the overrides, parses, validates.
// Throws cdro::service::ConfigError.
engine::EngineParams loadEngineParams(const std::string &config_path, const EngineOverrides &overrides);

// The `movement:` section (the movement stage, movement.hpp); defaults where absent.
engine::MovementParams parseMovementParams(const YAML::Node &root, const std::string &origin);

// Applies `section.key=value` settings to a YAML document (creating maps as needed).
// Throws cdro::service::ConfigError for a malformed setting.
void applySettings(YAML::Node &root, const std::vector<std::string> &settings);

// Every engine key with its current value, as YAML (for --print-config and the docs test).
std::string engineParamsYaml(const engine::EngineParams &params);
std::string movementParamsYaml(const engine::MovementParams &params);

// Every key, as "engine.<group>.<name>" and "movement.[<group>.]<name>" (docs/engine.md lists them).
std::vector<std::string> configurationKeys();

} // namespace cdro::hostd
