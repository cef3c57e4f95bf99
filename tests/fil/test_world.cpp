// The simulated network of cdro-fil without an AVR: the scenario's nodes on their tracks and
// accelerometer traces (host/netgen's model, tested itself in tests/netgen/test_track.cpp),
// faults applied at their times and accounted when the simulator injects them, rangings
// accounted by kind with the true distance, and the truth file.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <string>

#include "cdro/csv/reader.hpp"
#include "cdro_fw/pozyx_regs.h"
#include "scenario.hpp"
#include "world.hpp"

using cdro::fil::FaultKind;
using cdro::fil::parseScenario;
using cdro::fil::Scenario;
using cdro::fil::trackOf;
using cdro::fil::World;
using cdro::netgen::Track;
using cdro::netgen::Vector3;

namespace {

constexpr uint8_t kAddress = POZYX_SIM_DEFAULT_I2C_ADDRESS;

// A file for the world to write its CSV into, read back afterwards by the C++ side's one CSV
// reader (cdro_csv, Strict: a row that does not read as its columns say fails the test).
std::FILE *openCsv(const std::string &path)
{
    std::FILE *file = std::fopen(path.c_str(), "w");
    EXPECT_NE(file, nullptr) << path;
    return file;
}

std::string firstLine(const std::string &path)
{
    std::ifstream in(path);
    std::string line;
    std::getline(in, line);
    return line;
}

// Own tag at the origin, anchor 0x6A01 at (4, 0, 2) m, tag 0x6B02 carried from (0, 3) to (4, 3)
// at 2 m/s from 1 s (so moving during [1, 3) s). The ideal Pozyx model: these tests check the
// world's accounting, with the model's timings (15 ms a ranging), and 30 mm range noise.
const char *const kScenario = R"(
own_id: 0x6000
seed: 5
pozyx: {model: ideal}
uwb: {noise_std_m: 0.03}
nodes:
  - {id: 0x6000, accelerometer: true, x_m: 0, y_m: 0}
  - {id: 0x6A01, x_m: 4, y_m: 0, z_m: 2}
  - {id: 0x6B02, accelerometer: true, x_m: 0, y_m: 3, z_m: 1}
motion:
  - {node: 0x6B02, start_s: 1, speed_mps: 2, waypoints_m: [[4, 3]]}
)";

Scenario scenario(const std::string &extra = "") { return parseScenario(std::string(kScenario) + extra, "test.yaml"); }

uint64_t us(double t_s) { return static_cast<uint64_t>(std::llround(t_s * 1e6)); }

// A function call on the bus as the driver makes it: START W fn params, repeated START R,
// the return byte, STOP. Returns the return byte (0xFF if refused on the bus).
uint8_t call(World &world, uint8_t fn, std::initializer_list<uint8_t> params, uint64_t at_us)
{
    if (world.i2cStart(kAddress, false, at_us) != POZYX_SIM_ACK || world.i2cWrite(fn, at_us) != POZYX_SIM_ACK) {
        world.i2cStop(at_us);
        return 0xFF;
    }
    for (uint8_t p : params) {
        if (world.i2cWrite(p, at_us) != POZYX_SIM_ACK) {
            world.i2cStop(at_us);
            return 0xFF;
        }
    }
    (void)world.i2cStart(kAddress, true, at_us);
    const uint8_t result = world.i2cRead(false, at_us);
    world.i2cStop(at_us);
    return result;
}

uint8_t doRanging(World &world, uint16_t partner, uint64_t at_us)
{
    return call(world, POZYX_FN_DO_RANGING, {static_cast<uint8_t>(partner & 0xFF), static_cast<uint8_t>(partner >> 8)},
                at_us);
}

} // namespace

TEST(FilTrack, PositionFollowsTheWaypointsAtTheSpeed)
{
    const Scenario s = scenario("  - {node: 0x6B02, start_s: 5, speed_mps: 1, waypoints_m: [[4, 6], [4, 3, 2]]}\n");
    const Track track = trackOf(*s.node(0x6B02), s.motion, s.accel);
    auto at = [&](double t) { return track.positionM(t); };
    EXPECT_DOUBLE_EQ(at(0.0).x(), 0.0);
    EXPECT_DOUBLE_EQ(at(1.0).x(), 0.0);
    EXPECT_DOUBLE_EQ(at(2.0).x(), 2.0) << "2 m/s along x";
    EXPECT_DOUBLE_EQ(at(2.0).z(), 1.0) << "waypoints without z keep the height";
    EXPECT_DOUBLE_EQ(at(4.0).x(), 4.0) << "stays at the last waypoint";
    EXPECT_DOUBLE_EQ(at(6.5).y(), 4.5) << "second stretch, first leg at 1 m/s";
    const Vector3 end = at(100.0);
    EXPECT_DOUBLE_EQ(end.y(), 3.0);
    EXPECT_DOUBLE_EQ(end.z(), 2.0);
    EXPECT_FALSE(track.moving(0.99));
    EXPECT_TRUE(track.moving(1.0));
    EXPECT_TRUE(track.moving(2.99));
    EXPECT_FALSE(track.moving(3.0));
    EXPECT_FALSE(track.moving(4.9));
    EXPECT_TRUE(track.moving(5.0));
    EXPECT_TRUE(track.moving(5.0 + 3.0 + std::sqrt(1.0 + 9.0) - 0.01));
    EXPECT_FALSE(track.moving(5.0 + 3.0 + std::sqrt(1.0 + 9.0) + 0.01));
}

