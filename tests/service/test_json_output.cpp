// JSON Lines exactly per docs/outputs.md, and the update/rate policies on event time.
#include <fstream>
#include <sstream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "cdro/service/json_output.hpp"
#include "support.hpp"

using namespace cdro::service;

namespace {
std::vector<nlohmann::json> readLines(const std::string &path)
{
    std::vector<nlohmann::json> lines;
    std::ifstream in(path);
    std::string line;
    while (std::getline(in, line)) {
        lines.push_back(nlohmann::json::parse(line));
    }
    return lines;
}
MapState twoNodes(double x0)
{
    MapState map;
    map.nodes.push_back(
        {24577, x0, -0.502, 0.0041, -0.0003, 0.0052, true, false, true, false, "converged", "", {}, {}, {}, {}, {}});
    map.nodes.push_back({24578, 1.0, 2.0, 0.1, 0.0, 0.1, false, true, true, false, "moving", "", {}, {}, {}, {}, {}});
    return map;
}
} // namespace

TEST(JsonOutput, NodeRobotAndHealthLinesHaveTheDocumentedKeysInOrder)
{
    NodeEstimate node{24577, 3.214,       -0.502, 0.0041, -0.0003, 0.0052, true, false, true,
                      false, "converged", "",     {},     1.25,    {},     {},   {}};
    const OutputTime at{12.5, 1700000012.5};
    EXPECT_EQ(JsonLinesWriter::line(nodeJson(node, at)),
              R"({"type":"node","schema":2,"t_s":12.5,"t_unix_s":1700000012.5,"id":24577,"id_hex":"0x6001",)"
              R"("x_m":3.214,"y_m":-0.502,"z_m":1.25,"var_x_m2":0.0041,)"
              R"("cov_xy_m2":-0.0003,"var_y_m2":0.0052,"converged":true,"moving":false,"placed":true,)"
              R"("foldable":false,"status":"converged","reason":"","hinge":[],"hinge_hex":[]})");
    node.converged = false;
    node.foldable = true;
    node.status = "placed";
    node.reason = "foldable";
    node.hinge = {24580, 24581};
    EXPECT_NE(JsonLinesWriter::line(nodeJson(node, at))
                  .find(R"("converged":false,"moving":false,"placed":true,"foldable":true,"status":"placed",)"
                        R"("reason":"foldable","hinge":[24580,24581],"hinge_hex":["0x6004","0x6005"]})"),
              std::string::npos);
    RobotPose robot;
    robot.id = 24600;
    robot.x_m = 1.5;
    robot.y_m = 2.5;
    robot.heading_rad = 0.25;
    robot.var_x_m2 = 0.01;
    robot.var_y_m2 = 0.02;
    robot.frame = "map";
    robot.var_heading_rad2 = 0.003;
    robot.cov_x_heading_m_rad = 0.001;
    robot.cov_y_heading_m_rad = -0.002;
    robot.heading_hypotheses = 1;
    robot.range_scale = 1.0625;
    robot.range_scale_sigma = 0.0125;
    robot.range_offset_m = 0.25;
    robot.range_offset_sigma_m = 0.05;
    EXPECT_EQ(JsonLinesWriter::line(robotJson(robot, {1.0, 1700000001.0})),
              R"({"type":"robot","schema":2,"t_s":1.0,"t_unix_s":1700000001.0,"id":24600,"id_hex":"0x6018",)"
              R"("frame":"map","x_m":1.5,"y_m":2.5,"heading_rad":0.25,)"
              R"("var_x_m2":0.01,"cov_xy_m2":0.0,"var_y_m2":0.02,"var_heading_rad2":0.003,)"
              R"("cov_x_heading_m_rad":0.001,"cov_y_heading_m_rad":-0.002,"heading_hypotheses":1,)"
              R"("range_scale":1.0625,"range_scale_sigma":0.0125,"range_offset_m":0.25,"range_offset_sigma_m":0.05})");
    Health health;
    health.link = LinkState::Connected;
    health.counters.crc_errors = 3;
    health.device_node_id = 0x6000;
    const nlohmann::json h = nlohmann::json::parse(JsonLinesWriter::line(healthJson(health, {2.0, 1700000002.0})));
    EXPECT_EQ(h["type"], "health");
    EXPECT_EQ(h["schema"], 2);
    EXPECT_EQ(h["t_unix_s"], 1700000002.0);
    EXPECT_EQ(h["device_node_id_hex"], "0x6000");
    EXPECT_EQ(h["link"], "connected");
    EXPECT_EQ(h["counters"]["crc_errors"], 3);
    EXPECT_TRUE(h["counters"].contains("frames_ok"));
    EXPECT_TRUE(h["counters"].contains("device_resets"));
}

