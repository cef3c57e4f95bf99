#include "support.hpp"

#include <cerrno>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <stdexcept>
#include <system_error>
#include <thread>

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <poll.h>
#include <pty.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <termios.h>
#include <unistd.h>
#include <dirent.h>

#include <algorithm>
#include <iostream>

namespace cdro::test {

TempDir::TempDir()
{
    char pattern[] = "/tmp/cdro-service-test-XXXXXX";
    if (mkdtemp(pattern) == nullptr) {
        throw std::runtime_error("mkdtemp failed");
    }
    path_ = pattern;
}

TempDir::~TempDir()
{
    const std::string command = "rm -rf '" + path_ + "'";
    [[maybe_unused]] const int rc = std::system(command.c_str());
}

std::vector<std::string> listDirectory(const std::string &path)
{
    std::vector<std::string> names;
    DIR *dir = ::opendir(path.c_str());
    if (dir == nullptr) {
        return names;
    }
    while (const dirent *entry = ::readdir(dir)) {
        const std::string name = entry->d_name;
        if (name != "." && name != "..") {
            names.push_back(name);
        }
    }
    ::closedir(dir);
    std::sort(names.begin(), names.end());
    return names;
}

FakeDevicePty::FakeDevicePty(const std::string &link_path) : link_path_(link_path)
{
    char name[128];
    if (openpty(&master_, &slave_, name, nullptr, nullptr) != 0) {
        throw std::runtime_error(std::string("openpty: ") + std::strerror(errno));
    }
    slave_path_ = name;
    termios tio{};
    tcgetattr(slave_, &tio);
    cfmakeraw(&tio);
    tcsetattr(slave_, TCSANOW, &tio);
    ::unlink(link_path_.c_str());
    if (::symlink(slave_path_.c_str(), link_path_.c_str()) != 0) {
        throw std::runtime_error(std::string("symlink: ") + std::strerror(errno));
    }
}

FakeDevicePty::~FakeDevicePty() { vanish(); }

void FakeDevicePty::vanish()
{
    if (master_ >= 0) {
        ::close(master_);
        master_ = -1;
    }
    if (slave_ >= 0) {
        ::close(slave_);
        slave_ = -1;
    }
    ::unlink(link_path_.c_str());
}

void FakeDevicePty::write(const std::vector<uint8_t> &bytes) const
{
    size_t done = 0;
    while (done < bytes.size()) {
        const ssize_t n = ::write(master_, bytes.data() + done, bytes.size() - done);
        if (n < 0 && errno == EINTR) {
            continue;
        }
        if (n < 0) {
            throw std::runtime_error(std::string("pty write: ") + std::strerror(errno));
        }
        done += static_cast<size_t>(n);
    }
}

std::vector<uint8_t> FakeDevicePty::read(int timeout_ms) const
{
    std::vector<uint8_t> out;
    pollfd p{master_, POLLIN, 0};
    if (::poll(&p, 1, timeout_ms) > 0 && (p.revents & POLLIN)) {
        uint8_t buffer[4096];
        const ssize_t n = ::read(master_, buffer, sizeof buffer);
        if (n > 0) {
            out.assign(buffer, buffer + n);
        }
    }
    return out;
}

std::vector<uint8_t> encode(const cdro_frame_t &frame)
{
    uint8_t bytes[CDRO_MAX_ENCODED_FRAME];
    const size_t size = cdro_frame_encode(&frame, bytes, sizeof bytes);
    if (size == 0) {
        throw std::runtime_error("cannot encode frame");
    }
    return std::vector<uint8_t>(bytes, bytes + size);
}

cdro_frame_t helloFrame(uint16_t sequence, uint32_t device_time_ms, uint16_t node_id)
{
    cdro_frame_t f{};
    f.type = CDRO_FRAME_HELLO;
    f.sequence = sequence;
    f.as.hello.device_time_ms = device_time_ms;
    f.as.hello.firmware_version = 0x0102;
    f.as.hello.protocol_version = CDRO_PROTOCOL_VERSION;
    f.as.hello.layout_hash = CDRO_LAYOUT_HASH;
    f.as.hello.node_id = node_id;
    f.as.hello.capabilities = CDRO_CAP_DIRECT_RANGING | CDRO_CAP_REMOTE_RANGING;
    f.as.hello.max_nodes = 20;
    f.as.hello.reset_cause = CDRO_RESET_POWER_ON;
    return f;
}

cdro_frame_t rangeFrame(uint16_t sequence, uint32_t device_time_ms, uint16_t from, uint16_t to, uint32_t distance_mm)
{
    cdro_frame_t f{};
    f.type = CDRO_FRAME_RANGE;
    f.sequence = sequence;
    f.as.range.device_time_ms = device_time_ms;
    f.as.range.from_id = from;
    f.as.range.to_id = to;
    f.as.range.distance_mm = distance_mm;
    f.as.range.rss_dbm = -80;
    return f;
}

cdro_frame_t ackFrame(uint16_t sequence, uint8_t acked_type, uint16_t acked_sequence, uint32_t value)
{
    cdro_frame_t f{};
    f.type = CDRO_FRAME_ACK;
    f.sequence = sequence;
    f.as.ack.acked_type = acked_type;
    f.as.ack.acked_sequence = acked_sequence;
    f.as.ack.value = value;
    return f;
}

std::vector<cdro_frame_t> decodeAll(const std::vector<uint8_t> &bytes)
{
    std::vector<cdro_frame_t> frames;
    cdro_decoder_t decoder;
    cdro_decoder_init(&decoder);
    for (const uint8_t byte : bytes) {
        cdro_frame_t frame;
        if (cdro_decoder_push(&decoder, byte, &frame) == CDRO_OK) {
            frames.push_back(frame);
        }
    }
    return frames;
}

namespace {
Received make(const char *kind, const service::FrameContext &c)
{
    Received r;
    r.kind = kind;
    r.context = c;
    return r;
}
} // namespace

void RecordingConsumer::onRange(const cdro_range_t &v, const service::FrameContext &c)
{
    Received r = make("range", c);
    r.frame.as.range = v;
    received.push_back(r);
}
void RecordingConsumer::onMotion(const cdro_motion_t &v, const service::FrameContext &c)
{
    Received r = make("motion", c);
    r.frame.as.motion = v;
    received.push_back(r);
}
void RecordingConsumer::onHello(const cdro_hello_t &v, const service::FrameContext &c)
{
    Received r = make("hello", c);
    r.frame.as.hello = v;
    received.push_back(r);
}
void RecordingConsumer::onStatus(const cdro_status_t &v, const service::FrameContext &c)
{
    Received r = make("status", c);
    r.frame.as.status = v;
    received.push_back(r);
}
void RecordingConsumer::onNodeList(const cdro_node_list_t &v, const service::FrameContext &c)
{
    Received r = make("node_list", c);
    r.frame.as.node_list = v;
    received.push_back(r);
}
void RecordingConsumer::onDeviceError(const cdro_error_t &v, const service::FrameContext &c)
{
    Received r = make("error", c);
    r.frame.as.error = v;
    received.push_back(r);
}
void RecordingConsumer::onDeviceReset(service::DeviceResetReason, const service::FrameContext &c)
{
    received.push_back(make("reset", c));
}
void RecordingConsumer::onOdometry(const service::OdometryMessage &message)
{
    Received r;
    r.kind = "odometry";
    r.odometry = message;
    received.push_back(r);
}
size_t RecordingConsumer::count(const std::string &kind) const
{
    size_t n = 0;
    for (const Received &r : received) {
        n += r.kind == kind ? 1U : 0U;
    }
    return n;
}

namespace {
uint16_t freePort(int type)
{
    const int fd = ::socket(AF_INET, type, 0);
    sockaddr_in address{};
    address.sin_family = AF_INET;
    address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    address.sin_port = 0;
    if (::bind(fd, reinterpret_cast<sockaddr *>(&address), sizeof address) != 0) {
        ::close(fd);
        throw std::system_error(errno, std::generic_category(), "freePort: bind");
    }
    socklen_t len = sizeof address;
    ::getsockname(fd, reinterpret_cast<sockaddr *>(&address), &len);
    ::close(fd);
    return ntohs(address.sin_port);
}
} // namespace

uint16_t freeLoopbackPort() { return freePort(SOCK_STREAM); }
uint16_t freeLoopbackUdpPort() { return freePort(SOCK_DGRAM); }

Broker::Broker(uint16_t port) : port_(port) { start(); }

Broker::~Broker()
{
    if (pid_ > 0) {
        ::kill(pid_, SIGTERM);
        ::waitpid(pid_, nullptr, 0);
    }
}

void Broker::start()
{
    const std::string config = dir_.file("mosquitto.conf");
    {
        std::ofstream out(config);
        out << "listener " << port_ << " 127.0.0.1\nallow_anonymous true\npersistence false\n";
    }
    pid_ = ::fork();
    if (pid_ == 0) {
        const int devnull = ::open("/dev/null", O_WRONLY);
        ::dup2(devnull, STDOUT_FILENO);
        ::dup2(devnull, STDERR_FILENO);
        ::execlp("mosquitto", "mosquitto", "-c", config.c_str(), static_cast<char *>(nullptr));
        // Debian installs it in /usr/sbin, which a non-root PATH may not hold.
        ::execl("/usr/sbin/mosquitto", "mosquitto", "-c", config.c_str(), static_cast<char *>(nullptr));
        ::_exit(127);
    }
    // Ready when it accepts a connection (a deadlock guard, not a speed assumption).
    for (int attempt = 0; attempt < 1000; ++attempt) {
        const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
        sockaddr_in address{};
        address.sin_family = AF_INET;
        address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
        address.sin_port = htons(port_);
        const bool up = ::connect(fd, reinterpret_cast<sockaddr *>(&address), sizeof address) == 0;
        ::close(fd);
        if (up) {
            return;
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    throw std::runtime_error("mosquitto did not start on port " + std::to_string(port_));
}

void Broker::kill()
{
    if (pid_ > 0) {
        ::kill(pid_, SIGKILL);
        ::waitpid(pid_, nullptr, 0);
        pid_ = -1;
    }
}

uint32_t testSeed(const char *test_name)
{
    uint32_t seed = 20261122U;
    if (const char *env = std::getenv("CDRO_TEST_SEED")) {
        seed = static_cast<uint32_t>(std::strtoul(env, nullptr, 10));
    }
    std::cout << test_name << ": seed " << seed << " (replay with CDRO_TEST_SEED=" << seed << ")" << std::endl;
    return seed;
}

} // namespace cdro::test
