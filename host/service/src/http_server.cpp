#include "cdro/service/http_server.hpp"

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <map>
#include <optional>
#include <vector>

#include <arpa/inet.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <nlohmann/json.hpp>

#include "cdro/service/log.hpp"
#include "cdro/service/map_state.hpp"
#include "cdro/service/metrics.hpp"
#include "web_assets.hpp"

namespace cdro::service {

namespace {

// A node id as a path gives it: decimal (6001... as in JSON) or hex with 0x (0x6001, as in the
// topics, the logs and on the page). At most 5 decimal or 4 hex digits, so no number can overflow
// whatever reads it; 0 is no node.
std::optional<uint16_t> nodeIdOfPath(const std::string &text)
{
    const bool hex = text.size() > 2 && text[0] == '0' && (text[1] == 'x' || text[1] == 'X');
    const std::string digits = hex ? text.substr(2) : text;
    const char *allowed = hex ? "0123456789abcdefABCDEF" : "0123456789";
    if (digits.empty() || digits.size() > (hex ? 4U : 5U) || digits.find_first_not_of(allowed) != std::string::npos) {
        return std::nullopt;
    }
    const unsigned long value = std::stoul(digits, nullptr, hex ? 16 : 10);
    if (value == 0 || value > 65535) {
        return std::nullopt;
    }
    return static_cast<uint16_t>(value);
}

} // namespace

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
    std::lock_guard<std::mutex> lock(listener_mutex_);
    if (on_publish_) {
        on_publish_();
    }
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

void MapSnapshotStore::setOnPublish(std::function<void()> listener)
{
    std::lock_guard<std::mutex> lock(listener_mutex_);
    on_publish_ = std::move(listener);
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

const char *reasonPhrase(int status)
{
    switch (status) {
    case 200: return "OK";
    case 400: return "Bad Request";
    case 404: return "Not Found";
    case 405: return "Method Not Allowed";
    case 408: return "Request Timeout";
    case 413: return "Payload Too Large";
    case 431: return "Request Header Fields Too Large";
    case 503: return "Service Unavailable";
    default: return "Error";
    }
}

std::string errorJson(const std::string &message) { return "{\"error\": \"" + message + "\"}"; }

std::string lower(std::string text)
{
    std::transform(text.begin(), text.end(), text.begin(), [](unsigned char c) { return std::tolower(c); });
    return text;
}

std::string trim(const std::string &text)
{
    const size_t first = text.find_first_not_of(" \t");
    if (first == std::string::npos) {
        return "";
    }
    return text.substr(first, text.find_last_not_of(" \t") - first + 1);
}

constexpr int kAcceptBurst = 64;            // connections accepted per wake-up
constexpr size_t kReadChunk = 4096;         // bytes per read()
constexpr int64_t kSweepPeriodUs = 100'000; // us between deadline checks
constexpr int64_t kLingerUs = 1'000'000;    // us a refused request's unread body is drained for
constexpr size_t kLingerBytes = 1 << 20;    // bytes drained at most (discarded as read)
constexpr int64_t kAcceptPauseUs = 100'000; // us without accepting when out of descriptors
constexpr double kLogPerS = 2.0;            // "refused" log lines per second per reason

} // namespace

class HttpServer::Worker {
public:
    // Liveness shared with tasks posted to the service's loop: they answer a components
    // request through it, and find it empty once the server stopped.
    struct Alive {
        std::mutex mutex;
        Worker *worker = nullptr;
    };

    Worker(HttpServer &owner)
        : owner_(owner), loop_(owner.clock_), log_limit_(kLogPerS), alive_(std::make_shared<Alive>())
    {
        alive_->worker = this;
    }

    ~Worker()
    {
        {
            std::lock_guard<std::mutex> lock(alive_->mutex);
            alive_->worker = nullptr;
        }
        for (auto &entry : connections_) {
            ::close(entry.first);
        }
        if (listen_fd_ >= 0) {
            ::close(listen_fd_);
        }
    }

