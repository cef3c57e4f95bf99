// The live map's HTTP server: page and assets, the JSON API, components fetched on the loop
// thread, and server-sent events carrying a newly published map.
#include <atomic>
#include <cerrno>
#include <chrono>
#include <system_error>
#include <thread>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

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
        map.nodes.push_back({static_cast<uint16_t>(100 + i),
                             1.0 * i,
                             2.0,
                             0.1,
                             0.0,
                             0.1,
                             true,
                             false,
                             true,
                             false,
                             "converged",
                             "",
                             {},
                             {},
                             {},
                             {},
                             {}});
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
    // The id as the page, the topics and the logs show it.
    auto hex = c.Get("/api/nodes/0x64/components");
    ASSERT_EQ(hex->status, 200);
    EXPECT_EQ(nlohmann::json::parse(hex->body), json);
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

// ---- hostile clients (docs/service.md, "Security model") --------------------------------------

namespace {

// A raw TCP client, for what a well-behaved library would never send.
class RawClient {
public:
    explicit RawClient(int port, const char *source = "127.0.0.1")
    {
        fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
        sockaddr_in local{};
        local.sin_family = AF_INET;
        ::inet_pton(AF_INET, source, &local.sin_addr);
        // A client address of our choice.
        if (::bind(fd_, reinterpret_cast<sockaddr *>(&local), sizeof local) != 0) {
            throw std::system_error(errno, std::generic_category(), "RawClient: bind");
        }
        sockaddr_in server{};
        server.sin_family = AF_INET;
        server.sin_port = htons(static_cast<uint16_t>(port));
        ::inet_pton(AF_INET, "127.0.0.1", &server.sin_addr);
        connected_ = ::connect(fd_, reinterpret_cast<sockaddr *>(&server), sizeof server) == 0;
    }
    ~RawClient()
    {
        if (fd_ >= 0) {
            ::close(fd_);
        }
    }
    RawClient(const RawClient &) = delete;
    RawClient &operator=(const RawClient &) = delete;
    bool connected() const { return connected_; }
    // False once the server closed (EPIPE/ECONNRESET).
    bool send(const std::string &text)
    {
        size_t done = 0;
        while (done < text.size()) {
            const ssize_t n = ::send(fd_, text.data() + done, text.size() - done, MSG_NOSIGNAL);
            if (n <= 0) {
                return false;
            }
            done += static_cast<size_t>(n);
        }
        return true;
    }
    // Everything until the server closes or timeout_ms passes without a byte.
    std::string receive(int timeout_ms)
    {
        std::string out;
        char buffer[4096];
        for (;;) {
            pollfd p{fd_, POLLIN, 0};
            if (::poll(&p, 1, timeout_ms) <= 0) {
                timed_out_ = true;
                return out;
            }
            const ssize_t n = ::recv(fd_, buffer, sizeof buffer, 0);
            if (n <= 0) {
                return out;
            }
            out.append(buffer, static_cast<size_t>(n));
        }
    }
    bool timedOut() const { return timed_out_; }
    // Waits up to timeout_ms for the first bytes; true if some came.
    bool awaitBytes(int timeout_ms)
    {
        pollfd p{fd_, POLLIN, 0};
        return ::poll(&p, 1, timeout_ms) > 0;
    }
    // Closes with a reset (no FIN, no lingering): the server's next send on it fails at once.
    void reset()
    {
        const linger abort{1, 0};
        ::setsockopt(fd_, SOL_SOCKET, SO_LINGER, &abort, sizeof abort);
        ::close(fd_);
        fd_ = -1;
    }

private:
    int fd_ = -1;
    bool connected_ = false;
    bool timed_out_ = false;
};

std::string statusLine(const std::string &response) { return response.substr(0, response.find("\r\n")); }

} // namespace

