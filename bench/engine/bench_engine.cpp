// cdro-bench-engine: how fast the engine takes ranges, how soon it has a map, how good the map
// is and how much memory it holds, on two workloads:
//
//   PLANT    the real 28-node network (../shared/data/plant), its 1205 ranges in file order
//            replayed N times. The first pass builds the map (placement, re-initializations):
//            it is reported on its own; the steady state is passes 2..N.
//   networks random geometric networks of 10, 30, 100, 300 nodes (host/netgen: geometric.hpp),
//            mean degree ~10, Gaussian range noise, every link ranged once per sweep in a
//            seeded random order. Each draw runs in a fresh process (this program again,
//            --one-network), so that its peak resident memory is its own.
//
// The engine is single-threaded, so ranges/s is per core. Wall-clock rates are what a user
// gets; CPU-time rates (CLOCK_PROCESS_CPUTIME_ID) are less disturbed when other jobs share the
// machine. Figures only: nothing here passes or fails on a time. docs/bench.md has the figures.
//
//   cdro-bench-engine [--data-dir DIR] [--passes N] [--repeat K] [--sizes 10,30,100,300]
//                     [--seed S] [--draws D] [--plant-only | --networks-only] [--json] [--json-out FILE]
//   cdro-bench-engine --one-network NODES [--seed S] [--write-csv DIR]   one draw, JSON out
#include <algorithm>
#include <array>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <fstream>
#include <functional>
#include <map>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include <malloc.h>
#include <spawn.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include "cdro/engine/alignment.hpp"
#include "cdro/engine/engine.hpp"
#include "cdro/hostd/memory.hpp"
#include "cdro/netgen/geometric.hpp"
#include "cdro/netgen/random.hpp"
#include "bench_networks.hpp"
#include "plant_data.hpp"

