#include "cdro/hostd/engine_config.hpp"

#include <fstream>
#include <sstream>

#include <CLI/CLI.hpp>
#include <yaml-cpp/yaml.h>

#include "cdro/service/yaml_section.hpp"

namespace cdro::hostd {

using cdro::service::ConfigError;
using cdro::service::Section;

namespace {

constexpr double kHuge = 1e9;

void readNodeId(Section &s, const char *key, engine::NodeId &id)
{
    int64_t value = id;
    s.read<int64_t>(key, value, 0, 65535);
    id = static_cast<engine::NodeId>(value);
}

// Each group is one nested section: engine.<group>.<key>.
void parseRange(Section &s, engine::RangeParams &p)
{
    s.read<double>("sigma_m", p.sigma_m, 0.001, 100.0);
    s.read<double>("max_range_m", p.max_range_m, 0.1, 1e6);
    s.read<uint32_t>("window", p.window, 1, engine::RangeWindow::kCapacity);
}

void parseLikelihood(Section &s, engine::RangeLikelihoodParams &p)
{
    s.readBool("robust", p.robust);
    s.read<double>("nlos_fraction", p.nlos_fraction, 0.0, 1.0);
    s.read<double>("nlos_mean_excess_m", p.nlos_mean_excess_m, 0.001, 1000.0);
    s.read<double>("gross_density_per_m", p.gross_density_per_m, 1e-12, 1.0);
}

void parseSog(Section &s, engine::EngineParams &p)
{
    s.read<double>("arc_spacing_m", p.ring.arc_spacing_m, 0.01, 100.0);
    s.read<uint32_t>("min_components", p.ring.min_components, 3, 100000);
    s.read<uint32_t>("max_components", p.ring.max_components, 3, 100000);
    s.read<double>("tangential_overlap", p.ring.tangential_overlap, 0.1, 100.0);
    s.read<double>("weight_floor", p.ring.weight_floor, 0.0, 0.01);
    s.readBool("cooperative", p.sog.cooperative);
    s.readBool("weight_transfer", p.sog.weight_transfer);
    s.read<double>("transfer_sigma_m", p.sog.transfer_sigma_m, 0.001, 100.0);
    s.read<double>("gate_sigma", p.sog.gate_sigma, 0.5, 1000.0);
    s.read<double>("process_noise_m2", p.sog.process_noise_m2, 0.0, 100.0);
    s.read<uint32_t>("full_update_every", p.sog.full_update_every, 1, 100000);
}

void parsePlacement(Section &s, engine::PlacementParams &p)
{
    s.read<double>("min_triangle_height_m", p.min_triangle_height_m, 0.0, kHuge);
    s.read<double>("min_baseline_m", p.min_baseline_m, 0.0, kHuge);
    s.read<double>("ambiguity_gap_nats", p.ambiguity_gap_nats, 0.0, kHuge);
    s.read<double>("distinct_m", p.distinct_m, 0.001, kHuge);
    s.readBool("mds_tie_break", p.mds_tie_break);
    s.read<double>("mds_decisive_ratio", p.mds_decisive_ratio, 0.0, 1.0);
    s.read<double>("mds_margin_sigmas", p.mds_margin_sigmas, 0.0, kHuge);
}

void parseRefinement(Section &s, engine::RefinementParams &p)
{
    s.readBool("enabled", p.enabled);
    s.read<uint32_t>("max_iterations", p.max_iterations, 1, 1000);
    s.read<double>("hypothesis_switch_m", p.hypothesis_switch_m, 0.0, kHuge);
    s.read<double>("switch_gap_nats", p.switch_gap_nats, 0.0, kHuge);
    s.read<uint32_t>("relax_per_range", p.relax_per_range, 0, 100000);
    s.read<double>("relax_threshold_m", p.relax_threshold_m, 0.0, kHuge);
    s.read<uint32_t>("settle_per_placed", p.settle_per_placed, 0, 100000);
    s.read<double>("inconsistent_residual_m", p.inconsistent_residual_m, 0.0, kHuge);
    s.read<double>("inconsistent_fraction", p.inconsistent_fraction, 0.0, 1.0);
    s.read<uint32_t>("max_placements", p.max_placements, 1, 1000);
}

void parseReinitialization(Section &s, engine::ReinitializationParams &p)
{
    s.readBool("enabled", p.enabled);
    s.read<double>("link_growth", p.link_growth, 1.0001, 100.0);
    s.read<uint32_t>("min_links", p.min_links, 3, 1000000);
    s.read<double>("quiet_ranges_per_link", p.quiet_ranges_per_link, 0.0, kHuge);
    s.read<uint32_t>("sweeps", p.sweeps, 1, 10000);
    s.read<double>("min_gain_nats", p.min_gain_nats, 0.0, kHuge);
}

void parseMotion(Section &s, engine::MotionParams &p)
{
    s.readBool("reset", p.reset);
    s.readBool("infer_from_ranges", p.infer_from_ranges);
    s.read<double>("inferred_residual_m", p.inferred_residual_m, 0.0, kHuge);
    s.read<uint32_t>("inferred_window", p.inferred_window, 1, engine::NodeState::kRecentRanges);
    s.read<uint32_t>("inferred_min_large", p.inferred_min_large, 1, engine::NodeState::kRecentRanges);
    s.read<uint32_t>("inferred_min_links", p.inferred_min_links, 1, engine::NodeState::kRecentRanges);
    s.read<double>("inferred_still_speed_mps", p.inferred_still_speed_mps, 0.0, kHuge);
    s.read<double>("inferred_still_m", p.inferred_still_m, 0.0, kHuge);
    s.read<uint32_t>("inferred_still_updates", p.inferred_still_updates, 1, 100000);
    s.readBool("track", p.track);
    s.read<double>("track_accel_sigma_mps2", p.track_accel_sigma_mps2, 0.0, 1000.0);
    s.read<double>("track_speed_sigma_mps", p.track_speed_sigma_mps, 0.0, 1000.0);
    s.read<uint32_t>("track_warmup", p.track_warmup, 0, 1000);
}

void parseConvergence(Section &s, engine::ConvergenceParams &p)
{
    s.read<double>("smoothing", p.smoothing, 0.0, 0.9999);
    s.read<double>("threshold_m", p.threshold_m, 0.0, kHuge);
    s.read<uint32_t>("consecutive", p.consecutive, 1, 100000);
    s.read<uint32_t>("min_updates", p.min_updates, 0, 100000000);
    s.read<double>("unconverge_factor", p.unconverge_factor, 1.0, kHuge);
}

void parseFrame(Section &s, engine::FrameParams &p)
{
    readNodeId(s, "origin", p.origin);
    readNodeId(s, "x_axis", p.x_axis);
    readNodeId(s, "positive_y", p.positive_y);
}

template <typename Parse, typename Value>
void group(Section &engine_section, const char *name, Parse parse, Value &value)
{
    Section s(engine_section.child(name), std::string("engine.") + name, engine_section.origin());
    parse(s, value);
    s.rejectUnknownKeys();
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

void parseOdometryNoise(Section &s, engine::RobotFilterNoise &p)
{
    s.read<double>("distance_fraction", p.distance_fraction, 0.0, 10.0);
    s.read<double>("distance_floor_m", p.distance_floor_m, 0.0, kHuge);
    s.read<double>("heading_fraction", p.heading_fraction, 0.0, 10.0);
    s.read<double>("heading_floor_rad", p.heading_floor_rad, 0.0, 10.0);
    s.read<double>("heading_walk_rad_per_sqrt_s", p.heading_walk_rad_per_sqrt_s, 0.0, 10.0);
    s.read<double>("scale_walk_per_sqrt_s", p.scale_walk_per_sqrt_s, 0.0, 1.0);
    s.read<double>("offset_walk_m_per_sqrt_s", p.offset_walk_m_per_sqrt_s, 0.0, kHuge);
}

void parseMovement(Section &s, engine::MovementParams &p)
{
    readNodeId(s, "robot_id", p.robot_id);
    s.read<double>("range_sigma_m", p.range_sigma_m, 0.0, 100.0);
    s.read<double>("adaptive_initial_sigma_m", p.adaptive_initial_sigma_m, 0.001, 100.0);
    s.read<uint32_t>("adaptive_window", p.adaptive_window, 8, 100000);
    s.readBool("estimate_scale", p.estimate_scale);
    s.read<double>("scale_sigma", p.scale_sigma, 0.0, 1.0);
    s.readBool("estimate_offset", p.estimate_offset);
    s.read<double>("offset_sigma_m", p.offset_sigma_m, 0.0, 100.0);
    s.read<double>("gate_sigma", p.gate_sigma, 0.5, 1000.0);
    s.read<double>("motion_start_m", p.motion_start_m, 0.0, kHuge);
    s.read<uint32_t>("heading_hypotheses", p.heading_hypotheses, 1, 360);
    s.read<double>("heading_collapse_weight", p.heading_collapse_weight, 0.5, 1.0);
    s.read<double>("heading_prune_weight", p.heading_prune_weight, 0.0, 0.5);
    s.read<double>("heading_merge_m", p.heading_merge_m, 0.0, kHuge);
    s.read<double>("heading_merge_rad", p.heading_merge_rad, 0.0, 3.2);
    s.read<double>("beacon_arc_spacing_m", p.beacon_arc_spacing_m, 0.05, 100.0);
    s.read<uint32_t>("beacon_min_components", p.beacon_min_components, 3, 100000);
    s.read<double>("beacon_prune_ratio", p.beacon_prune_ratio, 0.0, 1.0);
    s.read<uint32_t>("beacon_min_ranges", p.beacon_min_ranges, 1, 100000);
    s.read<double>("beacon_insert_std_m", p.beacon_insert_std_m, 0.001, kHuge);
    s.read<double>("beacon_min_baseline_m", p.beacon_min_baseline_m, 0.0, kHuge);
    Section noise(s.child("odometry"), "movement.odometry", s.origin());
    parseOdometryNoise(noise, p.odometry);
    noise.rejectUnknownKeys();
}

} // namespace

engine::MovementParams parseMovementParams(const YAML::Node &root, const std::string &origin)
{
    engine::MovementParams params;
    if (!root || root.IsNull() || !root.IsMap()) {
        return params;
    }
    Section s(root["movement"], "movement", origin);
    parseMovement(s, params);
    s.rejectUnknownKeys();
    return params;
}

std::string movementParamsYaml(const engine::MovementParams &p)
{
    YAML::Emitter out;
    out.SetDoublePrecision(12); // round trips every default, without 0.10000000000000001
    auto b = [](bool value) { return value ? "true" : "false"; };
    out << YAML::BeginMap << YAML::Key << "movement" << YAML::Value << YAML::BeginMap;
    out << YAML::Key << "robot_id" << YAML::Value << p.robot_id;
    out << YAML::Key << "range_sigma_m" << YAML::Value << p.range_sigma_m;
    out << YAML::Key << "adaptive_initial_sigma_m" << YAML::Value << p.adaptive_initial_sigma_m;
    out << YAML::Key << "adaptive_window" << YAML::Value << p.adaptive_window;
    out << YAML::Key << "estimate_scale" << YAML::Value << b(p.estimate_scale);
    out << YAML::Key << "scale_sigma" << YAML::Value << p.scale_sigma;
    out << YAML::Key << "estimate_offset" << YAML::Value << b(p.estimate_offset);
    out << YAML::Key << "offset_sigma_m" << YAML::Value << p.offset_sigma_m;
    out << YAML::Key << "gate_sigma" << YAML::Value << p.gate_sigma;
    out << YAML::Key << "motion_start_m" << YAML::Value << p.motion_start_m;
    out << YAML::Key << "heading_hypotheses" << YAML::Value << p.heading_hypotheses;
    out << YAML::Key << "heading_collapse_weight" << YAML::Value << p.heading_collapse_weight;
    out << YAML::Key << "heading_prune_weight" << YAML::Value << p.heading_prune_weight;
    out << YAML::Key << "heading_merge_m" << YAML::Value << p.heading_merge_m;
    out << YAML::Key << "heading_merge_rad" << YAML::Value << p.heading_merge_rad;
    out << YAML::Key << "beacon_arc_spacing_m" << YAML::Value << p.beacon_arc_spacing_m;
    out << YAML::Key << "beacon_min_components" << YAML::Value << p.beacon_min_components;
    out << YAML::Key << "beacon_prune_ratio" << YAML::Value << p.beacon_prune_ratio;
    out << YAML::Key << "beacon_min_ranges" << YAML::Value << p.beacon_min_ranges;
    out << YAML::Key << "beacon_insert_std_m" << YAML::Value << p.beacon_insert_std_m;
    out << YAML::Key << "beacon_min_baseline_m" << YAML::Value << p.beacon_min_baseline_m;
    out << YAML::Key << "odometry" << YAML::Value << YAML::BeginMap;
    out << YAML::Key << "distance_fraction" << YAML::Value << p.odometry.distance_fraction;
    out << YAML::Key << "distance_floor_m" << YAML::Value << p.odometry.distance_floor_m;
    out << YAML::Key << "heading_fraction" << YAML::Value << p.odometry.heading_fraction;
    out << YAML::Key << "heading_floor_rad" << YAML::Value << p.odometry.heading_floor_rad;
    out << YAML::Key << "heading_walk_rad_per_sqrt_s" << YAML::Value << p.odometry.heading_walk_rad_per_sqrt_s;
    out << YAML::Key << "scale_walk_per_sqrt_s" << YAML::Value << p.odometry.scale_walk_per_sqrt_s;
    out << YAML::Key << "offset_walk_m_per_sqrt_s" << YAML::Value << p.odometry.offset_walk_m_per_sqrt_s;
    out << YAML::EndMap << YAML::EndMap << YAML::EndMap;
    return std::string(out.c_str()) + "\n";
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
    Section engine_section(root["engine"], "engine", origin);
    group(engine_section, "range", parseRange, params.range);
    group(engine_section, "likelihood", parseLikelihood, params.likelihood);
    group(engine_section, "sog", parseSog, params);
    group(engine_section, "placement", parsePlacement, params.placement);
    group(engine_section, "refinement", parseRefinement, params.refinement);
    group(engine_section, "reinitialization", parseReinitialization, params.reinitialization);
    group(engine_section, "motion", parseMotion, params.motion);
    group(engine_section, "convergence", parseConvergence, params.convergence);
    group(engine_section, "frame", parseFrame, params.frame);
    engine_section.rejectUnknownKeys();
    validate(params);
    return params;
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

engine::EngineParams loadEngineParams(const std::string &config_path, const EngineOverrides &overrides)
{
    YAML::Node root;
    std::string origin = "<defaults>";
    if (!config_path.empty()) {
        std::ifstream in(config_path, std::ios::binary);
        if (!in) {
            throw ConfigError(config_path + ": cannot read the configuration file");
        }
        std::ostringstream text;
        text << in.rdbuf();
        try {
            root = YAML::Load(text.str());
        } catch (const YAML::Exception &error) {
            throw ConfigError(config_path + ": not valid YAML: " + error.what());
        }
        origin = config_path;
    }
    if (!overrides.sets.empty()) {
        applySettings(root, overrides.sets);
        origin += " + --set";
    }
    engine::EngineParams params = parseEngineParams(root, origin);
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
    app.add_option("--set", o.sets, "set a parameter over the file: SECTION.KEY=VALUE, e.g. engine.range.sigma_m=0.13 "
                                    "(repeatable; docs/engine.md lists every key)");
    app.add_flag("--no-weight-transfer", o.no_weight_transfer, "ablation: no weight transfer (eq. 15)");
    app.add_flag("--no-cooperative", o.no_cooperative,
                 "ablation: SoG weights from the ring's own range only, not the other nodes' ranges");
    app.add_flag("--no-refinement", o.no_refinement,
                 "the paper's filter alone: the merged SoG is the estimate (no robust refinement)");
    app.add_flag("--no-motion-reset", o.no_motion_reset, "ablation: moving nodes handled as static (no SoG resets, no track)");
}

std::string engineParamsYaml(const engine::EngineParams &p)
{
    YAML::Emitter out;
    out.SetDoublePrecision(12);
    out.SetDoublePrecision(12); // round trips every default, without 0.10000000000000001
    auto b = [](bool value) { return value ? "true" : "false"; };
    out << YAML::BeginMap << YAML::Key << "engine" << YAML::Value << YAML::BeginMap;
    out << YAML::Key << "range" << YAML::Value << YAML::BeginMap << YAML::Key << "sigma_m" << YAML::Value
        << p.range.sigma_m << YAML::Key << "max_range_m" << YAML::Value << p.range.max_range_m << YAML::Key << "window"
        << YAML::Value << p.range.window << YAML::EndMap;
    out << YAML::Key << "likelihood" << YAML::Value << YAML::BeginMap << YAML::Key << "robust" << YAML::Value
        << b(p.likelihood.robust) << YAML::Key << "nlos_fraction" << YAML::Value << p.likelihood.nlos_fraction
        << YAML::Key << "nlos_mean_excess_m" << YAML::Value << p.likelihood.nlos_mean_excess_m << YAML::Key
        << "gross_density_per_m" << YAML::Value << p.likelihood.gross_density_per_m << YAML::EndMap;
    out << YAML::Key << "sog" << YAML::Value << YAML::BeginMap << YAML::Key << "arc_spacing_m" << YAML::Value
        << p.ring.arc_spacing_m << YAML::Key << "min_components" << YAML::Value << p.ring.min_components << YAML::Key
        << "max_components" << YAML::Value << p.ring.max_components << YAML::Key << "tangential_overlap" << YAML::Value
        << p.ring.tangential_overlap << YAML::Key << "weight_floor" << YAML::Value << p.ring.weight_floor << YAML::Key
        << "cooperative" << YAML::Value << b(p.sog.cooperative) << YAML::Key << "weight_transfer" << YAML::Value
        << b(p.sog.weight_transfer) << YAML::Key << "transfer_sigma_m" << YAML::Value << p.sog.transfer_sigma_m
        << YAML::Key << "gate_sigma" << YAML::Value << p.sog.gate_sigma << YAML::Key << "process_noise_m2"
        << YAML::Value << p.sog.process_noise_m2 << YAML::Key << "full_update_every" << YAML::Value
        << p.sog.full_update_every << YAML::EndMap;
    out << YAML::Key << "placement" << YAML::Value << YAML::BeginMap << YAML::Key << "min_triangle_height_m"
        << YAML::Value << p.placement.min_triangle_height_m << YAML::Key << "min_baseline_m" << YAML::Value
        << p.placement.min_baseline_m << YAML::Key << "ambiguity_gap_nats" << YAML::Value
        << p.placement.ambiguity_gap_nats << YAML::Key << "distinct_m" << YAML::Value << p.placement.distinct_m
        << YAML::Key << "mds_tie_break" << YAML::Value << b(p.placement.mds_tie_break) << YAML::Key
        << "mds_decisive_ratio" << YAML::Value << p.placement.mds_decisive_ratio << YAML::Key << "mds_margin_sigmas"
        << YAML::Value << p.placement.mds_margin_sigmas << YAML::EndMap;
    out << YAML::Key << "refinement" << YAML::Value << YAML::BeginMap << YAML::Key << "enabled" << YAML::Value
        << b(p.refinement.enabled) << YAML::Key << "max_iterations" << YAML::Value << p.refinement.max_iterations
        << YAML::Key << "hypothesis_switch_m" << YAML::Value << p.refinement.hypothesis_switch_m << YAML::Key
        << "switch_gap_nats" << YAML::Value << p.refinement.switch_gap_nats << YAML::Key << "relax_per_range"
        << YAML::Value << p.refinement.relax_per_range << YAML::Key << "relax_threshold_m" << YAML::Value
        << p.refinement.relax_threshold_m << YAML::Key << "settle_per_placed" << YAML::Value
        << p.refinement.settle_per_placed << YAML::Key << "inconsistent_residual_m" << YAML::Value
        << p.refinement.inconsistent_residual_m << YAML::Key << "inconsistent_fraction" << YAML::Value
        << p.refinement.inconsistent_fraction << YAML::Key << "max_placements" << YAML::Value
        << p.refinement.max_placements << YAML::EndMap;
    out << YAML::Key << "reinitialization" << YAML::Value << YAML::BeginMap << YAML::Key << "enabled" << YAML::Value
        << b(p.reinitialization.enabled) << YAML::Key << "link_growth" << YAML::Value << p.reinitialization.link_growth
        << YAML::Key << "min_links" << YAML::Value << p.reinitialization.min_links << YAML::Key
        << "quiet_ranges_per_link" << YAML::Value << p.reinitialization.quiet_ranges_per_link << YAML::Key << "sweeps"
        << YAML::Value << p.reinitialization.sweeps << YAML::Key << "min_gain_nats" << YAML::Value
        << p.reinitialization.min_gain_nats << YAML::EndMap;
    out << YAML::Key << "motion" << YAML::Value << YAML::BeginMap << YAML::Key << "reset" << YAML::Value
        << b(p.motion.reset) << YAML::Key << "infer_from_ranges" << YAML::Value << b(p.motion.infer_from_ranges)
        << YAML::Key << "inferred_residual_m" << YAML::Value << p.motion.inferred_residual_m << YAML::Key
        << "inferred_window" << YAML::Value << p.motion.inferred_window << YAML::Key << "inferred_min_large"
        << YAML::Value << p.motion.inferred_min_large << YAML::Key << "inferred_min_links" << YAML::Value
        << p.motion.inferred_min_links << YAML::Key << "inferred_still_speed_mps" << YAML::Value << p.motion.inferred_still_speed_mps
        << YAML::Key << "inferred_still_m" << YAML::Value << p.motion.inferred_still_m
        << YAML::Key << "inferred_still_updates" << YAML::Value << p.motion.inferred_still_updates << YAML::Key
        << "track" << YAML::Value << b(p.motion.track) << YAML::Key << "track_accel_sigma_mps2" << YAML::Value
        << p.motion.track_accel_sigma_mps2 << YAML::Key << "track_speed_sigma_mps" << YAML::Value
        << p.motion.track_speed_sigma_mps << YAML::Key << "track_warmup" << YAML::Value << p.motion.track_warmup
        << YAML::EndMap;
    out << YAML::Key << "convergence" << YAML::Value << YAML::BeginMap << YAML::Key << "smoothing" << YAML::Value
        << p.convergence.smoothing << YAML::Key << "threshold_m" << YAML::Value << p.convergence.threshold_m
        << YAML::Key << "consecutive" << YAML::Value << p.convergence.consecutive
        << YAML::Key << "min_updates" << YAML::Value << p.convergence.min_updates << YAML::Key << "unconverge_factor"
        << YAML::Value << p.convergence.unconverge_factor << YAML::EndMap;
    out << YAML::Key << "frame" << YAML::Value << YAML::BeginMap << YAML::Key << "origin" << YAML::Value
        << p.frame.origin << YAML::Key << "x_axis" << YAML::Value << p.frame.x_axis << YAML::Key << "positive_y"
        << YAML::Value << p.frame.positive_y << YAML::EndMap;
    out << YAML::EndMap << YAML::EndMap;
    return std::string(out.c_str()) + "\n";
}

} // namespace cdro::hostd
