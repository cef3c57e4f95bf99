// http_server.hpp: the live map. A small HTTP/1.1 server of its own, bound to 127.0.0.1 by
// default, serving an embedded page (HTML + JS + SVG, no CDN) and a JSON API:
//
//   GET /                           the page (/index.html, /app.js, /style.css)
//   GET /api/map                    {"t_s", "nodes": [node lines], "robot", "links", "health"}
//   GET /api/health                 the health line
//   GET /api/nodes/<id>/components  {"id", "components": [{center_id, x_m, ..., weight}]}
//   GET /api/events                 server-sent events: "event: map" with /api/map's JSON,
//                                   whenever a new snapshot is published
//   GET /api/floor-plan             the floor plan's placement (web.floor_plan), 404 if none
//   GET /floor-plan.png             its image, read once from web.floor_plan.path at start
//   GET /metrics                    the counters and rates for Prometheus (metrics.hpp)
//
// Why not a library's server: the one Debian ships (cpp-httplib 0.11) gives every connection a
// worker thread from a fixed pool while it reads the request, with no deadline on the request
// head and no bound on a body, so forty clients sending their headers slowly starved the live
// map, and large bodies were read into memory whole. This server reads every
// connection non-blocking in one poll() loop on its own thread, so that a slow client costs a
// descriptor and a buffer, never a thread, and it enforces Limits:
//   - the request head (request line and headers) must be complete within head_deadline_s
//     (else 408) and fit in max_head_bytes (else 431);
//   - no endpoint takes a body: a request announcing one (Content-Length above 0, or any
//     Transfer-Encoding) is answered 413 and its body is never stored;
//   - only GET and HEAD (else 405), only the paths above, matched exactly (no file system is
//     read while serving: the page is compiled in, the floor plan read at start); anything else
//     is 404, a malformed request 400;
//   - at most max_connections open connections and max_per_client from one address: when a
//     new one would exceed a cap, the oldest connection still sending its head (of that
//     address, then of any) is closed to make room, so that the newest request, a health
//     check say, is served; a connection that cannot make room is answered 503;
//   - at most http.max_event_clients event streams (more get 503); a stream, or a response,
//     whose client takes no byte for write_stall_s is closed; a stream holds at most one map
//     in its buffer (a slow reader skips maps and gets the newest), so memory stays flat.
// Every response closes its connection (Connection: close).
//
// Threads: the server runs its own loop on its own thread. It reads only the MapSnapshotStore
// (immutable strings swapped under a mutex). Components come from the engine, which lives on
// the service's loop thread: a request posts a task there (EventLoop::post) and is answered
// when the result comes back (503 after 2 s); no thread waits for it.
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

#include "cdro/service/clock.hpp"
#include "cdro/service/config.hpp"
#include "cdro/service/event_loop.hpp"

namespace cdro::service {

// The latest map and health as JSON text, published by the loop thread, read by HTTP threads.
class MapSnapshotStore {
public:
    struct Snapshot {
        uint64_t revision = 0; // 0 = nothing published yet
        std::shared_ptr<const std::string> map_json;
        std::shared_ptr<const std::string> health_json;
    };

    void publish(std::string map_json, std::string health_json);
    Snapshot latest() const;
    // Waits until a snapshot newer than `revision` exists, close() is called, or timeout_ms
    // passes; returns the latest snapshot either way.
    Snapshot waitNewer(uint64_t revision, int timeout_ms) const;
    void close(); // wakes every waiter; later waits return at once
    bool closed() const;
    // Called (on the publishing thread) after every publish; empty = none. The call is made
    // under a lock that setOnPublish also takes, so that once it returns no call is running.
    void setOnPublish(std::function<void()> listener);

private:
    mutable std::mutex mutex_;
    mutable std::condition_variable changed_;
    Snapshot snapshot_;
    bool closed_ = false;
    std::mutex listener_mutex_;
    std::function<void()> on_publish_;
};

// What the server refused and answered, for the health line (thread-safe reads).
struct HttpStats {
    uint64_t requests = 0; // requests answered with 200, 404 or a component lookup's answer
    uint64_t refused = 0;  // requests or connections refused: 400, 405, 408, 413, 431, 503, closed to make room
};

// Bounds no user needs to set (documented in docs/service.md, "Security model"); tests
// may shrink them.
struct HttpLimits {
    double head_deadline_s = 5.0;      // s from the connection to the end of its request head
    size_t max_head_bytes = 8192;      // bytes of request line and headers
    uint32_t max_connections = 256;    // open connections, all clients
    uint32_t max_per_client = 32;      // open connections from one address
    double write_stall_s = 10.0;       // s a response or stream may wait for its client to read
    double components_timeout_s = 2.0; // s the service's loop gets to answer a components request
    double keepalive_s = 10.0;         // s between comments on an idle event stream
};

class HttpServer {
public:
    // Runs on the loop thread; returns the JSON of a node's components, or nullopt if unknown.
    using ComponentsFetcher = std::function<std::optional<std::string>(uint16_t id)>;

    using Limits = HttpLimits;

    HttpServer(EventLoop &loop, const HttpConfig &config, MapSnapshotStore &store, ComponentsFetcher fetcher,
               Limits limits = Limits{});
    ~HttpServer();
    HttpServer(const HttpServer &) = delete;
    HttpServer &operator=(const HttpServer &) = delete;

    // The floor plan to serve (before start): reads the PNG whole now, so that the server never
    // touches the file system later. Throws ConfigError as readFloorPlan does.
    void setFloorPlan(const FloorPlanConfig &config);

    // Binds (port 0 = any free port, for tests) and starts serving. Throws ConfigError if the
    // address cannot be bound.
    void start();
    void stop(); // stops serving, closes every connection, joins the thread; idempotent
    int port() const { return port_; }
    std::string url() const;

    HttpStats stats() const;
    size_t openConnections() const { return open_connections_.load(); }
    size_t connectionsFrom(const std::string &address) const; // open connections from one address

private:
    class Worker;
    EventLoop &loop_;
    HttpConfig config_;
    MapSnapshotStore &store_;
    ComponentsFetcher fetcher_;
    Limits limits_;
    SystemClock clock_; // the HTTP thread's deadlines are wall-clock matters
    std::unique_ptr<Worker> worker_;
    std::thread thread_;
    std::atomic<size_t> open_connections_{0};
    int port_ = 0;
    std::string floor_plan_png_;  // empty = no floor plan
    std::string floor_plan_json_; // /api/floor-plan
};

} // namespace cdro::service
