// The live map's HTTP server: page and assets, the JSON API, components fetched on the loop
// thread, and server-sent events carrying a newly published map.
#include <atomic>
#include <thread>

#include <gtest/gtest.h>
#include <httplib.h>
#include <nlohmann/json.hpp>

#include "cdro/service/http_server.hpp"
#include "cdro/service/map_state.hpp"

using namespace cdro::service;

namespace {
std::string mapText(int nodes)
{
    MapState map;
    for (int i = 0; i < nodes; ++i) {
        map.nodes.push_back({static_cast<uint16_t>(100 + i), 1.0 * i, 2.0, 0.1, 0.0, 0.1, true, false, true, false, "converged", "", {}});
    }
    return mapJson(map).dump();
}
} // namespace

class HttpTest : public ::testing::Test {
protected:
    SystemClock clock;
    EventLoop loop{clock};
    MapSnapshotStore store;
    std::thread loop_thread;
    std::atomic<std::thread::id> fetch_thread{};
    std::unique_ptr<HttpServer> server;

    void SetUp() override
    {
        HttpConfig config;
        config.port = 0; // any free port
        server = std::make_unique<HttpServer>(loop, config, store, [this](uint16_t id) -> std::optional<std::string> {
            fetch_thread = std::this_thread::get_id();
            if (id != 100) {
                return std::nullopt;
            }
            NodeComponents c;
            c.id = id;
            c.components.push_back({101, 1.0, 2.0, 0.1, 0.0, 0.1, 0.75});
            return componentsJson(c).dump();
        });
        server->start();
        loop_thread = std::thread([this] { loop.run(); });
    }
    void TearDown() override
    {
        server->stop();
        loop.stop();
        loop_thread.join();
    }
    httplib::Client client() { return httplib::Client("127.0.0.1", server->port()); }
};

TEST_F(HttpTest, ServesThePageAndItsAssets)
{
    auto c = client();
    auto page = c.Get("/");
    ASSERT_TRUE(page);
    EXPECT_EQ(page->status, 200);
    EXPECT_NE(page->body.find("<svg id=\"map\""), std::string::npos);
    EXPECT_EQ(page->body.find("http://"), page->body.find("http://www.w3.org")); // no CDN
    auto js = c.Get("/app.js");
    ASSERT_TRUE(js);
    EXPECT_NE(js->body.find("EventSource"), std::string::npos);
    EXPECT_EQ(js->get_header_value("Content-Type").rfind("text/javascript", 0), 0U);
    EXPECT_EQ(c.Get("/style.css")->status, 200);
    EXPECT_EQ(c.Get("/nope")->status, 404);
}

TEST_F(HttpTest, ApiServesTheLatestSnapshot)
{
    auto c = client();
    EXPECT_EQ(c.Get("/api/map")->status, 503); // nothing published yet
    store.publish(mapText(3), R"({"type":"health","link":"connected"})");
    auto map = c.Get("/api/map");
    ASSERT_EQ(map->status, 200);
    const auto json = nlohmann::json::parse(map->body);
    EXPECT_EQ(json["nodes"].size(), 3U);
    EXPECT_EQ(json["nodes"][2]["id"], 102);
    EXPECT_EQ(nlohmann::json::parse(c.Get("/api/health")->body)["link"], "connected");
}

TEST_F(HttpTest, ComponentsAreFetchedOnTheLoopThread)
{
    auto c = client();
    auto found = c.Get("/api/nodes/100/components");
    ASSERT_EQ(found->status, 200);
    const auto json = nlohmann::json::parse(found->body);
    EXPECT_EQ(json["components"][0]["weight"], 0.75);
    EXPECT_EQ(fetch_thread.load(), loop_thread.get_id());
    EXPECT_EQ(c.Get("/api/nodes/7/components")->status, 404);
    EXPECT_EQ(c.Get("/api/nodes/70000/components")->status, 400);
}

TEST_F(HttpTest, EventsCarryEachNewSnapshot)
{
    store.publish(mapText(1), "{}");
    std::string received; // written by the reader thread only until it is joined
    std::atomic<bool> got_first{false};
    std::atomic<bool> got_second{false};
    std::thread reader([&] {
        auto c = client();
        c.Get("/api/events", [&](const char *data, size_t len) {
            received.append(data, len);
            if (received.find("event: map") != std::string::npos) {
                got_first = true;
            }
            if (received.find("\"id\":101") != std::string::npos) {
                got_second = true;
                return false; // enough: close the stream
            }
            return true;
        });
    });
    // The stream starts with the current map; publish a second one with two nodes.
    for (int i = 0; i < 1000 && !got_first.load(); ++i) {
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    store.publish(mapText(2), "{}");
    reader.join();
    EXPECT_TRUE(got_second.load());
    EXPECT_NE(received.find("event: map\ndata: {"), std::string::npos);
}