    // Binds and listens (on the caller's thread); returns the port.
    int bind(const std::string &address, uint16_t port)
    {
        addrinfo hints{};
        hints.ai_family = AF_UNSPEC;
        hints.ai_socktype = SOCK_STREAM;
        hints.ai_flags = AI_PASSIVE;
        addrinfo *found = nullptr;
        const std::string service = std::to_string(port);
        if (::getaddrinfo(address.c_str(), service.c_str(), &hints, &found) != 0 || found == nullptr) {
            throw ConfigError("http: cannot listen on " + address + ":" + service +
                              " (not an address of this machine)");
        }
        std::string error = "no address";
        for (addrinfo *ai = found; ai != nullptr; ai = ai->ai_next) {
            const int fd = ::socket(ai->ai_family, ai->ai_socktype | SOCK_NONBLOCK | SOCK_CLOEXEC, ai->ai_protocol);
            if (fd < 0) {
                error = std::strerror(errno);
                continue;
            }
            const int one = 1;
            ::setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
            if (::bind(fd, ai->ai_addr, ai->ai_addrlen) == 0 && ::listen(fd, 128) == 0) {
                listen_fd_ = fd;
                break;
            }
            error = std::strerror(errno);
            ::close(fd);
        }
        ::freeaddrinfo(found);
        if (listen_fd_ < 0) {
            throw ConfigError("http: cannot listen on " + address + ":" + service + ": " + error +
                              " (address in use or not local?)");
        }
        sockaddr_storage bound{};
        socklen_t len = sizeof bound;
        ::getsockname(listen_fd_, reinterpret_cast<sockaddr *>(&bound), &len);
        return ntohs(bound.ss_family == AF_INET6 ? reinterpret_cast<sockaddr_in6 *>(&bound)->sin6_port
                                                 : reinterpret_cast<sockaddr_in *>(&bound)->sin_port);
    }

    // The HTTP thread.
    void run()
    {
        loop_.watchFd(listen_fd_, POLLIN, [this](short) { acceptSome(); });
        loop_.addTimerAfter(kSweepPeriodUs, [this] { sweep(); });
        loop_.run();
    }

    void stop() { loop_.stop(); }

    // Any thread: a new snapshot is out.
    void wake()
    {
        loop_.post([this] {
            // A send that fails closes its stream: the pass goes by descriptor, never by an
            // iterator into the map it may erase from.
            for (const int fd : openDescriptors()) {
                const auto it = connections_.find(fd);
                if (it != connections_.end() && it->second.state == State::Streaming) {
                    pump(it->second);
                }
            }
        });
    }

    HttpStats stats() const { return {requests_.load(), refused_.load()}; }

    size_t connectionsFrom(const std::string &address) const
    {
        std::lock_guard<std::mutex> lock(clients_mutex_);
        const auto it = clients_.find(address);
        return it == clients_.end() ? 0 : it->second;
    }

private:
    enum class State {
        ReadingHead,        // waiting for the request line and headers
        AwaitingComponents, // the service's loop computes the answer
        Writing,            // a response goes out; then the connection closes
        Streaming,          // an event stream: maps go out as they are published
        Lingering,          // a refused request's body is drained (and discarded) before the close
    };

    struct Connection {
        int fd = -1;
        uint64_t id = 0;
        std::string client; // the peer's address, without the port
        State state = State::ReadingHead;
        std::string in;  // the request head so far
        std::string out; // bytes not yet written
        size_t out_offset = 0;
        bool head_only = false; // HEAD: headers without the body
        int64_t opened_us = 0;
        int64_t deadline_us = 0;      // head deadline, components deadline
        int64_t last_progress_us = 0; // last time the client took bytes (or out became empty)
        int64_t last_event_us = 0;    // event streams: last map or comment sent
        uint64_t sent_revision = 0;
        size_t lingered_bytes = 0;
    };

    int64_t now() const { return owner_.clock_.monotonicUs(); }

    std::vector<int> openDescriptors() const
    {
        std::vector<int> fds;
        fds.reserve(connections_.size());
        for (const auto &entry : connections_) {
            fds.push_back(entry.first);
        }
        return fds;
    }

    void acceptSome()
    {
        for (int i = 0; i < kAcceptBurst; ++i) {
            sockaddr_storage peer{};
            socklen_t len = sizeof peer;
            const int fd =
                ::accept4(listen_fd_, reinterpret_cast<sockaddr *>(&peer), &len, SOCK_NONBLOCK | SOCK_CLOEXEC);
            if (fd < 0) {
                if (errno == EMFILE || errno == ENFILE || errno == ENOBUFS || errno == ENOMEM) {
                    // Out of descriptors: the pending connection stays in the backlog; stop
                    // watching the socket for a moment rather than spin on it.
                    refuseLog("descriptors", "out of file descriptors; not accepting for 0.1 s");
                    loop_.unwatchFd(listen_fd_);
                    loop_.addTimerAfter(kAcceptPauseUs,
                                        [this] { loop_.watchFd(listen_fd_, POLLIN, [this](short) { acceptSome(); }); });
                }
                return;
            }
            admit(fd, addressOf(peer));
        }
    }

