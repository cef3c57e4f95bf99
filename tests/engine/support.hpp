// Test support for the engine suites: seeded randomness that can be replayed, random planar
// networks with their range streams, aligned errors against the truth, and the PLANT data.
//
// Randomness: netgen's seeded stream (cdro/netgen/random.hpp), so that a seed gives the same
// network on every standard library, drawn as cdro-netgen and the building families draw.
// Every randomised test prints its seed; the environment variable CDRO_TEST_SEED replays one (as
// tests/firmware does).
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "cdro/engine/engine.hpp"
#include "cdro/netgen/geometric.hpp"
#include "cdro/netgen/random.hpp"

namespace cdro::enginetest {

using engine::NodeId;
using engine::Vector2;

// The sanitized build (CDRO_SANITIZE) runs the engine about 250 times slower (Debug Eigen under
// ASan): the heaviest cases then run in the native build only, and say so when skipped.
#ifdef CDRO_TEST_SANITIZED
constexpr bool kSanitizedBuild = true;
#else
constexpr bool kSanitizedBuild = false;
#endif
#define CDRO_SKIP_WHEN_SANITIZED()                                                                         \
    do {                                                                                                   \
        if (::cdro::enginetest::kSanitizedBuild) {                                                         \
            GTEST_SKIP() << "sanitized build: the engine runs ~10-80x slower here; this test runs in the " \
                            "native build";                                                                \
        }                                                                                                  \
    } while (false)

// The seeds a randomised test runs with: CDRO_TEST_SEED alone when set, else `defaults`.
// Each is printed when used (seedTrace below), so a failure names the one to replay.
std::vector<uint64_t> testSeeds(const std::vector<uint64_t> &defaults);
uint64_t testSeed(uint64_t fallback);
std::string seedTrace(uint64_t seed); // "seed N (set CDRO_TEST_SEED=N to replay)"

// The tests' stream is netgen's (one definition of the seeded draws for tests, benchmarks and
// tools).
using Random = netgen::Random;

// A point with both coordinates uniform in [low_m, high_m), and one with both standard normal.
// y is drawn before x: the order GCC evaluated `Vector2(random.uniform(..), random.uniform(..))`
// in, which these tests were written with; as two statements the order no longer depends on the
// compiler, and every seeded case draws what it drew.
Vector2 uniformPoint(netgen::RandomSource &random, double low_m, double high_m);
Vector2 normalPoint(netgen::RandomSource &random);

struct TestNetwork {
    std::vector<NodeId> ids;
    std::vector<Vector2> truth_m;                 // m
    std::vector<double> height_m;                 // m, empty when the network is planar
    std::vector<std::pair<size_t, size_t>> links; // indices into ids
    double trueRange(size_t link) const;          // m, 3D when heights are set
};

// netgen's geometric network (cdro/netgen/geometric.hpp) with the tests' options: nodes uniformly
// in a square (one node per 25 m^2), no two closer than 1 m, heights 0..3 m if `heights`, ids
// 0x1000 + 37 i + 5, linked to the shortest pairs for a mean degree of exactly `degree`. Redrawn
// (on `random`) until every node has at least 3 links and the network is globally rigid:
// otherwise the ranges themselves allow another map, and no engine could be asked to find the
// true one.
TestNetwork randomNetwork(Random &random, size_t nodes, double degree, bool heights);

// A network drawn by netgen (cdro/netgen/geometric.hpp) as the tests hold it.
TestNetwork fromGeometric(const netgen::GeometricNetwork &drawn);

// netgen::globallyRigid (cdro/netgen/rigidity.hpp) on the network's true positions.
bool globallyRigid(const TestNetwork &network, Random &random);

struct TestRange {
    NodeId from = 0;
    NodeId to = 0;
    double range_m = 0.0;
};

// `sweeps` passes over every link, each pass in a fresh random order and random direction;
// Gaussian noise of noise_sigma_m (0: exact ranges).
std::vector<TestRange> roundRobin(const TestNetwork &network, Random &random, uint32_t sweeps, double noise_sigma_m);

// Feeds the network's heights and the ranges to the engine, then settles it.
void feed(engine::Engine &engine, const TestNetwork &network, const std::vector<TestRange> &ranges, bool settle = true);

// Aligned RMSE (rigid fit with reflection, no scale) of the placed estimates against the truth
// of the same ids. Returns nullopt if fewer than 2 nodes are placed; *placed counts them.
struct AlignedError {
    double rmse_m = 0.0;
    double max_m = 0.0;
    size_t placed = 0;
    size_t converged = 0;
    size_t nodes = 0; // nodes with at least one link
};
AlignedError alignedError(const std::vector<engine::NodeOutput> &estimates, const std::vector<NodeId> &ids,
                          const std::vector<Vector2> &truth_m);

// Bitwise equality of two estimate lists (every field, doubles by their bytes).
bool identical(const std::vector<engine::NodeOutput> &a, const std::vector<engine::NodeOutput> &b);

// The PLANT data (shared/data/README.md): $CDRO_DATA_DIR/plant, else ../shared/data/plant from
// the repository root. nullopt when it is not there; `where` says where it was looked for.
struct PlantData {
    std::vector<TestRange> ranges; // file order
    std::vector<NodeId> ids;       // every surveyed node
    std::vector<Vector2> truth_m;  // m
    std::vector<double> height_m;  // m
};
std::optional<PlantData> loadPlant(std::string *where);

} // namespace cdro::enginetest
