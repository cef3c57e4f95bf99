// Scenario files of cdro-fil: the shipped scenario reads as written, defaults apply, and every
// mistake is an error that names the file, the line and the key.
#include <gtest/gtest.h>

#include <string>

#include "scenario.hpp"

using cdro::fil::FaultKind;
using cdro::fil::parseScenario;
using cdro::fil::Scenario;
using cdro::fil::ScenarioError;

namespace {

const char *const kMinimal = R"(
own_id: 0x6000
nodes:
  - {id: 0x6000, accelerometer: true, x_m: 0, y_m: 0}
  - {id: 0x6A01, x_m: 4, y_m: 0, z_m: 2}
)";

// The message of the ScenarioError that parsing `text` throws ("" if it does not throw).
std::string errorOf(const std::string &text)
{
    try {
        (void)parseScenario(text, "test.yaml");
    } catch (const ScenarioError &error) {
        return error.what();
    }
    return "";
}

} // namespace

TEST(FilScenario, ShippedScenarioReadsAsWritten)
{
    const Scenario s = cdro::fil::loadScenario(CDRO_SOURCE_DIR "/tests/fil/office_60s.yaml");
    EXPECT_EQ(s.name, "office-60s");
    EXPECT_EQ(s.own_id, 0x6000);
    ASSERT_EQ(s.nodes.size(), 7U);
    EXPECT_TRUE(s.node(0x6B05)->accelerometer);
    EXPECT_FALSE(s.node(0x6A02)->accelerometer);
    EXPECT_DOUBLE_EQ(s.node(0x6A01)->position.z_m, 2.4);
    ASSERT_EQ(s.motion.size(), 1U);
    EXPECT_EQ(s.motion[0].node, 0x6B05);
    ASSERT_EQ(s.motion[0].waypoints.size(), 2U);
    EXPECT_DOUBLE_EQ(s.motion[0].waypoints[0].z_m, 1.1) << "a waypoint without z keeps the node's height";
    ASSERT_EQ(s.faults.size(), 10U);
    EXPECT_EQ(s.faults[9].kind, FaultKind::LateReply);
    EXPECT_TRUE(s.pozyx_realistic);
    for (size_t i = 1; i < s.faults.size(); ++i) {
        EXPECT_LE(s.faults[i - 1].at_s, s.faults[i].at_s) << "faults sorted by time";
    }
    EXPECT_EQ(s.faults[6].kind, FaultKind::PowerOff);
    EXPECT_EQ(s.faults[6].node, 0x6A02);
    EXPECT_DOUBLE_EQ(s.faults[6].duration_s, 14.0);
    EXPECT_EQ(s.faults[5].error_code, 0x11);
    EXPECT_GE(s.duration_s, 60.0);
}

TEST(FilScenario, DefaultsApply)
{
    // The defaults of the keys cdro-sim also reads are cdro-sim's (docs/tools.md, "Scenario files";
    // tests/scenarios/test_scenario_format.py compares the two tools on a file without them).
    const Scenario s = parseScenario(kMinimal, "some/dir/test.yaml");
    EXPECT_EQ(s.name, "test") << "the file's name without its extension";
    EXPECT_EQ(s.seed, 1U);
    EXPECT_DOUBLE_EQ(s.duration_s, 60.0);
    EXPECT_DOUBLE_EQ(s.uwb.noise_std_m, 0.1);
    EXPECT_DOUBLE_EQ(s.uwb.max_range_m, 100.0);
    EXPECT_DOUBLE_EQ(s.accel.noise_std_mg, 8.0);
    EXPECT_DOUBLE_EQ(s.accel.moving_frequency_hz, 1.8);
    EXPECT_EQ(s.pozyx_firmware_version, 0x11);
    EXPECT_DOUBLE_EQ(parseScenario(std::string(kMinimal) + "duration_s: 0\n", "test.yaml").duration_s, 0.0)
        << "0 = until a signal";
    EXPECT_TRUE(s.pozyx_realistic) << "the real device's behaviour by default";
    EXPECT_EQ(s.uwb.ranging_us, 40000U) << "and its timings";
    EXPECT_EQ(s.uwb.message_us, 3500U);
    EXPECT_DOUBLE_EQ(s.accel.moving_amplitude_mg, 250.0);
    EXPECT_EQ(s.pozyx_who_am_i, 0x43);
    EXPECT_DOUBLE_EQ(s.node(0x6000)->position.z_m, 0.0);
    EXPECT_TRUE(s.motion.empty());
    EXPECT_TRUE(s.faults.empty());
}