    static std::string addressOf(const sockaddr_storage &peer)
    {
        char text[INET6_ADDRSTRLEN] = "?";
        if (peer.ss_family == AF_INET) {
            ::inet_ntop(AF_INET, &reinterpret_cast<const sockaddr_in *>(&peer)->sin_addr, text, sizeof text);
        } else if (peer.ss_family == AF_INET6) {
            ::inet_ntop(AF_INET6, &reinterpret_cast<const sockaddr_in6 *>(&peer)->sin6_addr, text, sizeof text);
        }
        return text;
    }

    void admit(int fd, const std::string &client)
    {
        const Limits &limits = owner_.limits_;
        if (connectionsFrom(client) >= limits.max_per_client && !evictOldestReading(&client)) {
            refuseNow(fd, client, 503, "too many connections from this address");
            return;
        }
        if (connections_.size() >= limits.max_connections && !evictOldestReading(nullptr)) {
            refuseNow(fd, client, 503, "too many connections");
            return;
        }
        Connection c;
        c.fd = fd;
        c.id = next_id_++;
        c.client = client;
        c.opened_us = now();
        c.deadline_us = c.opened_us + secondsToUs(limits.head_deadline_s);
        c.last_progress_us = c.opened_us;
        connections_[fd] = std::move(c);
        by_id_[connections_[fd].id] = fd;
        {
            std::lock_guard<std::mutex> lock(clients_mutex_);
            ++clients_[client];
        }
        owner_.open_connections_.store(connections_.size());
        loop_.watchFd(fd, POLLIN, [this, fd](short revents) { onEvents(fd, revents); });
    }

    // Closes the oldest connection still sending its head (of `client` if given) to make room.
    bool evictOldestReading(const std::string *client)
    {
        Connection *oldest = nullptr;
        for (auto &entry : connections_) {
            Connection &c = entry.second;
            if (c.state == State::ReadingHead && (client == nullptr || c.client == *client) &&
                (oldest == nullptr || c.opened_us < oldest->opened_us)) {
                oldest = &c;
            }
        }
        if (oldest == nullptr) {
            return false;
        }
        ++refused_;
        refuseLog("evicted", "closed a connection from " + oldest->client +
                                 " that had not sent its request yet, to make room for a new one");
        closeConnection(oldest->fd);
        return true;
    }

    // A connection that never gets a slot: a short answer if the socket takes it, then close.
    void refuseNow(int fd, const std::string &client, int status, const std::string &why)
    {
        ++refused_;
        refuseLog(std::to_string(status), client + ": " + why);
        const std::string response = head(status, "application/json", errorJson(why).size()) + errorJson(why);
        [[maybe_unused]] const ssize_t n = ::send(fd, response.data(), response.size(), MSG_NOSIGNAL | MSG_DONTWAIT);
        ::close(fd);
    }

    void refuseLog(const std::string &key, const std::string &message)
    {
        uint64_t suppressed = 0;
        if (log_limit_.allow(key, now(), &suppressed)) {
            if (suppressed > 0) {
                log()->warn("http: {} ({} more like it not logged)", message, suppressed);
            } else {
                log()->warn("http: {}", message);
            }
        }
    }

    void closeConnection(int fd)
    {
        const auto it = connections_.find(fd);
        if (it == connections_.end()) {
            return;
        }
        loop_.unwatchFd(fd);
        ::close(fd);
        if (it->second.state == State::Streaming) {
            --event_clients_;
        }
        {
            std::lock_guard<std::mutex> lock(clients_mutex_);
            if (--clients_[it->second.client] == 0) {
                clients_.erase(it->second.client);
            }
        }
        by_id_.erase(it->second.id);
        connections_.erase(it);
        owner_.open_connections_.store(connections_.size());
    }

