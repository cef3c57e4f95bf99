// The engine as a whole: exact recovery of noise-free random networks (a property test over
// seeds), determinism, the verdicts on bad ranges, fixed nodes, the named frame, and the
// ablation switches. Bugs found while writing these stay as regression tests, with what they
// showed.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <optional>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <utility>

#include <gtest/gtest.h>
#include <sys/syscall.h>
#include <unistd.h>

#include "cdro/engine/engine.hpp"
#include "cdro/engine/worker_priority.hpp"
#include "support.hpp"

namespace cdro::enginetest {
namespace {

using engine::Engine;
using engine::EngineParams;
using engine::Gaussian2;
using engine::Matrix2;
using engine::NodeOutput;
using engine::RangeVerdict;

std::map<NodeId, NodeOutput> byId(const std::vector<NodeOutput> &estimates)
{
    std::map<NodeId, NodeOutput> out;
    for (const NodeOutput &node : estimates) {
        out[node.id] = node;
    }
    return out;
}

// Ranges of a noisy network with some NLOS readings (too long by 0.5 to 2 m), as on PLANT.
std::vector<TestRange> noisyRanges(const TestNetwork &network, Random &random, uint32_t sweeps)
{
    std::vector<TestRange> ranges = roundRobin(network, random, sweeps, 0.10);
    for (TestRange &range : ranges) {
        if (random.uniform() < 0.08) {
            range.range_m += random.uniform(0.5, 2.0);
        }
    }
    return ranges;
}

// ---- (a) noise-free random networks: the truth up to a rigid transform ----------------------

struct PropertyCase {
    uint64_t seed;
    size_t nodes;
    double degree; // mean links per node
    bool heights;  // random heights 0..3 m, 3D ranges
};

std::ostream &operator<<(std::ostream &out, const PropertyCase &c)
{
    return out << c.nodes << " nodes, degree " << c.degree << (c.heights ? ", heights" : ", planar") << ", seed "
               << c.seed;
}

class NoiseFreeRecovery : public ::testing::TestWithParam<PropertyCase> {};

TEST_P(NoiseFreeRecovery, RecoversTheTruthUpToARigidTransform)
{
    PropertyCase c = GetParam();
    if (kSanitizedBuild && c.nodes > 8) {
        GTEST_SKIP() << "sanitized build: networks over 8 nodes run in the native build only";
    }
    c.seed = testSeed(c.seed);
    SCOPED_TRACE(seedTrace(c.seed));
    Random random(c.seed);
    const TestNetwork network = randomNetwork(random, c.nodes, c.degree, c.heights);
    // Every link six times, each pass in a new random order and direction.
    const std::vector<TestRange> ranges = roundRobin(network, random, 6, 0.0);
    // An open hall: no wall makes these links read long, and the user says so (the default
    // excess guards walled buildings, where it leaves more nodes flexible).
    EngineParams params;
    params.convergence.common_excess_m = 0.0;
    params.convergence.room_excess_m = 0.0;
    Engine engine(params);
    feed(engine, network, ranges);
    const AlignedError error = alignedError(engine.estimates(), network.ids, network.truth_m);
    std::printf("%zu nodes, %zu links, %zu ranges: %zu placed, %zu converged, aligned RMSE %.3g m (max %.3g m)\n",
                c.nodes, network.links.size(), ranges.size(), error.placed, error.converged, error.rmse_m, error.max_m);
    // A node that the ranges do not determine (a mirror position that fits about as well, a link
    // nothing checks) says why instead of being converged: that is the honest answer for it, so it
    // counts as long as it is also where the truth is (the RMSE below). After settling, none is
    // merely unsettled.
    size_t doubted = 0;
    for (const engine::NodeOutput &node : engine.estimates()) {
        doubted += !node.converged() && node.doubt != engine::NodeDoubt::Unsettled ? 1U : 0U;
        if (!node.converged()) {
            const engine::NodeState &state = engine.map().nodes[engine.map().findNode(node.id)];
            std::printf("  not converged: node %u (%s, %s, %u links, %u updates, %u still)\n", node.id,
                        engine::nodeLifecycleName(node.lifecycle), engine::nodeDoubtName(node.doubt), node.link_count,
                        state.update_count, state.still_updates);
        }
    }
    EXPECT_EQ(error.nodes, c.nodes);
    EXPECT_EQ(error.placed, c.nodes);
    EXPECT_EQ(error.converged + doubted, c.nodes);
    // Sparse networks (degree 6) have nodes that one link error too small to be noticed under
    // 0.1 m of noise could move beyond the metre, or whose 95 % region reaches it: flexible (20 of
    // 40 in seed 1000, the sparsest case here; 0-2 of 20 at degree 10).
    EXPECT_LE(doubted * 2, c.nodes) << "more than half of the nodes in doubt";
    EXPECT_LT(error.rmse_m, 0.01);
    EXPECT_EQ(engine.counters().intake.ranges_received, ranges.size());
    EXPECT_EQ(engine.counters().intake.rejected_self + engine.counters().intake.rejected_value, 0U);
}

// 8 to 40 nodes, mean degree 6 to 10, with and without heights. The seeds are fixed (printed;
// CDRO_TEST_SEED replays one); seeds that fail are listed below, not dropped.
INSTANTIATE_TEST_SUITE_P(RandomNetworks, NoiseFreeRecovery,
                         ::testing::Values(PropertyCase{1000, 8, 6.0, true}, PropertyCase{1001, 8, 6.0, false},
                                           PropertyCase{1000, 12, 7.0, true}, PropertyCase{1000, 16, 8.0, true},
                                           PropertyCase{1001, 16, 8.0, false}, PropertyCase{1000, 20, 10.0, true},
                                           PropertyCase{1000, 25, 8.0, true}, PropertyCase{1000, 30, 9.0, true},
                                           PropertyCase{1003, 30, 9.0, false}, PropertyCase{1000, 40, 10.0, true},
                                           PropertyCase{1000, 40, 8.0, true}));

// Hard cases, same generator and stream: these seeds fail without the joint solve of the
// initialization that runs again, the NLOS term ramped in at e = 0 and eq. 16's average
// restarted when settling ends. Without those three, over seeds
// 1000..1029 per configuration: 8 nodes/degree 6, 16/8: 0 of 30 fail; 12/7: 1; 20/10: 2; 25/8:
// 2; 30/9: 1; 40/10: 3; 40/8: 14; 40/6: 28 of 30. Three kinds:
//  - 1028 (12/7), 1014 (20/10): the map is exact (RMSE < 1e-6 m) but a node is not converged
//    after settle(): settle stops once no position moves more than relax_threshold_m, while that
//    node's convergence average (eq. 16) still lags its final position by over 10 cm (its step
//    stays above threshold_m), and nothing updates it again until new ranges arrive.
//  - 1026 (20/10), 1000 (40/6): a local minimum: the truth explains the links better than the
//    engine's map (mapCost -127.8 against -125.5 nats, and -153.4 against -144.1), and neither
//    the hypothesis switch nor the re-initialization finds it (RMSE 1.33 m and 0.38 m).
//  - 1005 (40/8): RMSE 1.3 m though every link fits within 7 cm, and the engine's map costs
//    less than the truth under its own likelihood (-205.96 against -204.53 nats): the NLOS
//    term eps lambda exp(-lambda e) starts at e = 0+ with a jump (0.1 / m by default), so each
//    slightly positive residual is 0.027 nats cheaper than an exact one; see
//    RangeLikelihood.DensityIsContinuousAtZero. With sigma 0.1 m such near-flips are
//    also statistically close.
//  - 1001 (40/8): RMSE 3.2 cm: Gauss-Seidel along a soft mode stops at relax_threshold_m = 1 mm
//    per update (with 1e-7 m it reaches 5e-6 m). A tolerance more than a bug.
INSTANTIATE_TEST_SUITE_P(FormerFailures, NoiseFreeRecovery,
                         ::testing::Values(PropertyCase{1028, 12, 7.0, true}, PropertyCase{1014, 20, 10.0, true},
                                           PropertyCase{1026, 20, 10.0, true}, PropertyCase{1000, 40, 6.0, true},
                                           PropertyCase{1005, 40, 8.0, false}, PropertyCase{1001, 40, 8.0, false}));

TEST(NoiseFreeRecovery, TheGeneratorOnlyDrawsGloballyRigidNetworks)
{
    // The property needs networks whose ranges allow one map only; the check must tell.
    Random random(1);
    TestNetwork k4;
    k4.truth_m = {Vector2(0, 0), Vector2(5, 0), Vector2(1, 4), Vector2(6, 5)};
    k4.ids = {1, 2, 3, 4};
    k4.links = {{0, 1}, {0, 2}, {0, 3}, {1, 2}, {1, 3}, {2, 3}};
    EXPECT_TRUE(globallyRigid(k4, random));
    TestNetwork hinge = k4; // a quadrilateral with one diagonal folds about it
    hinge.links = {{0, 1}, {0, 2}, {1, 2}, {1, 3}, {2, 3}};
    EXPECT_FALSE(globallyRigid(hinge, random));
    TestNetwork square = k4; // a 4-cycle is not even rigid
    square.links = {{0, 1}, {1, 3}, {3, 2}, {2, 0}};
    EXPECT_FALSE(globallyRigid(square, random));
    // Two K4s sharing two nodes: rigid, but one half can be reflected across the shared line.
    TestNetwork hinged_k4s;
    hinged_k4s.truth_m = {Vector2(0, 0), Vector2(5, 0), Vector2(1, 4), Vector2(4, 3), Vector2(2, -4), Vector2(4, -3)};
    hinged_k4s.ids = {1, 2, 3, 4, 5, 6};
    hinged_k4s.links = {{0, 1}, {0, 2}, {0, 3}, {1, 2}, {1, 3}, {2, 3}, {0, 4}, {0, 5}, {1, 4}, {1, 5}, {4, 5}};
    EXPECT_FALSE(globallyRigid(hinged_k4s, random));
    hinged_k4s.links.push_back({2, 4}); // one link across the hinge fixes it
    EXPECT_TRUE(globallyRigid(hinged_k4s, random));
}

// ---- (b) determinism ---------------------------------------------------------------------------

TEST(Engine, SameInputGivesBitIdenticalEstimates)
{
    CDRO_SKIP_WHEN_SANITIZED();
    const uint64_t seed = testSeed(3501);
    SCOPED_TRACE(seedTrace(seed));
    Random random(seed);
    const TestNetwork network = randomNetwork(random, 8, 6.0, true);
    const std::vector<TestRange> ranges = noisyRanges(network, random, 5);
    Engine first;
    Engine second;
    // A trace sink is an observer: it must not change anything.
    size_t messages = 0;
    second.setTrace([&messages](const std::string &) { ++messages; });
    feed(first, network, ranges);
    feed(second, network, ranges);
    EXPECT_TRUE(identical(first.estimates(), second.estimates()));
    EXPECT_EQ(first.revision(), second.revision());
    const engine::EngineCounters counters_a = first.counters();
    const engine::EngineCounters counters_b = second.counters();
    EXPECT_EQ(std::memcmp(&counters_a, &counters_b, sizeof(engine::EngineCounters)), 0);
    const auto links_a = first.links();
    const auto links_b = second.links();
    ASSERT_EQ(links_a.size(), links_b.size());
    for (size_t i = 0; i < links_a.size(); ++i) {
        EXPECT_EQ(std::memcmp(&links_a[i].range_m, &links_b[i].range_m, sizeof(double)), 0);
        EXPECT_EQ(std::memcmp(&links_a[i].inlier_probability, &links_b[i].inlier_probability, sizeof(double)), 0);
    }
    // And a different order is a different run (the comparison above can fail).
    std::vector<TestRange> reordered = ranges;
    std::swap(reordered[3], reordered[reordered.size() - 4]);
    Engine third;
    feed(third, network, reordered);
    EXPECT_FALSE(identical(first.estimates(), third.estimates()));
}

// The global solve runs on a worker thread while ranges go on arriving, and its map is adopted at
// a fixed range of the stream: a caller that waits after every range until the worker is done
// (the solve finished long before its map is due) and one that never waits (addRange waits at
// the adoption point) get the same estimates, bit for bit; so does a copy of the engine made
// while a solve is under way.
TEST(Engine, TheWorkerThreadsSolveIsAdoptedAtTheSameRangeWhateverItsTiming)
{
    CDRO_SKIP_WHEN_SANITIZED();
    const uint64_t seed = testSeed(3502);
    SCOPED_TRACE(seedTrace(seed));
    Random random(seed);
    const TestNetwork network = randomNetwork(random, 16, 7.0, true);
    std::vector<TestRange> ranges = noisyRanges(network, random, 12);
    for (TestRange &range : ranges) {
        if (random.uniform() < 0.08) {
            range.range_m += random.uniform(0.5, 2.0); // NLOS
        }
    }
    engine::EngineParams params;
    params.solve.adopt_after_sweeps = 1.0;
    Engine hurried(params);
    Engine patient(params);
    std::optional<Engine> copy;
    uint64_t ranges_while_pending = 0;
    for (size_t i = 0; i < network.ids.size(); ++i) {
        hurried.setHeight(network.ids[i], network.height_m[i]);
        patient.setHeight(network.ids[i], network.height_m[i]);
    }
    for (const TestRange &range : ranges) {
        hurried.addRange(range.from, range.to, range.range_m);
        if (copy) {
            copy->addRange(range.from, range.to, range.range_m);
        }
        patient.addRange(range.from, range.to, range.range_m);
        if (patient.solvePending()) {
            ++ranges_while_pending;
            if (!copy && patient.counters().solve.solves >= 2) {
                copy.emplace(patient); // copied mid-solve, fed from the next range on
            }
            std::this_thread::sleep_for(std::chrono::milliseconds(2));
        }
    }
    ASSERT_TRUE(copy.has_value());
    // The worker was given ranges to overlap with: addRange returned while a solve was pending.
    EXPECT_GT(ranges_while_pending, 0U);
    EXPECT_GE(hurried.counters().solve.solves, 2U);
    for (Engine *engine : {&hurried, &patient, &*copy}) {
        engine->settle(200ULL * engine->map().nodes.size() + 1000ULL);
    }
    EXPECT_TRUE(identical(hurried.estimates(), patient.estimates()));
    EXPECT_TRUE(identical(hurried.estimates(), copy->estimates()));
    const engine::EngineCounters counters_a = hurried.counters();
    const engine::EngineCounters counters_b = patient.counters();
    EXPECT_EQ(std::memcmp(&counters_a, &counters_b, sizeof(engine::EngineCounters)), 0);
}

// An engine fed as cdro-hostd feeds it live: the worker's solves adopted by the caller between
// ranges, the network's heights told.
void adoptedByTheCaller(Engine &engine, const TestNetwork &network)
{
    engine.setSolveAdoption(Engine::SolveAdoption::ByCaller);
    for (size_t i = 0; i < network.ids.size(); ++i) {
        engine.setHeight(network.ids[i], network.height_m[i]);
    }
}

// Live, no range waits for the global solve: with SolveAdoption::ByCaller addRange never adopts a
// solve of the worker thread, however long it has been pending (a caller busy for two sweeps finds
// it still pending), and the caller adopts it between ranges once the worker is done, where the
// thread's timing puts it. A replay that adopts at the same places (cdro-hostd: the capture's host
// events) gets the same estimates and counters, bit for bit.
TEST(Engine, ASolveTheCallerAdoptsWhenItsWorkerIsDoneIsReplayedAtTheSamePlaces)
{
    CDRO_SKIP_WHEN_SANITIZED();
    const uint64_t seed = testSeed(3502);
    SCOPED_TRACE(seedTrace(seed));
    Random random(seed);
    const TestNetwork network = randomNetwork(random, 16, 7.0, true);
    const std::vector<TestRange> ranges = noisyRanges(network, random, 12);
    engine::EngineParams params;
    params.solve.adopt_after_sweeps = 0.25; // the default: the solve on the worker thread
    Engine live(params);
    Engine replayed(params);
    for (Engine *engine : {&live, &replayed}) {
        adoptedByTheCaller(*engine, network);
    }
    std::vector<size_t> adopted_after; // range index after which the live caller adopted
    size_t busy_until = 0;             // the caller does not look before this range
    size_t longest_pending = 0;        // ranges a solve stayed pending
    size_t pending_for = 0;
    for (size_t i = 0; i < ranges.size(); ++i) {
        live.addRange(ranges[i].from, ranges[i].to, ranges[i].range_m);
        pending_for = live.solvePending() ? pending_for + 1 : 0;
        longest_pending = std::max(longest_pending, pending_for);
        if (!live.solvePending()) {
            continue;
        }
        if (adopted_after.size() == 1 && busy_until == 0) {
            busy_until = i + 2 * network.links.size(); // two sweeps without a look (all links: the
            // map may not have heard them all yet)
        }
        if (i < busy_until) {
            continue;
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(2));
        if (live.adoptFinishedSolve()) {
            EXPECT_FALSE(live.solvePending());
            adopted_after.push_back(i);
        }
    }
    ASSERT_GE(adopted_after.size(), 2U);
    // The lag is a quarter sweep: addRange would have adopted long before.
    EXPECT_GT(longest_pending, live.map().links.size());
    size_t next = 0;
    for (size_t i = 0; i < ranges.size(); ++i) {
        replayed.addRange(ranges[i].from, ranges[i].to, ranges[i].range_m);
        if (next < adopted_after.size() && adopted_after[next] == i) {
            EXPECT_TRUE(replayed.adoptPendingSolve()) << "range " << i;
            ++next;
        }
    }
    EXPECT_EQ(next, adopted_after.size());
    for (Engine *engine : {&live, &replayed}) {
        engine->settle(200ULL * engine->map().nodes.size() + 1000ULL);
    }
    EXPECT_TRUE(identical(live.estimates(), replayed.estimates()));
    const engine::EngineCounters counters_live = live.counters();
    const engine::EngineCounters counters_replayed = replayed.counters();
    EXPECT_EQ(std::memcmp(&counters_live, &counters_replayed, sizeof(engine::EngineCounters)), 0);
}

// The nice values of this process's threads other than the caller, from /proc (Linux).
std::vector<int> otherThreadsNice()
{
    std::vector<int> nice;
    const std::string own = std::to_string(static_cast<long>(syscall(SYS_gettid)));
    for (const auto &task : std::filesystem::directory_iterator("/proc/self/task")) {
        if (task.path().filename().string() == own) {
            continue;
        }
        std::ifstream stat(task.path() / "stat");
        std::string line;
        if (!std::getline(stat, line) || line.rfind(')') == std::string::npos) {
            continue; // the thread ended meanwhile
        }
        // After the name in parentheses: state, then fields 4.. ; nice is field 19 (man 5 proc).
        std::istringstream fields(line.substr(line.rfind(')') + 1));
        std::string field;
        for (int index = 3; index <= 19 && fields >> field; ++index) {
            if (index == 19) {
                nice.push_back(std::stoi(field));
            }
        }
    }
    return nice;
}

// A thread that lowered its priority starts threads at the same priority (the solve's helpers, which
// the worker starts, run behind the ranges too), and the thread that started it keeps its own.
TEST(Engine, AWorkerThatLowersItsPriorityLowersItsHelpersToo)
{
    const int caller_nice = engine::thisThreadsNice();
    int worker_nice = caller_nice;
    int helper_nice = caller_nice;
    bool lowered = false;
    std::thread worker([&]() {
        lowered = engine::lowerThisThreadsPriority();
        worker_nice = engine::thisThreadsNice();
        std::thread helper([&]() { helper_nice = engine::thisThreadsNice(); });
        helper.join();
    });
    worker.join();
    ASSERT_TRUE(lowered);
    EXPECT_EQ(worker_nice, std::min(caller_nice + engine::kWorkerNiceSteps, 19));
    EXPECT_EQ(helper_nice, worker_nice);
    EXPECT_EQ(engine::thisThreadsNice(), caller_nice);
}

// The global solve's worker runs below the thread that feeds the ranges (worker_priority.hpp): a
// range that arrives while a solve runs takes a core at once. Seen from outside, in /proc, while
// solves are pending; the feeding thread's own priority is left as it was.
TEST(Engine, TheGlobalSolvesWorkerRunsBelowTheThreadThatFeedsTheRanges)
{
    const uint64_t seed = testSeed(3502);
    SCOPED_TRACE(seedTrace(seed));
    Random random(seed);
    const TestNetwork network = randomNetwork(random, 16, 7.0, true);
    const std::vector<TestRange> ranges = noisyRanges(network, random, 12);
    engine::EngineParams params;
    params.solve.adopt_after_sweeps = 0.25; // the default: the solve on the worker thread
    Engine engine(params);
    adoptedByTheCaller(engine, network);
    const int feeding_nice = engine::thisThreadsNice();
    const int worker_nice = std::min(feeding_nice + engine::kWorkerNiceSteps, 19);
    uint32_t looks_while_pending = 0;
    uint32_t workers_seen_lowered = 0;
    for (const TestRange &range : ranges) {
        engine.addRange(range.from, range.to, range.range_m);
        if (!engine.solvePending()) {
            continue;
        }
        ++looks_while_pending;
        for (int nice : otherThreadsNice()) {
            EXPECT_TRUE(nice == worker_nice || nice == feeding_nice) << nice;
            workers_seen_lowered += nice == worker_nice ? 1U : 0U;
        }
        engine.adoptFinishedSolve();
    }
    std::printf("%u looks while a solve was pending, the worker seen at nice %d %u times\n", looks_while_pending,
                worker_nice, workers_seen_lowered);
    EXPECT_GT(workers_seen_lowered, 0U);
    EXPECT_EQ(engine::thisThreadsNice(), feeding_nice);
}

// The steady state costs no global solve: once the links are known and a solve has seen their
// windows full, their medians only flicker and the solve is not run again, however many ranges
// come; while the ranges still change the links (a link reading 0.4 m longer from now on), it is.
TEST(Engine, TheSteadyStateRunsNoGlobalSolveUntilTheRangesChange)
{
    CDRO_SKIP_WHEN_SANITIZED();
    const uint64_t seed = testSeed(3601);
    SCOPED_TRACE(seedTrace(seed));
    Random random(seed);
    const TestNetwork network = randomNetwork(random, 12, 7.0, false);
    Engine engine;
    feed(engine, network, roundRobin(network, random, 80, 0.1), false);
    const uint64_t solves_at_80 = engine.counters().solve.solves;
    feed(engine, network, roundRobin(network, random, 320, 0.1), false);
    EXPECT_EQ(engine.counters().solve.solves, solves_at_80)
        << "80 sweeps: " << solves_at_80 << " offsets adopted " << engine.counters().solve.offsets_adopted
        << " refreshes " << engine.counters().solve.solve_refreshes;
    // A quarter of the links now read 0.4 m long (a door closed, a cabinet moved): solved again,
    // on the same links and nodes (a refresh).
    std::vector<TestRange> changed = roundRobin(network, random, 200, 0.1);
    std::set<std::pair<NodeId, NodeId>> links;
    for (const TestRange &range : changed) {
        links.insert(std::minmax(range.from, range.to));
    }
    std::set<std::pair<NodeId, NodeId>> longer;
    size_t count = 0;
    for (const auto &link : links) {
        if (count++ % 4 == 0) {
            longer.insert(link);
        }
    }
    for (TestRange &range : changed) {
        range.range_m += longer.count(std::minmax(range.from, range.to)) != 0 ? 0.4 : 0.0;
    }
    feed(engine, network, changed, false);
    EXPECT_GT(engine.counters().solve.solves, solves_at_80);
    EXPECT_GT(engine.counters().solve.solve_refreshes, 0U);
}

TEST(Engine, NoRangePaysForMoreThanOnePlacementAndItsShareOfTheSettling)
{
    // While a map forms, placing a node and settling its neighbourhood (settle_per_placed
    // neighbour updates) is the range path's largest piece of work, and a placement makes its
    // neighbours placeable: in one range a cascade of them and their settling was the slowest
    // addRange calls at 300 nodes (docs/bench.md). Counted, not timed: no range places more than
    // one node (the frame's three at once) or updates more than relax_per_range +
    // settle_per_range neighbours.
    const uint64_t seed = testSeed(3611);
    SCOPED_TRACE(seedTrace(seed));
    Random random(seed);
    const TestNetwork network = randomNetwork(random, 40, 8.0, false);
    EngineParams params;
    params.solve.enabled = false; // the global solve places nodes in bulk, off the range path
    Engine engine(params);
    const std::vector<TestRange> ranges = roundRobin(network, random, 3, 0.1);
    uint64_t most_placed = 0;
    uint64_t most_relaxed = 0;
    for (const TestRange &range : ranges) {
        const engine::EngineCounters before = engine.counters();
        engine.addRange(range.from, range.to, range.range_m);
        const engine::EngineCounters after = engine.counters();
        const uint64_t placed = after.placement.placements - before.placement.placements;
        if (before.placement.placements != 0) {
            most_placed = std::max(most_placed, placed);
        }
        most_relaxed = std::max(most_relaxed, after.relaxations - before.relaxations);
    }
    EXPECT_EQ(most_placed, 1U);
    EXPECT_LE(most_relaxed, params.refinement.relax_per_range + params.refinement.settle_per_range);
}

// ---- (c) verdicts and counters ---------------------------------------------------------------

bool sameLinks(const std::vector<engine::LinkOutput> &a, const std::vector<engine::LinkOutput> &b)
{
    if (a.size() != b.size()) {
        return false;
    }
    for (size_t i = 0; i < a.size(); ++i) {
        if (a[i].a != b[i].a || a[i].b != b[i].b || a[i].range_count != b[i].range_count ||
            std::memcmp(&a[i].range_m, &b[i].range_m, sizeof(double)) != 0 ||
            std::memcmp(&a[i].last_range_m, &b[i].last_range_m, sizeof(double)) != 0) {
            return false;
        }
    }
    return true;
}

TEST(Engine, BadRangesAreRefusedCountedAndNeverChangeTheMap)
{
    const uint64_t seed = testSeed(3502);
    SCOPED_TRACE(seedTrace(seed));
    Random random(seed);
    const TestNetwork network = randomNetwork(random, 8, 6.0, false);
    Engine engine;
    feed(engine, network, roundRobin(network, random, 4, 0.0));
    const std::vector<NodeOutput> before = engine.estimates();
    const std::vector<engine::LinkOutput> links_before = engine.links();
    const uint64_t revision = engine.revision();
    const engine::EngineCounters counters = engine.counters();
    const NodeId a = network.ids[0];
    const NodeId b = network.ids[1];
    const double max_m = engine.params().range.max_range_m;

    EXPECT_EQ(engine.addRange(a, a, 5.0), RangeVerdict::RejectedSelf);
    EXPECT_EQ(engine.addRange(b, b, std::numeric_limits<double>::quiet_NaN()), RangeVerdict::RejectedSelf);
    const double bad_m[] = {std::numeric_limits<double>::quiet_NaN(),
                            std::numeric_limits<double>::infinity(),
                            -std::numeric_limits<double>::infinity(),
                            -1.0,
                            0.0,
                            -0.0,
                            std::nextafter(max_m, std::numeric_limits<double>::infinity()),
                            1e9};
    for (double range_m : bad_m) {
        EXPECT_EQ(engine.addRange(a, b, range_m), RangeVerdict::RejectedValue) << range_m;
    }
    // A refused range does not make its nodes known either.
    EXPECT_EQ(engine.addRange(0xBEEF, a, -3.0), RangeVerdict::RejectedValue);
    EXPECT_EQ(engine.addRange(0xBEEF, 0xBEEF, 3.0), RangeVerdict::RejectedSelf);

    const size_t refused = 2 + std::size(bad_m) + 2;
    EXPECT_TRUE(identical(before, engine.estimates()));
    EXPECT_TRUE(sameLinks(links_before, engine.links()));
    EXPECT_EQ(engine.revision(), revision);
    EXPECT_FALSE(engine.estimate(0xBEEF).has_value());
    const engine::EngineCounters after = engine.counters();
    EXPECT_EQ(after.intake.ranges_received, counters.intake.ranges_received + refused);
    EXPECT_EQ(after.intake.rejected_self, counters.intake.rejected_self + 3);
    EXPECT_EQ(after.intake.rejected_value, counters.intake.rejected_value + std::size(bad_m) + 1);
    EXPECT_EQ(after.ranges_used, counters.ranges_used);
    EXPECT_EQ(after.ranges_stored, counters.ranges_stored);

    // The limit itself is a plausible range; a good range changes the map (so the checks above
    // could have failed).
    EXPECT_NE(engine.addRange(a, b, max_m), RangeVerdict::RejectedValue);
    EXPECT_NE(engine.revision(), revision);
    EXPECT_FALSE(sameLinks(links_before, engine.links()));
}

TEST(Engine, VerdictNamesAreDistinct)
{
    const RangeVerdict all[] = {RangeVerdict::Used, RangeVerdict::Stored, RangeVerdict::RejectedSelf,
                                RangeVerdict::RejectedValue};
    for (size_t i = 0; i < std::size(all); ++i) {
        EXPECT_GT(std::strlen(engine::rangeVerdictName(all[i])), 0U);
        for (size_t j = i + 1; j < std::size(all); ++j) {
            EXPECT_STRNE(engine::rangeVerdictName(all[i]), engine::rangeVerdictName(all[j]));
        }
    }
}

TEST(Engine, RangesWaitOnTheirLinkUntilBothEndsArePlaced)
{
    Engine engine;
    // Two nodes cannot be placed by one range: it is stored, not used.
    EXPECT_EQ(engine.addRange(1, 2, 5.0), RangeVerdict::Stored);
    EXPECT_EQ(engine.addRange(2, 1, 5.2), RangeVerdict::Stored);
    const auto links = engine.links();
    ASSERT_EQ(links.size(), 1U);
    EXPECT_EQ(links[0].a, 1);
    EXPECT_EQ(links[0].b, 2);
    EXPECT_EQ(links[0].range_count, 2U);
    EXPECT_DOUBLE_EQ(links[0].last_range_m, 5.2);
    EXPECT_DOUBLE_EQ(links[0].range_m, 5.1); // median of the window
    EXPECT_EQ(engine.counters().ranges_stored, 2U);
    for (const NodeOutput &node : engine.estimates()) {
        EXPECT_FALSE(node.placed());
    }
}

// ---- (d) fixed nodes ---------------------------------------------------------------------------

TestNetwork fixedTestNetwork(uint64_t seed)
{
    Random random(seed);
    return randomNetwork(random, 8, 6.0, false);
}

TEST(Engine, TwoOrMoreFixedNodesStayExactlyWhereGivenAndDefineTheFrame)
{
    const uint64_t seed = testSeed(3503);
    SCOPED_TRACE(seedTrace(seed));
    const TestNetwork network = fixedTestNetwork(seed);
    Random random(seed + 1);
    Engine engine;
    for (size_t i : {0U, 3U, 5U}) {
        engine.setFixed(network.ids[i], network.truth_m[i]);
    }
    feed(engine, network, roundRobin(network, random, 5, 0.0));
    const auto estimates = byId(engine.estimates());
    for (size_t i : {0U, 3U, 5U}) {
        const NodeOutput &node = estimates.at(network.ids[i]);
        EXPECT_TRUE(node.fixed());
        EXPECT_TRUE(node.placed());
        EXPECT_EQ(node.position_m, network.truth_m[i]); // bit for bit
        EXPECT_TRUE(node.covariance_m2.isZero(0.0));
    }
    // Their frame is the output frame: the others sit at their true coordinates, no alignment.
    double worst_m = 0.0;
    for (size_t i = 0; i < network.ids.size(); ++i) {
        const NodeOutput &node = estimates.at(network.ids[i]);
        ASSERT_TRUE(node.placed()) << node.id;
        worst_m = std::max(worst_m, (node.position_m - network.truth_m[i]).norm());
    }
    std::printf("three fixed nodes: largest error without alignment %.3g m\n", worst_m);
    EXPECT_LT(worst_m, 0.01);
    const engine::RigidTransform transform = engine.outputTransform();
    EXPECT_EQ(transform.rotation, Matrix2::Identity());
    EXPECT_EQ(transform.translation_m, Vector2::Zero());
    // The rings never describe a fixed node: its position is known.
    for (size_t i : {0U, 3U, 5U}) {
        EXPECT_TRUE(engine.ringsDescribing(network.ids[i]).empty());
    }
}

// Regression test: with exactly two fixed nodes the rest of the map must still be placed. Every
// node with two placed neighbours has two mirror-image candidates, and the MDS tie break that
// would decide needs three placed nodes to align its layout (alignedMdsLayout returns nothing
// for fewer); the re-initialization keeps the same placement. An engine that waits for that tie
// break places nothing else: on PLANT with nodes 1 and 2 fixed (`--fixed-csv` with their
// surveyed x, y) its output has those 2 nodes placed and 26 empty, while with 1, 2 and 3 fixed
// all 28 are placed. Two known points fix the frame up to the reflection through them, and
// either image is a valid answer.
TEST(Engine, TwoFixedNodesGiveTheFrameUpToTheMirrorThroughThem)
{
    const uint64_t seed = testSeed(3504);
    SCOPED_TRACE(seedTrace(seed));
    const TestNetwork network = fixedTestNetwork(seed);
    Random random(seed + 1);
    Engine engine;
    engine.setFixed(network.ids[1], network.truth_m[1]);
    engine.setFixed(network.ids[4], network.truth_m[4]);
    feed(engine, network, roundRobin(network, random, 5, 0.0));
    const auto estimates = byId(engine.estimates());
    EXPECT_EQ(estimates.at(network.ids[1]).position_m, network.truth_m[1]);
    EXPECT_EQ(estimates.at(network.ids[4]).position_m, network.truth_m[4]);
    // Two points fix position and rotation; the reflection across their line is left open.
    const Vector2 origin = network.truth_m[1];
    const Vector2 along = (network.truth_m[4] - origin).normalized();
    const auto mirrored = [&](const Vector2 &p) {
        const Vector2 d = p - origin;
        return Vector2(origin + 2.0 * d.dot(along) * along - d);
    };
    double direct_m = 0.0;
    double mirror_m = 0.0;
    for (size_t i = 0; i < network.ids.size(); ++i) {
        const NodeOutput &node = estimates.at(network.ids[i]);
        ASSERT_TRUE(node.placed()) << node.id;
        direct_m = std::max(direct_m, (node.position_m - network.truth_m[i]).norm());
        mirror_m = std::max(mirror_m, (node.position_m - mirrored(network.truth_m[i])).norm());
    }
    std::printf("two fixed nodes: largest error %.3g m as given, %.3g m mirrored\n", direct_m, mirror_m);
    EXPECT_LT(std::min(direct_m, mirror_m), 0.01);
}

TEST(Engine, OneFixedNodeIsOutputAtItsCoordinates)
{
    const uint64_t seed = testSeed(3505);
    SCOPED_TRACE(seedTrace(seed));
    const TestNetwork network = fixedTestNetwork(seed);
    Random random(seed + 1);
    Engine engine;
    const Vector2 known_m(100.25, -50.5); // anywhere: one node only says where the map sits
    engine.setFixed(network.ids[2], known_m);
    feed(engine, network, roundRobin(network, random, 5, 0.0));
    const auto estimates = engine.estimates();
    const auto by_id = byId(estimates);
    const NodeOutput &fixed = by_id.at(network.ids[2]);
    EXPECT_TRUE(fixed.fixed());
    EXPECT_EQ(fixed.position_m, known_m);
    // The rest is the map, shifted with it: the truth up to a rigid transform.
    const AlignedError error = alignedError(estimates, network.ids, network.truth_m);
    EXPECT_EQ(error.placed, network.ids.size());
    EXPECT_LT(error.rmse_m, 0.01);
    // And the distances from the fixed node are the true ones.
    for (size_t i = 0; i < network.ids.size(); ++i) {
        const double estimated = (by_id.at(network.ids[i]).position_m - known_m).norm();
        EXPECT_NEAR(estimated, (network.truth_m[i] - network.truth_m[2]).norm(), 0.02) << network.ids[i];
    }
}

TEST(Engine, FixedNodesMustComeBeforeTheFirstRange)
{
    Engine engine;
    engine.setFixed(7, Vector2(1.0, 2.0));
    engine.setFixed(7, Vector2(3.0, 4.0)); // before the first range: may be corrected
    engine.addRange(7, 8, 5.0);
    engine.addRange(8, 9, 5.0);
    EXPECT_THROW(engine.setFixed(9, Vector2(0.0, 0.0)), std::logic_error);
}

// ---- (e) the named frame -----------------------------------------------------------------------

void expectNamedFrame(const TestNetwork &network, size_t o, size_t x, size_t y)
{
    EngineParams params;
    params.frame.origin = network.ids[o];
    params.frame.x_axis = network.ids[x];
    params.frame.positive_y = network.ids[y];
    Random random(77);
    Engine engine(params);
    feed(engine, network, roundRobin(network, random, 5, 0.0));
    const auto estimates = byId(engine.estimates());
    const NodeOutput &origin = estimates.at(network.ids[o]);
    const NodeOutput &axis = estimates.at(network.ids[x]);
    const NodeOutput &third = estimates.at(network.ids[y]);
    EXPECT_NEAR(origin.position_m.norm(), 0.0, 1e-9);
    EXPECT_NEAR(axis.position_m.y(), 0.0, 1e-9);
    EXPECT_GT(axis.position_m.x(), 0.0);
    EXPECT_NEAR(axis.position_m.x(), (network.truth_m[x] - network.truth_m[o]).norm(), 0.01);
    EXPECT_GT(third.position_m.y(), 0.0);
    // Every node where the truth is in that frame (no alignment).
    const Vector2 unit_x = (network.truth_m[x] - network.truth_m[o]).normalized();
    Vector2 unit_y(-unit_x.y(), unit_x.x());
    if ((network.truth_m[y] - network.truth_m[o]).dot(unit_y) < 0.0) {
        unit_y = -unit_y;
    }
    double worst_m = 0.0;
    for (size_t i = 0; i < network.ids.size(); ++i) {
        const Vector2 d = network.truth_m[i] - network.truth_m[o];
        const Vector2 expected(d.dot(unit_x), d.dot(unit_y));
        worst_m = std::max(worst_m, (estimates.at(network.ids[i]).position_m - expected).norm());
    }
    EXPECT_LT(worst_m, 0.01);
}

TEST(Engine, NamedFramePutsOriginXAxisAndPositiveYWhereAsked)
{
    CDRO_SKIP_WHEN_SANITIZED();
    const uint64_t seed = testSeed(3506);
    SCOPED_TRACE(seedTrace(seed));
    Random random(seed);
    const TestNetwork network = randomNetwork(random, 8, 6.0, false);
    // Three nodes that ranged to each other and span a triangle: the frame triangle itself.
    bool found = false;
    for (size_t l = 0; l < network.links.size() && !found; ++l) {
        const auto [a, b] = network.links[l];
        for (size_t c = 0; c < network.ids.size() && !found; ++c) {
            const auto linked = [&](size_t p, size_t q) {
                for (const auto &[u, v] : network.links) {
                    if ((u == p && v == q) || (u == q && v == p)) {
                        return true;
                    }
                }
                return false;
            };
            const Vector2 ab = network.truth_m[b] - network.truth_m[a];
            const Vector2 ac = network.truth_m[c] - network.truth_m[a];
            const double height = std::abs(ab.x() * ac.y() - ab.y() * ac.x()) / std::max(ab.norm(), ac.norm());
            if (c != a && c != b && linked(a, c) && linked(b, c) && height > 2.0) {
                SCOPED_TRACE("linked triple");
                expectNamedFrame(network, c, a, b);
                found = true;
            }
        }
    }
    EXPECT_TRUE(found);
}

TEST(Engine, NamedFrameNeedNotBeLinked)
{
    const uint64_t seed = testSeed(3507);
    SCOPED_TRACE(seedTrace(seed));
    Random random(seed);
    const TestNetwork network = randomNetwork(random, 8, 5.0, false);
    // The two nodes farthest apart, and the node farthest from their line: they need not have
    // ranged to each other.
    size_t a = 0;
    size_t b = 1;
    for (size_t i = 0; i < network.ids.size(); ++i) {
        for (size_t j = i + 1; j < network.ids.size(); ++j) {
            if ((network.truth_m[i] - network.truth_m[j]).norm() > (network.truth_m[a] - network.truth_m[b]).norm()) {
                a = i;
                b = j;
            }
        }
    }
    bool ab_linked = false;
    for (const auto &[u, v] : network.links) {
        ab_linked = ab_linked || (u == a && v == b) || (u == b && v == a);
    }
    ASSERT_FALSE(ab_linked) << "the farthest pair should be out of range";
    size_t c = 0;
    double best = -1.0;
    for (size_t i = 0; i < network.ids.size(); ++i) {
        const Vector2 ab = network.truth_m[b] - network.truth_m[a];
        const Vector2 ai = network.truth_m[i] - network.truth_m[a];
        const double height = std::abs(ab.x() * ai.y() - ab.y() * ai.x());
        if (height > best) {
            best = height;
            c = i;
        }
    }
    expectNamedFrame(network, b, a, c);
}

// ---- (f) the ablation switches -----------------------------------------------------------------

// The merged SoG of eq. 12-14 from the rings that describe a node (each of weight 1).
Gaussian2 mergedRings(const Engine &engine, NodeId id)
{
    Vector2 first = Vector2::Zero();
    Matrix2 second = Matrix2::Zero();
    double total = 0.0;
    for (const engine::RingOutput &ring : engine.ringsDescribing(id)) {
        for (const engine::SogComponentState &c : ring.components) {
            first += c.weight * c.mean_m;
            second += c.weight * (c.covariance_m2 + c.mean_m * c.mean_m.transpose());
            total += c.weight;
        }
    }
    Gaussian2 merged;
    merged.mean_m = first / total;
    merged.covariance_m2 = second / total - merged.mean_m * merged.mean_m.transpose();
    return merged;
}

// The switches of the paper's filter, measured where they act. Weight transfer and the
// cooperative weights shape the SoGs, which are the estimate only in the paper's filter alone
// (no refinement, no global solve): there each switch changes the map. Each goes the way it is
// known to go over 30 seeded networks (the RMSE of the placed nodes, summed): without the
// cooperative weights the filter is worse (the paper's claim); without weight transfer it is
// better (docs/results.md, "The paper's Fig. 3 setting": eq. 15 throws a ring's evidence away);
// with the refinement the links decide. Measured over seeds 3501-3530: 55.5 m for the paper's
// filter, 97.2 m without the cooperative weights, 46.7 m without weight transfer, 2.1 m with the
// refinement (over 3501-3600: 158.6, 310.1, 117.6 and 8.0 m; network by network the switches go
// their way in 82 and 67 of the 100, so six networks were too few: the three sums went their way
// in 64 of the 95 runs of six consecutive seeds, and in all 71 runs of 30).
TEST(Engine, AblationSwitchesGoTheWayTheyAreKnownTo)
{
    CDRO_SKIP_WHEN_SANITIZED();
    struct Variant {
        const char *name;
        EngineParams params;
        double rmse_sum_m = 0.0;
    };
    EngineParams paper;
    paper.solve.enabled = false;
    paper.refinement.enabled = false;
    std::vector<Variant> variants(4, Variant{"", paper});
    variants[0].name = "the paper's filter";
    variants[1].name = "no weight transfer";
    variants[1].params.sog.weight_transfer = false;
    variants[2].name = "no cooperative";
    variants[2].params.sog.cooperative = false;
    variants[3].name = "with refinement";
    variants[3].params.refinement.enabled = true;
    bool first = true;
    for (uint64_t seed = 3501; seed <= 3530; ++seed) {
        SCOPED_TRACE(seedTrace(seed));
        Random random(seed);
        const TestNetwork network = randomNetwork(random, 8, 6.0, true);
        const std::vector<TestRange> ranges = noisyRanges(network, random, 5);
        std::vector<std::vector<NodeOutput>> results;
        std::vector<engine::EngineCounters> counters;
        for (Variant &variant : variants) {
            Engine engine(variant.params);
            feed(engine, network, ranges, false);
            const AlignedError error = alignedError(engine.estimates(), network.ids, network.truth_m);
            std::printf("seed %llu: %-19s %zu placed, %zu converged, aligned RMSE %.3f m\n",
                        static_cast<unsigned long long>(seed), variant.name, error.placed, error.converged,
                        error.rmse_m);
            EXPECT_GE(error.placed, 2U) << variant.name;
            variant.rmse_sum_m += error.rmse_m;
            results.push_back(engine.estimates());
            counters.push_back(engine.counters());
        }
        EXPECT_GT(counters[0].sogs.weight_transfers, 0U);
        EXPECT_EQ(counters[1].sogs.weight_transfers, 0U);
        EXPECT_EQ(counters[0].refinement.refinements, 0U);
        EXPECT_GT(counters[3].refinement.refinements, 0U);
        if (first) {
            for (size_t i = 1; i < results.size(); ++i) {
                EXPECT_FALSE(identical(results[0], results[i])) << variants[i].name;
            }
            first = false;
        }
    }
    const double paper_m = variants[0].rmse_sum_m;
    EXPECT_LT(variants[1].rmse_sum_m, paper_m) << "weight transfer throws evidence away";
    EXPECT_GT(variants[2].rmse_sum_m, paper_m) << "the cooperative weights help the filter";
    EXPECT_LT(variants[3].rmse_sum_m, 0.2 * variants[1].rmse_sum_m) << "the refinement makes the map";
}

// With refinement off the estimate is the merged SoG (eq. 12-14): checked on the node merged
// last after a range (the `to` node; no neighbour updates afterwards, so no ring has moved since).
double distanceOfLastMergedFromItsSog(bool refinement, double *covariance_difference_m2)
{
    Random random(3509);
    const TestNetwork network = randomNetwork(random, 8, 6.0, false);
    const std::vector<TestRange> ranges = noisyRanges(network, random, 4);
    EngineParams params;
    params.refinement.enabled = refinement;
    params.refinement.relax_per_range = 0;
    params.refinement.settle_per_placed = 0;
    Engine engine(params);
    double worst_m = 0.0;
    *covariance_difference_m2 = 0.0;
    size_t checked = 0;
    for (const TestRange &range : ranges) {
        if (engine.addRange(range.from, range.to, range.range_m) != RangeVerdict::Used) {
            continue;
        }
        const NodeOutput node = *engine.estimate(range.to);
        const Gaussian2 merged = mergedRings(engine, range.to);
        worst_m = std::max(worst_m, (node.position_m - merged.mean_m).norm());
        *covariance_difference_m2 =
            std::max(*covariance_difference_m2, (node.covariance_m2 - merged.covariance_m2).norm());
        ++checked;
    }
    EXPECT_GT(checked, ranges.size() / 2);
    return worst_m;
}

TEST(Engine, WithoutRefinementTheEstimateIsTheMergedSog)
{
    CDRO_SKIP_WHEN_SANITIZED();
    double covariance_m2 = 0.0;
    const double without_m = distanceOfLastMergedFromItsSog(false, &covariance_m2);
    EXPECT_LT(without_m, 1e-9);
    EXPECT_LT(covariance_m2, 1e-6); // m^2: summed in another order, with means ~100 m from the origin
    // With refinement the estimate is polished against the links instead: the check can fail.
    double refined_covariance_m2 = 0.0;
    const double with_m = distanceOfLastMergedFromItsSog(true, &refined_covariance_m2);
    std::printf("estimate - merged SoG: %.3g m without refinement, %.3g m with\n", without_m, with_m);
    EXPECT_GT(with_m, 0.01);
}

// ---- bugs found -----------------------------------------------------------------------------

// Regression test: while the map is still sparse, the re-initialization's MDS-MAP candidate must
// not place nodes that have fewer than two placed neighbours (here node 4434 would have none at
// all). If it does, a node with a single placed link takes its one ring's merged mean,
// and two such nodes linked to each other walk away together, about 11 m per range: after 8
// ranges of a 25 m network the outputs are 700 m from the origin, after 14 ranges 2.6 km. The
// aligned map is fine later on, but the output coordinates of a live run are absurd meanwhile,
// and the convergence averages lag the walk (one cause of nodes left unconverged after settle).
// The same 14 ranges through `cdro-hostd --ranges-csv F --out-csv O --trace-csv T
// --trace-every 1 --no-settle` show it.
TEST(Engine, OutputsStayNearTheNetworkWhileItIsBuilt)
{
    const TestRange ranges[] = {
        {4138, 4804, 12.320}, {4286, 4656, 5.224}, {4175, 4286, 11.120}, {4323, 4397, 9.077}, {4434, 4286, 12.522},
        {4434, 4508, 7.633},  {4656, 4582, 6.371}, {4730, 4656, 3.293},  {4693, 4619, 5.759}, {4249, 4730, 11.847},
        {4175, 4138, 6.700},  {4471, 4434, 6.325}, {4323, 4212, 10.902}, {4656, 4397, 4.110},
    };
    Engine engine;
    size_t count = 0;
    for (const TestRange &range : ranges) {
        engine.addRange(range.from, range.to, range.range_m);
        ++count;
        for (const NodeOutput &node : engine.estimates()) {
            if (!node.placed()) {
                continue;
            }
            // Every range is shorter than 13 m, the network is 6 links across at most.
            EXPECT_LT(node.position_m.norm(), 100.0) << "node " << node.id << " after " << count << " ranges";
            uint32_t placed_neighbours = 0;
            const engine::MapState &network = engine.map();
            const uint32_t index = network.findNode(node.id);
            for (uint32_t link : network.nodes[index].links) {
                placed_neighbours += network.nodes[network.otherNode(link, index)].placed() ? 1U : 0U;
            }
            EXPECT_GE(placed_neighbours, 1U) << "node " << node.id << " after " << count << " ranges";
        }
    }
}

// Regression test: with refinement off (`--no-refinement`, the paper's filter alone) the map must
// still come to rest. Otherwise each neighbour update re-weights and re-merges, nodes keep moving
// by more than relax_threshold_m, settle() always spends its whole budget, and no node is ever
// converged: on this network with exact ranges the whole map walks 97 m per 2000 updates
// (aligned RMSE 1.16 m); with noisy ranges it cycles. On PLANT `cdro-hostd --no-refinement`
// ends with 28 nodes placed and 0 converged (28 converged with refinement).
TEST(Engine, WithoutRefinementTheMapComesToRest)
{
    Random random(3508);
    const TestNetwork network = randomNetwork(random, 8, 6.0, true);
    Random stream(5);
    EngineParams params;
    params.refinement.enabled = false;
    Engine engine(params);
    feed(engine, network, roundRobin(network, stream, 5, 0.0));
    const auto before = byId(engine.estimates());
    const uint64_t updates = engine.settle(2000);
    EXPECT_LT(updates, 2000U) << "settle() should stop once nothing moves";
    double moved_m = 0.0;
    size_t converged = 0;
    for (const NodeOutput &node : engine.estimates()) {
        moved_m = std::max(moved_m, (node.position_m - before.at(node.id).position_m).norm());
        converged += node.converged() ? 1U : 0U;
    }
    EXPECT_LT(moved_m, 0.01);
    size_t doubted = 0;
    for (const NodeOutput &node : engine.estimates()) {
        doubted += !node.converged() && node.doubt != engine::NodeDoubt::Unsettled ? 1U : 0U;
    }
    EXPECT_EQ(converged + doubted, network.ids.size());
    // Every node placed (the global solve places what the filter's placement cannot decide). How
    // good the paper's filter alone is, is measured, not promised (docs/results.md): with weight
    // transfer it is metres here, without it a tenth of a metre.
    EXPECT_EQ(alignedError(engine.estimates(), network.ids, network.truth_m).placed, network.ids.size());
}

// Regression test, with OutputsStayNearTheNetworkWhileItIsBuilt: engine.hpp says the output
// frame is the named frame, else the frame triangle's (origin at (0, 0), x-axis node on +x,
// third on +y). When the re-initialization adopts its MDS-MAP candidate before a frame triangle
// was placed, frameNodes() must not stay empty for good: with an identity outputTransform() the
// outputs are in the engine's internal frame, wherever MDS and the refinement put it. An engine
// that picks the frame triangle only from the first placements has none at the end in 7 of 12
// eight-node networks (seeds 3500..3511) and on PLANT (no node is output at (0, 0)).
TEST(Engine, DefaultOutputFrameIsTheFrameTriangles)
{
    Random random(3506);
    const TestNetwork network = randomNetwork(random, 8, 6.0, false);
    Engine engine;
    feed(engine, network, roundRobin(network, random, 5, 0.0));
    const auto frame = engine.frameNodes();
    ASSERT_TRUE(frame.has_value());
    const auto estimates = byId(engine.estimates());
    EXPECT_NEAR(estimates.at((*frame)[0]).position_m.norm(), 0.0, 1e-9);
    EXPECT_NEAR(estimates.at((*frame)[1]).position_m.y(), 0.0, 1e-9);
    EXPECT_GT(estimates.at((*frame)[1]).position_m.x(), 0.0);
    EXPECT_GT(estimates.at((*frame)[2]).position_m.y(), 0.0);
}

// A node that will move (the robot's own tag, stage 2) must never be one of the output frame's
// nodes: the frame follows its nodes, and one that moves carries every output with it (the robot
// corridor's path read 15.7 m off, the robot pinned near (0, 0), when the first triangle the
// stage-1 map could form held the robot's tag). Here the first three links form the only
// triangle, and it holds the excluded node.
TEST(Engine, ANodeExcludedFromTheFrameIsNeverOneOfItsNodes)
{
    const std::vector<std::pair<NodeId, Vector2>> truth{
        {1, {0.0, 0.0}}, {2, {6.0, 0.0}}, {3, {2.0, 5.0}}, {4, {7.0, 6.0}}, {5, {-2.0, 7.0}}};
    auto distance = [&](NodeId a, NodeId b) { return (truth[a - 1].second - truth[b - 1].second).norm(); };
    Engine engine;
    engine.excludeFromFrame(1);
    const std::vector<std::pair<NodeId, NodeId>> order{{1, 2}, {1, 3}, {2, 3}, {1, 4}, {2, 4},
                                                       {3, 4}, {1, 5}, {3, 5}, {4, 5}, {2, 5}};
    for (int sweep = 0; sweep < 20; ++sweep) {
        for (const auto &[a, b] : order) {
            engine.addRange(a, b, distance(a, b));
        }
    }
    engine.settle(10000);
    const auto frame = engine.frameNodes();
    ASSERT_TRUE(frame.has_value());
    EXPECT_EQ(std::count(frame->begin(), frame->end(), NodeId{1}), 0);
    EXPECT_EQ(engine.estimates().size(), 5U);
    for (const NodeOutput &node : engine.estimates()) {
        EXPECT_TRUE(node.placed()) << node.id;
    }
}

// A node of the frame triangle that starts moving (a door, a cart): another triangle is picked
// and the outputs of the nodes that stay do not move. Before, the frame followed its origin node
// and every output went with it (here 3.6 m).
TEST(Engine, WhenAFrameNodeMovesTheOthersStayWhereTheyAreOutput)
{
    std::map<NodeId, Vector2> truth{{1, {0.0, 0.0}}, {2, {6.0, 0.0}},  {3, {2.0, 5.0}},
                                    {4, {7.0, 6.0}}, {5, {-2.0, 7.0}}, {6, {3.0, -4.0}}};
    Engine engine;
    auto sweep = [&]() {
        for (const auto &[a, pa] : truth) {
            for (const auto &[b, pb] : truth) {
                if (a < b) {
                    engine.addRange(a, b, (pa - pb).norm());
                }
            }
        }
    };
    for (int i = 0; i < 20; ++i) {
        sweep();
    }
    engine.settle(10000);
    const auto frame = engine.frameNodes();
    ASSERT_TRUE(frame.has_value());
    const NodeId carried = (*frame)[0];
    const auto before = byId(engine.estimates());

    engine.setMoving(carried, true);
    for (int step = 1; step <= 10; ++step) {
        truth[carried] += Vector2(0.3, 0.2);
        sweep();
    }
    engine.setMoving(carried, false);
    for (int i = 0; i < 10; ++i) {
        sweep();
    }
    engine.settle(10000);

    const auto after = byId(engine.estimates());
    const auto frame_after = engine.frameNodes();
    ASSERT_TRUE(frame_after.has_value());
    EXPECT_EQ(std::count(frame_after->begin(), frame_after->end(), carried), 0);
    for (const auto &[id, position] : truth) {
        if (id != carried) {
            EXPECT_LT((after.at(id).position_m - before.at(id).position_m).norm(), 0.05) << id;
        }
    }
    const Vector2 moved_m = after.at(carried).position_m - before.at(carried).position_m;
    EXPECT_NEAR(moved_m.norm(), std::hypot(3.0, 2.0), 0.1);
}

} // namespace
} // namespace cdro::enginetest
