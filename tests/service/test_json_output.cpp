// JSON Lines exactly per docs/outputs.md, and the update/rate policies on event time.
#include <fstream>

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
    map.nodes.push_back({24577, x0, -0.502, 0.0041, -0.0003, 0.0052, true, false, true, false, "converged", "", {}});
    map.nodes.push_back({24578, 1.0, 2.0, 0.1, 0.0, 0.1, false, true, true, false, "moving", "", {}});
    return map;
}
} // namespace

TEST(JsonOutput, NodeRobotAndHealthLinesHaveTheDocumentedKeysInOrder)
{
    NodeEstimate node{24577, 3.214, -0.502, 0.0041, -0.0003, 0.0052, true, false, true, false, "converged", "", {}};
    EXPECT_EQ(JsonLinesWriter::line(nodeJson(node, 12.5)),
              R"({"type":"node","t_s":12.5,"id":24577,"x_m":3.214,"y_m":-0.502,"var_x_m2":0.0041,)"
              R"("cov_xy_m2":-0.0003,"var_y_m2":0.0052,"converged":true,"moving":false,"placed":true,)"
              R"("foldable":false,"status":"converged","reason":"","hinge":[]})");
    node.converged = false;
    node.foldable = true;
    node.status = "placed";
    node.reason = "foldable";
    node.hinge = {24580, 24581};
    EXPECT_NE(JsonLinesWriter::line(nodeJson(node, 12.5))
                  .find(R"("converged":false,"moving":false,"placed":true,"foldable":true,"status":"placed",)"
                        R"("reason":"foldable","hinge":[24580,24581]})"),
              std::string::npos);
    RobotPose robot{24600, 1.5, 2.5, 0.25, 0.01, 0.0, 0.02};
    EXPECT_EQ(JsonLinesWriter::line(robotJson(robot, 1.0)),
              R"({"type":"robot","t_s":1.0,"id":24600,"x_m":1.5,"y_m":2.5,"heading_rad":0.25,)"
              R"("var_x_m2":0.01,"cov_xy_m2":0.0,"var_y_m2":0.02})");
    Health health;
    health.link = LinkState::Connected;
    health.counters.crc_errors = 3;
    const nlohmann::json h = nlohmann::json::parse(JsonLinesWriter::line(healthJson(health, 2.0)));
    EXPECT_EQ(h["type"], "health");
    EXPECT_EQ(h["link"], "connected");
    EXPECT_EQ(h["counters"]["crc_errors"], 3);
    EXPECT_TRUE(h["counters"].contains("frames_ok"));
    EXPECT_TRUE(h["counters"].contains("device_resets"));
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