    void onEvents(int fd, short revents)
    {
        auto it = connections_.find(fd);
        if (it == connections_.end()) {
            return;
        }
        Connection &c = it->second;
        if ((revents & (POLLIN | POLLHUP | POLLERR)) != 0 && !readSome(c)) {
            return; // closed
        }
        if ((revents & POLLOUT) != 0) {
            if (c.state == State::Streaming) {
                pump(c);
            } else {
                writeSome(c);
            }
        }
    }

    // False if the connection was closed.
    bool readSome(Connection &c)
    {
        const int fd = c.fd; // c is gone once the connection closes
        char buffer[kReadChunk];
        for (;;) {
            const ssize_t n = ::recv(c.fd, buffer, sizeof buffer, 0);
            if (n < 0 && errno == EINTR) {
                continue;
            }
            if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
                return true;
            }
            if (n <= 0) {
                closeConnection(c.fd); // the client closed (or reset): nothing to answer
                return false;
            }
            switch (c.state) {
            case State::ReadingHead: {
                const size_t room = owner_.limits_.max_head_bytes + 4 - c.in.size();
                c.in.append(buffer, std::min(static_cast<size_t>(n), room));
                if (!onHeadBytes(c)) {
                    return connections_.count(fd) != 0;
                }
                break;
            }
            case State::Lingering:
                c.lingered_bytes += static_cast<size_t>(n); // discarded
                if (c.lingered_bytes > kLingerBytes) {
                    closeConnection(c.fd);
                    return false;
                }
                break;
            default:
                // Bytes after the request (a body that was refused, or pipelining, which this
                // server does not do): discarded, never stored.
                break;
            }
        }
    }

    // Returns false once the head is complete (or refused): reading it stops.
    bool onHeadBytes(Connection &c)
    {
        // A request starts with a method (capital letters, then a space): anything else, a TLS
        // handshake say, is refused at once rather than held until the deadline.
        for (const char ch : c.in) {
            if (ch == ' ') {
                break;
            }
            if (ch < 'A' || ch > 'Z') {
                refuse(c, 400, "not an HTTP request");
                return false;
            }
        }
        size_t end = c.in.find("\r\n\r\n");
        size_t terminator = 4;
        if (end == std::string::npos) {
            end = c.in.find("\n\n");
            terminator = 2;
        }
        if (end == std::string::npos || end > owner_.limits_.max_head_bytes) {
            if (c.in.size() > owner_.limits_.max_head_bytes) {
                refuse(c, 431,
                       "the request head is larger than " + std::to_string(owner_.limits_.max_head_bytes) + " bytes");
                return false;
            }
            return true;
        }
        const std::string head_text = c.in.substr(0, end + terminator);
        c.in.clear();
        c.in.shrink_to_fit();
        handleRequest(c, head_text);
        return false;
    }

    void handleRequest(Connection &c, const std::string &head_text)
    {
        // Request line: METHOD SP TARGET SP HTTP/1.x
        size_t line_end = head_text.find('\n');
        std::string request_line = head_text.substr(0, line_end);
        if (!request_line.empty() && request_line.back() == '\r') {
            request_line.pop_back();
        }
        const size_t sp1 = request_line.find(' ');
        const size_t sp2 = sp1 == std::string::npos ? std::string::npos : request_line.find(' ', sp1 + 1);
        if (sp1 == std::string::npos || sp2 == std::string::npos ||
            request_line.find(' ', sp2 + 1) != std::string::npos || request_line.compare(sp2 + 1, 7, "HTTP/1.") != 0 ||
            request_line.size() != sp2 + 9) {
            refuse(c, 400, "not an HTTP/1.x request line");
            return;
        }
        const std::string method = request_line.substr(0, sp1);
        std::string target = request_line.substr(sp1 + 1, sp2 - sp1 - 1);
        // Headers: only the two that announce a body matter here.
        bool has_body = false;
        size_t pos = line_end + 1;
        while (pos < head_text.size()) {
            size_t next = head_text.find('\n', pos);
            if (next == std::string::npos) {
                next = head_text.size();
            }
            std::string line = head_text.substr(pos, next - pos);
            pos = next + 1;
            if (!line.empty() && line.back() == '\r') {
                line.pop_back();
            }
            if (line.empty()) {
                break;
            }
            const size_t colon = line.find(':');
            if (colon == std::string::npos || colon == 0) {
                refuse(c, 400, "a header line without a name");
                return;
            }
            const std::string name = lower(line.substr(0, colon));
            const std::string value = trim(line.substr(colon + 1));
            if (name == "transfer-encoding") {
                has_body = true;
            } else if (name == "content-length") {
                if (value.empty() || value.find_first_not_of("0123456789") != std::string::npos) {
                    refuse(c, 400, "Content-Length is not a number");
                    return;
                }
                has_body = has_body || value.find_first_not_of('0') != std::string::npos;
            }
        }
        if (has_body) {
            refuse(c, 413, "no endpoint takes a request body");
            return;
        }
        if (method != "GET" && method != "HEAD") {
            refuse(c, 405, "only GET and HEAD");
            return;
        }
        c.head_only = method == "HEAD";
        const size_t query = target.find('?');
        if (query != std::string::npos) {
            target.resize(query);
        }
        if (target.empty() || target[0] != '/') {
            refuse(c, 400, "the target must be a path");
            return;
        }
        route(c, target);
    }