namespace {

using cdro::engine::Engine;
using cdro::engine::EngineCounters;
using cdro::engine::NodeId;
using cdro::engine::Vector2;
using Json = nlohmann::ordered_json;

// ---- clocks and memory ----------------------------------------------------------------------

double wallSeconds()
{
    return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

double cpuSeconds()
{
    timespec now{};
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &now);
    return static_cast<double>(now.tv_sec) + 1e-9 * static_cast<double>(now.tv_nsec);
}

struct Memory {
    long max_rss_kib = -1;     // getrusage ru_maxrss (KiB on Linux): peak resident set so far; Linux
                               // carries it across exec, so a spawned child starts at its parent's
    long vm_hwm_kib = -1;      // /proc/self/status VmHWM: the peak of this address space only (the
                               // per-draw figure: the children are spawned)
    long vm_rss_kib = -1;      // /proc/self/status VmRSS: resident now
    long heap_in_use_kib = -1; // glibc mallinfo2: bytes allocated and not freed (RSS keeps memory
                               // that was freed but not returned to the system; this does not)
};

Memory memoryNow()
{
    Memory memory;
    rusage usage{};
    if (getrusage(RUSAGE_SELF, &usage) == 0) {
        memory.max_rss_kib = usage.ru_maxrss;
    }
    std::ifstream status("/proc/self/status");
    std::string key;
    while (status >> key) {
        if (key == "VmHWM:") {
            status >> memory.vm_hwm_kib;
        } else if (key == "VmRSS:") {
            status >> memory.vm_rss_kib;
        }
        status.ignore(256, '\n');
    }
#if defined(__GLIBC__) && (__GLIBC__ > 2 || (__GLIBC__ == 2 && __GLIBC_MINOR__ >= 33))
    const struct mallinfo2 heap = mallinfo2();
    memory.heap_in_use_kib = static_cast<long>((heap.uordblks + heap.hblkhd) / 1024U);
#endif
    return memory;
}

Json memoryJson(const Memory &memory)
{
    return Json{{"max_rss_kib", memory.max_rss_kib},
                {"vm_hwm_kib", memory.vm_hwm_kib},
                {"vm_rss_kib", memory.vm_rss_kib},
                {"heap_in_use_kib", memory.heap_in_use_kib}};
}

// ---- the workload ---------------------------------------------------------------------------

// A range as measured: 3D for PLANT, planar for the random networks (bench/common/plant_data.hpp).
using cdro::bench::Range;

double median(std::vector<double> values)
{
    if (values.empty()) {
        return std::nan("");
    }
    std::sort(values.begin(), values.end());
    const size_t mid = values.size() / 2;
    return values.size() % 2 == 1 ? values[mid] : 0.5 * (values[mid - 1] + values[mid]);
}

struct Accuracy {
    double rmse_m = std::nan(""); // m, aligned (rotation, translation, reflection), placed nodes
    size_t placed = 0;
    size_t converged = 0;
    size_t total = 0;   // nodes with a truth position
    bool finite = true; // no NaN or infinity in any estimate
    size_t over_1m = 0; // placed nodes more than 1 m off after the alignment
    // The same over the nodes the engine calls converged, fitted on them alone: how far the
    // engine's own claim can be trusted (a node a network cannot decide, e.g. with two links,
    // is placed but not converged, and moves the RMSE over all placed nodes).
    double converged_rmse_m = std::nan(""); // m
    size_t converged_over_1m = 0;           // converged nodes more than 1 m off after that fit
    // How well the map explains its own links (placed ends): a map far from the truth that
    // explains every link is a real ambiguity of the network (a flip about a hinge), one that
    // leaves links unexplained is a local minimum of the engine.
    size_t links_checked = 0;
    size_t links_over_0_5m = 0; // |link range - distance in the map| > 0.5 m (5 sigma)
    double link_residual_rms_m = std::nan("");
    double median_error_m = std::nan(""); // m, the typical node's error (one lost node moves the RMSE)
    struct Worst {
        double error_m = 0.0;
        NodeId id = 0;
        uint32_t links = 0;
    };
    std::vector<Worst> worst; // the largest errors, largest first
};

Accuracy accuracy(const Engine &engine, const std::map<NodeId, Vector2> &truth_m)
{
    Accuracy result;
    result.total = truth_m.size();
    const std::vector<cdro::engine::NodeOutput> estimates = engine.estimates();
    std::vector<cdro::engine::MapPoint> estimated;
    std::vector<cdro::engine::MapPoint> converged;
    std::map<NodeId, uint32_t> links_of;
    for (const cdro::engine::NodeOutput &node : estimates) {
        const auto known = truth_m.find(node.id);
        if (known == truth_m.end() || !node.placed()) {
            continue;
        }
        ++result.placed;
        result.converged += node.converged() ? 1U : 0U;
        if (!node.position_m.allFinite() || !node.covariance_m2.allFinite()) {
            result.finite = false;
            continue;
        }
        estimated.push_back({node.id, node.position_m});
        links_of[node.id] = node.link_count;
        if (node.converged()) {
            converged.push_back({node.id, node.position_m});
        }
    }
    if (converged.size() >= 2) {
        const cdro::engine::AlignedErrors aligned = cdro::engine::alignedErrors(converged, truth_m, true);
        result.converged_rmse_m = aligned.rmse_m;
        result.converged_over_1m = aligned.countOver(1.0);
    }
    if (estimated.size() >= 2) {
        const cdro::engine::AlignedErrors aligned = cdro::engine::alignedErrors(estimated, truth_m, true);
        result.rmse_m = aligned.rmse_m;
        result.over_1m = aligned.countOver(1.0);
        result.median_error_m = median(aligned.error_m);
        std::vector<Accuracy::Worst> errors;
        for (size_t k = 0; k < aligned.compared(); ++k) {
            errors.push_back({aligned.error_m[k], aligned.ids[k], links_of[aligned.ids[k]]});
        }
        std::sort(errors.begin(), errors.end(),
                  [](const Accuracy::Worst &x, const Accuracy::Worst &y) { return x.error_m > y.error_m; });
        errors.resize(std::min<size_t>(errors.size(), 5));
        result.worst = errors;
    }
    std::map<NodeId, Vector2> placed_m;
    for (const cdro::engine::NodeOutput &node : estimates) {
        if (node.placed()) {
            placed_m[node.id] = node.position_m;
        }
    }
    double sum_m2 = 0.0;
    for (const cdro::engine::LinkOutput &link : engine.links()) {
        const auto a = placed_m.find(link.a);
        const auto b = placed_m.find(link.b);
        if (a == placed_m.end() || b == placed_m.end()) {
            continue;
        }
        const double residual_m = link.range_m - (a->second - b->second).norm();
        ++result.links_checked;
        result.links_over_0_5m += std::abs(residual_m) > 0.5 ? 1U : 0U;
        sum_m2 += residual_m * residual_m;
    }
    if (result.links_checked > 0) {
        result.link_residual_rms_m = std::sqrt(sum_m2 / static_cast<double>(result.links_checked));
    }
    return result;
}

Json accuracyJson(const Accuracy &a)
{
    Json worst = Json::array();
    for (const Accuracy::Worst &w : a.worst) {
        worst.push_back(Json{{"id", w.id}, {"error_m", w.error_m}, {"links", w.links}});
    }
    return Json{{"rmse_m", std::isfinite(a.rmse_m) ? Json(a.rmse_m) : Json(nullptr)},
                {"placed", a.placed},
                {"converged", a.converged},
                {"nodes", a.total},
                {"finite", a.finite},
                {"median_error_m", std::isfinite(a.median_error_m) ? Json(a.median_error_m) : Json(nullptr)},
                {"nodes_over_1m", a.over_1m},
                {"converged_rmse_m", std::isfinite(a.converged_rmse_m) ? Json(a.converged_rmse_m) : Json(nullptr)},
                {"converged_over_1m", a.converged_over_1m},
                {"links_checked", a.links_checked},
                {"links_residual_over_0_5m", a.links_over_0_5m},
                {"link_residual_rms_m",
                 std::isfinite(a.link_residual_rms_m) ? Json(a.link_residual_rms_m) : Json(nullptr)},
                {"worst", worst}};
}

// What the engine's state should take: every ring component (its 56-byte state), the per-ring,
// per-link and per-node records, adjacency, and the two id hash maps (~32 bytes an entry with
// libstdc++'s nodes and buckets). Vectors' spare capacity and the allocator's overhead are not
// counted; the peak RSS holds them, and the copies that re-initialization makes.
struct StateSize {
    size_t nodes = 0;
    size_t links = 0;
    size_t rings = 0;
    size_t components = 0;
    size_t bytes = 0;
};

StateSize stateSize(const Engine &engine)
{
    constexpr size_t kHashEntryBytes = 32;
    constexpr size_t kPerComponentBytes = sizeof(cdro::engine::SogComponentState);
    StateSize size;
    size.nodes = engine.map().nodes.size();
    size.links = engine.map().links.size();
    size_t adjacency = 0;
    for (const cdro::engine::NodeState &node : engine.map().nodes) {
        adjacency += node.links.size();
    }
    for (const cdro::engine::RingSog &ring : engine.map().rings) {
        size.rings += ring.empty() ? 0U : 1U;
        size.components += ring.size();
    }
    size.bytes = size.components * kPerComponentBytes + engine.map().rings.size() * sizeof(cdro::engine::RingSog) +
                 size.links * sizeof(cdro::engine::LinkState) + size.nodes * sizeof(cdro::engine::NodeState) +
                 adjacency * sizeof(uint32_t) + (size.links + size.nodes) * kHashEntryBytes;
    return size;
}

Json stateJson(const StateSize &s)
{
    return Json{
        {"nodes", s.nodes}, {"links", s.links}, {"rings", s.rings}, {"components", s.components}, {"bytes", s.bytes}};
}

// The number of placed nodes over the run: an event each time it changes. Counting costs
// O(nodes), so it is done only when a placement, a re-placement or an adopted re-initialization
// happened since the last range (rare once the map stands).
class PlacementTimeline {
public:
    struct Event {
        uint64_t ranges = 0; // ranges fed when it happened
        double wall_s = 0.0; // s of feeding ranges until then
        size_t placed = 0;
    };
    // wall_s: the time spent feeding ranges so far (what happens between passes is not counted).
    void check(const Engine &engine, uint64_t ranges_fed, double wall_s)
    {
        const EngineCounters c = engine.counters();
        const uint64_t signature = c.placement.placements + c.placement.replacements + c.solve.solves;
        if (signature == signature_) {
            return;
        }
        signature_ = signature;
        size_t placed = 0;
        for (const cdro::engine::NodeState &node : engine.map().nodes) {
            placed += node.placed() ? 1U : 0U;
        }
        if (events_.empty() || events_.back().placed != placed) {
            events_.push_back(Event{ranges_fed, wall_s, placed});
        }
    }
    // The first event with at least `placed` nodes placed, if any.
    const Event *firstReaching(size_t placed) const
    {
        for (const Event &event : events_) {
            if (event.placed >= placed) {
                return &event;
            }
        }
        return nullptr;
    }

private:
    uint64_t signature_ = UINT64_MAX;
    std::vector<Event> events_;
};

// "The first complete map": the first moment every node was placed; when some never are (a
// node with fewer than three links can be left unplaced: one or two ranges do not decide it),
// the first moment the final number of placed nodes was reached.
Json firstMapJson(const PlacementTimeline &timeline, size_t nodes, size_t final_placed, uint64_t ranges_per_pass)
{
    const PlacementTimeline::Event *all = timeline.firstReaching(nodes);
    const PlacementTimeline::Event *final_count = timeline.firstReaching(std::max<size_t>(final_placed, 1));
    const PlacementTimeline::Event *event = all != nullptr ? all : final_count;
    if (event == nullptr) {
        return Json{{"reached", false}, {"all_nodes", false}, {"placed", final_placed}};
    }
    return Json{{"reached", true},
                {"all_nodes", all != nullptr},
                {"placed", event->placed},
                {"ranges", event->ranges},
                {"passes", static_cast<double>(event->ranges) / static_cast<double>(ranges_per_pass)},
                {"wall_s", event->wall_s}};
}

// The addRange calls over 1 ms, by what the engine did in them (its counters before and after),
// the first that applies: placed a node again (found inconsistent), placed nodes, started a
// global solve (its problem is built on this thread), or none of these.
struct SlowCalls {
    static constexpr double kOverS = 1e-3; // s
    std::array<uint64_t, 4> count{};
    std::array<double, 4> longest_s{};
    static constexpr std::array<const char *, 4> kCauses = {"replaced", "placed", "started_solve", "other"};
    void add(const EngineCounters &before, const EngineCounters &after, double call_s)
    {
        if (call_s <= kOverS) {
            return;
        }
        size_t cause = 3;
        if (after.placement.replacements != before.placement.replacements) {
            cause = 0;
        } else if (after.placement.placements != before.placement.placements) {
            cause = 1;
        } else if (after.solve.solves != before.solve.solves) {
            cause = 2;
        }
        ++count[cause];
        longest_s[cause] = std::max(longest_s[cause], call_s);
    }
    SlowCalls &operator+=(const SlowCalls &other)
    {
        for (size_t k = 0; k < count.size(); ++k) {
            count[k] += other.count[k];
            longest_s[k] = std::max(longest_s[k], other.longest_s[k]);
        }
        return *this;
    }
};

struct Timed {
    double wall_s = 0.0;
    double cpu_s = 0.0;
    uint64_t ranges = 0;
    uint64_t refused = 0;            // ranges the engine rejected (none expected)
    double longest_call_s = 0.0;     // s, the slowest addRange call (wall clock; with the ranges fed
                                     // back to back it includes waiting for the solve's worker)
    double longest_adoption_s = 0.0; // s, with --adopt-when-done: the slowest adoption between ranges
    uint64_t adoptions = 0;          // ... and how many there were
    double most_behind_s = 0.0;      // s, with --pace: the furthest a range's processing ended behind the
                                     // time it was due (a network's rate is kept up with while this stays
                                     // near the longest call; it grows without bound otherwise)
    std::optional<SlowCalls> slow;   // with --explain-slow-calls
    double rate() const { return wall_s > 0.0 ? static_cast<double>(ranges) / wall_s : 0.0; }
    double cpuRate() const { return cpu_s > 0.0 ? static_cast<double>(ranges) / cpu_s : 0.0; }
    Timed &operator+=(const Timed &other)
    {
        wall_s += other.wall_s;
        cpu_s += other.cpu_s;
        ranges += other.ranges;
        refused += other.refused;
        longest_call_s = std::max(longest_call_s, other.longest_call_s);
        longest_adoption_s = std::max(longest_adoption_s, other.longest_adoption_s);
        adoptions += other.adoptions;
        most_behind_s = std::max(most_behind_s, other.most_behind_s);
        if (other.slow) {
            slow = slow ? *slow += *other.slow : *other.slow;
        }
        return *this;
    }
};

// A live network's rate: each range is due 1 / ranges_per_s after the one before, on one schedule
// over the whole run (a sweep that ends late leaves the next one behind, as a network would).
struct Pace {
    double ranges_per_s = 0.0; // 0: back to back
    double due_s = -1.0;       // s (wall clock), when the last range fed was due; < 0: none yet
};

// Feeds one pass or sweep; the watch (if any) runs between ranges. *fed counts the ranges fed
// so far, *fed_wall_s the time spent feeding them. With a pace the ranges come at its rate, as
// from a live network (the time waited between them is not feeding time). With
// `adopt_when_done` the engine adopts its solves between ranges once done (SolveAdoption::ByCaller,
// as cdro-hostd live), each adoption timed apart from the addRange calls.
Timed feed(Engine &engine, const std::vector<Range> &ranges, PlacementTimeline *watch, uint64_t *fed,
           double *fed_wall_s, Pace *pace = nullptr, bool adopt_when_done = false, bool explain_slow_calls = false)
{
    Timed timed;
    if (explain_slow_calls) {
        timed.slow = SlowCalls{};
    }
    EngineCounters before;
    double wall0 = wallSeconds();
    const double cpu0 = cpuSeconds();
    double waited_s = 0.0;
    const bool paced = pace != nullptr && pace->ranges_per_s > 0.0;
    if (paced && pace->due_s < 0.0) {
        pace->due_s = wall0;
    }
    for (const Range &range : ranges) {
        if (paced) {
            pace->due_s += 1.0 / pace->ranges_per_s;
            const double before_s = wallSeconds();
            if (pace->due_s > before_s) {
                std::this_thread::sleep_for(std::chrono::duration<double>(pace->due_s - before_s));
            }
            waited_s += wallSeconds() - before_s;
        }
        if (explain_slow_calls) {
            before = engine.counters();
        }
        const double call0 = wallSeconds();
        const cdro::engine::RangeVerdict verdict = engine.addRange(range.from, range.to, range.range_m);
        const double call_s = wallSeconds() - call0;
        timed.longest_call_s = std::max(timed.longest_call_s, call_s);
        if (explain_slow_calls) {
            timed.slow->add(before, engine.counters(), call_s);
        }
        if (adopt_when_done) {
            const double adoption0 = wallSeconds();
            if (engine.adoptFinishedSolve()) {
                ++timed.adoptions;
                timed.longest_adoption_s = std::max(timed.longest_adoption_s, wallSeconds() - adoption0);
            }
        }
        if (paced) {
            timed.most_behind_s = std::max(timed.most_behind_s, wallSeconds() - pace->due_s);
        }
        timed.refused += (verdict == cdro::engine::RangeVerdict::RejectedSelf ||
                          verdict == cdro::engine::RangeVerdict::RejectedValue)
                             ? 1U
                             : 0U;
        ++*fed;
        if (watch != nullptr) {
            watch->check(engine, *fed, *fed_wall_s + (wallSeconds() - wall0));
        }
    }
    timed.wall_s = wallSeconds() - wall0 - waited_s;
    *fed_wall_s += timed.wall_s;
    timed.cpu_s = cpuSeconds() - cpu0;
    timed.ranges = ranges.size();
    return timed;
}

// cdro-hostd's offline default: enough neighbour updates for every node to move many times.
uint64_t settleBudget(const Engine &engine) { return 200ULL * engine.map().nodes.size() + 1000ULL; }

// {cause: {"calls", "longest_ms"}}, or null without --explain-slow-calls.
Json slowJson(const std::optional<SlowCalls> &slow)
{
    if (!slow) {
        return nullptr;
    }
    Json out = Json::object();
    for (size_t k = 0; k < slow->count.size(); ++k) {
        out[SlowCalls::kCauses[k]] = Json{{"calls", slow->count[k]}, {"longest_ms", 1e3 * slow->longest_s[k]}};
    }
    return out;
}

Json timedJson(const Timed &t)
{
    return Json{{"ranges", t.ranges},
                {"wall_s", t.wall_s},
                {"cpu_s", t.cpu_s},
                {"ranges_per_s", t.rate()},
                {"ranges_per_cpu_s", t.cpuRate()},
                {"refused", t.refused},
                {"longest_call_ms", 1e3 * t.longest_call_s},
                {"adoptions_between_ranges", t.adoptions},
                {"longest_adoption_ms", 1e3 * t.longest_adoption_s},
                {"most_behind_ms", 1e3 * t.most_behind_s},
                {"calls_over_1ms", slowJson(t.slow)}};
}

// ---- PLANT ----------------------------------------------------------------------------------

using cdro::bench::loadPlant;
using cdro::bench::Plant;

std::string findPlant(const std::string &option) { return cdro::bench::findPlant(option, CDRO_SOURCE_DIR); }

// Its implicit move may throw (a member's move is not noexcept); the bench only returns it by value.
struct PlantRun {              // NOLINT(bugprone-exception-escape)
    Timed first;               // pass 1
    std::vector<Timed> steady; // passes 2..N
    Timed steady_total;
    Json first_map;               // firstMapJson
    uint64_t reinit_first = 0;    // re-initializations during pass 1
    uint64_t reinit_steady = 0;   // ... during the steady state (0 expected: no new link)
    Accuracy after_first;         // live estimates after pass 1
    Accuracy after_first_settled; // a copy settled as cdro-hostd does at the end of a file
    Accuracy end;                 // live estimates after pass N
    Accuracy end_settled;
    StateSize state;
    long heap_kib = -1;                  // heap in use by the engine after the last pass (mallinfo2)
    EngineCounters after_first_counters; // the engine's counters after pass 1 ...
    EngineCounters counters;             // ... and after pass N (before the final settle)
};

PlantRun runPlant(const Plant &plant, uint32_t passes)
{
    PlantRun run;
    const long heap_before_kib = memoryNow().heap_in_use_kib;
    Engine engine;
    for (const auto &[id, height_m] : plant.heights_m) {
        engine.setHeight(id, height_m);
    }
    PlacementTimeline timeline;
    uint64_t fed = 0;
    double fed_wall_s = 0.0;
    run.first = feed(engine, plant.ranges, &timeline, &fed, &fed_wall_s);
    run.reinit_first = engine.counters().solve.solves;
    run.after_first_counters = engine.counters();
    run.after_first = accuracy(engine, plant.truth_m);
    {
        Engine settled = engine;
        settled.settle(settleBudget(settled));
        run.after_first_settled = accuracy(settled, plant.truth_m);
    }
    for (uint32_t pass = 1; pass < passes; ++pass) {
        run.steady.push_back(feed(engine, plant.ranges, &timeline, &fed, &fed_wall_s));
        run.steady_total += run.steady.back();
    }
    run.reinit_steady = engine.counters().solve.solves - run.reinit_first;
    run.counters = engine.counters();
    run.end = accuracy(engine, plant.truth_m);
    run.first_map = firstMapJson(timeline, plant.truth_m.size(), run.end.placed, plant.ranges.size());
    run.state = stateSize(engine);
    run.heap_kib = memoryNow().heap_in_use_kib - heap_before_kib;
    engine.settle(settleBudget(engine));
    run.end_settled = accuracy(engine, plant.truth_m);
    return run;
}

// What the steady state does per range, from the counters before and after it: where its time
// can go (each is a loop over a node's links or a ring's components).
Json steadyWorkJson(const EngineCounters &before, const EngineCounters &after, uint64_t ranges)
{
    const double per = 1.0 / static_cast<double>(std::max<uint64_t>(ranges, 1));
    auto rate = [per](uint64_t from, uint64_t to) { return static_cast<double>(to - from) * per; };
    return Json{
        {"ranges_used", rate(before.ranges_used, after.ranges_used)},
        {"node_updates", rate(before.node_updates, after.node_updates)},
        {"relaxations", rate(before.relaxations, after.relaxations)},
        {"refinements", rate(before.refinement.refinements, after.refinement.refinements)},
        {"ekf_component_updates", rate(before.sogs.ekf_component_updates, after.sogs.ekf_component_updates)},
        {"weight_terms", rate(before.sogs.weight_terms, after.sogs.weight_terms)},
        {"weight_updates_deferred", rate(before.sogs.weight_updates_deferred, after.sogs.weight_updates_deferred)},
        {"global_solves", rate(before.solve.solves, after.solve.solves)},
    };
}

Json plantJson(const Plant &plant, const std::vector<PlantRun> &runs, uint32_t passes, const Memory &before,
               const Memory &after)
{
    std::vector<double> steady_rates;
    std::vector<double> steady_cpu_rates;
    std::vector<double> first_s;
    std::vector<double> first_cpu_s;
    bool identical = true;
    for (const PlantRun &run : runs) {
        steady_rates.push_back(run.steady_total.rate());
        steady_cpu_rates.push_back(run.steady_total.cpuRate());
        first_s.push_back(run.first.wall_s);
        first_cpu_s.push_back(run.first.cpu_s);
        // The engine is deterministic: every repeat must end on the same map.
        identical = identical && run.end.rmse_m == runs.front().end.rmse_m &&
                    run.end_settled.rmse_m == runs.front().end_settled.rmse_m;
    }
    Json repeats = Json::array();
    for (const PlantRun &run : runs) {
        std::vector<double> pass_rates;
        for (const Timed &pass : run.steady) {
            pass_rates.push_back(pass.rate());
        }
        repeats.push_back(Json{{"first_pass", timedJson(run.first)},
                               {"steady", timedJson(run.steady_total)},
                               {"steady_pass_rate_min",
                                pass_rates.empty() ? 0.0 : *std::min_element(pass_rates.begin(), pass_rates.end())},
                               {"steady_pass_rate_median", median(pass_rates)},
                               {"steady_pass_rate_max",
                                pass_rates.empty() ? 0.0 : *std::max_element(pass_rates.begin(), pass_rates.end())}});
    }
    const PlantRun &last = runs.back();
    std::vector<double> complete_s;
    for (const PlantRun &run : runs) {
        if (run.first_map["reached"].get<bool>()) {
            complete_s.push_back(run.first_map["wall_s"].get<double>());
        }
    }
    Json first_map = last.first_map; // ranges and placements are the same in every repeat
    if (!complete_s.empty()) {
        first_map["wall_s"] = median(complete_s);
    }
    return Json{
        {"data_dir", plant.dir},
        {"ranges_per_pass", plant.ranges.size()},
        {"nodes", plant.truth_m.size()},
        {"links", last.state.links},
        {"passes", passes},
        {"repeats", runs.size()},
        {"steady_ranges_per_s_median", median(steady_rates)},
        {"steady_ranges_per_s_min", *std::min_element(steady_rates.begin(), steady_rates.end())},
        {"steady_ranges_per_s_max", *std::max_element(steady_rates.begin(), steady_rates.end())},
        {"steady_ranges_per_cpu_s_median", median(steady_cpu_rates)},
        {"steady_us_per_range_median", 1e6 / median(steady_rates)},
        {"first_pass_s_median", median(first_s)},
        {"first_pass_us_per_range_median", 1e6 * median(first_s) / static_cast<double>(plant.ranges.size())},
        {"first_pass_cpu_us_per_range_median", 1e6 * median(first_cpu_s) / static_cast<double>(plant.ranges.size())},
        {"steady_cpu_us_per_range_median", 1e6 / median(steady_cpu_rates)},
        {"first_complete_map", first_map},
        {"reinitializations_first_pass", last.reinit_first},
        {"reinitializations_steady", last.reinit_steady},
        {"steady_work_per_range", steadyWorkJson(last.after_first_counters, last.counters, last.steady_total.ranges)},
        {"accuracy_after_first_pass", accuracyJson(last.after_first)},
        {"accuracy_after_first_pass_settled", accuracyJson(last.after_first_settled)},
        {"accuracy_end", accuracyJson(last.end)},
        {"accuracy_end_settled", accuracyJson(last.end_settled)},
        {"repeats_identical", identical},
        {"engine_state", stateJson(last.state)},
        {"engine_heap_kib", last.heap_kib},
        {"memory_before", memoryJson(before)},
        {"memory_after", memoryJson(after)},
        {"runs", repeats},
    };
}

// ---- random geometric networks --------------------------------------------------------------

using cdro::bench::drawNetwork; // bench_networks.hpp

struct NetworkOptions {
    double degree = cdro::bench::kNetworkDegree;
    double area_per_node_m2 = cdro::bench::kNetworkAreaPerNodeM2; // m^2, PLANT's density
    double noise_sigma_m = 0.10;                                  // m, Gaussian range noise (Pozyx nominal)
    uint32_t warmup_sweeps = 4; // the map is built and, two sweeps after the last new link,
                                // the initialization runs once more on the whole network
    uint32_t min_sweeps = 20;
    uint64_t steady_ranges = 60000; // at least this many ranges in the steady state
    std::string write_csv_dir;      // with --one-network: the stream and the truth as CSV files
    double pace_ranges_per_s = 0.0; // ranges/s, fed at this rate as from a live network (0: back to back)
    double adopt_after_sweeps = cdro::engine::SolveParams{}.adopt_after_sweeps; // engine.solve's (0: in addRange)
    bool adopt_when_done = false;    // the solves adopted between ranges once done (cdro-hostd live)
    bool explain_slow_calls = false; // the addRange calls over 1 ms by what the engine did in them
};

Json runNetwork(uint32_t nodes, uint64_t seed, const NetworkOptions &options)
{
    const cdro::netgen::GeometricNetwork net = drawNetwork(nodes, options.degree, options.area_per_node_m2, seed);
    const uint64_t links = net.links.size();
    std::map<NodeId, Vector2> truth_m;
    for (size_t i = 0; i < net.ids.size(); ++i) {
        truth_m[net.ids[i]] = net.position_m[i];
    }
    const uint32_t sweeps =
        std::max<uint32_t>(options.min_sweeps,
                           options.warmup_sweeps + static_cast<uint32_t>((options.steady_ranges + links - 1) / links));
    cdro::netgen::MersenneRandom noise(
        cdro::netgen::mixSeed(net.draw_seed ^ 0x6E6F697365ULL)); // "noise": its own stream
    std::vector<Range> sweep_ranges(links);
    // The same stream as files, so that a case can be replayed through cdro-hostd --ranges-csv
    // and judged by cdro-eval (%.17g: the doubles read back exactly, the engine repeats itself).
    std::FILE *ranges_csv = nullptr;
    if (!options.write_csv_dir.empty()) {
        std::FILE *truth_csv = std::fopen((options.write_csv_dir + "/truth.csv").c_str(), "w");
        std::FILE *heights_csv = std::fopen((options.write_csv_dir + "/heights.csv").c_str(), "w");
        ranges_csv = std::fopen((options.write_csv_dir + "/ranges.csv").c_str(), "w");
        if (truth_csv == nullptr || heights_csv == nullptr || ranges_csv == nullptr) {
            throw std::runtime_error("cannot write into " + options.write_csv_dir);
        }
        std::fprintf(truth_csv, "id,x,y\n");
        std::fprintf(heights_csv, "id,z\n");
        for (const auto &[id, position_m] : truth_m) {
            std::fprintf(truth_csv, "%u,%.17g,%.17g\n", static_cast<unsigned>(id), position_m.x(), position_m.y());
            std::fprintf(heights_csv, "%u,0\n", static_cast<unsigned>(id));
        }
        std::fclose(truth_csv);
        std::fclose(heights_csv);
        std::fprintf(ranges_csv, "from,to,range_m\n");
    }
    const Memory before = memoryNow();

    cdro::engine::EngineParams params;
    params.solve.adopt_after_sweeps = options.adopt_after_sweeps;
    Engine engine(params);
    if (options.adopt_when_done) {
        engine.setSolveAdoption(Engine::SolveAdoption::ByCaller);
    }
    // The networks are planar and a deployment in one plane knows it: every height is 0.
    for (const NodeId id : net.ids) {
        engine.setHeight(id, 0.0);
    }
    PlacementTimeline timeline;
    uint64_t fed = 0;
    double fed_wall_s = 0.0;
    std::vector<double> warmup_sweep_s;
    Timed warmup;
    Timed steady;
    std::vector<double> sweep_rates;
    uint64_t reinit_warmup = 0;
    Pace pace{options.pace_ranges_per_s};
    for (uint32_t sweep = 0; sweep < sweeps; ++sweep) {
        // The noisy ranges of this sweep are drawn before the clock starts.
        for (size_t i = 0; i < links; ++i) {
            const cdro::netgen::GeometricLink &link = net.links[i];
            // A range cannot be zero or negative (the engine would refuse it): clip at 1 cm.
            sweep_ranges[i] = Range{net.ids[link.a], net.ids[link.b],
                                    std::max(0.01, link.distance_m + options.noise_sigma_m * noise.normal())};
        }
        if (ranges_csv != nullptr) {
            for (const Range &range : sweep_ranges) {
                std::fprintf(ranges_csv, "%u,%u,%.17g\n", static_cast<unsigned>(range.from),
                             static_cast<unsigned>(range.to), range.range_m);
            }
        }
        const bool warming = sweep < options.warmup_sweeps;
        const Timed timed = feed(engine, sweep_ranges, &timeline, &fed, &fed_wall_s, &pace, options.adopt_when_done,
                                 options.explain_slow_calls);
        if (warming) {
            warmup += timed;
            warmup_sweep_s.push_back(timed.wall_s);
            reinit_warmup = engine.counters().solve.solves;
        } else {
            steady += timed;
            sweep_rates.push_back(timed.rate());
        }
    }
    if (ranges_csv != nullptr) {
        std::fclose(ranges_csv);
    }
    const uint64_t reinit_steady = engine.counters().solve.solves - reinit_warmup;
    const Accuracy end = accuracy(engine, truth_m);
    // Which nodes the map left out, with their links: a node with one link cannot be placed, one
    // with two has two mirror positions that its ranges cannot tell apart.
    Json unplaced = Json::array();
    const cdro::engine::MapState &graph = engine.map();
    for (const cdro::engine::NodeState &node : graph.nodes) {
        if (!node.placed()) {
            uint32_t placed_neighbours = 0;
            for (uint32_t link : node.links) {
                placed_neighbours += graph.nodes[graph.otherNode(link, graph.findNode(node.id))].placed() ? 1U : 0U;
            }
            unplaced.push_back(Json{{"id", node.id},
                                    {"links", node.links.size()},
                                    {"placed_neighbours", placed_neighbours},
                                    {"times_placed", node.placements}});
        }
    }
    std::vector<uint32_t> degree(nodes, 0); // by node index
    for (const cdro::netgen::GeometricLink &link : net.links) {
        ++degree[link.a];
        ++degree[link.b];
    }
    const auto below_three = static_cast<size_t>(
        std::count_if(degree.begin(), degree.end(), [](uint32_t links_of_node) { return links_of_node < 3; }));
    const StateSize state = stateSize(engine);
    const Memory after = memoryNow();
    const double settle_wall0 = wallSeconds();
    const uint64_t settled_updates = engine.settle(settleBudget(engine));
    const double settle_s = wallSeconds() - settle_wall0;
    const Accuracy settled = accuracy(engine, truth_m);
    const EngineCounters &c = engine.counters();
    return Json{
        {"nodes", nodes},
        {"links", links},
        {"mean_degree", net.mean_degree},
        {"side_m", net.side_m},
        {"radius_m", net.radius_m},
        {"noise_sigma_m", options.noise_sigma_m},
        {"seed", seed},
        {"draw_seed", net.draw_seed},
        {"draws", net.draws},
        {"nodes_with_fewer_than_3_links", below_three},
        {"sweeps", sweeps},
        {"warmup_sweeps", options.warmup_sweeps},
        {"first_complete_map", firstMapJson(timeline, nodes, end.placed, links)},
        {"warmup", timedJson(warmup)},
        {"warmup_sweep_s", warmup_sweep_s},
        {"steady", timedJson(steady)},
        {"steady_sweep_rate_median", median(sweep_rates)},
        {"reinitializations_warmup", reinit_warmup},
        {"reinitializations_steady", reinit_steady},
        {"accuracy_end", accuracyJson(end)},
        {"accuracy_end_settled", accuracyJson(settled)},
        {"unplaced_at_end", unplaced},
        {"settle", Json{{"updates", settled_updates}, {"wall_s", settle_s}}},
        {"engine_state", stateJson(state)},
        {"memory_before", memoryJson(before)},
        {"memory_after", memoryJson(after)},
        {"counters", Json{{"ranges_used", c.ranges_used},
                          {"ranges_stored", c.ranges_stored},
                          {"placements", c.placement.placements},
                          {"replacements", c.placement.replacements},
                          {"global_solves", c.solve.solves},
                          {"global_solves_adopted", c.solve.solves_adopted},
                          {"global_solve_refreshes", c.solve.solve_refreshes},
                          {"ekf_gated", c.sogs.ekf_gated},
                          {"weight_collapses", c.sogs.weight_collapses}}},
    };
}

// Runs this program again for one network size; its JSON comes back on a pipe.
Json spawnNetwork(const std::vector<std::string> &arguments, std::string *failure)
{
    int pipe_fds[2];
    if (::pipe(pipe_fds) != 0) {
        *failure = std::string("pipe: ") + std::strerror(errno);
        return nullptr;
    }
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_adddup2(&actions, pipe_fds[1], STDOUT_FILENO);
    posix_spawn_file_actions_addclose(&actions, pipe_fds[0]);
    posix_spawn_file_actions_addclose(&actions, pipe_fds[1]);
    std::vector<char *> argv;
    argv.reserve(arguments.size() + 1);
    for (const std::string &argument : arguments) {
        argv.push_back(const_cast<char *>(argument.c_str()));
    }
    argv.push_back(nullptr);
    pid_t child = 0;
    const int spawned = posix_spawn(&child, "/proc/self/exe", &actions, nullptr, argv.data(), environ);
    posix_spawn_file_actions_destroy(&actions);
    ::close(pipe_fds[1]);
    std::string output;
    if (spawned == 0) {
        char buffer[4096];
        for (;;) {
            const ssize_t n = ::read(pipe_fds[0], buffer, sizeof buffer);
            if (n < 0 && errno == EINTR) {
                continue;
            }
            if (n <= 0) {
                break;
            }
            output.append(buffer, static_cast<size_t>(n));
        }
    }
    ::close(pipe_fds[0]);
    if (spawned != 0) {
        *failure = std::string("posix_spawn: ") + std::strerror(spawned);
        return nullptr;
    }
    int status = 0;
    while (::waitpid(child, &status, 0) < 0 && errno == EINTR) {
    }
    std::string command;
    for (const std::string &argument : arguments) {
        command += (command.empty() ? "" : " ") + argument;
    }
    if (WIFSIGNALED(status)) {
        *failure = "killed by signal " + std::to_string(WTERMSIG(status)) + ": " + command;
        return nullptr;
    }
    if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) {
        *failure = "exit status " + std::to_string(WEXITSTATUS(status)) + ": " + command;
        return nullptr;
    }
    try {
        return Json::parse(output);
    } catch (const Json::exception &error) {
        *failure = std::string("unreadable output (") + error.what() + "): " + command;
        return nullptr;
    }
}

