// cdro-bench-service: how many frames per second the service sustains from a pseudo-terminal,
// the latency from a frame's arrival (the read() that delivered it) to its estimate going out
// (the map being read for the outputs after the consumer took the frame), and the resident
// memory over a long run.
//
// A device thread plays the Pozyx tag on the PTY master: boot HELLO, ACKs for the handshake,
// then RANGE frames, as fast as the PTY takes them (or at --rate-hz). The service runs exactly
// as cdro-hostd does (event loop, LibSerial link, intake, capture, JSON Lines to a file). Two
// consumers:
//
//   --engine none   (default) a stand-in whose map changes on every range, so that every frame
//                   produces output: the I/O side's share. The device ranges among 1 + 7 nodes.
//   --engine plant  the real engine (cdro::engine::Engine, default EngineParams, PLANT's heights)
//                   behind cdro-hostd's EngineAdapter, timed by a thin wrapper. The device
//                   streams PLANT's 1205 ranges (../shared/data/plant/ranges.csv) pass after
//                   pass, node id k as 0x6000 + k; at the end the map is scored against
//                   PLANT's surveyed positions (rigid fit with reflection, as cdro-bench-engine).
//   --engine network  the same engine on a random network of docs/bench.md (--nodes, --seed:
//                   bench_networks.hpp, degree ~10 at PLANT's density, heights 0), node id k as
//                   0x1000 + k; the device streams every link once a pass (one noisy pass of
//                   0.1 m, drawn once, repeated), and the map is scored against the truth.
// With the engine, its global solves are adopted between frames once done, as cdro-hostd does
// live (Engine::SolveAdoption::ByCaller: no frame waits for a solve); each adoption is timed.
//
// Figures only: nothing here passes or fails on a time. docs/bench.md has the figures.
//
// In a run, the JSON Lines file (in a temporary folder, removed at the end) is truncated each
// time it passes 1 GiB, so that a soak does not fill the disk.
//
//   cdro-bench-service [--engine none|plant|network] [--nodes N] [--seed S] [--frames N | --soak-s S] [--rate-hz R]
//                      [--jsonl on|off] [--jsonl-path FILE] [--jsonl-rate-hz R] [--capture on|off]
//                      [--checkpoint on|off] [--data-dir DIR]
#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include <malloc.h>
#include <poll.h>
#include <sys/types.h>
#include <pty.h>
#include <sys/stat.h>
#include <termios.h>
#include <unistd.h>

#include <CLI/CLI.hpp>

#include "cdro/engine/alignment.hpp"
#include "cdro/engine/engine.hpp"
#include "cdro/hostd/engine_adapter.hpp"
#include "cdro/hostd/memory.hpp"
#include "cdro/service/log.hpp"
#include "cdro/service/service.hpp"
#include "bench_networks.hpp"
#include "cdro/netgen/random.hpp"
#include "plant_data.hpp"

using namespace cdro::service;

namespace {

// The I/O-only stand-in's network.
constexpr uint16_t kOwnNode = 0x6000;
constexpr uint16_t kRemoteNodes[] = {0x6069, 0x6A11, 0x6A2C, 0x6A3E, 0x6A4F, 0x6A5B, 0x6A60};
// PLANT's node k is the Pozyx id 0x6000 + k on both sides (device and engine).
constexpr uint16_t kPlantIdBase = 0x6000;
// A random network's node k (1..n) is the Pozyx id 0x1000 + k.
constexpr uint16_t kNetworkIdBase = 0x1000;
constexpr double kNetworkNoiseM = 0.10; // m, the ranges' Gaussian noise (Pozyx nominal)
// The run's JSON Lines file is truncated when it passes this (bytes). Each truncation frees
// the file's pages while holding its lock against the service's writes: it shows in the
// latency tail of a soak with JSON Lines (docs/bench.md).
constexpr long kJsonlLimitBytes = 1L << 30;
uint16_t pozyxIdOfPlant(cdro::engine::NodeId plant_id) { return static_cast<uint16_t>(kPlantIdBase + plant_id); }

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

// glibc mallinfo2: bytes allocated and not freed (RSS keeps freed memory the allocator holds).
long heapInUseKiB()
{
#if defined(__GLIBC__) && (__GLIBC__ > 2 || (__GLIBC__ == 2 && __GLIBC_MINOR__ >= 33))
    const struct mallinfo2 heap = mallinfo2();
    return static_cast<long>((heap.uordblks + heap.hblkhd) / 1024U);
#else
    return -1;
#endif
}

int64_t steadyNs()
{
    return std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now().time_since_epoch())
        .count();
}