// A node tracked in 3D (map.moving) carries its track's z covariance after the keys every node
// has; the others do not have those keys at all, and a change in them is a change of estimate.
TEST(JsonOutput, OnlyA3dTrackCarriesItsZCovariance)
{
    NodeEstimate node;
    node.id = 10;
    node.placed = true;
    node.moving = true;
    node.status = "moving";
    node.z_m = 0.75;
    const OutputTime at{1.0, 1700000001.0};
    const std::string flat = JsonLinesWriter::line(nodeJson(node, at));
    EXPECT_EQ(flat.find("var_z_m2"), std::string::npos) << flat;
    NodeEstimate tracked = node;
    tracked.var_z_m2 = 0.04;
    tracked.cov_xz_m2 = -0.01;
    tracked.cov_yz_m2 = 0.02;
    EXPECT_NE(JsonLinesWriter::line(nodeJson(tracked, at))
                  .find(R"("hinge":[],"hinge_hex":[],"var_z_m2":0.04,"cov_xz_m2":-0.01,"cov_yz_m2":0.02})"),
              std::string::npos);
    EXPECT_FALSE(sameEstimate(node, tracked));
    NodeEstimate moved = tracked;
    moved.var_z_m2 = 0.05;
    EXPECT_FALSE(sameEstimate(tracked, moved));
    EXPECT_TRUE(sameEstimate(tracked, tracked));
}

TEST(JsonOutput, AnUnplacedNodeHasNoPositionAndAnUnknownHeightNoZ)
{
    // What the engine leaves in an unplaced node's fields must not reach a consumer as a
    // certain position at the origin.
    NodeEstimate node;
    node.id = 0x6A3F;
    node.status = "unplaced";
    const nlohmann::json j = nlohmann::json::parse(JsonLinesWriter::line(nodeJson(node, {3.0, 1700000003.0})));
    for (const char *key : {"x_m", "y_m", "z_m", "var_x_m2", "cov_xy_m2", "var_y_m2"}) {
        EXPECT_TRUE(j.at(key).is_null()) << key;
    }
    EXPECT_EQ(j["placed"], false);
    EXPECT_EQ(j["id_hex"], "0x6A3F");
    // A robot whose filter gave no range model says so with null, not with 1 and 0.
    const nlohmann::json r = nlohmann::json::parse(JsonLinesWriter::line(robotJson(RobotPose{}, {3.0, 1700000003.0})));
    EXPECT_TRUE(r.at("range_scale").is_null());
    EXPECT_TRUE(r.at("range_offset_m").is_null());
    EXPECT_EQ(r["frame"], "odometry");
}

TEST(JsonOutput, TheMapObjectCarriesTheSchemaAndBothTimes)
{
    MapState map = twoNodes(1.0);
    map.t_s = 2.5;
    map.t_unix_s = 1700000002.5;
    LinkEstimate link;
    link.a = 24577;
    link.b = 24578;
    map.links.push_back(link);
    const nlohmann::json j = nlohmann::json::parse(mapJson(map).dump());
    EXPECT_EQ(j["schema"], 2);
    EXPECT_EQ(j["t_unix_s"], 1700000002.5);
    EXPECT_EQ(j["nodes"][1]["t_unix_s"], 1700000002.5);
    EXPECT_EQ(j["links"][0]["a_hex"], "0x6001");
    EXPECT_EQ(j["links"][0]["b_hex"], "0x6002");
    EXPECT_EQ(j["health"]["t_unix_s"], 1700000002.5);
    EXPECT_TRUE(j["health"]["device_node_id_hex"].is_null()); // not known yet
}