// ---- the machine and the report -------------------------------------------------------------

Json machineJson()
{
    std::string model = "unknown";
    std::ifstream cpuinfo("/proc/cpuinfo");
    std::string line;
    while (std::getline(cpuinfo, line)) {
        if (line.rfind("model name", 0) == 0) {
            model = line.substr(line.find(':') + 2);
            break;
        }
    }
    return Json{{"nproc", sysconf(_SC_NPROCESSORS_ONLN)}, {"cpu", model}, {"build_type", CDRO_BUILD_TYPE}};
}

std::string rmseText(const Json &accuracy_json)
{
    char text[64];
    if (accuracy_json["rmse_m"].is_null()) {
        std::snprintf(text, sizeof text, "n/a (%d/%d placed)", accuracy_json["placed"].get<int>(),
                      accuracy_json["nodes"].get<int>());
    } else {
        std::snprintf(text, sizeof text, "%.3f m", accuracy_json["rmse_m"].get<double>());
    }
    std::string out = text;
    if (accuracy_json["placed"] != accuracy_json["nodes"]) {
        out += " (" + std::to_string(accuracy_json["placed"].get<int>()) + "/" +
               std::to_string(accuracy_json["nodes"].get<int>()) + " placed)";
    }
    if (!accuracy_json["finite"].get<bool>()) {
        out += " NON-FINITE ESTIMATES";
    }
    return out;
}