// What the firmware's detector would see at its poll rate: the largest |norm - 1 g| over the
// last 8 samples taken every 200 ms. Above 80 mg through the walk, exactly 0 at rest (the trace
// is noiseless; the simulator adds the sensor noise).
TEST(FilTrack, AccelerometerTraceMovesExactlyWhileCarried)
{
    const Scenario s = scenario();
    const Track track = trackOf(*s.node(0x6B02), s.motion, s.accel);
    std::vector<double> deviations;
    for (double t = 0.0; t < 6.0; t += 0.2) {
        deviations.push_back(std::fabs(track.accelMg(t).norm() - 1000.0));
        const size_t from = deviations.size() > 8 ? deviations.size() - 8 : 0;
        const double window = *std::max_element(deviations.begin() + static_cast<long>(from), deviations.end());
        if (!track.moving(t) && t > 0.0 && (t < 1.0 || t >= 3.0 + 8 * 0.2)) {
            EXPECT_DOUBLE_EQ(window, 0.0) << "at rest at " << t << " s";
        }
        if (t >= 1.0 + 0.4 && t < 3.0) {
            EXPECT_GT(window, 80.0) << "carried at " << t << " s";
        }
    }
    const Vector3 rest = track.accelMg(0.5);
    EXPECT_DOUBLE_EQ(rest.z(), 1000.0);
    EXPECT_DOUBLE_EQ(rest.x(), 0.0);
}

TEST(FilWorld, DirectRangingIsAccountedWithTheTrueDistance)
{
    World world(scenario());
    const std::string path = testing::TempDir() + "fil_world_ranges.csv";
    std::FILE *csv = openCsv(path);
    ASSERT_NE(csv, nullptr);
    world.setRangesCsv(csv);
    ASSERT_EQ(doRanging(world, 0x6A01, us(0.5)), 1);
    world.advance(us(0.5) + 14000);
    EXPECT_EQ(world.rangingsDirect(), 0U) << "a ranging takes 15 ms";
    world.advance(us(0.5) + 16000);
    EXPECT_EQ(world.rangingsDirect(), 1U);
    EXPECT_EQ(world.rangingsRemote(), 0U);

    std::fclose(csv);
    EXPECT_EQ(firstLine(path), "t,kind,from,to,distance_mm,true_distance_mm,result");
    cdro::csv::Reader reader(path, {{"t", "kind", "from", "to", "distance_mm", "true_distance_mm", "result"}, {}, {}},
                             cdro::csv::Policy::Strict);
    int rows = 0;
    reader.forEach([&](const cdro::csv::Row &row) {
        ++rows;
        double t_s = 0, distance_mm = 0, true_mm = 0;
        uint16_t from = 0, to = 0;
        std::string_view kind, result;
        ASSERT_TRUE(row.number("t", &t_s) && row.text("kind", &kind) && row.nodeId("from", &from) &&
                    row.nodeId("to", &to) && row.number("distance_mm", &distance_mm) &&
                    row.number("true_distance_mm", &true_mm) && row.text("result", &result));
        EXPECT_EQ(kind, "direct");
        EXPECT_EQ(from, 0x6000U);
        EXPECT_EQ(to, 0x6A01U);
        EXPECT_NEAR(true_mm, std::sqrt(16.0 + 4.0) * 1000.0, 0.1);
        EXPECT_NEAR(distance_mm, true_mm, 5 * 30.0) << "30 mm noise";
        EXPECT_EQ(result, "ok");
    });
    EXPECT_EQ(rows, 1);
}

