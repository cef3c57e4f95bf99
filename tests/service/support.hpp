// Test support: pseudo-terminals that play the device, frame builders, a recording consumer,
// free loopback ports, temporary directories, and a mosquitto broker on loopback.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <sys/types.h>

#include "cdro/frames.h"
#include "cdro/service/consumer.hpp"
#include "cdro/service/odometry.hpp"

namespace cdro::test {

// A fresh temporary directory, removed with its contents at destruction.
class TempDir {
public:
    TempDir();
    ~TempDir();
    const std::string &path() const { return path_; }
    std::string file(const std::string &name) const { return path_ + "/" + name; }

private:
    std::string path_;
};

// The names in a directory (without . and ..), sorted.
std::vector<std::string> listDirectory(const std::string &path);

// A pseudo-terminal whose master side plays the device. The slave side is in raw mode and
// reachable through a symlink (link_path), like /dev/serial/by-id/...; the test keeps a slave
// descriptor open so that nothing the master writes is lost before the service opens it.
class FakeDevicePty {
public:
    explicit FakeDevicePty(const std::string &link_path);
    ~FakeDevicePty();
    void write(const std::vector<uint8_t> &bytes) const;
    // Bytes from the host, waiting up to timeout_ms for at least one.
    std::vector<uint8_t> read(int timeout_ms) const;
    void vanish(); // closes both sides: the service sees a hang-up
    const std::string &slavePath() const { return slave_path_; }

private:
    int master_ = -1;
    int slave_ = -1;
    std::string link_path_;
    std::string slave_path_;
};

std::vector<uint8_t> encode(const cdro_frame_t &frame);
cdro_frame_t helloFrame(uint16_t sequence, uint32_t device_time_ms, uint16_t node_id = 0x6000);
cdro_frame_t rangeFrame(uint16_t sequence, uint32_t device_time_ms, uint16_t from, uint16_t to, uint32_t distance_mm);
cdro_frame_t ackFrame(uint16_t sequence, uint8_t acked_type, uint16_t acked_sequence, uint32_t value = 0);

// Decodes every frame in a byte stream (host-to-device included).
std::vector<cdro_frame_t> decodeAll(const std::vector<uint8_t> &bytes);

struct Received {
    std::string kind;     // "range", "motion", "hello", "status", "node_list", "error", "reset",
                          // "odometry"
    cdro_frame_t frame{}; // the payload in frame.as
    service::FrameContext context;
    service::OdometryMessage odometry{0.0, 0.0, 0.0}; // kind "odometry"
};

// Frames and odometry in one list, in the order the service delivered them.
class RecordingConsumer final : public service::FrameConsumer, public service::OdometryConsumer {
public:
    void onRange(const cdro_range_t &r, const service::FrameContext &c) override;
    void onMotion(const cdro_motion_t &m, const service::FrameContext &c) override;
    void onHello(const cdro_hello_t &h, const service::FrameContext &c) override;
    void onStatus(const cdro_status_t &s, const service::FrameContext &c) override;
    void onNodeList(const cdro_node_list_t &l, const service::FrameContext &c) override;
    void onDeviceError(const cdro_error_t &e, const service::FrameContext &c) override;
    void onDeviceReset(service::DeviceResetReason reason, const service::FrameContext &c) override;
    void onOdometry(const service::OdometryMessage &message) override;
    std::vector<Received> received;
    size_t count(const std::string &kind) const;
};

uint16_t freeLoopbackPort();
uint16_t freeLoopbackUdpPort();

// mosquitto on 127.0.0.1:<port> with a generated config; stopped (SIGTERM) at destruction.
class Broker {
public:
    explicit Broker(uint16_t port);
    ~Broker();
    void start();
    void kill(); // SIGKILL, to simulate a lost broker
    uint16_t port() const { return port_; }

private:
    uint16_t port_;
    TempDir dir_;
    pid_t pid_ = -1;
};

// Seed for randomised tests: CDRO_TEST_SEED from the environment, else a fixed default;
// printed so that a failure can be replayed.
uint32_t testSeed(const char *test_name);

} // namespace cdro::test