void printPlant(const Json &p)
{
    std::printf("PLANT (%s): %d nodes, %d links, %d ranges a pass, %d passes, %d repeats (fresh engine each)\n",
                p["data_dir"].get<std::string>().c_str(), p["nodes"].get<int>(), p["links"].get<int>(),
                p["ranges_per_pass"].get<int>(), p["passes"].get<int>(), p["repeats"].get<int>());
    std::printf("  steady state (passes 2..N)  %9.0f ranges/s per core, median of repeats (min %.0f, max %.0f); "
                "%.0f per CPU-second; %.2f us/range\n",
                p["steady_ranges_per_s_median"].get<double>(), p["steady_ranges_per_s_min"].get<double>(),
                p["steady_ranges_per_s_max"].get<double>(), p["steady_ranges_per_cpu_s_median"].get<double>(),
                p["steady_us_per_range_median"].get<double>());
    std::printf("  first pass (builds the map) %9.1f ms, %.1f us/range (%.1f per CPU time; median of repeats); %d "
                "re-initializations\n",
                1e3 * p["first_pass_s_median"].get<double>(), p["first_pass_us_per_range_median"].get<double>(),
                p["first_pass_cpu_us_per_range_median"].get<double>(), p["reinitializations_first_pass"].get<int>());
    const Json &work = p["steady_work_per_range"];
    std::printf("  steady-state work a range   %.2f node updates (%.2f neighbours), %.1f SoG component updates, "
                "%.1f weight terms, %.2f weight updates deferred, %.2g global solves\n",
                work["node_updates"].get<double>(), work["relaxations"].get<double>(),
                work["ekf_component_updates"].get<double>(), work["weight_terms"].get<double>(),
                work["weight_updates_deferred"].get<double>(), work["global_solves"].get<double>());
    const Json &complete = p["first_complete_map"];
    if (complete["reached"].get<bool>()) {
        std::printf("  first complete map          %s nodes placed after %d ranges (pass %.2f), %.1f ms of feeding\n",
                    complete["all_nodes"].get<bool>() ? "all" : std::to_string(complete["placed"].get<int>()).c_str(),
                    complete["ranges"].get<int>(), complete["passes"].get<double>(),
                    1e3 * complete["wall_s"].get<double>());
    } else {
        std::printf("  first complete map          never: nothing placed\n");
    }
    std::printf("  aligned RMSE                after pass 1: %s live, %s settled; at the end: %s live, %s settled\n",
                rmseText(p["accuracy_after_first_pass"]).c_str(),
                rmseText(p["accuracy_after_first_pass_settled"]).c_str(), rmseText(p["accuracy_end"]).c_str(),
                rmseText(p["accuracy_end_settled"]).c_str());
    std::printf("  re-initializations in the steady state: %d; repeats identical: %s\n",
                p["reinitializations_steady"].get<int>(), p["repeats_identical"].get<bool>() ? "yes" : "NO");
    std::printf("  memory                      peak RSS %ld KiB (VmHWM %ld KiB; %ld KiB before the engine); "
                "engine heap %ld KiB, ~%.0f KiB estimated from its parts (%d ring components)\n",
                p["memory_after"]["max_rss_kib"].get<long>(), p["memory_after"]["vm_hwm_kib"].get<long>(),
                p["memory_before"]["vm_rss_kib"].get<long>(), p["engine_heap_kib"].get<long>(),
                p["engine_state"]["bytes"].get<double>() / 1024.0, p["engine_state"]["components"].get<int>());
}