TEST(FilScenario, MistakesNameTheLineAndTheKey)
{
    const std::string base = kMinimal;
    // An unknown key: file, line, path and the known keys.
    std::string message = errorOf(base + "    \n" + "seeed: 3\n");
    EXPECT_NE(message.find("test.yaml:7: scenario.seeed: unknown key"), std::string::npos) << message;
    EXPECT_NE(message.find("seed"), std::string::npos) << message;
    message =
        errorOf("own_id: 0x6000\nnodes:\n  - {id: 0x6000, x_m: 0, y_m: 0, colour: red}\n  - {id: 2, x_m: 1, y_m: 0}\n");
    EXPECT_NE(message.find("test.yaml:3: nodes[0].colour: unknown key"), std::string::npos) << message;
    // Missing and malformed values.
    message = errorOf("own_id: 0x6000\nnodes:\n  - {id: 0x6000, y_m: 0}\n  - {id: 2, x_m: 1, y_m: 0}\n");
    EXPECT_NE(message.find("nodes[0].x_m: missing"), std::string::npos) << message;
    message = errorOf("own_id: 0x6000\nnodes:\n  - {id: 0x6000, x_m: far, y_m: 0}\n  - {id: 2, x_m: 1, y_m: 0}\n");
    EXPECT_NE(message.find("nodes[0].x_m: expected a number, got 'far'"), std::string::npos) << message;
    message = errorOf("own_id: 0x6000\nnodes:\n  - {id: 0xFFFF, x_m: 0, y_m: 0}\n  - {id: 2, x_m: 1, y_m: 0}\n");
    EXPECT_NE(message.find("nodes[0].id: must be in [1, 0xFFFE], got 0xFFFF"), std::string::npos) << message;
    message = errorOf("own_id: 0x6000\nnodes:\n  - {id: 0x6000, x_m: 0, y_m: 0}\n  - {id: 0x6000, x_m: 1, y_m: 0}\n");
    EXPECT_NE(message.find("listed twice"), std::string::npos) << message;
    message = errorOf("own_id: 0x7000\nnodes:\n  - {id: 0x6000, x_m: 0, y_m: 0}\n  - {id: 2, x_m: 1, y_m: 0}\n");
    EXPECT_NE(message.find("scenario.own_id: node 28672 is not in nodes"), std::string::npos) << message;
    message = errorOf("own_id: 0x6000\nnodes:\n  - {id: 0x6000, x_m: 0, y_m: 0}\n");
    EXPECT_NE(message.find("nodes: the number of entries must be in [2, 21], got 1"), std::string::npos) << message;
    EXPECT_NE(errorOf("nodes: [").find("not valid YAML"), std::string::npos);
    EXPECT_NE(errorOf("").find("empty scenario"), std::string::npos);
    message = errorOf(base + "uwb: {noise_std_m: -1}\n");
    EXPECT_NE(message.find("uwb.noise_std_m: must be in [0, 10] m, got -1"), std::string::npos) << message;
    message = errorOf(base + "pozyx: {model: perfect}\n");
    EXPECT_NE(message.find("pozyx.model: 'perfect' is not one of: realistic, ideal"), std::string::npos) << message;
}

TEST(FilScenario, TheIdealModelHasItsOwnTimingsAndUwbOverridesEither)
{
    const std::string base = kMinimal;
    Scenario s = parseScenario(base + "pozyx: {model: ideal}\n", "test.yaml");
    EXPECT_FALSE(s.pozyx_realistic);
    EXPECT_EQ(s.uwb.ranging_us, 15000U);
    EXPECT_EQ(s.uwb.message_us, 3000U);
    s = parseScenario(base + "uwb: {ranging_us: 25000}\npozyx: {model: realistic}\n", "test.yaml");
    EXPECT_EQ(s.uwb.ranging_us, 25000U);
    EXPECT_EQ(s.uwb.message_us, 3500U);
    s = parseScenario(base + "faults:\n  - {kind: late_reply, at_s: 3, count: 2}\n", "test.yaml");
    ASSERT_EQ(s.faults.size(), 1U);
    EXPECT_EQ(s.faults[0].kind, cdro::fil::FaultKind::LateReply);
    EXPECT_EQ(s.faults[0].count, 2U);
}