    void route(Connection &c, const std::string &path)
    {
        for (const WebAsset &asset : webAssets()) {
            if (path == asset.path || (path == "/" && std::string(asset.path) == "/index.html")) {
                respond(c, 200, contentType(asset.path), std::string(asset.data, asset.size));
                return;
            }
        }
        if (path == "/api/map" || path == "/api/health") {
            const MapSnapshotStore::Snapshot snapshot = owner_.store_.latest();
            const auto &json = path == "/api/map" ? snapshot.map_json : snapshot.health_json;
            if (!json) {
                respond(c, 503, "application/json",
                        errorJson(std::string("no ") + (path == "/api/map" ? "map" : "health") + " published yet"));
                return;
            }
            respond(c, 200, "application/json", *json);
            return;
        }
        if (path == "/api/events") {
            startStream(c);
            return;
        }
        if (path == "/metrics") {
            const MapSnapshotStore::Snapshot snapshot = owner_.store_.latest();
            respond(c, 200, "text/plain; version=0.0.4; charset=utf-8",
                    prometheusText(snapshot.map_json, snapshot.health_json));
            return;
        }
        const std::string prefix = "/api/nodes/";
        const std::string suffix = "/components";
        if (path.size() > prefix.size() + suffix.size() && path.compare(0, prefix.size(), prefix) == 0 &&
            path.compare(path.size() - suffix.size(), suffix.size(), suffix) == 0) {
            const std::optional<uint16_t> id =
                nodeIdOfPath(path.substr(prefix.size(), path.size() - prefix.size() - suffix.size()));
            if (!id) {
                refuse(c, 400, "node ids are 1..65535, decimal or 0x hex");
                return;
            }
            askComponents(c, *id);
            return;
        }
        if (routeFloorPlan(c, path)) {
            return;
        }
        respond(c, 404, "application/json", errorJson("not found"));
    }

    bool routeFloorPlan(Connection &c, const std::string &path)
    {
        if (path != "/api/floor-plan" && path != "/floor-plan.png") {
            return false;
        }
        if (owner_.floor_plan_png_.empty()) {
            respond(c, 404, "application/json", errorJson("no floor plan configured (web.floor_plan.path)"));
        } else if (path == "/floor-plan.png") {
            respond(c, 200, "image/png", owner_.floor_plan_png_);
        } else {
            respond(c, 200, "application/json", owner_.floor_plan_json_);
        }
        return true;
    }

    void askComponents(Connection &c, uint16_t id)
    {
        c.state = State::AwaitingComponents;
        c.deadline_us = now() + secondsToUs(owner_.limits_.components_timeout_s);
        loop_.setFdEvents(c.fd, 0);
        const uint64_t connection = c.id;
        std::shared_ptr<Alive> alive = alive_;
        owner_.loop_.post([alive, fetcher = owner_.fetcher_, id, connection] {
            std::optional<std::string> json = fetcher ? fetcher(id) : std::nullopt;
            std::lock_guard<std::mutex> lock(alive->mutex);
            if (alive->worker != nullptr) {
                Worker *worker = alive->worker;
                worker->loop_.post(
                    [worker, connection, json = std::move(json)] { worker->onComponents(connection, json); });
            }
        });
    }

    void onComponents(uint64_t connection, const std::optional<std::string> &json)
    {
        const auto id = by_id_.find(connection);
        if (id == by_id_.end()) {
            return; // closed meanwhile (timed out, or the client went away)
        }
        Connection &c = connections_[id->second];
        if (c.state != State::AwaitingComponents) {
            return;
        }
        if (!json) {
            respond(c, 404, "application/json", errorJson("unknown node"));
        } else {
            respond(c, 200, "application/json", *json);
        }
    }