std::string formatRmse(const Json &a)
{
    char text[32];
    if (a["rmse_m"].is_null()) {
        std::snprintf(text, sizeof text, "n/a");
    } else {
        std::snprintf(text, sizeof text, "%.3f", a["rmse_m"].get<double>());
    }
    return text;
}

// One line per draw, then per size the medians over its draws and what went wrong where.
void printNetworks(const Json &networks)
{
    std::printf("\nRandom geometric networks (a fresh process per draw; Gaussian range noise; every link once a\n"
                "sweep, in a seeded random order)\n");
    std::printf("%5s %5s %6s %6s %6s %6s | %9s %9s | %8s %8s %7s | %8s %8s %9s | %7s %8s %6s | %8s %8s %9s\n", "nodes",
                "seed", "links", "degree", "radio", "sweeps", "ranges/s", "per_cpu_s", "map_rng", "map_s", "placed",
                "rmse_m", "median_m", "bad_links", "conv", "conv_rms", "conv>1", "peak_MiB", "heap_MiB", "state_MiB");
    for (const Json &size : networks) {
        for (const Json &n : size["draws"]) {
            if (n.contains("error")) {
                std::printf("%5d %5llu FAILED: %s\n", n["nodes"].get<int>(), n["seed"].get<unsigned long long>(),
                            n["error"].get<std::string>().c_str());
                continue;
            }
            const Json &complete = n["first_complete_map"];
            char map_ranges[32] = "never";
            char map_s[32] = "-";
            if (complete["reached"].get<bool>()) {
                std::snprintf(map_ranges, sizeof map_ranges, "%d%s", complete["ranges"].get<int>(),
                              complete["all_nodes"].get<bool>() ? "" : "*");
                std::snprintf(map_s, sizeof map_s, "%.2f", complete["wall_s"].get<double>());
            }
            const Json &a = n["accuracy_end"];
            char placed[32];
            std::snprintf(placed, sizeof placed, "%d/%d", a["placed"].get<int>(), n["nodes"].get<int>());
            char bad_links[32];
            std::snprintf(bad_links, sizeof bad_links, "%d/%d", a["links_residual_over_0_5m"].get<int>(),
                          a["links_checked"].get<int>());
            char converged_rmse[32] = "n/a";
            if (!a["converged_rmse_m"].is_null()) {
                std::snprintf(converged_rmse, sizeof converged_rmse, "%.3f", a["converged_rmse_m"].get<double>());
            }
            std::printf("%5d %5llu %6d %6.1f %6.1f %6d | %9.0f %9.0f | %8s %8s %7s | %8s %8.3f %9s | %7d %8s %6d | "
                        "%8.1f %8.2f %9.2f%s\n",
                        n["nodes"].get<int>(), n["seed"].get<unsigned long long>(), n["links"].get<int>(),
                        n["mean_degree"].get<double>(), n["radius_m"].get<double>(), n["sweeps"].get<int>(),
                        n["steady"]["ranges_per_s"].get<double>(), n["steady"]["ranges_per_cpu_s"].get<double>(),
                        map_ranges, map_s, placed, formatRmse(a).c_str(), a["median_error_m"].get<double>(), bad_links,
                        a["converged"].get<int>(), converged_rmse, a["converged_over_1m"].get<int>(),
                        static_cast<double>(n["memory_after"]["vm_hwm_kib"].get<long>()) / 1024.0,
                        static_cast<double>(n["memory_after"]["heap_in_use_kib"].get<long>() -
                                            n["memory_before"]["heap_in_use_kib"].get<long>()) /
                            1024.0,
                        n["engine_state"]["bytes"].get<double>() / (1024.0 * 1024.0),
                        a["finite"].get<bool>() ? "" : "  NON-FINITE ESTIMATES");
        }
    }
    std::printf(
        "  ranges/s: steady state (after the warm-up sweeps), per core, wall clock and CPU time. map_rng, map_s:\n"
        "  ranges fed and seconds spent feeding them until every node was first placed (* = some never were:\n"
        "  until the final number of placed nodes was first reached). placed: at the end. rmse_m: aligned RMSE\n"
        "  over the placed nodes at the end; median_m: the median node's error; bad_links: links the map itself\n"
        "  misses by more than 0.5 m (5 sigma). conv, conv_rms, conv>1: the nodes the engine calls converged,\n"
        "  the aligned RMSE over them alone (fitted on them), and how many of them are more than 1 m off: how\n"
        "  far the engine's own claim holds (nodes the links cannot decide are placed, not converged).\n"
        "  peak_MiB: peak resident memory of that process (VmHWM; its resident memory before the engine existed\n"
        "  is given below; the peak includes the copies of the engine that re-initialization makes, and freed\n"
        "  memory that the allocator keeps); heap_MiB: heap in use at\n"
        "  the end less that before the engine (glibc mallinfo2): the engine's live state; state_MiB: the\n"
        "  engine's state as estimated from its parts (ring components x 68 B + node, link and ring records).\n");
    for (const Json &size : networks) {
        const Json &summary = size["summary"];
        if (summary["draws_ok"].get<int>() == 0) {
            continue;
        }
        std::printf("  %d nodes, median of %d draws: %.0f ranges/s (%.0f per CPU-second), first map after %.2f s, "
                    "peak %.1f MiB (%.1f before the engine), RMSE %.3f m (%d draws over 1 m); warm-up %.2f s; "
                    "longest addRange %.1f ms\n",
                    size["nodes"].get<int>(), summary["draws_ok"].get<int>(),
                    summary["steady_ranges_per_s_median"].get<double>(),
                    summary["steady_ranges_per_cpu_s_median"].get<double>(),
                    summary["first_map_s_median"].get<double>(), summary["peak_rss_mib_median"].get<double>(),
                    summary["base_rss_mib_median"].get<double>(), summary["rmse_m_median"].get<double>(),
                    summary["draws_rmse_over_1m"].get<int>(), summary["warmup_s_median"].get<double>(),
                    summary["longest_call_ms"].get<double>());
        if (summary["most_behind_ms"].get<double>() > 0.0) {
            std::printf("    paced: the furthest a range ended behind the time it was due %.1f ms\n",
                        summary["most_behind_ms"].get<double>());
        }
        for (const Json &n : size["draws"]) {
            if (n.contains("error")) {
                continue;
            }
            const Json &a = n["accuracy_end"];
            std::string notes;
            if (a["rmse_m"].is_null() || a["rmse_m"].get<double>() > 1.0) {
                notes += a["links_residual_over_0_5m"].get<int>() > 0
                             ? " RMSE over 1 m with links the map does not explain (a local minimum);"
                             : " RMSE over 1 m although the map explains every link (an ambiguity of the network);";
                notes += " worst nodes";
                for (const Json &w : a["worst"]) {
                    char text[64];
                    std::snprintf(text, sizeof text, " %d (%.1f m, %d links)", w["id"].get<int>(),
                                  w["error_m"].get<double>(), w["links"].get<int>());
                    notes += text;
                }
                notes += ";";
            }
            std::string stuck;
            for (const Json &node : n["unplaced_at_end"]) {
                if (node["placed_neighbours"].get<int>() >= 3) {
                    stuck += " " + std::to_string(node["id"].get<int>()) + " (" +
                             std::to_string(node["placed_neighbours"].get<int>()) + " placed neighbours)";
                }
            }
            if (!stuck.empty()) {
                notes += " never placed although 3+ neighbours are:" + stuck + ";";
            }
            if (n["reinitializations_steady"].get<int>() > 0) {
                notes += " " + std::to_string(n["reinitializations_steady"].get<int>()) +
                         " re-initializations in the steady state;";
            }
            if (!notes.empty()) {
                std::printf("    seed %llu:%s\n", n["seed"].get<unsigned long long>(), notes.c_str());
            }
        }
    }
}