// The latencies of a run, in 1 us bins, allocated and touched up front so that they do not show
// up as memory growth in the soak.
class LatencyHistogram {
public:
    static constexpr size_t kBins = 50'000; // us; longer latencies land in the last bin
    LatencyHistogram() : bins_(kBins + 1, 0) {}
    void add(int64_t latency_us)
    {
        ++bins_[std::min<size_t>(kBins, static_cast<size_t>(std::max<int64_t>(0, latency_us)))];
        max_us_ = std::max(max_us_, latency_us);
        ++samples_;
    }
    // The latency below which a fraction p of the samples lie (us).
    int64_t percentileUs(double p) const
    {
        const auto wanted = static_cast<uint64_t>(p * static_cast<double>(samples_));
        uint64_t seen = 0;
        for (size_t bin = 0; bin <= kBins; ++bin) {
            seen += bins_[bin];
            if (seen > wanted) {
                return static_cast<int64_t>(bin);
            }
        }
        return static_cast<int64_t>(kBins);
    }
    int64_t maxUs() const { return max_us_; }
    uint64_t samples() const { return samples_; }
    void print(const char *label) const
    {
        std::printf("%-21s p50 %lld us, p99 %lld us, p99.9 %lld us, max %lld us (goal p99 < 2000 us; %llu samples)\n",
                    label, static_cast<long long>(percentileUs(0.50)), static_cast<long long>(percentileUs(0.99)),
                    static_cast<long long>(percentileUs(0.999)), static_cast<long long>(max_us_),
                    static_cast<unsigned long long>(samples_));
    }

private:
    std::vector<uint64_t> bins_;
    uint64_t samples_ = 0;
    int64_t max_us_ = 0;
};

// Frames taken, and the latency of each frame whose estimate went out: from its arrival
// (FrameContext::host_unix_us, the read() that delivered it) to the first time the outputs read
// the map (MapSource::updateEstimates, or fill) after its revision changed. Health timers read the map too, without a new frame: those reads are
// not latencies. The samples of frames after the first warmup_frames are also kept apart, and
// those of frames that arrived steady_after_us or more after the first (the map formed).
class FrameTimer {
public:
    FrameTimer(const Clock &clock, uint64_t warmup_frames) : clock_(clock), warmup_frames_(warmup_frames) {}

    void onFrame(const FrameContext &context)
    {
        ++ranges_;
        last_arrival_unix_us_ = context.host_unix_us;
        last_us_ = clock_.monotonicUs();
        if (first_us_ == 0) {
            first_us_ = last_us_;
        }
    }
    // Called when the outputs have read the map of this revision.
    void onFilled(uint64_t revision)
    {
        if (filled_revision_ == revision) {
            return;
        }
        filled_revision_ = revision;
        const int64_t latency_us = clock_.unixUs() - last_arrival_unix_us_;
        all_.add(latency_us);
        if (ranges_ > warmup_frames_) {
            after_warmup_.add(latency_us);
        }
        if (steady_after_us_ > 0 && last_us_ - first_us_ >= steady_after_us_) {
            steady_.add(latency_us);
        }
    }
    void setSteadyAfterUs(int64_t steady_after_us) { steady_after_us_ = steady_after_us; }

    uint64_t ranges() const { return ranges_; }
    double seconds() const { return static_cast<double>(last_us_ - first_us_) * 1e-6; }
    uint64_t warmupFrames() const { return warmup_frames_; }
    const LatencyHistogram &all() const { return all_; }
    const LatencyHistogram &afterWarmup() const { return after_warmup_; }
    const LatencyHistogram &steady() const { return steady_; }

private:
    const Clock &clock_;
    uint64_t warmup_frames_ = 0;
    uint64_t ranges_ = 0;
    int64_t last_arrival_unix_us_ = 0;
    int64_t first_us_ = 0;
    int64_t last_us_ = 0;
    uint64_t filled_revision_ = 0;
    LatencyHistogram all_;
    LatencyHistogram after_warmup_;
    int64_t steady_after_us_ = 0; // 0: not kept apart
    LatencyHistogram steady_;
};

// --engine none: a map source that changes on every range.
class BenchConsumer final : public FrameConsumer, public MapSource {
public:
    explicit BenchConsumer(const Clock &clock) : timer_(clock, 0) {}
    void onRange(const cdro_range_t &range, const FrameContext &context) override
    {
        timer_.onFrame(context);
        last_distance_mm_ = range.distance_mm;
        ++revision_;
    }
    void onMotion(const cdro_motion_t &, const FrameContext &) override {}
    uint64_t revision() const override { return revision_; }
    void fill(MapState &map) const override
    {
        timer_.onFilled(revision_);
        NodeEstimate node;
        node.id = kOwnNode;
        node.x_m = static_cast<double>(last_distance_mm_) * 1e-3;
        node.placed = true;
        map.nodes.push_back(node);
    }
    std::optional<NodeComponents> components(uint16_t) const override { return std::nullopt; }
    FrameTimer &timer() const { return timer_; }

private:
    mutable FrameTimer timer_;
    uint64_t revision_ = 0;
    uint32_t last_distance_mm_ = 0;
};