    static std::string head(int status, const char *type, size_t length)
    {
        return "HTTP/1.1 " + std::to_string(status) + " " + reasonPhrase(status) + "\r\nContent-Type: " + type +
               "\r\nContent-Length: " + std::to_string(length) +
               "\r\nCache-Control: no-cache\r\nX-Content-Type-Options: nosniff\r\nConnection: close\r\n\r\n";
    }

    void respond(Connection &c, int status, const char *type, const std::string &body)
    {
        if (status == 200 || status == 404) {
            ++requests_;
        } else {
            ++refused_;
        }
        c.out = head(status, type, body.size());
        if (!c.head_only) {
            c.out += body;
        }
        c.out_offset = 0;
        c.state = State::Writing;
        c.last_progress_us = now();
        writeSome(c);
    }

    // A request refused before it was routed: answered, then its unread body (if any) is
    // drained and discarded for a moment, so that the client reads the answer instead of a reset.
    void refuse(Connection &c, int status, const std::string &why)
    {
        refuseLog(std::to_string(status),
                  c.client + ": " + std::to_string(status) + " " + reasonPhrase(status) + " (" + why + ")");
        respond(c, status, "application/json", errorJson(why));
    }

    void startStream(Connection &c)
    {
        if (event_clients_ >= owner_.config_.max_event_clients) {
            refuse(c, 503, "too many event streams");
            return;
        }
        ++event_clients_;
        ++requests_;
        c.state = State::Streaming;
        c.out = "HTTP/1.1 200 OK\r\nContent-Type: text/event-stream\r\nCache-Control: no-cache\r\n"
                "X-Content-Type-Options: nosniff\r\nConnection: close\r\n\r\n";
        c.out_offset = 0;
        c.last_progress_us = now();
        c.last_event_us = now();
        if (c.head_only) {
            c.state = State::Writing;
            --event_clients_;
            writeSome(c);
            return;
        }
        pump(c);
    }

    // Event streams: the newest map, once the previous one is out (a slow reader skips maps).
    void pump(Connection &c)
    {
        const int fd = c.fd; // c is gone once the connection closes
        writeSome(c);
        if (connections_.count(fd) == 0 || c.state != State::Streaming || c.out_offset < c.out.size()) {
            return;
        }
        const MapSnapshotStore::Snapshot snapshot = owner_.store_.latest();
        if (snapshot.revision > c.sent_revision && snapshot.map_json) {
            c.sent_revision = snapshot.revision;
            c.out = "event: map\ndata: " + *snapshot.map_json + "\n\n";
            c.out_offset = 0;
            c.last_event_us = now();
            writeSome(c);
        }
    }