Json summarizeDraws(const Json &draws)
{
    std::vector<double> rates;
    std::vector<double> cpu_rates;
    std::vector<double> first_map_s;
    std::vector<double> peak_mib;
    std::vector<double> base_mib;
    std::vector<double> rmse;
    std::vector<double> warmup_s;
    double longest_call_ms = 0.0;
    double most_behind_ms = 0.0;
    int over_1m = 0;
    for (const Json &n : draws) {
        if (n.contains("error")) {
            continue;
        }
        rates.push_back(n["steady"]["ranges_per_s"].get<double>());
        cpu_rates.push_back(n["steady"]["ranges_per_cpu_s"].get<double>());
        if (n["first_complete_map"]["reached"].get<bool>()) {
            first_map_s.push_back(n["first_complete_map"]["wall_s"].get<double>());
        }
        peak_mib.push_back(static_cast<double>(n["memory_after"]["vm_hwm_kib"].get<long>()) / 1024.0);
        base_mib.push_back(static_cast<double>(n["memory_before"]["vm_rss_kib"].get<long>()) / 1024.0);
        const Json &a = n["accuracy_end"];
        rmse.push_back(a["rmse_m"].is_null() ? std::nan("") : a["rmse_m"].get<double>());
        over_1m += a["rmse_m"].is_null() || a["rmse_m"].get<double>() > 1.0 ? 1 : 0;
        warmup_s.push_back(n["warmup"]["wall_s"].get<double>());
        longest_call_ms = std::max({longest_call_ms, n["warmup"]["longest_call_ms"].get<double>(),
                                    n["steady"]["longest_call_ms"].get<double>()});
        most_behind_ms = std::max(
            {most_behind_ms, n["warmup"]["most_behind_ms"].get<double>(), n["steady"]["most_behind_ms"].get<double>()});
    }
    return Json{{"draws_ok", rates.size()},
                {"steady_ranges_per_s_median", median(rates)},
                {"steady_ranges_per_cpu_s_median", median(cpu_rates)},
                {"first_map_s_median", median(first_map_s)},
                {"peak_rss_mib_median", median(peak_mib)},
                {"base_rss_mib_median", median(base_mib)},
                {"rmse_m_median", median(rmse)},
                {"draws_rmse_over_1m", over_1m},
                {"warmup_s_median", median(warmup_s)},
                {"longest_call_ms", longest_call_ms},
                {"most_behind_ms", most_behind_ms}};
}

} // namespace