// --engine plant|network: cdro-hostd's EngineAdapter, timed. The latency is taken when the
// adapter's updateEstimates() returns (the changed estimates converted for the outputs); the
// time spent in the engine (onRange) and there is summed, to tell where the time per frame goes.
class TimedEngine final : public FrameConsumer, public MapSource {
public:
    TimedEngine(const Clock &clock, cdro::hostd::EngineAdapter &adapter, uint64_t warmup_frames)
        : timer_(clock, warmup_frames), adapter_(adapter)
    {
    }
    void onRange(const cdro_range_t &range, const FrameContext &context) override
    {
        timer_.onFrame(context);
        const int64_t begin_ns = steadyNs();
        adapter_.onRange(range, context);
        const int64_t spent_ns = steadyNs() - begin_ns;
        engine_ns_ += spent_ns;
        max_engine_ns_ = std::max(max_engine_ns_, spent_ns);
        if (spent_ns > 1'000'000) {
            ++engine_calls_over_1ms_;
        }
    }
    void onMotion(const cdro_motion_t &motion, const FrameContext &context) override
    {
        adapter_.onMotion(motion, context);
    }
    std::vector<uint8_t> hostEventAfterFrame(const FrameContext &context) override
    {
        const int64_t begin_ns = steadyNs();
        std::vector<uint8_t> event = adapter_.hostEventAfterFrame(context);
        if (!event.empty()) {
            const int64_t spent_ns = steadyNs() - begin_ns;
            ++adoptions_;
            max_adoption_ns_ = std::max(max_adoption_ns_, spent_ns);
        }
        return event;
    }
    uint64_t revision() const override { return adapter_.revision(); }
    void fill(MapState &map) const override { adapter_.fill(map); } // the live map's, not per frame
    void updateEstimates(MapState &map, std::vector<size_t> &changed) override
    {
        const int64_t begin_ns = steadyNs();
        adapter_.updateEstimates(map, changed);
        fill_ns_ += steadyNs() - begin_ns;
        ++fills_;
        timer_.onFilled(adapter_.revision());
    }
    std::optional<NodeComponents> components(uint16_t id) const override { return adapter_.components(id); }

    FrameTimer &timer() const { return timer_; }
    double engineS() const { return static_cast<double>(engine_ns_) * 1e-9; }
    double fillS() const { return static_cast<double>(fill_ns_) * 1e-9; }
    uint64_t fills() const { return fills_; }
    double maxEngineUs() const { return static_cast<double>(max_engine_ns_) * 1e-3; }
    uint64_t engineCallsOver1ms() const { return engine_calls_over_1ms_; }
    uint64_t adoptions() const { return adoptions_; }
    double maxAdoptionUs() const { return static_cast<double>(max_adoption_ns_) * 1e-3; }

private:
    mutable FrameTimer timer_;
    cdro::hostd::EngineAdapter &adapter_;
    int64_t engine_ns_ = 0;
    int64_t max_engine_ns_ = 0;
    uint64_t engine_calls_over_1ms_ = 0;
    uint64_t adoptions_ = 0; // global solves adopted between frames
    int64_t max_adoption_ns_ = 0;
    int64_t fill_ns_ = 0;
    uint64_t fills_ = 0;
};

// ---- the device -----------------------------------------------------------------------------

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

size_t encode(const cdro_frame_t &frame, uint8_t *out)
{
    return cdro_frame_encode(&frame, out, CDRO_MAX_ENCODED_FRAME);
}

struct DeviceScript {
    uint16_t own_node = kOwnNode;
    uint64_t frames = 0;  // 0 = until soak_s
    double soak_s = 0.0;  // s; 0 = until frames
    double rate_hz = 0.0; // frames/s; 0 = as fast as the PTY takes them
    // The i-th RANGE frame's payload (device time included).
    std::function<void(uint64_t i, cdro_range_t &range)> range;
};

// The device: boot, answer SET_SCHEDULE and START, then stream ranges until told to stop.
void device(int master, const DeviceScript &script, std::atomic<bool> &stop)
{
    uint16_t sequence = 0;
    uint8_t buffer[CDRO_MAX_ENCODED_FRAME];
    cdro_frame_t hello{};
    hello.type = CDRO_FRAME_HELLO;
    hello.sequence = sequence++;
    hello.as.hello = {1, 0x0100, CDRO_PROTOCOL_VERSION, CDRO_LAYOUT_HASH, script.own_node, 0x03, 0x12, 20, 1, 1};
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
    const auto elapsedS = [&] {
        return std::chrono::duration<double>(std::chrono::steady_clock::now() - begin).count();
    };
    std::vector<uint8_t> batch;
    uint64_t due = 0; // paced: frames due by now
    for (uint64_t i = 0; !stop; ++i) {
        if (script.frames > 0 && i >= script.frames) {
            break;
        }
        if (script.soak_s > 0.0 && (i & 1023U) == 0 && elapsedS() > script.soak_s) {
            break;
        }
        if (script.rate_hz > 0.0 && i >= due) {
            // Paced: send what is due as one write, then wait for the next frame's time.
            writeAll(master, batch.data(), batch.size());
            batch.clear();
            while (!stop) {
                due = static_cast<uint64_t>(elapsedS() * script.rate_hz);
                if (due > i) {
                    break;
                }
                std::this_thread::sleep_for(std::chrono::microseconds(50));
            }
        }
        cdro_frame_t range{};
        range.type = CDRO_FRAME_RANGE;
        range.sequence = sequence++;
        script.range(i, range.as.range);
        const size_t n = encode(range, buffer);
        batch.insert(batch.end(), buffer, buffer + n);
        if (batch.size() >= 4096) { // a UART-sized burst
            writeAll(master, batch.data(), batch.size());
            batch.clear();
        }
    }
    writeAll(master, batch.data(), batch.size());
}

