#include "cdro/service/http_server.hpp"

#include <chrono>
#include <future>

#include <httplib.h>

#include "cdro/service/log.hpp"
#include "web_assets.hpp"

namespace cdro::service {

// ---- snapshot store --------------------------------------------------------------------------

void MapSnapshotStore::publish(std::string map_json, std::string health_json)
{
    auto map = std::make_shared<const std::string>(std::move(map_json));
    auto health = std::make_shared<const std::string>(std::move(health_json));
    {
        std::lock_guard<std::mutex> lock(mutex_);
        snapshot_.map_json = std::move(map);
        snapshot_.health_json = std::move(health);
        ++snapshot_.revision;
    }
    changed_.notify_all();
}

MapSnapshotStore::Snapshot MapSnapshotStore::latest() const
{
    std::lock_guard<std::mutex> lock(mutex_);
    return snapshot_;
}

MapSnapshotStore::Snapshot MapSnapshotStore::waitNewer(uint64_t revision, int timeout_ms) const
{
    std::unique_lock<std::mutex> lock(mutex_);
    changed_.wait_for(lock, std::chrono::milliseconds(timeout_ms),
                      [&] { return closed_ || snapshot_.revision > revision; });
    return snapshot_;
}

void MapSnapshotStore::close()
{
    {
        std::lock_guard<std::mutex> lock(mutex_);
        closed_ = true;
    }
    changed_.notify_all();
}

bool MapSnapshotStore::closed() const
{
    std::lock_guard<std::mutex> lock(mutex_);
    return closed_;
}

// ---- server ----------------------------------------------------------------------------------

namespace {

const char *contentType(const std::string &path)
{
    if (path.size() >= 3 && path.compare(path.size() - 3, 3, ".js") == 0) {
        return "text/javascript; charset=utf-8";
    }
    if (path.size() >= 4 && path.compare(path.size() - 4, 4, ".css") == 0) {
        return "text/css; charset=utf-8";
    }
    return "text/html; charset=utf-8";
}

constexpr int kComponentsTimeoutMs = 2000; // ms the loop gets to answer a components request
constexpr int kEventKeepaliveMs = 10000;   // ms between SSE keep-alive comments

} // namespace

HttpServer::HttpServer(EventLoop &loop, const HttpConfig &config, MapSnapshotStore &store, ComponentsFetcher fetcher)
    : loop_(loop), config_(config), store_(store), fetcher_(std::move(fetcher))
{
}

HttpServer::~HttpServer() { stop(); }

std::string HttpServer::url() const { return "http://" + config_.bind + ":" + std::to_string(port_) + "/"; }

void HttpServer::start()
{
    server_ = std::make_unique<httplib::Server>();
    const size_t workers = config_.max_event_clients + 4; // SSE streams hold a worker each
    server_->new_task_queue = [workers] { return new httplib::ThreadPool(workers); };
    server_->set_keep_alive_timeout(1);
    server_->set_read_timeout(5, 0);
    server_->set_write_timeout(5, 0);

    for (const WebAsset &asset : webAssets()) {
        const std::string path = asset.path;
        const std::string body(asset.data, asset.size);
        auto handler = [body, type = contentType(path)](const httplib::Request &, httplib::Response &res) {
            res.set_content(body, type);
            res.set_header("Cache-Control", "no-cache");
        };
        server_->Get(path, handler);
        if (path == "/index.html") {
            server_->Get("/", handler);
        }
    }

    server_->Get("/api/map", [this](const httplib::Request &, httplib::Response &res) {
        const MapSnapshotStore::Snapshot snapshot = store_.latest();
        if (!snapshot.map_json) {
            res.status = 503;
            res.set_content("{\"error\": \"no map published yet\"}", "application/json");
            return;
        }
        res.set_content(*snapshot.map_json, "application/json");
    });

    server_->Get("/api/health", [this](const httplib::Request &, httplib::Response &res) {
        const MapSnapshotStore::Snapshot snapshot = store_.latest();
        if (!snapshot.health_json) {
            res.status = 503;
            res.set_content("{\"error\": \"no health published yet\"}", "application/json");
            return;
        }
        res.set_content(*snapshot.health_json, "application/json");
    });

    server_->Get(R"(/api/nodes/(\d+)/components)", [this](const httplib::Request &req, httplib::Response &res) {
        const unsigned long id = std::stoul(req.matches[1].str());
        if (id == 0 || id > 65535) {
            res.status = 400;
            res.set_content("{\"error\": \"node ids are 1..65535\"}", "application/json");
            return;
        }
        auto promise = std::make_shared<std::promise<std::optional<std::string>>>();
        std::future<std::optional<std::string>> answer = promise->get_future();
        loop_.post([promise, fetcher = fetcher_, id] {
            promise->set_value(fetcher ? fetcher(static_cast<uint16_t>(id)) : std::nullopt);
        });
        if (answer.wait_for(std::chrono::milliseconds(kComponentsTimeoutMs)) != std::future_status::ready) {
            res.status = 503;
            res.set_content("{\"error\": \"the service is busy\"}", "application/json");
            return;
        }
        const std::optional<std::string> json = answer.get();
        if (!json) {
            res.status = 404;
            res.set_content("{\"error\": \"unknown node\"}", "application/json");
            return;
        }
        res.set_content(*json, "application/json");
    });

    server_->Get("/api/events", [this](const httplib::Request &, httplib::Response &res) {
        if (event_clients_.fetch_add(1) >= config_.max_event_clients) {
            --event_clients_;
            res.status = 503;
            res.set_content("too many event streams", "text/plain");
            return;
        }
        res.set_header("Cache-Control", "no-cache");
        auto last = std::make_shared<uint64_t>(0);
        res.set_chunked_content_provider(
            "text/event-stream",
            [this, last](size_t, httplib::DataSink &sink) {
                const MapSnapshotStore::Snapshot snapshot = store_.waitNewer(*last, kEventKeepaliveMs);
                if (stopping_.load() || store_.closed()) {
                    sink.done();
                    return true;
                }
                std::string message;
                if (snapshot.revision > *last && snapshot.map_json) {
                    *last = snapshot.revision;
                    message = "event: map\ndata: " + *snapshot.map_json + "\n\n";
                } else {
                    message = ": keep-alive\n\n";
                }
                return sink.write(message.data(), message.size());
            },
            [this](bool) { --event_clients_; });
    });

    const int bound = config_.port == 0 ? server_->bind_to_any_port(config_.bind)
                                        : (server_->bind_to_port(config_.bind, config_.port) ? config_.port : -1);
    if (bound <= 0) {
        server_.reset();
        throw ConfigError("http: cannot listen on " + config_.bind + ":" + std::to_string(config_.port) +
                          " (address in use or not local?)");
    }
    port_ = bound;
    thread_ = std::thread([this] { server_->listen_after_bind(); });
    // stop() is a no-op until the server runs; wait for that, so a quick stop cannot be lost.
    for (int i = 0; i < 5000 && !server_->is_running(); ++i) {
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
    log()->info("http: live map at {}", url());
}

void HttpServer::stop()
{
    if (!server_) {
        return;
    }
    stopping_.store(true);
    store_.close();
    server_->stop();
    if (thread_.joinable()) {
        thread_.join();
    }
    server_.reset();
}

} // namespace cdro::service
