#include "cdro/service/odometry_udp.hpp"

#include <cerrno>
#include <cstring>

#include <arpa/inet.h>
#include <netdb.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include "cdro/service/log.hpp"

namespace cdro::service {

namespace {

// "udp:127.0.0.1:40312" or "udp:[::1]:40312" for a sender's (or our own) address.
std::string addressText(const sockaddr_storage &address)
{
    char host[INET6_ADDRSTRLEN] = "?";
    uint16_t port = 0;
    if (address.ss_family == AF_INET) {
        const auto *v4 = reinterpret_cast<const sockaddr_in *>(&address);
        ::inet_ntop(AF_INET, &v4->sin_addr, host, sizeof host);
        port = ntohs(v4->sin_port);
        return "udp:" + std::string(host) + ":" + std::to_string(port);
    }
    if (address.ss_family == AF_INET6) {
        const auto *v6 = reinterpret_cast<const sockaddr_in6 *>(&address);
        ::inet_ntop(AF_INET6, &v6->sin6_addr, host, sizeof host);
        port = ntohs(v6->sin6_port);
        return "udp:[" + std::string(host) + "]:" + std::to_string(port);
    }
    return "udp:?";
}

} // namespace

OdometryUdpSource::OdometryUdpSource(EventLoop &loop, std::string bind, uint16_t port, OdometryIntake &intake)
    : loop_(loop), bind_(std::move(bind)), port_(port), intake_(intake)
{
}

OdometryUdpSource::~OdometryUdpSource() { stop(); }

std::string OdometryUdpSource::description() const
{
    const bool v6 = bind_.find(':') != std::string::npos;
    return "udp:" + (v6 ? "[" + bind_ + "]" : bind_) + ":" + std::to_string(bound_port_ != 0 ? bound_port_ : port_);
}

void OdometryUdpSource::start()
{
    stop();
    const std::string where = "odometry: cannot listen for UDP on " + bind_ + ":" + std::to_string(port_);
    addrinfo hints{};
    hints.ai_family = AF_UNSPEC;
    hints.ai_socktype = SOCK_DGRAM;
    hints.ai_flags = AI_NUMERICHOST | AI_NUMERICSERV | AI_PASSIVE; // an address, never a name lookup
    addrinfo *found = nullptr;
    const int rc = ::getaddrinfo(bind_.c_str(), std::to_string(port_).c_str(), &hints, &found);
    if (rc != 0 || found == nullptr) {
        throw ConfigError(where + ": '" + bind_ + "' is not a numeric IPv4 or IPv6 address (" + ::gai_strerror(rc) +
                          ")");
    }
    const int fd = ::socket(found->ai_family, SOCK_DGRAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    if (fd < 0) {
        const int error = errno;
        ::freeaddrinfo(found);
        throw ConfigError(where + ": socket: " + std::strerror(error));
    }
    if (::bind(fd, found->ai_addr, found->ai_addrlen) != 0) {
        const int error = errno;
        ::freeaddrinfo(found);
        ::close(fd);
        throw ConfigError(where + ": " + std::strerror(error));
    }
    ::freeaddrinfo(found);
    sockaddr_storage bound{};
    socklen_t len = sizeof bound;
    ::getsockname(fd, reinterpret_cast<sockaddr *>(&bound), &len);
    bound_port_ = bound.ss_family == AF_INET6 ? ntohs(reinterpret_cast<const sockaddr_in6 *>(&bound)->sin6_port)
                                              : ntohs(reinterpret_cast<const sockaddr_in *>(&bound)->sin_port);
    fd_ = fd;
    buffer_.resize(kMaxDatagramBytes);
    loop_.watchFd(fd_, POLLIN, [this](short revents) { onReadable(revents); });
    log()->info("odometry: listening for UDP JSON on {}", description());
}

void OdometryUdpSource::stop()
{
    if (fd_ >= 0) {
        loop_.unwatchFd(fd_);
        ::close(fd_);
        fd_ = -1;
    }
}

void OdometryUdpSource::onReadable(short)
{
    bool any = false;
    for (int i = 0; i < kBurstDatagrams && fd_ >= 0; ++i) {
        sockaddr_storage from{};
        socklen_t from_len = sizeof from;
        const ssize_t n =
            ::recvfrom(fd_, buffer_.data(), buffer_.size(), 0, reinterpret_cast<sockaddr *>(&from), &from_len);
        if (n < 0) {
            if (errno == EINTR) {
                continue;
            }
            if (errno != EAGAIN && errno != EWOULDBLOCK && !error_logged_) {
                // A datagram socket has no connection to lose: log it once and keep reading.
                error_logged_ = true;
                log()->warn("odometry: UDP receive on {} failed: {} (further errors are not logged)", description(),
                            std::strerror(errno));
            }
            break;
        }
        ++datagrams_;
        any = true;
        intake_.push(addressText(from), buffer_.data(), static_cast<size_t>(n), loop_.clock().unixUs());
    }
    if (any && after_burst_) {
        after_burst_();
    }
}

} // namespace cdro::service