// ---- PLANT's map at the end -----------------------------------------------------------------

struct MapScore {
    size_t nodes = 0; // with a surveyed position
    size_t placed = 0;
    size_t converged = 0;
    size_t converged_over_1m = 0; // converged nodes more than 1 m off, the converged fitted on their own
    double rmse_m = std::nan(""); // m, aligned (rotation, translation, reflection), placed nodes
    double worst_m = std::nan("");
};

MapScore scoreMap(const cdro::engine::Engine &engine, const std::map<uint16_t, cdro::engine::Vector2> &truth_m)
{
    MapScore score;
    score.nodes = truth_m.size();
    std::vector<cdro::engine::MapPoint> estimated;
    std::vector<cdro::engine::MapPoint> converged;
    for (const cdro::engine::NodeOutput &node : engine.estimates()) {
        const auto known = truth_m.find(node.id);
        if (known == truth_m.end() || !node.placed()) {
            continue;
        }
        ++score.placed;
        score.converged += node.converged() ? 1U : 0U;
        if (node.position_m.allFinite()) {
            estimated.push_back({node.id, node.position_m});
            if (node.converged()) {
                converged.push_back({node.id, node.position_m});
            }
        }
    }
    if (converged.size() >= 3) {
        score.converged_over_1m = cdro::engine::alignedErrors(converged, truth_m, true).countOver(1.0);
    }
    if (estimated.size() >= 2) {
        const cdro::engine::AlignedErrors aligned = cdro::engine::alignedErrors(estimated, truth_m, true);
        score.rmse_m = aligned.rmse_m;
        score.worst_m = aligned.worst_m;
    }
    return score;
}

// What the device streams with the engine behind the service: one pass of RANGE frames (without
// the device time), repeated; the heights the engine is told; the truth the map is scored against.
struct Workload {
    std::string description;
    uint16_t own_node = 0;
    std::vector<cdro_range_t> pass;
    std::vector<std::pair<uint16_t, double>> heights_m; // m, by Pozyx id
    std::map<uint16_t, cdro::engine::Vector2> truth_m;  // m, by Pozyx id
};

cdro_range_t rangeFrame(uint16_t own_node, uint16_t from, uint16_t to, double range_m)
{
    cdro_range_t range{};
    range.from_id = from;
    range.to_id = to;
    range.distance_mm = static_cast<uint32_t>(std::lround(range_m * 1000.0));
    range.rss_dbm = -80;
    range.flags = from != own_node && to != own_node ? CDRO_RANGE_FLAG_REMOTE : 0;
    return range;
}

Workload plantWorkload(const cdro::bench::Plant &plant)
{
    Workload workload;
    workload.own_node = pozyxIdOfPlant(plant.ranges.front().from);
    for (const cdro::bench::Range &r : plant.ranges) {
        workload.pass.push_back(rangeFrame(workload.own_node, pozyxIdOfPlant(r.from), pozyxIdOfPlant(r.to), r.range_m));
    }
    for (const auto &[id, height_m] : plant.heights_m) {
        workload.heights_m.emplace_back(pozyxIdOfPlant(id), height_m);
    }
    for (const auto &[id, position_m] : plant.truth_m) {
        workload.truth_m[pozyxIdOfPlant(id)] = position_m;
    }
    workload.description = "PLANT (" + plant.dir + "): " + std::to_string(plant.truth_m.size()) + " nodes, " +
                           std::to_string(plant.ranges.size()) + " ranges a pass, ids 0x6000 + k";
    return workload;
}

Workload networkWorkload(uint32_t nodes, uint64_t seed)
{
    const cdro::netgen::GeometricNetwork net =
        cdro::bench::drawNetwork(nodes, cdro::bench::kNetworkDegree, cdro::bench::kNetworkAreaPerNodeM2, seed);
    const auto pozyxId = [](cdro::engine::NodeId id) { return static_cast<uint16_t>(kNetworkIdBase + id); };
    Workload workload;
    workload.own_node = pozyxId(net.ids.front());
    cdro::netgen::MersenneRandom noise(cdro::netgen::mixSeed(net.draw_seed ^ 0x6E6F697365ULL)); // "noise"
    for (size_t i = 0; i < net.links.size(); ++i) {
        const cdro::netgen::GeometricLink &link = net.links[i];
        // A range cannot be zero or negative (the engine would refuse it): clipped at 1 cm.
        const double range_m = std::max(0.01, link.distance_m + kNetworkNoiseM * noise.normal());
        workload.pass.push_back(
            rangeFrame(workload.own_node, pozyxId(net.ids[link.a]), pozyxId(net.ids[link.b]), range_m));
    }
    for (size_t i = 0; i < net.ids.size(); ++i) {
        workload.heights_m.emplace_back(pozyxId(net.ids[i]), 0.0); // planar, and known to be
        workload.truth_m[pozyxId(net.ids[i])] = net.position_m[i];
    }
    char text[160];
    std::snprintf(text, sizeof text,
                  "random network, seed %llu: %u nodes, %zu links (a pass), mean degree %.1f, ids 0x%04X + k",
                  static_cast<unsigned long long>(seed), nodes, net.links.size(), net.mean_degree, kNetworkIdBase);
    workload.description = text;
    return workload;
}