// Forty connections sending their headers a byte at a time must not starve the others: with a
// worker per connection (cpp-httplib's pool) they hold every worker, and the health endpoint
// fails for as long as they keep going.
TEST_F(HttpTest, SlowHeadersDoNotStarveTheHealthEndpoint)
{
    store.publish(mapText(1), R"({"type":"health","link":"connected"})");
    std::vector<std::unique_ptr<RawClient>> slow;
    for (int i = 0; i < 40; ++i) {
        slow.push_back(std::make_unique<RawClient>(server->port(), "127.0.0.2"));
        slow.back()->send("GET /api/health HTTP/1.1\r\n");
    }
    std::atomic<bool> trickling{true};
    std::thread trickle([&] {
        while (trickling.load()) {
            for (auto &client : slow) {
                client->send("X");
            }
            std::this_thread::sleep_for(std::chrono::milliseconds(100));
        }
    });
    int answered = 0;
    for (int i = 0; i < 10; ++i) {
        RawClient check(server->port());
        check.send("GET /api/health HTTP/1.1\r\nHost: x\r\n\r\n");
        const std::string response = check.receive(10000);
        answered += statusLine(response) == "HTTP/1.1 200 OK" ? 1 : 0;
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    trickling = false;
    trickle.join();
    EXPECT_EQ(answered, 10);
}

TEST_F(HttpTest, ARequestHeadNotCompleteInTimeIsAnswered408AndClosed)
{
    HttpLimits limits;
    limits.head_deadline_s = 0.5;
    HttpConfig config;
    config.port = 0;
    HttpServer quick(loop, config, store, nullptr, limits);
    quick.start();
    RawClient client(quick.port());
    client.send("GET /api/health HTTP/1.1\r\nHost: x\r\n");
    const auto start = std::chrono::steady_clock::now();
    const std::string response = client.receive(30000); // a deadlock guard only
    const double waited_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    EXPECT_FALSE(client.timedOut());
    EXPECT_EQ(statusLine(response), "HTTP/1.1 408 Request Timeout");
    EXPECT_GE(waited_s, limits.head_deadline_s * 0.9);
    EXPECT_EQ(quick.stats().refused, 1U);
}

TEST_F(HttpTest, ConnectionsPerClientAndInTotalAreCappedAndTheNewestIsServed)
{
    store.publish(mapText(1), R"({"type":"health","link":"connected"})");
    const HttpServer::Limits limits;
    std::vector<std::unique_ptr<RawClient>> idle;
    for (uint32_t i = 0; i < limits.max_connections + 50; ++i) {
        // From many addresses (all of 127/8 is this machine), so that the total cap is reached.
        const std::string source = "127.0.1." + std::to_string(1 + i % 200);
        idle.push_back(std::make_unique<RawClient>(server->port(), source.c_str()));
        idle.back()->send("GET / HTTP/1.1\r\n");
    }
    for (int i = 0; i < 3; ++i) {
        RawClient check(server->port(), "127.0.1.7");
        check.send("GET /api/health HTTP/1.1\r\n\r\n");
        EXPECT_EQ(statusLine(check.receive(10000)), "HTTP/1.1 200 OK");
    }
    EXPECT_LE(server->openConnections(), limits.max_connections);
    // One address alone is held to its own cap.
    std::vector<std::unique_ptr<RawClient>> greedy;
    for (uint32_t i = 0; i < limits.max_per_client + 20; ++i) {
        greedy.push_back(std::make_unique<RawClient>(server->port(), "127.0.2.1"));
        greedy.back()->send("GET / HTTP/1.1\r\n");
    }
    RawClient check(server->port(), "127.0.2.1");
    check.send("GET /api/health HTTP/1.1\r\n\r\n");
    EXPECT_EQ(statusLine(check.receive(10000)), "HTTP/1.1 200 OK");
    EXPECT_LE(server->connectionsFrom("127.0.2.1"), limits.max_per_client);
}

// Request bodies must not be read into memory whole (24 POSTs of 64 MiB would take the service
// to 1.55 GiB). No endpoint takes a body: it is refused from its announced length, unread.
TEST_F(HttpTest, BodiesAreRefusedUnreadAndHugeHeadsAre431)
{
    RawClient post(server->port());
    post.send("POST /api/map HTTP/1.1\r\nHost: x\r\nContent-Length: 67108864\r\n\r\n");
    EXPECT_EQ(statusLine(post.receive(10000)), "HTTP/1.1 413 Payload Too Large");

    RawClient chunked(server->port());
    chunked.send("POST /api/map HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n4000000\r\n");
    EXPECT_EQ(statusLine(chunked.receive(10000)), "HTTP/1.1 413 Payload Too Large");

    RawClient get_with_body(server->port());
    get_with_body.send("GET /api/health HTTP/1.1\r\nContent-Length: 5\r\n\r\nhello");
    EXPECT_EQ(statusLine(get_with_body.receive(10000)), "HTTP/1.1 413 Payload Too Large");

    RawClient huge(server->port());
    huge.send("GET /api/health HTTP/1.1\r\nX-Big: " + std::string(64 * 1024, 'a'));
    EXPECT_EQ(statusLine(huge.receive(10000)), "HTTP/1.1 431 Request Header Fields Too Large");

    RawClient put(server->port());
    put.send("PUT /api/map HTTP/1.1\r\n\r\n");
    EXPECT_EQ(statusLine(put.receive(10000)), "HTTP/1.1 405 Method Not Allowed");

    RawClient nonsense(server->port()); // a TLS ClientHello's first bytes
    nonsense.send(std::string("\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03", 11));
    EXPECT_EQ(statusLine(nonsense.receive(10000)), "HTTP/1.1 400 Bad Request");
}

// An id too large for std::stoul must be a 400, not an exception (HTTP 500).
TEST_F(HttpTest, NodeIdsOutsideTheirRangeAre400)
{
    auto c = client();
    for (const char *path :
         {"/api/nodes/99999999999999999999/components", "/api/nodes/65536/components", "/api/nodes/0/components",
          "/api/nodes/000000000000000000001/components", "/api/nodes/0x10000/components", "/api/nodes/0x/components",
          "/api/nodes/0x0/components", "/api/nodes/0xg1/components"}) {
        auto response = c.Get(path);
        ASSERT_TRUE(response) << path;
        EXPECT_EQ(response->status, 400) << path;
        EXPECT_NE(response->body.find("1..65535"), std::string::npos) << path;
    }
}

TEST_F(HttpTest, NothingButThePagesAndTheApiIsServed)
{
    store.publish(mapText(1), "{}");
    for (const char *path : {"/../../../../etc/passwd",
                             "/..%2f..%2f..%2fetc%2fpasswd",
                             "/%2e%2e/%2e%2e/etc/passwd",
                             "/static/../../etc/passwd",
                             "//etc/passwd",
                             "/index.html/../../etc/passwd",
                             "/api/../../etc/passwd",
                             "/app.js%00.png",
                             "/.git/config",
                             "/web/app.js",
                             "/api/map/../../../etc/shadow",
                             "/%c0%ae%c0%ae/%c0%ae%c0%ae/etc/passwd",
                             "/....//....//etc/passwd",
                             "/..\\..\\etc\\passwd",
                             "/api/nodes/../../etc/passwd",
                             "/proc/self/environ",
                             "/api/nodes/1/../../../etc/passwd",
                             "/./././etc/passwd",
                             "/%252e%252e/etc/passwd",
                             "/api/events/../../etc/passwd",
                             "/style.css/..",
                             "/index.html%2f..%2f..%2fetc%2fpasswd"}) {
        RawClient client(server->port());
        client.send(std::string("GET ") + path + " HTTP/1.1\r\nHost: x\r\n\r\n");
        const std::string response = client.receive(10000);
        const std::string status = statusLine(response);
        EXPECT_TRUE(status == "HTTP/1.1 404 Not Found" || status == "HTTP/1.1 400 Bad Request")
            << path << ": " << status;
        EXPECT_EQ(response.find("root:"), std::string::npos) << path;
    }
    RawClient absolute(server->port());
    absolute.send("GET http://127.0.0.1/etc/passwd HTTP/1.1\r\n\r\n");
    EXPECT_EQ(statusLine(absolute.receive(10000)), "HTTP/1.1 400 Bad Request");
}

TEST_F(HttpTest, ManyEventStreamsAreCappedAndTheRestStillAnswered)
{
    store.publish(mapText(1), R"({"type":"health","link":"connected"})");
    std::vector<std::unique_ptr<RawClient>> streams;
    int refused = 0;
    for (uint32_t i = 0; i < HttpConfig{}.max_event_clients + 4; ++i) {
        streams.push_back(std::make_unique<RawClient>(server->port(), ("127.0.3." + std::to_string(i + 1)).c_str()));
        streams.back()->send("GET /api/events HTTP/1.1\r\n\r\n");
        const std::string head = streams.back()->receive(200);
        refused += statusLine(head) == "HTTP/1.1 503 Service Unavailable" ? 1 : 0;
    }
    EXPECT_EQ(refused, 4);
    RawClient check(server->port());
    check.send("GET /api/health HTTP/1.1\r\n\r\n");
    EXPECT_EQ(statusLine(check.receive(10000)), "HTTP/1.1 200 OK");
}

// A map going out to the event streams while their clients reset them: each failed send closes
// its stream in the middle of the pass over all of them, and the pass must carry on safely (under
// AddressSanitizer a pass that walked a closed stream's entry stops the test; without it the
// service died of SIGSEGV once in CI, closing 600 connections at once).
TEST_F(HttpTest, StreamsResetWhileAMapGoesOutAreClosedAndTheOthersServed)
{
    HttpConfig config;
    config.port = 0;
    config.max_event_clients = 48;
    MapSnapshotStore streams_store;
    HttpServer busy(loop, config, streams_store, nullptr);
    busy.start();
    streams_store.publish(mapText(40), R"({"type":"health","link":"connected"})");
    for (int round = 0; round < 30; ++round) {
        std::vector<std::unique_ptr<RawClient>> streams;
        for (uint32_t i = 0; i < config.max_event_clients; ++i) {
            const std::string source = "127.0.4." + std::to_string(1 + i);
            streams.push_back(std::make_unique<RawClient>(busy.port(), source.c_str()));
            streams.back()->send("GET /api/events HTTP/1.1\r\n\r\n");
        }
        for (auto &stream : streams) {
            ASSERT_TRUE(stream->awaitBytes(10000)) << "round " << round; // the stream is open
        }
        streams_store.publish(mapText(40 + round), R"({"type":"health","link":"connected"})");
        for (auto &stream : streams) {
            stream->reset();
        }
    }
    RawClient check(busy.port());
    check.send("GET /api/health HTTP/1.1\r\n\r\n");
    EXPECT_EQ(statusLine(check.receive(10000)), "HTTP/1.1 200 OK");
    busy.stop();
}
