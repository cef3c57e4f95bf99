// cdro-bench-service: how many frames per second the service sustains from a pseudo-terminal,
// the latency from a frame's arrival (the read() that delivered it) to its estimate going out
// (the map being read for the outputs after the consumer took the frame), and the resident
// memory over a long run.
//
// A device thread plays the Pozyx tag on the PTY master: boot HELLO, ACKs for the handshake,
// then RANGE frames among 1 + 7 nodes as fast as the PTY takes them. The service runs exactly
// as cdro-hostd will (event loop, LibSerial link, intake, capture, JSON Lines to a file), with
// a map source that changes on every range, so that every frame produces output. The engine
// itself is not in this loop (part B adds it); this measures the I/O side's share.
//
//   cdro-bench-service [--frames N] [--soak-s S] [--jsonl on|off] [--capture on|off]
#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

#include <poll.h>
#include <pty.h>
#include <termios.h>
#include <unistd.h>

#include "cdro/service/service.hpp"

using namespace cdro::service;

namespace {

constexpr uint16_t kOwnNode = 0x6000;
constexpr uint16_t kRemoteNodes[] = {0x6069, 0x6A11, 0x6A2C, 0x6A3E, 0x6A4F, 0x6A5B, 0x6A60};

long residentKiB()
{
    std::ifstream status("/proc/self/status");
    std::string key;
    while (status >> key) {
        if (key == "VmRSS:") {
            long kib = 0;
            status >> kib;
            return kib;
        }
        status.ignore(256, '\n');
    }
    return -1;
}

class BenchConsumer final : public FrameConsumer, public MapSource {
public:
    // A histogram of 1 us bins, allocated and touched up front so that it does not show up as
    // memory growth in the soak.
    static constexpr size_t kBins = 50'000; // us; longer latencies land in the last bin
    explicit BenchConsumer(const Clock &clock) : clock_(clock), histogram_(kBins + 1, 0) {}
    void onRange(const cdro_range_t &range, const FrameContext &context) override
    {
        ++ranges_;
        last_arrival_unix_us_ = context.host_unix_us;
        last_distance_mm_ = range.distance_mm;
        ++revision_;
        if (first_us_ == 0) {
            first_us_ = clock_.monotonicUs();
        }
        last_us_ = clock_.monotonicUs();
    }
    void onMotion(const cdro_motion_t &, const FrameContext &) override {}
    uint64_t revision() const override { return revision_; }
    void fill(MapState &map) const override
    {
        // "Estimate out": the outputs read the map after the consumer took the frame (health
        // timers read it too, without a new frame: those reads are not latencies).
        if (filled_revision_ != revision_) {
            filled_revision_ = revision_;
            const int64_t latency_us = std::max<int64_t>(0, clock_.unixUs() - last_arrival_unix_us_);
            ++histogram_[std::min<size_t>(kBins, static_cast<size_t>(latency_us))];
            ++samples_;
        }
        NodeEstimate node;
        node.id = kOwnNode;
        node.x_m = static_cast<double>(last_distance_mm_) * 1e-3;
        node.placed = true;
        map.nodes.push_back(node);
    }
    std::optional<NodeComponents> components(uint16_t) const override { return std::nullopt; }

