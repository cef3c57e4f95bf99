// Anchors calibrated from the ranges of moving nodes alone (moving_calibration.hpp): a seeded,
// dense simulated flight of three tags under six nearly coplanar anchors (a 4 m x 4 m room,
// anchors at 1.6-1.9 m, their heights given, no anchor-to-anchor range) gives the anchors back
// within a stated bound after a rigid fit (the solution's frame is its own), and the tags' batch
// positions with them; the same input gives the same output bit for bit; bad input is refused.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <stdexcept>
#include <utility>
#include <vector>

#include "cdro/engine/alignment.hpp"
#include "cdro/engine/moving_calibration.hpp"
#include "simulated_flight.hpp"
#include "support.hpp"

namespace cdro::enginetest {
namespace {

using namespace cdro::engine; // NOLINT(google-build-using-namespace): the engine's types throughout

constexpr std::array<NodeId, 3> kTags = {10, 20, 30};

std::vector<NodeId> tags() { return {kTags.begin(), kTags.end()}; }

// In every 4 slots of 0.1 s, 3 tag-anchor ranges and one tag-to-tag range (the pairs in turn).
std::vector<CalibrationRange> simulate(uint64_t seed)
{
    FlightSchedule schedule;
    schedule.slots_per_cycle = 4;
    std::vector<CalibrationRange> out;
    for (const FlightRange &r : simulateFlight(seed, tags(), schedule)) {
        out.push_back({r.t_s, r.from, r.to, r.range_m});
    }
    return out;
}

std::vector<std::pair<NodeId, double>> heights()
{
    std::vector<std::pair<NodeId, double>> out;
    for (size_t a = 0; a < kFlightAnchors.size(); ++a) {
        out.emplace_back(kFlightAnchors[a], kFlightAnchorPositionsM[a].z());
    }
    return out;
}

TEST(MovingCalibration, AnchorsComeBackFromADenseSimulatedFlight)
{
    // Stated bound: the anchors' horizontal RMSE after a rigid fit (rotation, translation,
    // reflection) at most 0.15 m, the tags' 3D RMSE under the same fit at most 0.35 m. Observed on
    // seeds 1-3: anchors 0.056-0.087 m, tags 0.223-0.258 m (printed).
    for (uint64_t seed : testSeeds({1, 2, 3})) {
        SCOPED_TRACE(seedTrace(seed));
        MovingCalibration calibration(MovingCalibrationParams{}, MotionParams{});
        const std::vector<CalibratedAnchor> anchors = calibration.solve(simulate(seed), tags(), heights());
        ASSERT_EQ(anchors.size(), kFlightAnchors.size());
        std::vector<Vector2> estimate;
        std::vector<Vector2> target;
        for (size_t a = 0; a < anchors.size(); ++a) {
            EXPECT_EQ(anchors[a].id, kFlightAnchors[a]);
            EXPECT_TRUE(anchors[a].height_given);
            EXPECT_EQ(anchors[a].position_m.z(), kFlightAnchorPositionsM[a].z());
            estimate.push_back(anchors[a].position_m.head<2>());
            target.push_back(kFlightAnchorPositionsM[a].head<2>());
        }
        const RigidTransform fit = fitRigid(estimate, target, true);
        double tags_m2 = 0.0;
        for (const CalibratedEpoch &epoch : calibration.epochs()) {
            size_t k = 0;
            while (kTags[k] != epoch.id) {
                ++k;
            }
            const Eigen::Vector3d aligned(fit.apply(epoch.position_m.head<2>()).x(),
                                          fit.apply(epoch.position_m.head<2>()).y(), epoch.position_m.z());
            tags_m2 += (aligned - flightTagPositionM(k, epoch.t_s)).squaredNorm();
        }
        const double tags_rmse_m = std::sqrt(tags_m2 / static_cast<double>(calibration.epochs().size()));
        const MovingCalibrationCounters &c = calibration.counters();
        std::printf("calibration, %s: anchors' aligned RMSE %.3f m (horizontal), tags' %.3f m (3D, %zu epochs); "
                    "%llu of %llu windows placed, %u + %u iterations, residual RMS %.3f m\n",
                    seedTrace(seed).c_str(), fit.rms_error_m, tags_rmse_m, calibration.epochs().size(),
                    static_cast<unsigned long long>(c.windows_placed), static_cast<unsigned long long>(c.windows),
                    c.static_iterations, c.batch_iterations, c.rms_residual_m);
        EXPECT_LE(fit.rms_error_m, 0.15);
        EXPECT_LE(tags_rmse_m, 0.35);
    }
}

TEST(MovingCalibration, TheSameInputGivesTheSameOutputBitForBit)
{
    const uint64_t seed = testSeed(4);
    SCOPED_TRACE(seedTrace(seed));
    const std::vector<CalibrationRange> ranges = simulate(seed);
    auto run = [&]() {
        MovingCalibration calibration(MovingCalibrationParams{}, MotionParams{});
        std::vector<double> out;
        for (const CalibratedAnchor &anchor : calibration.solve(ranges, tags(), heights())) {
            out.insert(out.end(), anchor.position_m.data(), anchor.position_m.data() + 3);
        }
        for (const CalibratedEpoch &epoch : calibration.epochs()) {
            out.push_back(epoch.t_s);
            out.insert(out.end(), epoch.position_m.data(), epoch.position_m.data() + 3);
        }
        return out;
    };
    const std::vector<double> a = run();
    const std::vector<double> b = run();
    ASSERT_EQ(a.size(), b.size());
    ASSERT_FALSE(a.empty());
    EXPECT_EQ(0, std::memcmp(a.data(), b.data(), a.size() * sizeof(double)));
}

TEST(MovingCalibration, BadInputIsRefusedByName)
{
    MovingCalibration calibration(MovingCalibrationParams{}, MotionParams{});
    std::vector<CalibrationRange> three_anchors;
    for (const CalibrationRange &r : simulate(testSeed(5))) {
        if (r.b == kFlightAnchors[0] || r.b == kFlightAnchors[1] || r.b == kFlightAnchors[2]) {
            three_anchors.push_back(r);
        }
    }
    EXPECT_THROW(calibration.solve(three_anchors, tags(), heights()), std::invalid_argument);
    std::vector<NodeId> with_silent = tags();
    with_silent.push_back(99); // no range
    EXPECT_THROW(calibration.solve(simulate(testSeed(5)), with_silent, heights()), std::invalid_argument);
}

} // namespace
} // namespace cdro::enginetest
