// The engine's configuration: every key of engineParamsYaml (what --print-config prints) reads
// back to the same parameters, bit for bit; unknown keys and bad values name file, line and
// key; --set KEY=VALUE goes over the file and is checked the same way.
#include <cstdio>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>

#include "cdro/hostd/engine_config.hpp"
#include "cdro/hostd/known_geometry.hpp"
#include "cdro/service/config.hpp"

namespace cdro::hostd {
namespace {

using service::ConfigError;

engine::EngineParams parse(const std::string &text, const std::string &origin = "test.yaml")
{
    return parseEngineParams(YAML::Load(text), origin);
}

std::string errorOf(const std::string &text)
{
    try {
        parse(text);
    } catch (const ConfigError &error) {
        return error.what();
    }
    return "";
}

// Every parameter moved off its default, to values that need all 17 digits.
engine::EngineParams unusual()
{
    engine::EngineParams p;
    p.range.sigma_m = 0.123456789012345678;
    p.range.max_range_m = 87.654321098765432;
    p.range.window = 7;
    p.range.unknown_height_spread_m = 0.8765432109876543;
    p.likelihood.robust = false;
    p.likelihood.nlos_fraction = 0.2345678901234567;
    p.likelihood.nlos_mean_excess_m = 1.7777777777777777;
    p.likelihood.gross_density_per_m = 3.3333333333333333e-5;
    p.ring.arc_spacing_m = 0.7071067811865476;
    p.ring.min_components = 40;
    p.ring.max_components = 500;
    p.ring.tangential_overlap = 2.2;
    p.ring.weight_floor = 2.5e-7;
    p.sog.cooperative = false;
    p.sog.weight_transfer = false;
    p.sog.transfer_sigma_m = 0.3141592653589793;
    p.sog.gate_sigma = 5.5;
    p.sog.process_noise_m2 = 1.2345e-7;
    p.sog.full_update_every = 3;
    p.placement.min_triangle_height_m = 1.5;
    p.placement.min_baseline_m = 0.75;
    p.placement.ambiguity_gap_nats = 3.25;
    p.placement.distinct_m = 0.9;
    p.refinement.enabled = false;
    p.refinement.max_iterations = 9;
    p.refinement.hypothesis_switch_m = 1.25;
    p.refinement.switch_gap_nats = 2.75;
    p.refinement.relax_per_range = 4;
    p.refinement.relax_threshold_m = 2e-3;
    p.refinement.settle_per_placed = 11;
    p.refinement.settle_per_range = 3;
    p.refinement.inconsistent_residual_m = 1.75;
    p.refinement.inconsistent_fraction = 0.6;
    p.refinement.max_placements = 6;
    p.solve.enabled = false;
    p.solve.link_growth = 1.5;
    p.solve.min_links = 9;
    p.solve.quiet_ranges_per_link = 3.5;
    p.solve.min_gain_nats = 0.5;
    p.solve.adopt_after_sweeps = 1.5;
    p.solve.range_offsets = false;
    p.solve.connectivity = false;
    p.solve.threads = 3;
    p.convergence.reliable_m = 0.75;
    p.convergence.common_excess_m = 0.125;
    p.convergence.room_excess_m = 0.375;
    p.convergence.smoothing = 0.95;
    p.convergence.threshold_m = 0.02;
    p.convergence.consecutive = 4;
    p.convergence.unconverge_factor = 8.0;
    p.convergence.min_updates = 21;
    p.ring.weight_floor = 2.5e-7;
    p.sog.collapse_reset = false;
    p.sog.rings_follow_center = false;
    p.placement.patience_ranges = 77;
    p.motion.reset = false;
    p.motion.infer_from_ranges = false;
    p.motion.inferred_residual_m = 0.625;
    p.motion.inferred_window = 10;
    p.motion.inferred_min_large = 5;
    p.motion.inferred_min_links = 3;
    p.motion.inferred_still_speed_mps = 0.3;
    p.motion.inferred_still_m = 0.2;
    p.motion.inferred_still_updates = 9;
    p.motion.track = false;
    p.motion.track_accel_sigma_mps2 = 0.75;
    p.motion.track_speed_sigma_mps = 1.25;
    p.motion.track_warmup = 4;
    p.motion.track_max_speed_mps = 2.5;
    p.motion.flight_speed_sigma_mps = 0.9;
    p.motion.flight_speed_tau_s = 3.5;
    p.motion.flight_floor_z_m = -0.25;
    p.frame.origin = 0x6001;
    p.frame.x_axis = 0x6002;
    p.frame.positive_y = 65535;
    return p;
}

TEST(EngineConfig, PrintedSettingsReadBackBitForBit)
{
    for (const engine::EngineParams &params : {engine::EngineParams{}, unusual()}) {
        const std::string yaml = engineParamsYaml(params);
        const engine::EngineParams back = parse(yaml);
        // The printed form is complete, so printing what was read gives the same text...
        EXPECT_EQ(engineParamsYaml(back), yaml);
        // ...and the values are the same doubles (17 significant digits survive).
        EXPECT_EQ(back.range.sigma_m, params.range.sigma_m);
        EXPECT_EQ(back.likelihood.gross_density_per_m, params.likelihood.gross_density_per_m);
        EXPECT_EQ(back.ring.arc_spacing_m, params.ring.arc_spacing_m);
        EXPECT_EQ(back.sog.transfer_sigma_m, params.sog.transfer_sigma_m);
        EXPECT_EQ(back.sog.process_noise_m2, params.sog.process_noise_m2);
        EXPECT_EQ(back.frame.positive_y, params.frame.positive_y);
        EXPECT_EQ(back.refinement.enabled, params.refinement.enabled);
    }
    // The unusual values are not the defaults: the comparison above is not trivial.
    EXPECT_NE(engineParamsYaml(unusual()), engineParamsYaml(engine::EngineParams{}));
}

TEST(EngineConfig, EveryParameterHasAKey)
{
    // Each key of the printed form changes its parameter when set alone: none is printed but
    // ignored on reading.
    const std::string defaults = engineParamsYaml(engine::EngineParams{});
    const YAML::Node printed = YAML::Load(engineParamsYaml(unusual()));
    size_t keys = 0;
    for (const auto &group : printed["engine"]) {
        for (const auto &key : group.second) {
            const std::string name = "engine." + group.first.as<std::string>() + "." + key.first.as<std::string>();
            YAML::Node root;
            applySettings(root, {name + "=" + key.second.as<std::string>()});
            std::string setting_error;
            std::string text;
            try {
                text = engineParamsYaml(parseEngineParams(root, "--set"));
            } catch (const ConfigError &error) {
                setting_error = error.what(); // the frame needs all three ids: set together below
            }
            if (group.first.as<std::string>() == "frame") {
                EXPECT_NE(setting_error.find("give all three"), std::string::npos) << setting_error;
            } else {
                EXPECT_EQ(setting_error, "") << name;
                EXPECT_NE(text, defaults) << name << " is printed but not read";
            }
            ++keys;
        }
    }
    size_t listed = 0;
    for (const std::string &name : configurationKeys()) {
        listed += name.rfind("engine.", 0) == 0 ? 1U : 0U;
    }
    EXPECT_EQ(keys, listed);
    EXPECT_GE(keys, 60U); // the table is not empty by accident
}

// docs/engine.md has a table row for every key a user can set (engine.* and movement.*), so a
// parameter cannot be added without its default, unit and meaning written down.
TEST(EngineConfig, EveryKeyHasARowInDocsEngineMd)
{
    const std::string path = std::string(CDRO_SOURCE_DIR) + "/docs/engine.md";
    std::ifstream file(path);
    ASSERT_TRUE(file.good()) << path;
    // Through a stringstream: gcc 12 sees a null dereference in istreambuf_iterator into a string.
    std::stringstream text;
    text << file.rdbuf();
    const std::string doc = text.str();
    size_t checked = 0;
    for (const std::string &name : configurationKeys()) {
        EXPECT_NE(doc.find("| `" + name + "` |"), std::string::npos) << name << " has no row in " << path;
        ++checked;
    }
    EXPECT_GE(checked, 80U);
}

TEST(EngineConfig, AnUnknownKeyNamesFileLineKeyAndTheKnownKeys)
{
    const std::string message = errorOf("engine:\n  range:\n    sigma_m: 0.2\n    sigmaa_m: 0.1\n");
    EXPECT_NE(message.find("test.yaml:4"), std::string::npos) << message;
    EXPECT_NE(message.find("'sigmaa_m'"), std::string::npos) << message;
    EXPECT_NE(message.find("engine.range"), std::string::npos) << message;
    EXPECT_NE(message.find("known keys: max_range_m, sigma_m, unknown_height_spread_m, window"), std::string::npos)
        << message;
    const std::string group = errorOf("engine:\n  rnage:\n    sigma_m: 0.2\n");
    EXPECT_NE(group.find("test.yaml:2"), std::string::npos) << group;
    EXPECT_NE(group.find("'rnage'"), std::string::npos) << group;
    for (const char *known :
         {"convergence", "frame", "likelihood", "placement", "range", "refinement", "sog", "solve"}) {
        EXPECT_NE(group.find(known), std::string::npos) << group;
    }
    // Other sections of the file (the service's) are not the engine's business.
    EXPECT_NO_THROW(parse("serial:\n  device: /dev/null\nengine:\n  range:\n    sigma_m: 0.2\n"));
}

TEST(EngineConfig, BadValuesAreErrorsWithTheirLine)
{
    const std::string low = errorOf("engine:\n  range:\n    sigma_m: 0\n");
    EXPECT_NE(low.find("test.yaml:3"), std::string::npos) << low;
    EXPECT_NE(low.find("sigma_m"), std::string::npos) << low;
    EXPECT_NE(low.find("must be between"), std::string::npos) << low;
    EXPECT_NE(errorOf("engine:\n  range:\n    window: 33\n").find("must be between 1 and 32"), std::string::npos);
    EXPECT_NE(errorOf("engine:\n  sog:\n    cooperative: maybe\n").find("expected true or false"), std::string::npos);
    EXPECT_NE(errorOf("engine:\n  range:\n    sigma_m: abc\n").find("expected a number"), std::string::npos);
    EXPECT_NE(errorOf("engine:\n  range:\n    sigma_m: .nan\n").find("finite"), std::string::npos);
    EXPECT_NE(errorOf("engine:\n  range: 3\n").find("must be a map"), std::string::npos);
    EXPECT_NE(errorOf("engine:\n  sog:\n    min_components: 800\n").find("larger than engine.sog.max_components"),
              std::string::npos);
    EXPECT_NE(errorOf("engine:\n  frame:\n    origin: 5\n").find("all three"), std::string::npos);
    EXPECT_NE(errorOf("engine:\n  frame:\n    origin: 5\n    x_axis: 5\n    positive_y: 6\n").find("three different"),
              std::string::npos);
    EXPECT_NE(
        errorOf("engine:\n  frame:\n    origin: 70000\n    x_axis: 5\n    positive_y: 6\n").find("between 0 and 65535"),
        std::string::npos);
    EXPECT_NE(errorOf("- a\n- b\n").find("must be a map of sections"), std::string::npos);
}

TEST(EngineConfig, SettingsGoOverTheFileAndAreCheckedTheSameWay)
{
    YAML::Node root = YAML::Load("engine:\n  range:\n    sigma_m: 0.2\n    window: 9\n");
    applySettings(root, {"engine.range.sigma_m=0.13", "engine.sog.weight_transfer=false", "engine.frame.origin=0x10",
                         "engine.frame.x_axis=17", "engine.frame.positive_y=18"});
    const engine::EngineParams p = parseEngineParams(root, "f + --set");
    EXPECT_EQ(p.range.sigma_m, 0.13);
    EXPECT_EQ(p.range.window, 9U); // the file's, untouched
    EXPECT_FALSE(p.sog.weight_transfer);
    EXPECT_EQ(p.frame.origin, 16); // node ids in hex, as Pozyx prints them
    // Applied in order: the last setting of a key wins.
    YAML::Node twice;
    applySettings(twice, {"engine.range.sigma_m=0.3", "engine.range.sigma_m=0.4"});
    EXPECT_EQ(parseEngineParams(twice, "--set").range.sigma_m, 0.4);
    // A setting of an unknown key is the same error as in a file.
    YAML::Node unknown;
    applySettings(unknown, {"engine.range.sigma=0.1"});
    EXPECT_THROW(parseEngineParams(unknown, "--set"), ConfigError);
}

TEST(EngineConfig, MalformedSettingsAreErrors)
{
    for (const char *bad : {"engine.range.sigma_m", "=0.1", "engine..sigma_m=1", "engine=1", ".engine.range=1"}) {
        YAML::Node root;
        EXPECT_THROW(applySettings(root, {bad}), ConfigError) << bad;
    }
    YAML::Node root;
    applySettings(root, {"engine.range.sigma_m=0.1"});
    try {
        applySettings(root, {"engine.range.sigma_m.deeper=1"});
        ADD_FAILURE() << "a scalar was taken for a section";
    } catch (const ConfigError &error) {
        EXPECT_NE(std::string(error.what()).find("'sigma_m' is not a section"), std::string::npos) << error.what();
    }
}

TEST(EngineConfig, LoadAppliesFileSettingsAndSwitches)
{
    const std::string path = ::testing::TempDir() + "cdro-engine-config-test.yaml";
    {
        std::ofstream out(path);
        out << "engine:\n  range:\n    sigma_m: 0.2\n  sog:\n    gate_sigma: 6\n";
    }
    EngineOverrides overrides;
    overrides.sets = {"engine.range.sigma_m=0.13"};
    overrides.no_weight_transfer = true;
    overrides.no_cooperative = true;
    overrides.no_refinement = true;
    const engine::EngineParams p = loadEngineParams(path, overrides);
    EXPECT_EQ(p.range.sigma_m, 0.13);
    EXPECT_EQ(p.sog.gate_sigma, 6.0);
    EXPECT_FALSE(p.sog.weight_transfer);
    EXPECT_FALSE(p.sog.cooperative);
    EXPECT_FALSE(p.refinement.enabled);
    // No file: the defaults.
    EXPECT_EQ(engineParamsYaml(loadEngineParams("", EngineOverrides{})), engineParamsYaml(engine::EngineParams{}));
    try {
        loadEngineParams(path + ".missing", EngineOverrides{});
        ADD_FAILURE() << "a missing file was read";
    } catch (const ConfigError &error) {
        EXPECT_NE(std::string(error.what()).find("cannot read"), std::string::npos) << error.what();
    }
    // A setting in a section that does not exist is a mistake, not a new section (the same check
    // as cdro-hostd's: one loader).
    EngineOverrides misspelt;
    misspelt.sets = {"solve.adopt_after_sweeps=1"};
    try {
        loadEngineParams("", misspelt);
        ADD_FAILURE() << "a setting of an unknown section was taken";
    } catch (const ConfigError &error) {
        EXPECT_NE(std::string(error.what()).find("unknown section 'solve'"), std::string::npos) << error.what();
    }
    std::remove(path.c_str());
}

// map.moving: the nodes tracked in 3D, read as node ids, and recorded in a capture's run context
// (only when there are some: a run without them records what it did before).
TEST(KnownGeometry, MapMovingIsReadCheckedAndRecordedInTheRunContext)
{
    const KnownGeometry geometry = parseKnownGeometry(YAML::Load("map:\n  moving: [0x6A70, 11]\n"), "test.yaml");
    EXPECT_EQ(geometry.moving, (std::vector<uint16_t>{0x6A70, 11}));
    std::string error;
    try {
        parseKnownGeometry(YAML::Load("map:\n  moving: [10, 0]\n"), "test.yaml");
    } catch (const ConfigError &thrown) {
        error = thrown.what();
    }
    EXPECT_NE(error.find("map.moving"), std::string::npos) << error;
    EXPECT_NE(error.find("outside 1..65535"), std::string::npos) << error;

    RunContext context;
    context.settings = "engine: {}\n";
    const std::string without = encodeRunContext(context);
    EXPECT_EQ(without.find("moving"), std::string::npos) << without;
    EXPECT_TRUE(decodeRunContext(without, "test").moving.empty());
    context.moving = {0x6A70, 11};
    const RunContext back = decodeRunContext(encodeRunContext(context), "test");
    EXPECT_EQ(back.moving, context.moving);
    EXPECT_EQ(back.settings, context.settings);
}

// A live run records that it adopted its global solves between frames (host events in its
// capture), so that its replay adopts them there; a context without the key (cdro-sim's captures,
// older cdro-hostd's) keeps the fixed lag, and a value this build does not know is refused.
TEST(KnownGeometry, TheRunContextSaysWhetherTheSolvesAdoptionsWereRecorded)
{
    RunContext context;
    context.settings = "engine: {}\n";
    const std::string lagged = encodeRunContext(context);
    EXPECT_EQ(lagged.find("solve_adoption"), std::string::npos) << lagged;
    EXPECT_FALSE(decodeRunContext(lagged, "test").solve_adoption_recorded);
    context.solve_adoption_recorded = true;
    const std::string recorded = encodeRunContext(context);
    EXPECT_TRUE(decodeRunContext(recorded, "test").solve_adoption_recorded);
    std::string unknown = recorded;
    unknown.replace(unknown.find("\"recorded\""), 10, "\"whenever\"");
    EXPECT_THROW(decodeRunContext(unknown, "test"), ConfigError);
}

} // namespace
} // namespace cdro::hostd