TEST(JsonOutput, TheMapsLinksCarryTheirResidualAndItsNodesTheirUpdateTime)
{
    // Node 0x6001 at (1, -0.502), 0x6002 at (1, 2): 2.502 m apart in the plane.
    MapState map = twoNodes(1.0);
    map.updated_unix_s[24577] = 1700000001.25;
    LinkEstimate link;
    link.a = 24577;
    link.b = 24578;
    link.range_median_m = 3.0;
    link.inlier_probability = 0.25;
    map.links.push_back(link);
    link.b = 24579; // 0x6003 is not in the map
    link.range_median_m.reset();
    link.inlier_probability.reset();
    map.links.push_back(link);
    const nlohmann::json j = nlohmann::json::parse(mapJson(map).dump());
    EXPECT_EQ(j["nodes"][0]["t_updated_unix_s"], 1700000001.25);
    EXPECT_TRUE(j["nodes"][1]["t_updated_unix_s"].is_null());
    const nlohmann::json &l = j["links"][0];
    EXPECT_DOUBLE_EQ(l["range_median_m"].get<double>(), 3.0);
    EXPECT_DOUBLE_EQ(l["inlier_probability"].get<double>(), 0.25);
    EXPECT_DOUBLE_EQ(l["fitted_distance_m"].get<double>(), 2.502);
    EXPECT_DOUBLE_EQ(l["residual_m"].get<double>(), 3.0 - 2.502);
    for (const char *key : {"range_median_m", "inlier_probability", "fitted_distance_m", "residual_m"}) {
        EXPECT_TRUE(j["links"][1][key].is_null()) << key;
    }
    // An end that is not placed: no distance, no residual, whatever the range says.
    map.nodes[1].placed = false;
    const nlohmann::json unplaced = nlohmann::json::parse(mapJson(map).dump());
    EXPECT_TRUE(unplaced["links"][0]["fitted_distance_m"].is_null());
    EXPECT_TRUE(unplaced["links"][0]["residual_m"].is_null());
    EXPECT_DOUBLE_EQ(unplaced["links"][0]["range_median_m"].get<double>(), 3.0);
    // The node lines of JSON Lines and MQTT do not carry it: a line's t_unix_s is its update.
    const nlohmann::json line = nlohmann::json::parse(JsonLinesWriter::line(nodeJson(map.nodes[0], {1.0, 2.0})));
    EXPECT_FALSE(line.contains("t_updated_unix_s"));
}

TEST(JsonOutput, EveryUpdateWritesOnlyTheNodesThatChanged)
{
    cdro::test::TempDir dir;
    ServiceCounters counters;
    OutputConfig config;
    config.jsonl = dir.file("out.jsonl");
    JsonLinesWriter writer(config, counters);
    writer.open();
    MapState map = twoNodes(3.0);
    map.t_s = 1.0;
    writer.onUpdate(map, 1'000'000);
    map.t_s = 2.0;
    writer.onUpdate(map, 2'000'000); // nothing changed
    map = twoNodes(3.5);
    map.t_s = 3.0;
    writer.onUpdate(map, 3'000'000); // only the first node moved
    writer.close();
    const auto lines = readLines(config.jsonl);
    ASSERT_EQ(lines.size(), 3U);
    EXPECT_EQ(lines[2]["id"], 24577);
    EXPECT_EQ(lines[2]["x_m"], 3.5);
    EXPECT_EQ(lines[2]["t_s"], 3.0);
    EXPECT_EQ(counters.jsonl_lines, 3U);
}