TEST(FilWorld, FaultsApplyAtTheirTimeAndAreCountedWhenInjected)
{
    World world(scenario("faults:\n"
                         "  - {kind: nack_address, at_s: 1.0, count: 2}\n"
                         "  - {kind: garbage_range, at_s: 1.5, count: 1}\n"
                         "  - {kind: stale_range, at_s: 1.5, count: 1}\n"
                         "  - {kind: power_off, node: 0x6A01, at_s: 2.0, duration_s: 1.0}\n"));
    EXPECT_EQ(world.i2cStart(kAddress, false, us(0.9)), POZYX_SIM_ACK) << "not armed before its time";
    world.i2cStop(us(0.9));
    EXPECT_EQ(world.i2cStart(kAddress, false, us(1.0)), POZYX_SIM_NACK);
    world.i2cStop(us(1.0));
    EXPECT_EQ(world.injected(FaultKind::NackAddress), 1U);
    EXPECT_EQ(world.i2cStart(kAddress, false, us(1.1)), POZYX_SIM_NACK);
    world.i2cStop(us(1.1));
    EXPECT_EQ(world.i2cStart(kAddress, false, us(1.2)), POZYX_SIM_ACK) << "both used up";
    world.i2cStop(us(1.2));
    EXPECT_EQ(world.injected(FaultKind::NackAddress), 2U);

    // Stale first (the simulator checks it first): counted, no entry changed; then garbage.
    ASSERT_EQ(doRanging(world, 0x6A01, us(1.5)), 1);
    world.advance(us(1.52));
    EXPECT_EQ(world.rangingsStale(), 1U);
    ASSERT_EQ(doRanging(world, 0x6A01, us(1.6)), 1);
    world.advance(us(1.62));
    EXPECT_EQ(world.rangingsGarbage(), 1U);
    EXPECT_EQ(world.rangingsDirect(), 0U) << "garbage is not a good ranging";
    ASSERT_EQ(doRanging(world, 0x6A01, us(1.7)), 1);
    world.advance(us(1.72));
    EXPECT_EQ(world.rangingsDirect(), 1U);

    world.advance(us(2.0));
    EXPECT_EQ(pozyx_sim_find(world.sim(), 0x6A01)->config.powered, 0);
    ASSERT_EQ(doRanging(world, 0x6A01, us(2.1)), 1);
    world.advance(us(2.2));
    EXPECT_EQ(world.rangingsDirect(), 1U) << "no ranging with a node that is off";
    world.advance(us(3.0));
    EXPECT_EQ(pozyx_sim_find(world.sim(), 0x6A01)->config.powered, 1);
    EXPECT_EQ(world.injected(FaultKind::PowerOff), 1U);

    nlohmann::ordered_json report;
    world.report(report, 3.0);
    ASSERT_EQ(report["fault_events"].size(), 4U);
    const auto &nack = report["fault_events"][0];
    EXPECT_EQ(nack["kind"], "nack_address");
    EXPECT_EQ(nack["injected"], 2);
    EXPECT_DOUBLE_EQ(nack["first_injected_s"].get<double>(), 1.0);
    EXPECT_DOUBLE_EQ(nack["last_injected_s"].get<double>(), 1.1);
    EXPECT_EQ(report["fault_events"][3]["powered_again"], true);
    EXPECT_EQ(report["faults_injected"]["garbage_range"], 1);
    EXPECT_EQ(report["faults_armed"]["nack_address"], 2);
    EXPECT_EQ(report["rangings"]["per_pair"]["0x6000-0x6A01"], 1);
}

TEST(FilWorld, TruthFileSamplesEveryNodeOnItsTrack)
{
    World world(scenario());
    const std::string path = testing::TempDir() + "fil_world_truth.csv";
    std::FILE *csv = openCsv(path);
    ASSERT_NE(csv, nullptr);
    world.setTruthCsv(csv, 500000);
    world.advance(us(2.0));
    std::fclose(csv);
    EXPECT_EQ(firstLine(path), "t,id,x,y,z");
    int rows = 0;
    double carried_x_at_2 = -1;
    cdro::csv::Reader reader(path, {{"t", "id", "x", "y", "z"}, {}, {}}, cdro::csv::Policy::Strict);
    reader.forEach([&](const cdro::csv::Row &row) {
        double t = 0, x = 0, y = 0, z = 0;
        uint16_t id = 0;
        ASSERT_TRUE(row.number("t", &t) && row.nodeId("id", &id) && row.number("x", &x) && row.number("y", &y) &&
                    row.number("z", &z))
            << "line " << row.line();
        if (id == 0x6B02 && t == 2.0) {
            carried_x_at_2 = x;
        }
        ++rows;
    });
    EXPECT_EQ(rows, 3 * 5) << "3 nodes at 0, 0.5, 1, 1.5, 2 s";
    EXPECT_DOUBLE_EQ(carried_x_at_2, 2.0);
}