struct MemorySample {
    double t_s = 0.0; // s since the start
    long rss_kib = -1;
    long heap_kib = -1;
    uint64_t ranges = 0;
};

long fileBytes(const std::string &path)
{
    struct stat info {};
    return ::stat(path.c_str(), &info) == 0 ? static_cast<long>(info.st_size) : -1;
}

std::string shortNumber(double value)
{
    char text[32];
    std::snprintf(text, sizeof text, "%g", value);
    return text;
}

std::string loadAverage()
{
    std::ifstream in("/proc/loadavg");
    std::string one, five, fifteen;
    in >> one >> five >> fifteen;
    return one + " " + five + " " + fifteen;
}

// Keeps the run's JSON Lines file under a size, so that a soak does not fill the disk (tens of
// GB in 10 minutes with the engine): truncates it to 0 when it passes limit_bytes, from its own
// thread (the service opened it O_APPEND, so its writes go on at the new end). Sums the bytes.
class FileJanitor {
public:
    FileJanitor(std::string path, long limit_bytes) : path_(std::move(path)), limit_bytes_(limit_bytes)
    {
        thread_ = std::thread([this] {
            while (!stop_) {
                std::this_thread::sleep_for(std::chrono::milliseconds(250));
                const long bytes = fileBytes(path_);
                if (bytes > limit_bytes_ && ::truncate(path_.c_str(), 0) == 0) {
                    truncated_bytes_ += bytes; // lines written between the stat and the truncate are not counted
                    ++truncations_;
                }
            }
        });
    }
    ~FileJanitor() { stopNow(); }
    void stopNow()
    {
        stop_ = true;
        if (thread_.joinable()) {
            thread_.join();
        }
    }
    long totalBytes() const { return truncated_bytes_ + std::max(0L, fileBytes(path_)); }
    int truncations() const { return truncations_; }

private:
    std::string path_;
    long limit_bytes_;
    std::atomic<bool> stop_{false};
    std::atomic<long> truncated_bytes_{0};
    std::atomic<int> truncations_{0};
    std::thread thread_;
};

} // namespace

