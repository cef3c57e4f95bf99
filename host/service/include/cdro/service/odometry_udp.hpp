// odometry_udp.hpp: the robot's odometry over UDP (odometry.udp_bind, odometry.udp_port): one
// JSON message per datagram (or several, one per line), read from a non-blocking socket in
// the service's event loop and handed to the OdometryIntake with the receive time.
//
// Bound to loopback by default: the robot's own computer runs cdro-hostd next to its drive
// software, and nothing else on the network should be able to move the robot's estimate.
// Each wake-up drains at most kBurstDatagrams datagrams, so a flood cannot starve the serial
// input, the timers or the signals (the rest is read at the next turn of the loop).
//
// Threading: loop thread only.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "cdro/service/event_loop.hpp"
#include "cdro/service/odometry_intake.hpp"

namespace cdro::service {

class OdometryUdpSource {
public:
    // port 0 lets the kernel choose (tests); the service only makes a source for a port > 0.
    OdometryUdpSource(EventLoop &loop, std::string bind, uint16_t port, OdometryIntake &intake);
    ~OdometryUdpSource();
    OdometryUdpSource(const OdometryUdpSource &) = delete;
    OdometryUdpSource &operator=(const OdometryUdpSource &) = delete;

    // Binds and starts watching. Throws ConfigError naming the address, port and the reason.
    void start();
    void stop();
    // After each burst of datagrams (the service flushes its outputs there).
    void setAfterBurst(std::function<void()> after) { after_burst_ = std::move(after); }

    uint16_t port() const { return bound_port_; } // the bound port (the kernel's choice for 0)
    std::string description() const;              // "udp:127.0.0.1:5005"
    uint64_t datagrams() const { return datagrams_; }

    static constexpr int kBurstDatagrams = 64;
    static constexpr size_t kMaxDatagramBytes = 65536; // bytes; more than UDP carries, so nothing is cut

private:
    void onReadable(short revents);

    EventLoop &loop_;
    std::string bind_;
    uint16_t port_;
    OdometryIntake &intake_;
    int fd_ = -1;
    uint16_t bound_port_ = 0;
    uint64_t datagrams_ = 0;
    bool error_logged_ = false;
    std::vector<char> buffer_;
    std::function<void()> after_burst_;
};

} // namespace cdro::service