    uint64_t ranges() const { return ranges_; }
    double seconds() const { return static_cast<double>(last_us_ - first_us_) * 1e-6; }
    // The latency below which a fraction p of the samples lie (us).
    int64_t percentileUs(double p) const
    {
        const auto wanted = static_cast<uint64_t>(p * static_cast<double>(samples_));
        uint64_t seen = 0;
        for (size_t bin = 0; bin <= kBins; ++bin) {
            seen += histogram_[bin];
            if (seen > wanted) {
                return static_cast<int64_t>(bin);
            }
        }
        return static_cast<int64_t>(kBins);
    }
    uint64_t samples() const { return samples_; }

private:
    const Clock &clock_;
    uint64_t ranges_ = 0;
    uint64_t revision_ = 0;
    int64_t last_arrival_unix_us_ = 0;
    uint32_t last_distance_mm_ = 0;
    int64_t first_us_ = 0;
    int64_t last_us_ = 0;
    mutable uint64_t filled_revision_ = 0;
    mutable std::vector<uint64_t> histogram_;
    mutable uint64_t samples_ = 0;
};

void writeAll(int fd, const uint8_t *bytes, size_t len)
{
    while (len > 0) {
        const ssize_t n = ::write(fd, bytes, len);
        if (n < 0 && errno == EINTR) {
            continue;
        }
        if (n < 0) {
            std::perror("device write");
            return;
        }
        bytes += n;
        len -= static_cast<size_t>(n);
    }
}

size_t encode(const cdro_frame_t &frame, uint8_t *out) { return cdro_frame_encode(&frame, out, CDRO_MAX_ENCODED_FRAME); }

// The device: boot, answer SET_SCHEDULE and START, then stream ranges until told to stop.
void device(int master, uint64_t frames, double soak_s, std::atomic<bool> &stop)
{
    uint16_t sequence = 0;
    uint8_t buffer[CDRO_MAX_ENCODED_FRAME];
    cdro_frame_t hello{};
    hello.type = CDRO_FRAME_HELLO;
    hello.sequence = sequence++;
    hello.as.hello = {1, 0x0100, CDRO_PROTOCOL_VERSION, CDRO_LAYOUT_HASH, kOwnNode, 0x03, 0x12, 20, 1};
    const uint8_t zero = 0;
    writeAll(master, &zero, 1);
    writeAll(master, buffer, encode(hello, buffer));
    cdro_decoder_t decoder;
    cdro_decoder_init(&decoder);
    bool started = false;
    while (!started && !stop) {
        pollfd p{master, POLLIN, 0};
        if (::poll(&p, 1, 100) <= 0) {
            continue;
        }
        uint8_t in[256];
        const ssize_t n = ::read(master, in, sizeof in);
        for (ssize_t i = 0; i < n; ++i) {
            cdro_frame_t command;
            if (cdro_decoder_push(&decoder, in[i], &command) != CDRO_OK) {
                continue;
            }
            if (command.type == CDRO_FRAME_HELLO_REQUEST) {
                hello.sequence = sequence++;
                writeAll(master, buffer, encode(hello, buffer));
                continue;
            }
            cdro_frame_t ack{};
            ack.type = CDRO_FRAME_ACK;
            ack.sequence = sequence++;
            ack.as.ack = {command.type, command.sequence, command.type == CDRO_FRAME_PING ? command.as.ping.nonce : 0};
            writeAll(master, buffer, encode(ack, buffer));
            started = started || command.type == CDRO_FRAME_START;
        }
    }
    const auto begin = std::chrono::steady_clock::now();
    std::vector<uint8_t> batch;
    uint32_t device_time_ms = 1000;
    for (uint64_t i = 0; !stop; ++i) {
        if (frames > 0 && i >= frames) {
            break;
        }
        if (soak_s > 0.0 && (i & 1023U) == 0 &&
            std::chrono::duration<double>(std::chrono::steady_clock::now() - begin).count() > soak_s) {
            break;
        }
        cdro_frame_t range{};
        range.type = CDRO_FRAME_RANGE;
        range.sequence = sequence++;
        device_time_ms += (i % 4 == 0) ? 1U : 0U;
        range.as.range = {device_time_ms, kOwnNode, kRemoteNodes[i % 7], static_cast<uint32_t>(2000 + i % 5000), -80, 0};
        const size_t n = encode(range, buffer);
        batch.insert(batch.end(), buffer, buffer + n);
        if (batch.size() >= 4096) { // a UART-sized burst
            writeAll(master, batch.data(), batch.size());
            batch.clear();
        }
    }
    writeAll(master, batch.data(), batch.size());
}

} // namespace

