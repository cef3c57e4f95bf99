// http_server.hpp: the live map. A cpp-httplib server, bound to 127.0.0.1 by default, serving
// an embedded page (HTML + JS + SVG, no CDN) and a JSON API:
//
//   GET /                           the page
//   GET /api/map                    {"t_s", "nodes": [node lines], "robot", "links", "health"}
//   GET /api/health                 the health line
//   GET /api/nodes/<id>/components  {"id", "components": [{center_id, x_m, ..., weight}]}
//   GET /api/events                 server-sent events: "event: map" with /api/map's JSON,
//                                   whenever a new snapshot is published
//
// Threads: cpp-httplib runs its own listener thread and worker pool. They read only the
// MapSnapshotStore (immutable strings swapped under a mutex). Components come from the engine,
// which lives on the loop thread: a request posts a task to the loop (EventLoop::post) and
// waits (bounded) for its answer, so the engine is never touched from an HTTP thread.
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

#include "cdro/service/config.hpp"
#include "cdro/service/event_loop.hpp"

namespace httplib {
class Server;
}

namespace cdro::service {

// The latest map and health as JSON text, published by the loop thread, read by HTTP threads.
class MapSnapshotStore {
public:
    struct Snapshot {
        uint64_t revision = 0;          // 0 = nothing published yet
        std::shared_ptr<const std::string> map_json;
        std::shared_ptr<const std::string> health_json;
    };

    void publish(std::string map_json, std::string health_json);
    Snapshot latest() const;
    // Waits until a snapshot newer than `revision` exists, close() is called, or timeout_ms
    // passes; returns the latest snapshot either way.
    Snapshot waitNewer(uint64_t revision, int timeout_ms) const;
    void close();           // wakes every waiter; later waits return at once
    bool closed() const;

private:
    mutable std::mutex mutex_;
    mutable std::condition_variable changed_;
    Snapshot snapshot_;
    bool closed_ = false;
};

class HttpServer {
public:
    // Runs on the loop thread; returns the JSON of a node's components, or nullopt if unknown.
    using ComponentsFetcher = std::function<std::optional<std::string>(uint16_t id)>;

    HttpServer(EventLoop &loop, const HttpConfig &config, MapSnapshotStore &store, ComponentsFetcher fetcher);
    ~HttpServer();
    HttpServer(const HttpServer &) = delete;
    HttpServer &operator=(const HttpServer &) = delete;

    // Binds (port 0 = any free port, for tests) and starts serving. Throws ConfigError if the
    // address cannot be bound.
    void start();
    void stop(); // stops serving and joins the threads; idempotent
    int port() const { return port_; }
    std::string url() const;

private:
    EventLoop &loop_;
    HttpConfig config_;
    MapSnapshotStore &store_;
    ComponentsFetcher fetcher_;
    std::unique_ptr<httplib::Server> server_;
    std::thread thread_;
    std::atomic<uint32_t> event_clients_{0};
    std::atomic<bool> stopping_{false};
    int port_ = 0;
};

} // namespace cdro::service