TEST(FilScenario, MotionIsChecked)
{
    const std::string base = kMinimal;
    std::string message =
        errorOf(base + "motion:\n  - {node: 0x6A09, start_s: 1, speed_mps: 1, waypoints_m: [[1, 1]]}\n");
    EXPECT_NE(message.find("motion[0].node: node 27145 is not in nodes"), std::string::npos) << message;
    message = errorOf(base + "motion:\n  - {node: 0x6A01, start_s: 1, speed_mps: 1, waypoints_m: [[1]]}\n");
    EXPECT_NE(message.find("each waypoint is [x, y] or [x, y, z]"), std::string::npos) << message;
    message = errorOf(base + "motion:\n  - {node: 0x6A01, start_s: 1, speed_mps: 0, waypoints_m: [[1, 1]]}\n");
    EXPECT_NE(message.find("motion[0].speed_mps: must be in [0.01, 20] m/s"), std::string::npos) << message;
    // 4 m at 1 m/s from 1 s: busy until 5 s; a second stretch at 3 s overlaps.
    message = errorOf(base + "motion:\n  - {node: 0x6A01, start_s: 1, speed_mps: 1, waypoints_m: [[8, 0, 2]]}\n"
                             "  - {node: 0x6A01, start_s: 3, speed_mps: 1, waypoints_m: [[4, 0]]}\n");
    EXPECT_NE(message.find("before its previous one ends at 5"), std::string::npos) << message;
    EXPECT_EQ(errorOf(base + "motion:\n  - {node: 0x6A01, start_s: 1, speed_mps: 1, waypoints_m: [[8, 0, 2]]}\n"
                             "  - {node: 0x6A01, start_s: 5, speed_mps: 1, waypoints_m: [[4, 0]]}\n"),
              "");
}

TEST(FilScenario, FaultsAreChecked)
{
    const std::string base = kMinimal;
    std::string message = errorOf(base + "faults:\n  - {kind: hang, at_s: 1}\n");
    EXPECT_NE(message.find("'hang' cannot be simulated here"), std::string::npos) << message;
    message = errorOf(base + "faults:\n  - {kind: lightning, at_s: 1}\n");
    EXPECT_NE(message.find("'lightning' is not one of: nack_address, nack_write"), std::string::npos) << message;
    message = errorOf(base + "faults:\n  - {kind: power_off, at_s: 1, node: 0x6A01}\n");
    EXPECT_NE(message.find("faults[0].duration_s: missing"), std::string::npos) << message;
    message = errorOf(base + "faults:\n  - {kind: power_off, at_s: 1, node: 0x6A01, duration_s: 5}\n"
                             "  - {kind: power_off, at_s: 4, node: 0x6A01, duration_s: 5}\n");
    EXPECT_NE(message.find("overlapping power_off of node 27137"), std::string::npos) << message;
    message = errorOf(base + "faults:\n  - {kind: garbage_range, at_s: 1, count: 0}\n");
    EXPECT_NE(message.find("faults[0].count: must be in [1, 1000000], got 0"), std::string::npos) << message;
    message = errorOf(base + "faults:\n  - {kind: garbage_range, at_s: 1, node: 0x6A01}\n");
    EXPECT_NE(message.find("faults[0].node: unknown key"), std::string::npos) << message;
    message = errorOf(base + "faults:\n  - {kind: nack_write, at_s: 1, error_code: 3}\n");
    EXPECT_NE(message.find("faults[0].error_code: unknown key"), std::string::npos) << message;

    const Scenario s =
        parseScenario(base + "faults:\n  - {kind: error_completion, at_s: 2, count: 3, error_code: 0x17}\n"
                             "  - {kind: nack_write, at_s: 1}\n",
                      "test.yaml");
    ASSERT_EQ(s.faults.size(), 2U);
    EXPECT_EQ(s.faults[0].kind, FaultKind::NackWrite);
    EXPECT_EQ(s.faults[0].count, 1U);
    EXPECT_EQ(s.faults[1].count, 3U);
    EXPECT_EQ(s.faults[1].error_code, 0x17);
}

