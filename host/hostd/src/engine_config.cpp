#include "cdro/hostd/engine_config.hpp"

#include <algorithm>
#include <charconv>
#include <fstream>
#include <sstream>

#include <CLI/CLI.hpp>
#include <yaml-cpp/yaml.h>

#include "cdro/service/config.hpp"
#include "cdro/service/yaml_section.hpp"

namespace cdro::hostd {

using cdro::service::ConfigError;
using cdro::service::Section;

namespace {

constexpr double kHuge = 1e9;

// One configuration key: where it lives, its type and range, and how to reach it. The same
// table parses the file, prints --print-config and is what docs/engine.md must list.
template <typename Params> struct Key {
    const char *group; // nested section under the top one ("" = directly in it)
    const char *name;
    enum class Kind { Real, Count, Flag, Id } kind;
    double minimum;
    double maximum;
    double *(*real)(Params &);
    uint32_t *(*count)(Params &);
    bool *(*flag)(Params &);
    uint16_t *(*id)(Params &);
};

#define CDRO_REAL(G, N, MIN, MAX, FIELD)                                                             \
    Key<P>                                                                                           \
    {                                                                                                \
        G, N, Key<P>::Kind::Real, MIN, MAX, [](P &p) { return &p.FIELD; }, nullptr, nullptr, nullptr \
    }
#define CDRO_COUNT(G, N, MIN, MAX, FIELD)                                                             \
    Key<P>                                                                                            \
    {                                                                                                 \
        G, N, Key<P>::Kind::Count, MIN, MAX, nullptr, [](P &p) { return &p.FIELD; }, nullptr, nullptr \
    }
#define CDRO_FLAG(G, N, FIELD)                                                                   \
    Key<P>                                                                                       \
    {                                                                                            \
        G, N, Key<P>::Kind::Flag, 0, 1, nullptr, nullptr, [](P &p) { return &p.FIELD; }, nullptr \
    }
#define CDRO_ID(G, N, FIELD)                                                                       \
    Key<P>                                                                                         \
    {                                                                                              \
        G, N, Key<P>::Kind::Id, 0, 65535, nullptr, nullptr, nullptr, [](P &p) { return &p.FIELD; } \
    }

const std::vector<Key<engine::EngineParams>> &engineKeys()
{
    using P = engine::EngineParams;
    static const std::vector<Key<P>> keys = {
        CDRO_REAL("range", "sigma_m", 0.001, 100.0, range.sigma_m),
        CDRO_REAL("range", "unknown_height_spread_m", 0.0, 100.0, range.unknown_height_spread_m),
        CDRO_REAL("range", "max_range_m", 0.1, 1e6, range.max_range_m),
        CDRO_COUNT("range", "window", 1, engine::RangeWindow::kCapacity, range.window),
        CDRO_FLAG("likelihood", "robust", likelihood.robust),
        CDRO_REAL("likelihood", "nlos_fraction", 0.0, 1.0, likelihood.nlos_fraction),
        CDRO_REAL("likelihood", "nlos_mean_excess_m", 0.001, 1000.0, likelihood.nlos_mean_excess_m),
        CDRO_REAL("likelihood", "gross_density_per_m", 1e-12, 1.0, likelihood.gross_density_per_m),
        CDRO_REAL("sog", "arc_spacing_m", 0.01, 100.0, ring.arc_spacing_m),
        CDRO_COUNT("sog", "min_components", 3, 100000, ring.min_components),
        CDRO_COUNT("sog", "max_components", 3, 100000, ring.max_components),
        CDRO_REAL("sog", "tangential_overlap", 0.1, 100.0, ring.tangential_overlap),
        CDRO_REAL("sog", "weight_floor", 0.0, 0.01, ring.weight_floor),
        CDRO_FLAG("sog", "collapse_reset", sog.collapse_reset),
        CDRO_FLAG("sog", "rings_follow_center", sog.rings_follow_center),
        CDRO_FLAG("sog", "cooperative", sog.cooperative),
        CDRO_FLAG("sog", "weight_transfer", sog.weight_transfer),
        CDRO_REAL("sog", "transfer_sigma_m", 0.001, 100.0, sog.transfer_sigma_m),
        CDRO_REAL("sog", "gate_sigma", 0.5, 1000.0, sog.gate_sigma),
        CDRO_REAL("sog", "process_noise_m2", 0.0, 100.0, sog.process_noise_m2),
        CDRO_COUNT("sog", "full_update_every", 1, 100000, sog.full_update_every),
        CDRO_REAL("placement", "min_triangle_height_m", 0.0, kHuge, placement.min_triangle_height_m),
        CDRO_REAL("placement", "min_baseline_m", 0.0, kHuge, placement.min_baseline_m),
        CDRO_REAL("placement", "ambiguity_gap_nats", 0.0, kHuge, placement.ambiguity_gap_nats),
        CDRO_REAL("placement", "distinct_m", 0.001, kHuge, placement.distinct_m),
        CDRO_COUNT("placement", "patience_ranges", 1, 100000000, placement.patience_ranges),
        CDRO_FLAG("refinement", "enabled", refinement.enabled),
        CDRO_COUNT("refinement", "max_iterations", 1, 1000, refinement.max_iterations),
        CDRO_REAL("refinement", "hypothesis_switch_m", 0.0, kHuge, refinement.hypothesis_switch_m),
        CDRO_REAL("refinement", "switch_gap_nats", 0.0, kHuge, refinement.switch_gap_nats),
        CDRO_COUNT("refinement", "relax_per_range", 0, 100000, refinement.relax_per_range),
        CDRO_REAL("refinement", "relax_threshold_m", 0.0, kHuge, refinement.relax_threshold_m),
        CDRO_COUNT("refinement", "settle_per_placed", 0, 100000, refinement.settle_per_placed),
        CDRO_COUNT("refinement", "settle_per_range", 1, 100000, refinement.settle_per_range),
        CDRO_REAL("refinement", "inconsistent_residual_m", 0.0, kHuge, refinement.inconsistent_residual_m),
        CDRO_REAL("refinement", "inconsistent_fraction", 0.0, 1.0, refinement.inconsistent_fraction),
        CDRO_COUNT("refinement", "max_placements", 1, 1000, refinement.max_placements),
        CDRO_FLAG("solve", "enabled", solve.enabled),
        CDRO_REAL("solve", "link_growth", 1.0001, 100.0, solve.link_growth),
        CDRO_COUNT("solve", "min_links", 3, 1000000, solve.min_links),
        CDRO_REAL("solve", "quiet_ranges_per_link", 0.0, kHuge, solve.quiet_ranges_per_link),
        CDRO_REAL("solve", "min_gain_nats", 0.0, kHuge, solve.min_gain_nats),
        CDRO_REAL("solve", "adopt_after_sweeps", 0.0, kHuge, solve.adopt_after_sweeps),
        CDRO_FLAG("solve", "range_offsets", solve.range_offsets),
        CDRO_FLAG("solve", "connectivity", solve.connectivity),
        CDRO_COUNT("solve", "threads", 0, 256, solve.threads),
        CDRO_FLAG("motion", "reset", motion.reset),
        CDRO_FLAG("motion", "infer_from_ranges", motion.infer_from_ranges),
        CDRO_REAL("motion", "inferred_residual_m", 0.0, kHuge, motion.inferred_residual_m),
        CDRO_COUNT("motion", "inferred_window", 1, engine::MotionMemory::kRecentRanges, motion.inferred_window),
        CDRO_COUNT("motion", "inferred_min_large", 1, engine::MotionMemory::kRecentRanges, motion.inferred_min_large),
        CDRO_COUNT("motion", "inferred_min_links", 1, engine::MotionMemory::kRecentRanges, motion.inferred_min_links),
        CDRO_REAL("motion", "inferred_still_speed_mps", 0.0, kHuge, motion.inferred_still_speed_mps),
        CDRO_REAL("motion", "inferred_still_m", 0.0, kHuge, motion.inferred_still_m),
        CDRO_COUNT("motion", "inferred_still_updates", 1, 100000, motion.inferred_still_updates),
        CDRO_FLAG("motion", "track", motion.track),
        CDRO_REAL("motion", "track_accel_sigma_mps2", 0.0, 1000.0, motion.track_accel_sigma_mps2),
        CDRO_REAL("motion", "track_speed_sigma_mps", 0.0, 1000.0, motion.track_speed_sigma_mps),
        CDRO_COUNT("motion", "track_warmup", 0, 1000, motion.track_warmup),
        CDRO_REAL("motion", "track_max_speed_mps", 0.01, 1000.0, motion.track_max_speed_mps),
        CDRO_REAL("motion", "flight_speed_sigma_mps", 0.001, 1000.0, motion.flight_speed_sigma_mps),
        CDRO_REAL("motion", "flight_speed_tau_s", 0.001, 1e6, motion.flight_speed_tau_s),
        CDRO_REAL("motion", "flight_floor_z_m", -kHuge, kHuge, motion.flight_floor_z_m),
        CDRO_REAL("convergence", "reliable_m", 0.01, kHuge, convergence.reliable_m),
        CDRO_REAL("convergence", "common_excess_m", 0.0, 100.0, convergence.common_excess_m),
        CDRO_REAL("convergence", "room_excess_m", 0.0, 100.0, convergence.room_excess_m),
        CDRO_REAL("convergence", "smoothing", 0.0, 0.9999, convergence.smoothing),
        CDRO_REAL("convergence", "threshold_m", 0.0, kHuge, convergence.threshold_m),
        CDRO_COUNT("convergence", "consecutive", 1, 100000, convergence.consecutive),
        CDRO_COUNT("convergence", "min_updates", 0, 100000000, convergence.min_updates),
        CDRO_REAL("convergence", "unconverge_factor", 1.0, kHuge, convergence.unconverge_factor),
        CDRO_ID("frame", "origin", frame.origin),
        CDRO_ID("frame", "x_axis", frame.x_axis),
        CDRO_ID("frame", "positive_y", frame.positive_y),
    };
    return keys;
}

const std::vector<Key<engine::MovementParams>> &movementKeys()
{
    using P = engine::MovementParams;
    static const std::vector<Key<P>> keys = {
        CDRO_ID("", "robot_id", robot_id),
        CDRO_REAL("", "range_sigma_m", 0.0, 100.0, range_sigma_m),
        CDRO_REAL("", "adaptive_initial_sigma_m", 0.001, 100.0, adaptive_initial_sigma_m),
        CDRO_COUNT("", "adaptive_window", 8, 100000, adaptive_window),
        CDRO_FLAG("", "estimate_scale", estimate_scale),
        CDRO_REAL("", "scale_sigma", 0.0, 1.0, scale_sigma),
        CDRO_FLAG("", "estimate_offset", estimate_offset),
        CDRO_REAL("", "offset_sigma_m", 0.0, 100.0, offset_sigma_m),
        CDRO_REAL("", "gate_sigma", 0.5, 1000.0, gate_sigma),
        CDRO_REAL("", "motion_start_m", 0.0, kHuge, motion_start_m),
        CDRO_COUNT("", "heading_hypotheses", 1, 360, heading_hypotheses),
        CDRO_REAL("", "heading_collapse_weight", 0.5, 1.0, heading_collapse_weight),
        CDRO_REAL("", "heading_prune_weight", 0.0, 0.5, heading_prune_weight),
        CDRO_REAL("", "heading_merge_m", 0.0, kHuge, heading_merge_m),
        CDRO_REAL("", "heading_merge_rad", 0.0, 3.2, heading_merge_rad),
        CDRO_REAL("", "beacon_arc_spacing_m", 0.05, 100.0, beacon_arc_spacing_m),
        CDRO_COUNT("", "beacon_min_components", 3, 100000, beacon_min_components),
        CDRO_REAL("", "beacon_prune_ratio", 0.0, 1.0, beacon_prune_ratio),
        CDRO_COUNT("", "beacon_min_ranges", 1, 100000, beacon_min_ranges),
        CDRO_REAL("", "beacon_insert_std_m", 0.001, kHuge, beacon_insert_std_m),
        CDRO_REAL("", "beacon_min_baseline_m", 0.0, kHuge, beacon_min_baseline_m),
        CDRO_COUNT("", "nlos_window", 4, 100000, nlos_window),
        CDRO_REAL("", "nlos_min_m", 0.0, kHuge, nlos_min_m),
        CDRO_REAL("", "nlos_sigmas", 0.0, kHuge, nlos_sigmas),
        CDRO_REAL("odometry", "distance_fraction", 0.0, 10.0, odometry.distance_fraction),
        CDRO_REAL("odometry", "distance_floor_m", 0.0, kHuge, odometry.distance_floor_m),
        CDRO_REAL("odometry", "heading_fraction", 0.0, 10.0, odometry.heading_fraction),
        CDRO_REAL("odometry", "heading_floor_rad", 0.0, 10.0, odometry.heading_floor_rad),
        CDRO_REAL("odometry", "heading_walk_rad_per_sqrt_s", 0.0, 10.0, odometry.heading_walk_rad_per_sqrt_s),
        CDRO_REAL("odometry", "scale_walk_per_sqrt_s", 0.0, 1.0, odometry.scale_walk_per_sqrt_s),
        CDRO_REAL("odometry", "offset_walk_m_per_sqrt_s", 0.0, kHuge, odometry.offset_walk_m_per_sqrt_s),
    };
    return keys;
}

// The calibration's parameters a user may set; min_prior_sigma_m only keeps the motion prior's
// weights finite and is left out.
const std::vector<Key<engine::MovingCalibrationParams>> &calibrationKeys()
{
    using P = engine::MovingCalibrationParams;
    static const std::vector<Key<P>> keys = {
        CDRO_REAL("", "window_s", 0.001, 1e6, window_s),
        CDRO_REAL("", "range_sigma_m", 0.001, 100.0, range_sigma_m),
        CDRO_REAL("", "huber_sigmas", 0.1, 1000.0, huber_sigmas),
        CDRO_COUNT("", "max_iterations", 1, 1000000, max_iterations),
        CDRO_REAL("", "unknown_plane_height_m", -kHuge, kHuge, unknown_plane_height_m),
    };
    return keys;
}

#undef CDRO_REAL
#undef CDRO_COUNT
#undef CDRO_FLAG
#undef CDRO_ID

// Reads every key of `keys` under the top section `top` of root, group by group, rejecting
// keys (and groups) that are not in the table.
template <typename Params>
void parseKeys(const YAML::Node &root, const char *top, const std::string &origin, const std::vector<Key<Params>> &keys,
               Params &params)
{
    Section top_section(root[top], top, origin);
    std::vector<std::string> groups;
    for (const Key<Params> &key : keys) {
        if (std::find(groups.begin(), groups.end(), key.group) == groups.end()) {
            groups.push_back(key.group);
        }
    }
    for (const std::string &group : groups) {
        const bool nested = !group.empty();
        Section nested_section(nested ? top_section.child(group.c_str()) : YAML::Node(YAML::NodeType::Undefined),
                               std::string(top) + "." + group, origin);
        Section &section = nested ? nested_section : top_section;
        for (const Key<Params> &key : keys) {
            if (group != key.group) {
                continue;
            }
            switch (key.kind) {
            case Key<Params>::Kind::Real:
                section.read<double>(key.name, *key.real(params), key.minimum, key.maximum);
                break;
            case Key<Params>::Kind::Count:
                section.read<uint32_t>(key.name, *key.count(params), static_cast<uint32_t>(key.minimum),
                                       static_cast<uint32_t>(key.maximum));
                break;
            case Key<Params>::Kind::Flag: section.readBool(key.name, *key.flag(params)); break;
            case Key<Params>::Kind::Id: {
                int64_t value = *key.id(params);
                section.read<int64_t>(key.name, value, 0, 65535);
                *key.id(params) = static_cast<uint16_t>(value);
                break;
            }
            }
        }
        if (nested) {
            nested_section.rejectUnknownKeys();
        }
    }
    top_section.rejectUnknownKeys();
}

template <typename Params>
std::string emitKeys(const char *top, const std::vector<Key<Params>> &keys, const Params &defaults)
{
    Params params = defaults;
    YAML::Emitter out;
    out << YAML::BeginMap << YAML::Key << top << YAML::Value << YAML::BeginMap;
    std::string open_group;
    bool in_group = false;
    for (const Key<Params> &key : keys) {
        if (key.group != open_group) {
            if (in_group) {
                out << YAML::EndMap;
                in_group = false;
            }
            open_group = key.group;
            if (!open_group.empty()) {
                out << YAML::Key << open_group << YAML::Value << YAML::BeginMap;
                in_group = true;
            }
        }
        out << YAML::Key << key.name << YAML::Value;
        switch (key.kind) {
        case Key<Params>::Kind::Real: {
            // The shortest text that reads back as the same double: 0.1, not 0.10000000000000001.
            char text[32];
            const std::to_chars_result written = std::to_chars(text, text + sizeof text, *key.real(params));
            out << std::string(text, written.ptr);
            break;
        }
        case Key<Params>::Kind::Count: out << *key.count(params); break;
        case Key<Params>::Kind::Flag: out << (*key.flag(params) ? "true" : "false"); break;
        case Key<Params>::Kind::Id: out << *key.id(params); break;
        }
    }
    if (in_group) {
        out << YAML::EndMap;
    }
    out << YAML::EndMap << YAML::EndMap;
    return std::string(out.c_str()) + "\n";
}

template <typename Params> std::vector<std::string> keyNames(const char *top, const std::vector<Key<Params>> &keys)
{
    std::vector<std::string> names;
    names.reserve(keys.size());
    for (const Key<Params> &key : keys) {
        names.push_back(std::string(top) + "." + (key.group[0] != '\0' ? std::string(key.group) + "." : "") + key.name);
    }
    return names;
}

void validate(const engine::EngineParams &p)
{
    if (p.ring.min_components > p.ring.max_components) {
        throw ConfigError("engine.sog.min_components (" + std::to_string(p.ring.min_components) +
                          ") is larger than engine.sog.max_components (" + std::to_string(p.ring.max_components) + ")");
    }
    const engine::FrameParams &f = p.frame;
    const int named = (f.origin != 0) + (f.x_axis != 0) + (f.positive_y != 0);
    if (named != 0 && named != 3) {
        throw ConfigError("engine.frame: give all three of origin, x_axis and positive_y, or none");
    }
    if (named == 3 && (f.origin == f.x_axis || f.origin == f.positive_y || f.x_axis == f.positive_y)) {
        throw ConfigError("engine.frame: origin, x_axis and positive_y must be three different nodes");
    }
}

} // namespace

engine::MovementParams parseMovementParams(const YAML::Node &root, const std::string &origin)
{
    engine::MovementParams params;
    if (!root || root.IsNull() || !root.IsMap()) {
        return params;
    }
    parseKeys(root, "movement", origin, movementKeys(), params);
    return params;
}

std::string movementParamsYaml(const engine::MovementParams &params)
{
    return emitKeys("movement", movementKeys(), params);
}

engine::MovingCalibrationParams parseCalibrationParams(const YAML::Node &root, const std::string &origin,
                                                       const engine::EngineParams &engine)
{
    engine::MovingCalibrationParams params;
    params.range_sigma_m = engine.range.sigma_m;
    if (!root || root.IsNull() || !root.IsMap()) {
        return params;
    }
    parseKeys(root, "calibration", origin, calibrationKeys(), params);
    return params;
}

std::string calibrationParamsYaml(const engine::MovingCalibrationParams &params)
{
    return emitKeys("calibration", calibrationKeys(), params);
}

engine::EngineParams parseEngineParams(const YAML::Node &root, const std::string &origin)
{
    engine::EngineParams params;
    if (!root || root.IsNull()) {
        return params;
    }
    if (!root.IsMap()) {
        throw ConfigError(origin + ": the configuration must be a map of sections (serial:, engine:, ...)");
    }
    parseKeys(root, "engine", origin, engineKeys(), params);
    validate(params);
    return params;
}

std::string engineParamsYaml(const engine::EngineParams &params) { return emitKeys("engine", engineKeys(), params); }

std::vector<std::string> configurationKeys()
{
    std::vector<std::string> names = keyNames("engine", engineKeys());
    const std::vector<std::string> movement = keyNames("movement", movementKeys());
    names.insert(names.end(), movement.begin(), movement.end());
    const std::vector<std::string> calibration = keyNames("calibration", calibrationKeys());
    names.insert(names.end(), calibration.begin(), calibration.end());
    return names;
}

void applySettings(YAML::Node &root, const std::vector<std::string> &settings)
{
    if (!root || root.IsNull()) {
        root = YAML::Node(YAML::NodeType::Map);
    }
    for (const std::string &setting : settings) {
        const size_t equals = setting.find('=');
        if (equals == std::string::npos || equals == 0) {
            throw ConfigError("--set '" + setting + "': expected SECTION.KEY=VALUE, e.g. engine.range.sigma_m=0.13");
        }
        const std::string path = setting.substr(0, equals);
        const std::string value = setting.substr(equals + 1);
        std::vector<std::string> parts;
        std::stringstream stream(path);
        std::string part;
        while (std::getline(stream, part, '.')) {
            if (part.empty()) {
                throw ConfigError("--set '" + setting + "': empty name in '" + path + "'");
            }
            parts.push_back(part);
        }
        if (parts.size() < 2) {
            throw ConfigError("--set '" + setting + "': expected SECTION.KEY=VALUE");
        }
        // Walk down, creating maps; yaml-cpp nodes are handles, so reassigning is needed.
        std::vector<YAML::Node> chain{root};
        for (size_t i = 0; i + 1 < parts.size(); ++i) {
            YAML::Node next = chain.back()[parts[i]];
            if (!next || next.IsNull()) {
                next = YAML::Node(YAML::NodeType::Map);
                chain.back()[parts[i]] = next;
                next = chain.back()[parts[i]];
            } else if (!next.IsMap()) {
                throw ConfigError("--set '" + setting + "': '" + parts[i] + "' is not a section");
            }
            chain.push_back(next);
        }
        YAML::Node parsed;
        try {
            parsed = YAML::Load(value);
        } catch (const YAML::Exception &) {
            parsed = YAML::Node(value);
        }
        chain.back()[parts.back()] = parsed;
    }
}

ConfigDocument loadConfigDocument(const std::string &path, const std::vector<std::string> &sets)
{
    ConfigDocument document;
    document.origin = path.empty() ? "<defaults>" : path;
    if (!path.empty()) {
        std::ifstream in(path, std::ios::binary);
        if (!in) {
            throw ConfigError(path + ": cannot read the configuration file");
        }
        std::ostringstream text;
        text << in.rdbuf();
        document.service_text = text.str();
        try {
            document.root = YAML::Load(document.service_text);
        } catch (const YAML::Exception &error) {
            throw ConfigError(path + ": not valid YAML: " + error.what());
        }
    }
    // Each layer rejects unknown keys inside its sections; a misspelt section name, in the file or
    // in a --set, is caught here, where every layer's sections are known.
    std::vector<std::string> sections = service::serviceSectionNames();
    sections.insert(sections.end(), {"engine", "movement", "calibration", "map"});
    service::rejectUnknownSections(document.root, document.origin, sections);
    if (!sets.empty()) {
        applySettings(document.root, sets);
        service::rejectUnknownSections(document.root, "--set", sections);
        YAML::Emitter out;
        out << document.root;
        document.service_text = out.c_str();
        document.origin += " + --set";
    }
    return document;
}

engine::EngineParams loadEngineParams(const std::string &config_path, const EngineOverrides &overrides)
{
    const ConfigDocument document = loadConfigDocument(config_path, overrides.sets);
    engine::EngineParams params = parseEngineParams(document.root, document.origin);
    applySwitches(params, overrides);
    return params;
}

void applySwitches(engine::EngineParams &params, const EngineOverrides &overrides)
{
    if (overrides.no_weight_transfer) {
        params.sog.weight_transfer = false;
    }
    if (overrides.no_cooperative) {
        params.sog.cooperative = false;
    }
    if (overrides.no_refinement) {
        params.refinement.enabled = false;
    }
    if (overrides.no_motion_reset) {
        params.motion.reset = false;
    }
}

void addEngineOptions(CLI::App &app, EngineOverrides &o)
{
    app.add_option("--set", o.sets,
                   "set a parameter over the file: SECTION.KEY=VALUE, e.g. engine.range.sigma_m=0.13 "
                   "(repeatable; docs/engine.md lists every key)");
    app.add_flag("--no-weight-transfer", o.no_weight_transfer, "ablation: no weight transfer (eq. 15)");
    app.add_flag("--no-cooperative", o.no_cooperative,
                 "ablation: SoG weights from the ring's own range only, not the other nodes' ranges");
    app.add_flag("--no-refinement", o.no_refinement,
                 "the paper's filter alone: the merged SoG is the estimate (no robust refinement)");
    app.add_flag("--no-motion-reset", o.no_motion_reset,
                 "ablation: moving nodes handled as static (no SoG resets, no track)");
}

} // namespace cdro::hostd
