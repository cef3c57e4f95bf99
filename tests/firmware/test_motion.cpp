// Motion detection (firmware/core/src/motion.c) on constructed and recorded-like traces.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "cdro_fw/motion.h"
#include "support.hpp"

namespace {

cdro_accel_t along_z(int16_t z_mg) { return cdro_accel_t{0, 0, z_mg}; }

TEST(Motion, NormIsRoundedToTheNearestMilliG)
{
    const uint64_t seed = fwtest::testSeed(31);
    std::mt19937_64 rng(seed);
    std::uniform_int_distribution<int> axis(-32768, 32767);
    for (int i = 0; i < 200000; ++i) {
        const cdro_accel_t a{static_cast<int16_t>(axis(rng)), static_cast<int16_t>(axis(rng)),
                             static_cast<int16_t>(axis(rng))};
        const double exact = std::sqrt(static_cast<double>(a.x_mg) * a.x_mg + static_cast<double>(a.y_mg) * a.y_mg +
                                       static_cast<double>(a.z_mg) * a.z_mg);
        ASSERT_LE(std::fabs(cdro_accel_norm_mg(&a) - exact), 0.5) << a.x_mg << " " << a.y_mg << " " << a.z_mg;
    }
    const cdro_accel_t extreme{-32768, -32768, -32768};
    EXPECT_EQ(cdro_accel_norm_mg(&extreme), 56756) << "sqrt(3) * 32768 = 56755.8";
    const cdro_accel_t rest{0, 0, 1000};
    EXPECT_EQ(cdro_accel_norm_mg(&rest), 1000);
}

TEST(Motion, StartsStillAndStaysStillUnderSensorNoise)
{
    cdro_motion_detector_t m;
    cdro_motion_detector_init(&m);
    std::mt19937_64 rng(fwtest::testSeed(32));
    std::normal_distribution<double> noise(0.0, 8.0); // mg per axis, a real sensor at rest
    for (int i = 0; i < 5000; ++i) {
        const cdro_accel_t a{static_cast<int16_t>(std::lround(noise(rng))),
                             static_cast<int16_t>(std::lround(noise(rng))),
                             static_cast<int16_t>(std::lround(1000.0 + noise(rng)))};
        ASSERT_EQ(cdro_motion_detector_update(&m, &a), 0) << "sample " << i;
    }
    EXPECT_EQ(m.moving, 0);
}

TEST(Motion, MovingOnlyWhenTheDeviationExceeds80)
{
    cdro_motion_detector_t m;
    cdro_motion_detector_init(&m);
    const cdro_accel_t at80 = along_z(1080);
    const cdro_accel_t below80 = along_z(920);
    for (int i = 0; i < 20; ++i) {
        EXPECT_EQ(cdro_motion_detector_update(&m, &at80), 0);
        EXPECT_EQ(cdro_motion_detector_update(&m, &below80), 0);
    }
    EXPECT_EQ(m.window_deviation_mg, 80);
    const cdro_accel_t at81 = along_z(919);
    EXPECT_EQ(cdro_motion_detector_update(&m, &at81), 1);
    EXPECT_EQ(m.moving, 1);
    EXPECT_EQ(m.window_deviation_mg, 81);
    EXPECT_EQ(m.norm_mg, 919);
}

TEST(Motion, StillAfterTheWindowClearsAnd16QuietSamples)
{
    cdro_motion_detector_t m;
    cdro_motion_detector_init(&m);
    const cdro_accel_t shake = along_z(1300);
    const cdro_accel_t quiet = along_z(1039); // deviation 39 < 40
    ASSERT_EQ(cdro_motion_detector_update(&m, &shake), 1);
    // The shake stays in the 8-sample window for 7 more samples, then 16 below 40 are needed:
    // the 23rd quiet sample makes the node still.
    for (int i = 1; i <= 22; ++i) {
        ASSERT_EQ(cdro_motion_detector_update(&m, &quiet), 0) << "quiet sample " << i;
        ASSERT_EQ(m.moving, 1);
    }
    EXPECT_EQ(cdro_motion_detector_update(&m, &quiet), 1);
    EXPECT_EQ(m.moving, 0);
    EXPECT_EQ(m.window_deviation_mg, 39);
}

TEST(Motion, HysteresisBandKeepsEitherState)
{
    cdro_motion_detector_t m;
    cdro_motion_detector_init(&m);
    const cdro_accel_t band = along_z(1060); // between 40 and 80
    for (int i = 0; i < 50; ++i) {
        ASSERT_EQ(cdro_motion_detector_update(&m, &band), 0);
    }
    EXPECT_EQ(m.moving, 0);
    const cdro_accel_t shake = along_z(700);
    ASSERT_EQ(cdro_motion_detector_update(&m, &shake), 1);
    for (int i = 0; i < 50; ++i) {
        ASSERT_EQ(cdro_motion_detector_update(&m, &band), 0) << "a node moving gently stays moving";
    }
    EXPECT_EQ(m.moving, 1);
    // A single quiet-band interruption restarts the still count.
    const cdro_accel_t quiet = along_z(1000);
    for (int i = 0; i < 15; ++i) {
        ASSERT_EQ(cdro_motion_detector_update(&m, &quiet), 0);
    }
    ASSERT_EQ(cdro_motion_detector_update(&m, &band), 0);
    for (int i = 0; i < 15; ++i) {
        ASSERT_EQ(cdro_motion_detector_update(&m, &quiet), 0);
    }
    EXPECT_EQ(m.moving, 1);
}

// A recorded-like trace: a tag at rest, carried by a walking person (vertical bounce at the
// step frequency, forward sway, tilt), put down again; sampled every 200 ms (motion_poll_ms).
TEST(Motion, WalkTraceGivesExactlyTwoChangesAtTheRightTimes)
{
    std::mt19937_64 rng(fwtest::testSeed(33));
    std::normal_distribution<double> noise(0.0, 6.0);
    cdro_motion_detector_t m;
    cdro_motion_detector_init(&m);
    std::vector<double> changes_s;
    for (int k = 0; k < 150; ++k) { // 30 s
        const double t = k * 0.2;
        const bool walking = t >= 10.0 && t < 20.0;
        double x = 0.0;
        double y = 0.0;
        double z = 1000.0;
        if (walking) {
            const double step_hz = 1.8;
            z += 220.0 * std::sin(2.0 * M_PI * step_hz * t);
            x += 90.0 * std::sin(2.0 * M_PI * step_hz * t + 1.0);
            y += 60.0 * std::sin(2.0 * M_PI * step_hz / 2.0 * t);
        }
        // At rest after the walk, on a slight tilt: the norm is still 1 g.
        if (t >= 20.0) {
            x = 1000.0 * std::sin(0.1);
            z = 1000.0 * std::cos(0.1);
        }
        const cdro_accel_t a{static_cast<int16_t>(std::lround(x + noise(rng))),
                             static_cast<int16_t>(std::lround(y + noise(rng))),
                             static_cast<int16_t>(std::lround(z + noise(rng)))};
        if (cdro_motion_detector_update(&m, &a) != 0U) {
            changes_s.push_back(t);
        }
    }
    ASSERT_EQ(changes_s.size(), 2U);
    EXPECT_GE(changes_s[0], 10.0);
    EXPECT_LE(changes_s[0], 10.6) << "moving within 3 samples of the first step";
    EXPECT_GE(changes_s[1], 20.0 + 22 * 0.2) << "still only after the window and 16 quiet samples";
    EXPECT_LE(changes_s[1], 20.0 + 24 * 0.2);
}

} // namespace