    void writeSome(Connection &c)
    {
        while (c.out_offset < c.out.size()) {
            const ssize_t n =
                ::send(c.fd, c.out.data() + c.out_offset, c.out.size() - c.out_offset, MSG_NOSIGNAL | MSG_DONTWAIT);
            if (n < 0 && errno == EINTR) {
                continue;
            }
            if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
                break;
            }
            if (n <= 0) {
                closeConnection(c.fd);
                return;
            }
            c.out_offset += static_cast<size_t>(n);
            c.last_progress_us = now();
        }
        const bool pending = c.out_offset < c.out.size();
        if (!pending && c.state == State::Writing) {
            // Done: no more bytes from us; drain what the client still sends, then close.
            ::shutdown(c.fd, SHUT_WR);
            c.state = State::Lingering;
            c.deadline_us = now() + kLingerUs;
            c.out.clear();
            c.out.shrink_to_fit();
            loop_.setFdEvents(c.fd, POLLIN);
            return;
        }
        if (!pending && c.state == State::Streaming) {
            c.out.clear();
            c.out_offset = 0;
        }
        loop_.setFdEvents(c.fd, static_cast<short>(POLLIN | (pending ? POLLOUT : 0)));
    }

    void sweep()
    {
        const int64_t t = now();
        const int64_t stall_us = secondsToUs(owner_.limits_.write_stall_s);
        const int64_t keepalive_us = secondsToUs(owner_.limits_.keepalive_s);
        for (const int fd : openDescriptors()) {
            const auto it = connections_.find(fd);
            if (it == connections_.end()) {
                continue;
            }
            Connection &c = it->second;
            switch (c.state) {
            case State::ReadingHead:
                if (t >= c.deadline_us) {
                    refuse(c, 408,
                           "the request head did not arrive within " + std::to_string(owner_.limits_.head_deadline_s) +
                               " s");
                }
                break;
            case State::AwaitingComponents:
                if (t >= c.deadline_us) {
                    refuse(c, 503, "the service is busy");
                }
                break;
            case State::Lingering:
                if (t >= c.deadline_us) {
                    closeConnection(fd);
                }
                break;
            case State::Writing:
            case State::Streaming:
                if (c.out_offset < c.out.size() && t - c.last_progress_us >= stall_us) {
                    refuseLog("stalled", "closed a connection from " + c.client + ": it read nothing for " +
                                             std::to_string(owner_.limits_.write_stall_s) + " s");
                    closeConnection(fd);
                } else if (c.state == State::Streaming && c.out_offset == c.out.size() &&
                           t - c.last_event_us >= keepalive_us) {
                    c.out = ": keep-alive\n\n";
                    c.out_offset = 0;
                    c.last_event_us = t;
                    writeSome(c);
                }
                break;
            }
        }
        loop_.addTimerAfter(kSweepPeriodUs, [this] { sweep(); });
    }

    HttpServer &owner_;
    EventLoop loop_;
    RateLimiter log_limit_;
    std::shared_ptr<Alive> alive_;
    int listen_fd_ = -1;
    std::map<int, Connection> connections_;
    std::map<uint64_t, int> by_id_;
    uint64_t next_id_ = 1;
    uint32_t event_clients_ = 0;
    mutable std::mutex clients_mutex_;
    std::map<std::string, size_t> clients_; // open connections per address
    std::atomic<uint64_t> requests_{0};
    std::atomic<uint64_t> refused_{0};
};

HttpServer::HttpServer(EventLoop &loop, const HttpConfig &config, MapSnapshotStore &store, ComponentsFetcher fetcher,
                       Limits limits)
    : loop_(loop), config_(config), store_(store), fetcher_(std::move(fetcher)), limits_(limits)
{
}

HttpServer::~HttpServer() { stop(); }

void HttpServer::setFloorPlan(const FloorPlanConfig &config)
{
    floor_plan_png_.clear();
    floor_plan_json_.clear();
    if (config.path.empty()) {
        return;
    }
    FloorPlanImage image = readFloorPlan(config.path);
    nlohmann::ordered_json j;
    j["schema"] = kOutputSchemaVersion;
    j["url"] = "/floor-plan.png";
    j["width_px"] = image.width_px;
    j["height_px"] = image.height_px;
    j["metres_per_pixel"] = config.metres_per_pixel;
    j["origin_x_m"] = config.origin_x_m;
    j["origin_y_m"] = config.origin_y_m;
    j["rotation_rad"] = config.rotation_rad;
    floor_plan_json_ = j.dump();
    floor_plan_png_ = std::move(image.png);
    log()->info("http: floor plan {} ({} x {} px, {} m per pixel)", config.path, image.width_px, image.height_px,
                config.metres_per_pixel);
}

std::string HttpServer::url() const
{
    const bool v6 = config_.bind.find(':') != std::string::npos;
    return "http://" + (v6 ? "[" + config_.bind + "]" : config_.bind) + ":" + std::to_string(port_) + "/";
}

void HttpServer::start()
{
    worker_ = std::make_unique<Worker>(*this);
    try {
        port_ = worker_->bind(config_.bind, config_.port);
    } catch (...) {
        worker_.reset();
        throw;
    }
    Worker *worker = worker_.get();
    store_.setOnPublish([worker] { worker->wake(); });
    thread_ = std::thread([worker] { worker->run(); });
    log()->info("http: live map at {}", url());
}

void HttpServer::stop()
{
    if (!worker_) {
        return;
    }
    store_.setOnPublish(nullptr);
    store_.close();
    worker_->stop();
    if (thread_.joinable()) {
        thread_.join();
    }
    worker_.reset();
    open_connections_.store(0);
}

HttpStats HttpServer::stats() const { return worker_ ? worker_->stats() : HttpStats{}; }

size_t HttpServer::connectionsFrom(const std::string &address) const
{
    return worker_ ? worker_->connectionsFrom(address) : 0;
}

} // namespace cdro::service