int main(int argc, char **argv)
{
    uint64_t frames = 1'000'000;
    double soak_s = 0.0;
    bool jsonl = true;
    bool capture = true;
    for (int i = 1; i + 1 < argc; i += 2) {
        const std::string option = argv[i];
        const std::string value = argv[i + 1];
        if (option == "--frames") {
            frames = std::strtoull(value.c_str(), nullptr, 10);
        } else if (option == "--soak-s") {
            soak_s = std::strtod(value.c_str(), nullptr);
            frames = 0;
        } else if (option == "--jsonl") {
            jsonl = value == "on";
        } else if (option == "--capture") {
            capture = value == "on";
        } else {
            std::fprintf(stderr, "usage: %s [--frames N] [--soak-s S] [--jsonl on|off] [--capture on|off]\n", argv[0]);
            return 2;
        }
    }
    char dir_pattern[] = "/tmp/cdro-bench-XXXXXX";
    const std::string dir = mkdtemp(dir_pattern);
    int master = -1, slave = -1;
    char name[128];
    if (openpty(&master, &slave, name, nullptr, nullptr) != 0) {
        std::perror("openpty");
        return 1;
    }
    termios tio{};
    tcgetattr(slave, &tio);
    cfmakeraw(&tio);
    tcsetattr(slave, TCSANOW, &tio);

    ServiceConfig config;
    config.serial.device = name;
    config.serial.keepalive_period_s = 0.0;
    config.serial.hello_timeout_s = 0.5;
    config.capture.path = capture ? dir + "/bench.cdrocap" : "";
    config.capture.rotate_mib = 64;
    config.capture.keep = 1;
    config.output.jsonl = jsonl ? dir + "/bench.jsonl" : "";
    config.output.health_period_s = 1.0;
    config.http.port = 0;
    config.checkpoint.path = "";
    config.logging.level = "warn";
    setupLogging(config.logging);

    SystemClock clock;
    BenchConsumer consumer(clock);
    Service service(config, RunOptions{}, {&consumer, &consumer, nullptr}, clock);
    service.start();
    const long rss_start_kib = residentKiB();
    std::atomic<bool> stop{false};
    std::thread device_thread(device, master, frames, soak_s, std::ref(stop));

    // Sample memory every second; stop when the device is done and everything arrived.
    std::vector<long> rss_samples_kib;
    std::atomic<bool> device_done{false};
    std::thread watcher([&] {
        device_thread.join();
        device_done = true;
    });
    uint64_t last_ranges = 0;
    int quiet_ticks = 0;
    std::function<void()> tick = [&] {
        rss_samples_kib.push_back(residentKiB());
        const uint64_t ranges = consumer.ranges();
        quiet_ticks = (device_done && ranges == last_ranges) ? quiet_ticks + 1 : 0;
        last_ranges = ranges;
        if (quiet_ticks >= 2) {
            service.requestStop();
            return;
        }
        service.loop().addTimerAfter(1'000'000, tick);
    };
    service.loop().addTimerAfter(1'000'000, tick);
    service.run();
    stop = true;
    watcher.join();

    const ServiceCounters &c = service.counters();
    std::printf("frames delivered      %llu, rejected chunks %llu, frames lost %llu\n",
                static_cast<unsigned long long>(consumer.ranges()), static_cast<unsigned long long>(c.chunks_rejected),
                static_cast<unsigned long long>(c.frames_lost));
    std::printf("throughput            %.0f frames/s over %.2f s (goal > 20000)\n",
                static_cast<double>(consumer.ranges()) / std::max(1e-9, consumer.seconds()), consumer.seconds());
    std::printf("arrival -> output     p50 %lld us, p99 %lld us, p99.9 %lld us (goal p99 < 2000 us; %llu samples)\n",
                static_cast<long long>(consumer.percentileUs(0.50)), static_cast<long long>(consumer.percentileUs(0.99)),
                static_cast<long long>(consumer.percentileUs(0.999)), static_cast<unsigned long long>(consumer.samples()));
    std::printf("capture               %llu records, %llu bytes, %llu rotations\n",
                static_cast<unsigned long long>(c.capture_records), static_cast<unsigned long long>(c.capture_bytes),
                static_cast<unsigned long long>(c.capture_rotations));
    std::printf("JSON lines            %llu\n", static_cast<unsigned long long>(c.jsonl_lines));
    std::printf("resident memory       start %ld KiB", rss_start_kib);
    for (size_t i = 0; i < rss_samples_kib.size(); i += std::max<size_t>(1, rss_samples_kib.size() / 10)) {
        std::printf(", %zus %ld", i + 1, rss_samples_kib[i]);
    }
    std::printf(", end %ld KiB\n", residentKiB());
    ::close(master);
    ::close(slave);
    const std::string cleanup = "rm -rf '" + dir + "'";
    return std::system(cleanup.c_str()) == 0 ? 0 : 1;
}