static int runMain(int argc, char **argv)
{
    CLI::App app{"cdro-bench-engine: engine throughput (ranges/s per core), time to the first map, aligned RMSE and\n"
                 "memory, on PLANT replayed in a loop and on random geometric networks. Figures only; run on\n"
                 "purpose (scripts/bench-engine.sh runs it next to GTSAM iSAM2).\n"};
    std::string data_dir;
    uint32_t passes = 100;
    uint32_t repeats = 5;
    std::vector<uint32_t> sizes{10, 30, 100, 300};
    uint64_t seed = 1;
    uint32_t draws = 3;
    bool plant_only = false;
    bool networks_only = false;
    bool json = false;
    std::string json_out;
    uint32_t one_network = 0;
    NetworkOptions network;
    app.add_option("--data-dir", data_dir,
                   "folder that holds plant/ (default $CDRO_DATA_DIR, else ../shared/data from the repository root)");
    app.add_option("--passes", passes, "PLANT: passes over the 1205 ranges per repeat (>= 2)")
        ->capture_default_str()
        ->check(CLI::Range(2U, 1000000U));
    app.add_option("--repeat", repeats, "PLANT: repeats, each with a fresh engine; the median is reported")
        ->capture_default_str()
        ->check(CLI::Range(1U, 1000U));
    app.add_option("--sizes", sizes, "network sizes (nodes)")
        ->capture_default_str()
        ->delimiter(',')
        ->check(CLI::Range(3U, 60000U));
    app.add_option("--seed", seed, "seed of the first draw of each size; draw k uses seed + k")->capture_default_str();
    app.add_option("--draws", draws, "networks drawn per size (each in a fresh process)")
        ->capture_default_str()
        ->check(CLI::Range(1U, 1000U));
    app.add_option("--degree", network.degree, "mean degree of the networks")->capture_default_str();
    app.add_option("--area-per-node-m2", network.area_per_node_m2, "m^2 of the square per node")->capture_default_str();
    app.add_option("--noise-m", network.noise_sigma_m, "m, standard deviation of the Gaussian range noise")
        ->capture_default_str();
    app.add_option("--warmup-sweeps", network.warmup_sweeps, "sweeps before the steady state")->capture_default_str();
    app.add_option("--min-sweeps", network.min_sweeps, "sweeps at least")->capture_default_str();
    app.add_option("--steady-ranges", network.steady_ranges, "ranges in the steady state at least")
        ->capture_default_str();
    app.add_option("--pace", network.pace_ranges_per_s,
                   "ranges/s: feed the networks' ranges at this rate, as a live network would (0: back to back); "
                   "the longest addRange call then shows whether a range ever waits for the global solve")
        ->capture_default_str()
        ->check(CLI::Range(0.0, 1e7));
    app.add_option("--adopt-after-sweeps", network.adopt_after_sweeps,
                   "networks: engine.solve.adopt_after_sweeps (0: the global solve inside addRange, no worker thread)")
        ->capture_default_str()
        ->check(CLI::Range(0.0, 1e6));
    app.add_flag("--adopt-when-done", network.adopt_when_done,
                 "networks: adopt each global solve between ranges once its worker is done, as cdro-hostd does "
                 "live (Engine::SolveAdoption::ByCaller), never inside addRange; the adoptions are timed apart");
    app.add_flag("--explain-slow-calls", network.explain_slow_calls,
                 "networks: count the addRange calls over 1 ms by what the engine did in them (placed a node "
                 "again, placed nodes, started a global solve, other), in the JSON's calls_over_1ms");
    auto *plant_flag = app.add_flag("--plant-only", plant_only, "PLANT only");
    app.add_flag("--networks-only", networks_only, "random networks only")->excludes(plant_flag);
    app.add_flag("--json", json, "print one JSON document instead of the table");
    app.add_option("--json-out", json_out, "also write the JSON document to this file (with the table)");
    app.add_option("--one-network", one_network, "run one network of this size in this process, print its JSON");
    app.add_option(
        "--write-csv", network.write_csv_dir,
        "with --one-network: write the stream fed (DIR/ranges.csv), the truth (DIR/truth.csv) and the heights the "
        "engine is told (DIR/heights.csv: 0, the networks are planar), for "
        "cdro-hostd --ranges-csv and cdro-eval");
    CLI11_PARSE(app, argc, argv);

    try {
        if (one_network != 0) {
            std::printf("%s\n", runNetwork(one_network, seed, network).dump().c_str());
            return 0;
        }
        Json report{{"machine", machineJson()}};
        const std::string build_type = CDRO_BUILD_TYPE;
        if (build_type != "Release" && build_type != "RelWithDebInfo") {
            std::fprintf(stderr, "cdro-bench-engine: built as %s: the figures mean little without optimization\n",
                         build_type.c_str());
        }
        if (!json) {
            std::printf("cdro-bench-engine (%s build) on %s, %ld cores\n\n", CDRO_BUILD_TYPE,
                        report["machine"]["cpu"].get<std::string>().c_str(), sysconf(_SC_NPROCESSORS_ONLN));
            std::fflush(stdout);
        }
        bool failed = false;
        if (!networks_only) {
            const Plant plant = loadPlant(findPlant(data_dir));
            const Memory before = memoryNow();
            std::vector<PlantRun> runs;
            for (uint32_t r = 0; r < repeats; ++r) {
                runs.push_back(runPlant(plant, passes));
            }
            report["plant"] = plantJson(plant, runs, passes, before, memoryNow());
            if (!json) {
                printPlant(report["plant"]);
                std::fflush(stdout);
            }
            failed = failed || !report["plant"]["accuracy_end"]["finite"].get<bool>();
        }
        if (!plant_only) {
            Json networks = Json::array();
            for (uint32_t nodes : sizes) {
                Json results = Json::array();
                for (uint32_t draw = 0; draw < draws; ++draw) {
                    const uint64_t draw_seed = seed + draw;
                    std::vector<std::string> arguments{argv[0],
                                                       "--one-network",
                                                       std::to_string(nodes),
                                                       "--seed",
                                                       std::to_string(draw_seed),
                                                       "--degree",
                                                       std::to_string(network.degree),
                                                       "--area-per-node-m2",
                                                       std::to_string(network.area_per_node_m2),
                                                       "--noise-m",
                                                       std::to_string(network.noise_sigma_m),
                                                       "--warmup-sweeps",
                                                       std::to_string(network.warmup_sweeps),
                                                       "--min-sweeps",
                                                       std::to_string(network.min_sweeps),
                                                       "--steady-ranges",
                                                       std::to_string(network.steady_ranges),
                                                       "--pace",
                                                       std::to_string(network.pace_ranges_per_s),
                                                       "--adopt-after-sweeps",
                                                       std::to_string(network.adopt_after_sweeps)};
                    if (network.adopt_when_done) {
                        arguments.emplace_back("--adopt-when-done");
                    }
                    if (network.explain_slow_calls) {
                        arguments.emplace_back("--explain-slow-calls");
                    }
                    std::string failure;
                    Json result = spawnNetwork(arguments, &failure);
                    if (result.is_null()) {
                        result = Json{{"nodes", nodes}, {"seed", draw_seed}, {"error", failure}};
                        failed = true;
                    } else {
                        failed = failed || !result["accuracy_end"]["finite"].get<bool>();
                    }
                    results.push_back(result);
                }
                networks.push_back(Json{{"nodes", nodes}, {"summary", summarizeDraws(results)}, {"draws", results}});
            }
            report["networks"] = networks;
            if (!json) {
                printNetworks(networks);
            }
        }
        if (json) {
            std::printf("%s\n", report.dump(2).c_str());
        }
        if (!json_out.empty()) {
            std::ofstream file(json_out);
            file << report.dump(2) << "\n";
            if (!file) {
                std::fprintf(stderr, "cdro-bench-engine: cannot write %s\n", json_out.c_str());
                return 2;
            }
        }
        return failed ? 1 : 0;
    } catch (const std::exception &error) {
        std::fprintf(stderr, "cdro-bench-engine: %s\n", error.what());
        return 2;
    }
}

// An exception that escapes (from setting up the options, or a library's) ends the run with its
// message and status 1, not with std::terminate's abort.
int main(int argc, char **argv)
{
    cdro::hostd::returnLargeBuffersToTheSystem(); // as cdro-hostd does: the memory measured is its
    try {
        return runMain(argc, argv);
    } catch (const std::exception &error) {
        std::fprintf(stderr, "cdro-bench-engine: %s\n", error.what());
        return 1;
    }
}