TEST(JsonOutput, ARateWritesEveryNodeOncePerPeriodOfEventTime)
{
    cdro::test::TempDir dir;
    ServiceCounters counters;
    OutputConfig config;
    config.jsonl = dir.file("out.jsonl");
    config.rate_hz = 2.0; // every 0.5 s of event time
    JsonLinesWriter writer(config, counters);
    writer.open();
    // 100 updates over 2 s of event time: 4 periods (0, 0.5, 1.0, 1.5) -> 4 x 2 lines.
    for (int i = 0; i < 100; ++i) {
        MapState map = twoNodes(0.01 * i);
        map.t_s = 0.02 * i;
        writer.onUpdate(map, 20'000 * i);
    }
    MapState last = twoNodes(0.99);
    writer.finish(last); // updates since the last period
    writer.close();
    const auto lines = readLines(config.jsonl);
    EXPECT_EQ(lines.size(), 10U);
}

TEST(JsonOutput, StdoutAndOffAreSupported)
{
    ServiceCounters counters;
    OutputConfig off;
    off.jsonl = "";
    JsonLinesWriter writer(off, counters);
    writer.open();
    EXPECT_FALSE(writer.enabled());
    OutputConfig bad;
    bad.jsonl = "/nonexistent/dir/out.jsonl";
    JsonLinesWriter broken(bad, counters);
    EXPECT_THROW(broken.open(), ConfigError);
}

TEST(JsonOutput, ThePerNodeLimitHoldsAChangeBackUntilItsIntervalAndWritesTheLastAtTheEnd)
{
    cdro::test::TempDir dir;
    ServiceCounters counters;
    OutputConfig config;
    config.jsonl = dir.file("out.jsonl");
    config.limits.max_node_rate_hz = 2.0; // a line per node per 0.5 s of event time
    JsonLinesWriter writer(config, counters);
    writer.open();
    // The first node moves every 0.1 s for 1.1 s; the second stays.
    for (int i = 0; i <= 11; ++i) {
        MapState map = twoNodes(0.1 * i);
        map.t_s = 0.1 * i;
        writer.onUpdate(map, 100'000 * i);
    }
    MapState at_exit = twoNodes(1.5);
    at_exit.t_s = 2.0;
    writer.finish(at_exit); // the held-back update at 1.1 s comes out as of 1.1 s
    writer.close();
    const auto lines = readLines(config.jsonl);
    std::vector<double> first_node_t_s;
    for (const auto &line : lines) {
        if (line["id"] == 24577) {
            first_node_t_s.push_back(line["t_s"].get<double>());
        }
    }
    // 0, 0.5 and 1.0 s (every 5th update), then what 1.1 s held back.
    ASSERT_EQ(first_node_t_s.size(), 4U);
    EXPECT_DOUBLE_EQ(first_node_t_s[1], 0.5);
    EXPECT_DOUBLE_EQ(first_node_t_s[2], 1.0);
    EXPECT_DOUBLE_EQ(first_node_t_s[3], 1.1);
    EXPECT_DOUBLE_EQ(lines.back()["x_m"].get<double>(), 0.1 * 11);
    EXPECT_EQ(lines.size(), 5U); // the second node once
    EXPECT_EQ(counters.jsonl_lines_held, 9U);
}

// The service tells the writer which nodes an update changed (MapSource::updateEstimates); a
// node held back by the per-node limit must still go out after its interval even when later
// updates do not change it. Six nodes, each moving at its own times, a line per node per 0.5 s:
// the writer told only of the changes writes byte for byte what a writer looking at every node
// writes, the held-back lines and the end included.
TEST(JsonOutput, AWriterToldOnlyOfTheChangedNodesWritesWhatOneLookingAtAllWrites)
{
    cdro::test::TempDir dir;
    ServiceCounters counters_all;
    ServiceCounters counters_changed;
    OutputConfig config;
    config.limits.max_node_rate_hz = 2.0;
    config.jsonl = dir.file("all.jsonl");
    JsonLinesWriter all(config, counters_all);
    config.jsonl = dir.file("changed.jsonl");
    JsonLinesWriter told(config, counters_changed);
    all.open();
    told.open();
    MapState map;
    for (uint16_t k = 0; k < 6; ++k) {
        NodeEstimate node;
        node.id = static_cast<uint16_t>(0x6001 + k);
        node.placed = true;
        node.status = "placed";
        map.nodes.push_back(node);
    }
    uint64_t state = 20261207; // a fixed LCG: which nodes move at each update
    for (int i = 0; i < 200; ++i) {
        std::vector<size_t> changed;
        for (size_t k = 0; k < map.nodes.size(); ++k) {
            state = state * 6364136223846793005ULL + 1442695040888963407ULL;
            if ((state >> 60U) < 3U) { // 3 in 16
                map.nodes[k].x_m += 0.01;
            }
            if ((state >> 60U) < 3U || i == 0) { // at first, every node is new
                changed.push_back(k);
            }
        }
        map.t_s = 0.05 * i;
        all.onUpdate(map, 50'000 * i);
        told.onUpdate(map, changed, 50'000 * i);
    }
    all.finish(map);
    told.finish(map);
    all.close();
    told.close();
    std::ostringstream bytes_all;
    std::ostringstream bytes_told;
    bytes_all << std::ifstream(dir.file("all.jsonl")).rdbuf();
    bytes_told << std::ifstream(dir.file("changed.jsonl")).rdbuf();
    EXPECT_GT(counters_all.jsonl_lines_held, 50U); // the limit was at work
    EXPECT_FALSE(bytes_all.str().empty());
    EXPECT_TRUE(bytes_all.str() == bytes_told.str())
        << bytes_all.str().size() << " bytes against " << bytes_told.str().size();
    EXPECT_EQ(counters_all.jsonl_lines, counters_changed.jsonl_lines);
    EXPECT_EQ(counters_all.jsonl_lines_held, counters_changed.jsonl_lines_held);
}

TEST(JsonOutput, AFileIsAppendedToAndRotatedBeforeItGrowsPastTheLimit)
{
    cdro::test::TempDir dir;
    ServiceCounters counters;
    OutputConfig config;
    config.jsonl = dir.file("out.jsonl");
    config.limits.max_node_rate_hz = 0.0;
    config.limits.rotate_mib = 2000.0 / (1024.0 * 1024.0); // 2000 bytes
    config.limits.keep = 2;
    {
        std::ofstream earlier(config.jsonl);
        earlier << "{\"earlier\":true}\n";
    }
    JsonLinesWriter writer(config, counters);
    writer.open();
    for (int i = 0; i < 40; ++i) {
        MapState map = twoNodes(0.01 * i);
        map.t_s = 1.0 * i;
        writer.onUpdate(map, 1'000'000 * i);
        writer.flush();
    }
    writer.close();
    std::vector<nlohmann::json> all;
    for (const std::string &name : {config.jsonl + ".2", config.jsonl + ".1", config.jsonl}) {
        std::ifstream in(name, std::ios::binary | std::ios::ate);
        ASSERT_TRUE(in) << name;
        EXPECT_LE(static_cast<long>(in.tellg()), 2000L) << name;
        const auto lines = readLines(name);
        all.insert(all.end(), lines.begin(), lines.end());
    }
    EXPECT_FALSE(std::ifstream(config.jsonl + ".3"));
    EXPECT_GE(counters.jsonl_rotations, 3U); // the oldest file (and the earlier line) fell off the end
    EXPECT_EQ(all.back()["x_m"], 0.39);
    EXPECT_LT(all.size(), 40U + 1U);
}

TEST(JsonOutput, AnEarlierFileIsKeptWhenNothingRotates)
{
    cdro::test::TempDir dir;
    ServiceCounters counters;
    OutputConfig config;
    config.jsonl = dir.file("out.jsonl");
    {
        std::ofstream earlier(config.jsonl);
        earlier << "{\"earlier\":true}\n";
    }
    JsonLinesWriter writer(config, counters);
    writer.open();
    MapState map = twoNodes(3.0);
    writer.onUpdate(map, 1'000'000);
    writer.close();
    const auto lines = readLines(config.jsonl);
    ASSERT_EQ(lines.size(), 3U);
    EXPECT_EQ(lines[0]["earlier"], true);
}