static int runMain(int argc, char **argv)
{
    CLI::App app{"cdro-bench-service: frames/s the service sustains from a pseudo-terminal, the latency from a\n"
                 "frame's arrival to its estimate going out (p50/p99/p99.9), and the resident memory over the run.\n"
                 "Figures only; run on purpose (docs/bench.md).\n"};
    std::string engine_mode = "none";
    uint64_t frames = 1'000'000;
    double soak_s = 0.0;
    double rate_hz = 0.0;
    std::string jsonl_switch = "on";
    std::string capture_switch = "on";
    std::string checkpoint_switch = "off";
    std::string data_dir;
    std::string jsonl_path;
    double jsonl_rate_hz = 0.0;
    uint32_t nodes = 1000;
    uint64_t seed = 1;
    double steady_after_s = 0.0;
    app.add_option("--engine", engine_mode,
                   "the consumer: none = an I/O-only stand-in (a map that changes on every range, 1 + 7 nodes); "
                   "plant = the engine behind cdro-hostd's adapter, the device streaming PLANT in a loop; network = "
                   "the same engine, the device streaming a random network of --nodes nodes (docs/bench.md) in a loop")
        ->capture_default_str()
        ->check(CLI::IsMember({"none", "plant", "network"}));
    app.add_option("--nodes", nodes, "--engine network: nodes of the random network")
        ->capture_default_str()
        ->check(CLI::Range(4U, 65535U - kNetworkIdBase));
    app.add_option("--seed", seed, "--engine network: the network's seed (as cdro-bench-engine --seed)")
        ->capture_default_str();
    auto *frames_option = app.add_option("--frames", frames, "RANGE frames the device sends")->capture_default_str();
    app.add_option("--soak-s", soak_s, "s: stream for this long instead of --frames")
        ->excludes(frames_option)
        ->check(CLI::PositiveNumber);
    app.add_option("--rate-hz", rate_hz, "frames/s the device sends at; 0 = as fast as the PTY takes them")
        ->capture_default_str()
        ->check(CLI::NonNegativeNumber);
    app.add_option("--jsonl", jsonl_switch, "JSON Lines to a file (a line per node per update)")
        ->capture_default_str()
        ->check(CLI::IsMember({"on", "off"}));
    app.add_option("--jsonl-path", jsonl_path,
                   "with --jsonl on: write the lines here (e.g. /dev/null: serialization without the file) instead "
                   "of a file in the run's temporary folder");
    app.add_option("--jsonl-rate-hz", jsonl_rate_hz,
                   "output.rate_hz: all nodes' lines at this rate (Hz of event time) instead of a line per node per "
                   "update")
        ->capture_default_str()
        ->check(CLI::NonNegativeNumber);
    app.add_option("--capture", capture_switch, "the capture file (rotated at 64 MiB, one kept)")
        ->capture_default_str()
        ->check(CLI::IsMember({"on", "off"}));
    app.add_option("--steady-after-s", steady_after_s,
                   "s: the latencies of the frames that arrive this long after the first are also reported apart "
                   "(the map formed); 0 = not")
        ->check(CLI::NonNegativeNumber);
    app.add_option("--checkpoint", checkpoint_switch, "with the engine: checkpoints every 30 s, as cdro-hostd")
        ->capture_default_str()
        ->check(CLI::IsMember({"on", "off"}));
    app.add_option("--data-dir", data_dir,
                   "--engine plant: the folder that holds plant/ (default $CDRO_DATA_DIR, else ../shared/data from "
                   "the repository root)");
    CLI11_PARSE(app, argc, argv);
    if (soak_s > 0.0) {
        frames = 0;
    }
    const bool with_engine = engine_mode != "none";
    const bool jsonl = jsonl_switch == "on";
    const bool capture = capture_switch == "on";
    const bool checkpoint = with_engine && checkpoint_switch == "on";

    Workload workload;
    if (engine_mode == "plant") {
        try {
            workload = plantWorkload(cdro::bench::loadPlant(cdro::bench::findPlant(data_dir, CDRO_SOURCE_DIR)));
        } catch (const std::exception &error) {
            std::fprintf(stderr, "cdro-bench-service: %s\n", error.what());
            return 2;
        }
    } else if (engine_mode == "network") {
        workload = networkWorkload(nodes, seed);
    }
    const std::string run_text = soak_s > 0.0 ? shortNumber(soak_s) + " s soak" : std::to_string(frames) + " frames";
    const std::string rate_text = rate_hz > 0.0 ? shortNumber(rate_hz) + " frames/s" : "flood";
    const std::string jsonl_text = !jsonl                ? "off"
                                   : jsonl_rate_hz > 0.0 ? "on, all nodes at " + shortNumber(jsonl_rate_hz) + " Hz"
                                                         : "on, a line per node per update";
    std::printf("cdro-bench-service (%s build, %ld cores): engine %s, %s, rate %s, JSON Lines %s, capture %s%s\n",
                CDRO_BUILD_TYPE, sysconf(_SC_NPROCESSORS_ONLN), engine_mode.c_str(), run_text.c_str(),
                rate_text.c_str(), jsonl_text.c_str(), capture_switch.c_str(),
                checkpoint ? ", checkpoints every 30 s" : "");
    if (with_engine) {
        std::printf("%s\n", workload.description.c_str());
    }
    std::fflush(stdout);

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
    config.output.jsonl = !jsonl ? "" : !jsonl_path.empty() ? jsonl_path : dir + "/bench.jsonl";
    config.output.rate_hz = jsonl_rate_hz;
    config.output.health_period_s = 1.0;
    config.http.port = 0;
    config.checkpoint.path = checkpoint ? dir + "/bench.cdrosog" : "";
    config.checkpoint.period_s = 30.0;
    config.logging.level = "warn";
    setupLogging(config.logging);

    SystemClock clock;
    // The engine, as cdro-hostd builds it (default parameters, the heights known before start).
    // Its solves adopted between frames once done, as cdro-hostd does live.
    cdro::engine::Engine engine;
    engine.setSolveAdoption(cdro::engine::Engine::SolveAdoption::ByCaller);
    engine.setTrace([](const std::string &message) { log()->debug("engine: {}", message); });
    for (const auto &[id, height_m] : workload.heights_m) {
        engine.setHeight(id, height_m);
    }
    cdro::hostd::EngineAdapter adapter(engine);
    // The first two passes build the map (placements, re-initializations): the warm-up.
    TimedEngine timed(clock, adapter, 2 * workload.pass.size());
    BenchConsumer stand_in(clock);
    FrameTimer &timer = with_engine ? timed.timer() : stand_in.timer();
    timer.setSteadyAfterUs(static_cast<int64_t>(std::llround(steady_after_s * 1e6)));
    ServiceHooks hooks = with_engine ? ServiceHooks{&timed, &timed, checkpoint ? &adapter : nullptr, &adapter}
                                     : ServiceHooks{&stand_in, &stand_in, nullptr, nullptr};
    Service service(config, RunOptions{}, hooks, clock);
    service.start();

    DeviceScript script;
    script.frames = frames;
    script.soak_s = soak_s;
    script.rate_hz = rate_hz;
    if (with_engine) {
        script.own_node = workload.own_node;
        // Pass after pass, 1 ms of device time a frame.
        script.range = [&workload](uint64_t i, cdro_range_t &range) {
            range = workload.pass[i % workload.pass.size()];
            range.device_time_ms = static_cast<uint32_t>(1000U + i);
        };
    } else {
        script.range = [](uint64_t i, cdro_range_t &range) {
            range = {static_cast<uint32_t>(1001U + i / 4U),  kOwnNode, kRemoteNodes[i % 7],
                     static_cast<uint32_t>(2000 + i % 5000), -80,      0};
        };
    }

    std::unique_ptr<FileJanitor> janitor;
    if (jsonl && jsonl_path.empty()) {
        janitor = std::make_unique<FileJanitor>(config.output.jsonl, kJsonlLimitBytes);
    }
    const std::string load_start = loadAverage();
    const long rss_start_kib = residentKiB();
    const long heap_start_kib = heapInUseKiB();
    std::atomic<bool> stop{false};
    std::thread device_thread(device, master, std::cref(script), std::ref(stop));

    // Sample memory every second; stop when the device is done and everything arrived.
    std::vector<MemorySample> samples;
    samples.reserve(static_cast<size_t>(soak_s) + 4096);
    std::atomic<bool> device_done{false};
    std::thread watcher([&] {
        device_thread.join();
        device_done = true;
    });
    uint64_t last_ranges = 0;
    int quiet_ticks = 0;
    const int64_t start_us = clock.monotonicUs();
    int64_t next_tick_us = start_us + 1'000'000; // on a grid of 1 s (a busy loop fires timers late)
    std::function<void()> tick = [&] {
        const uint64_t ranges = timer.ranges();
        const int64_t now_us = clock.monotonicUs();
        samples.push_back({static_cast<double>(now_us - start_us) * 1e-6, residentKiB(), heapInUseKiB(), ranges});
        quiet_ticks = (device_done && ranges == last_ranges) ? quiet_ticks + 1 : 0;
        last_ranges = ranges;
        if (quiet_ticks >= 2) {
            service.requestStop();
            return;
        }
        while (next_tick_us <= now_us) {
            next_tick_us += 1'000'000;
        }
        service.loop().addTimerAfter(next_tick_us - now_us, tick);
    };
    service.loop().addTimerAfter(next_tick_us - start_us, tick);
    service.run();
    stop = true;
    watcher.join();
    const long rss_end_kib = residentKiB();
    const long heap_end_kib = heapInUseKiB();
    const std::string load_end = loadAverage();
    if (janitor) {
        janitor->stopNow();
    }

    const ServiceCounters &c = service.counters();
    const uint64_t ranges = timer.ranges();
    const double seconds = std::max(1e-9, timer.seconds());
    std::printf("frames delivered      %llu, rejected chunks %llu, frames lost %llu\n",
                static_cast<unsigned long long>(ranges), static_cast<unsigned long long>(c.chunks_rejected),
                static_cast<unsigned long long>(c.frames_lost));
    std::printf("throughput            %.0f frames/s over %.2f s (goal > 20000)\n",
                static_cast<double>(ranges) / seconds, timer.seconds());
    timer.all().print("arrival -> output");
    if (with_engine) {
        timer.afterWarmup().print("  from pass 3 on");
    }
    if (steady_after_s > 0.0) {
        timer.steady().print(("  from " + std::to_string(static_cast<long>(steady_after_s)) + " s on").c_str());
    }
    std::printf("capture               %llu records, %llu bytes, %llu rotations\n",
                static_cast<unsigned long long>(c.capture_records), static_cast<unsigned long long>(c.capture_bytes),
                static_cast<unsigned long long>(c.capture_rotations));
    const long jsonl_bytes = janitor ? janitor->totalBytes() : jsonl ? std::max(0L, fileBytes(config.output.jsonl)) : 0;
    std::printf("JSON lines            %llu (%.2f a frame), %.1f MiB in %s%s\n",
                static_cast<unsigned long long>(c.jsonl_lines),
                static_cast<double>(c.jsonl_lines) / static_cast<double>(std::max<uint64_t>(1, ranges)),
                static_cast<double>(jsonl_bytes) / 1048576.0, jsonl ? config.output.jsonl.c_str() : "-",
                janitor && janitor->truncations() > 0
                    ? (" (truncated " + std::to_string(janitor->truncations()) + " times at 1 GiB)").c_str()
                    : "");
    if (checkpoint) {
        std::printf("checkpoints           %s, %ld bytes\n", config.checkpoint.path.c_str(),
                    fileBytes(config.checkpoint.path));
    }
    // Memory (sampled every second): in a soak the first sample from each 30 s on, else up to 10.
    std::vector<MemorySample> shown;
    const double every_s = soak_s > 0.0 ? 30.0 : std::max(1.0, std::ceil(static_cast<double>(samples.size()) / 10.0));
    for (const MemorySample &sample : samples) {
        if (sample.t_s >= every_s * static_cast<double>(shown.size() + 1) - 0.5) {
            shown.push_back(sample);
        }
    }
    std::printf("resident memory       start %ld KiB", rss_start_kib);
    for (const MemorySample &sample : shown) {
        std::printf(", %.0fs %ld", sample.t_s, sample.rss_kib);
    }
    std::printf(", end %ld KiB\n", rss_end_kib);
    if (soak_s > 0.0) {
        std::printf("soak                  t_s  rss_kib  heap_kib  frames/s (since the row before)\n");
        std::printf("                      %5.0f %8ld %9ld\n", 0.0, rss_start_kib, heap_start_kib);
        MemorySample before;
        for (const MemorySample &sample : shown) {
            std::printf("                      %5.0f %8ld %9ld %9.0f\n", sample.t_s, sample.rss_kib, sample.heap_kib,
                        static_cast<double>(sample.ranges - before.ranges) / std::max(1e-9, sample.t_s - before.t_s));
            before = sample;
        }
        std::printf("                      end   %8ld %9ld\n", rss_end_kib, heap_end_kib);
    }
    const auto minute =
        std::find_if(samples.begin(), samples.end(), [](const MemorySample &x) { return x.t_s >= 59.5; });
    if (minute != samples.end()) {
        std::printf("memory growth         from %.0f s (%ld KiB resident, %ld KiB heap) to the end: %+ld KiB resident, "
                    "%+ld KiB heap\n",
                    minute->t_s, minute->rss_kib, minute->heap_kib, rss_end_kib - minute->rss_kib,
                    heap_end_kib - minute->heap_kib);
    } else {
        std::printf("heap in use           start %ld KiB, end %ld KiB\n", heap_start_kib, heap_end_kib);
    }
    std::printf("load average          %s at the start, %s at the end\n", load_start.c_str(), load_end.c_str());
    if (with_engine) {
        const cdro::engine::EngineCounters e = engine.counters();
        std::printf(
            "engine ranges         received %llu, used %llu, stored %llu, refused %llu (self %llu, value %llu)\n",
            static_cast<unsigned long long>(e.intake.ranges_received), static_cast<unsigned long long>(e.ranges_used),
            static_cast<unsigned long long>(e.ranges_stored), static_cast<unsigned long long>(adapter.rangesRefused()),
            static_cast<unsigned long long>(e.intake.rejected_self),
            static_cast<unsigned long long>(e.intake.rejected_value));
        std::printf("engine events         %llu global solves (%llu maps adopted), %llu placements, %llu motion starts "
                    "(%llu inferred), %llu track updates\n",
                    static_cast<unsigned long long>(e.solve.solves),
                    static_cast<unsigned long long>(e.solve.solves_adopted),
                    static_cast<unsigned long long>(e.placement.placements),
                    static_cast<unsigned long long>(e.motion.motion_starts),
                    static_cast<unsigned long long>(e.motion.motion_inferred),
                    static_cast<unsigned long long>(e.motion.track_updates));
        const double wall_us_per_frame = seconds * 1e6 / static_cast<double>(std::max<uint64_t>(1, ranges));
        const double engine_us = timed.engineS() * 1e6 / static_cast<double>(std::max<uint64_t>(1, ranges));
        const double fill_us = timed.fillS() * 1e6 / static_cast<double>(std::max<uint64_t>(1, ranges));
        std::printf("time a frame          %.2f us wall: engine %.2f us (max %.0f us, %llu calls over 1 ms), adapter "
                    "update %.2f us (%llu updates), the rest %.2f us (intake, capture, JSON Lines, loop, idle)\n",
                    wall_us_per_frame, engine_us, timed.maxEngineUs(),
                    static_cast<unsigned long long>(timed.engineCallsOver1ms()), fill_us,
                    static_cast<unsigned long long>(timed.fills()), wall_us_per_frame - engine_us - fill_us);
        std::printf("solves adopted        %llu between frames, the slowest %.0f us (not in the engine's time above)\n",
                    static_cast<unsigned long long>(timed.adoptions()), timed.maxAdoptionUs());
        const MapScore score = scoreMap(engine, workload.truth_m);
        std::printf(
            "map at the end        %zu of %zu nodes placed, %zu converged (%zu more than 1 m off); aligned RMSE "
            "%.3f m (worst node %.3f m; live, not settled)\n",
            score.placed, score.nodes, score.converged, score.converged_over_1m, score.rmse_m, score.worst_m);
    }
    ::close(master);
    ::close(slave);
    const std::string cleanup = "rm -rf '" + dir + "'";
    return std::system(cleanup.c_str()) == 0 ? 0 : 1;
}

// An exception that escapes (from setting up the options, or a library's) ends the run with its
// message and status 1, not with std::terminate's abort.
int main(int argc, char **argv)
{
    cdro::hostd::returnLargeBuffersToTheSystem(); // as cdro-hostd does: the memory measured is its
    try {
        return runMain(argc, argv);
    } catch (const std::exception &error) {
        std::fprintf(stderr, "cdro-bench-service: %s\n", error.what());
        return 1;
    }
}