TEST(FilScenario, AStretchGivesItsSpeedOrItsEnd)
{
    const std::string base = kMinimal;
    // 0x6A01 from (4, 0) to (4, 6) and on to (4, 6, 4): 6 m + 2 m.
    Scenario s = parseScenario(base + "motion:\n  - {node: 0x6A01, start_s: 2, end_s: 6, waypoints_m: [[4, 6]]}\n"
                                      "  - {node: 0x6A01, start_s: 10, speed_mps: 0.5, waypoints_m: [[4, 6, 4]]}\n",
                               "test.yaml");
    ASSERT_EQ(s.motion.size(), 2U);
    EXPECT_DOUBLE_EQ(s.motion[0].speed_mps, 1.5);
    EXPECT_DOUBLE_EQ(s.motion[0].end_s, 6.0);
    EXPECT_DOUBLE_EQ(s.motion[1].speed_mps, 0.5);
    EXPECT_DOUBLE_EQ(s.motion[1].end_s, 14.0);
    std::string message =
        errorOf(base + "motion:\n  - {node: 0x6A01, start_s: 2, end_s: 6, speed_mps: 1, waypoints_m: [[4, 6]]}\n");
    EXPECT_NE(message.find("motion[0]: give exactly one of speed_mps and end_s"), std::string::npos) << message;
    message = errorOf(base + "motion:\n  - {node: 0x6A01, start_s: 2, end_s: 2, waypoints_m: [[4, 6]]}\n");
    EXPECT_NE(message.find("motion[0].end_s: must be after start_s"), std::string::npos) << message;
    message = errorOf(base + "motion:\n  - {node: 0x6A01, start_s: 2, end_s: 3, waypoints_m: [[400, 6]]}\n");
    EXPECT_NE(message.find("motion[0].end_s: "), std::string::npos) << message;
    EXPECT_NE(message.find("the speed must be in [0.01, 20] m/s"), std::string::npos) << message;
}

TEST(FilScenario, AnEarlierSpellingSaysWhatItIsCalledNow)
{
    std::string message =
        errorOf("own: 0x6000\nnodes:\n  - {id: 0x6000, x_m: 0, y_m: 0}\n  - {id: 2, x_m: 1, y_m: 0}\n");
    EXPECT_NE(message.find("test.yaml:1: scenario.own: this key is now called own_id"), std::string::npos) << message;
    message = errorOf("own_id: 0x6000\nnodes:\n  - {id: 0x6000, x: 0, y_m: 0}\n  - {id: 2, x_m: 1, y_m: 0}\n");
    EXPECT_NE(message.find("test.yaml:3: nodes[0].x: this key is now called x_m"), std::string::npos) << message;
    message = errorOf("own_id: 0x6000\nnodes:\n  - {id: 0x6000, tag: true, x_m: 0, y_m: 0}\n"
                      "  - {id: 2, x_m: 1, y_m: 0}\n");
    EXPECT_NE(message.find("nodes[0].tag: this key is now called accelerometer"), std::string::npos) << message;
    const std::string base = kMinimal;
    message = errorOf(base + "uwb: {noise_std_mm: 30}\n");
    EXPECT_NE(message.find("uwb.noise_std_mm: this key is now called noise_std_m (in metres)"), std::string::npos)
        << message;
    message = errorOf(base + "motion:\n  - {node: 0x6A01, start_s: 1, speed_mps: 1, waypoints: [[1, 1]]}\n");
    EXPECT_NE(message.find("motion[0].waypoints: this key is now called waypoints_m"), std::string::npos) << message;
}

TEST(FilScenario, AKeyOnlyCdroSimActsOnIsRefusedSayingSo)
{
    const std::string base = kMinimal;
    for (const char *extra : {"schedule: {mode: all_pairs}\n", "robot: {id: 0x6000, waypoints_m: [[1, 1]]}\n",
                              "uwb: {scale: 1.03}\n", "uwb: {nlos: {outlier_probability: 0.01}}\n",
                              "pozyx: {present: false}\n", "device: {free_ram_bytes: 500}\n"}) {
        const std::string message = errorOf(base + extra);
        EXPECT_NE(message.find("only cdro-sim supports this key"), std::string::npos) << extra << message;
        EXPECT_EQ(message.find("unknown key"), std::string::npos) << extra << message;
    }
    const std::string message = errorOf(base + "faults:\n  - {kind: vanish, at_s: 3, duration_s: 2}\n");
    EXPECT_NE(message.find("faults[0].kind: only cdro-sim supports the fault kind 'vanish'"), std::string::npos)
        << message;
}

TEST(FilScenario, TheSharedViewHasWhatBothToolsRead)
{
    const Scenario s = parseScenario(std::string(kMinimal) + "seed: 9\nduration_s: 12\nuwb: {noise_std_m: 0.05}\n"
                                                             "motion:\n  - {node: 0x6A01, start_s: 2, end_s: 6, "
                                                             "waypoints_m: [[4, 6]]}\n",
                                     "test.yaml");
    const std::string view = cdro::fil::sharedViewJson(s);
    for (const char *part : {"\"own_id\": 24576", "\"seed\": 9", "\"duration_s\": 12.0", "\"noise_std_m\": 0.05",
                             "\"speed_mps\": 1.5", "\"accelerometer\": true", "\"firmware_version\": 17"}) {
        EXPECT_NE(view.find(part), std::string::npos) << part << "\n" << view;
    }
}
