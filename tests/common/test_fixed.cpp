#include <cmath>
#include <string>

#include <gtest/gtest.h>

#include "cdro/fixed.h"
#include "golden.hpp"

namespace {

double parse(const nlohmann::json &value) { return std::stod(value.get<std::string>()); }

TEST(Fixed, GoldenConversionsRoundHalfAwayFromZeroAndSaturate)
{
    const auto &v = golden::vectors()["fixed"];
    for (const auto &c : v["mm_from_m"]) {
        EXPECT_EQ(cdro_fixed_mm_from_m(parse(c["in"])), c["out"].get<int64_t>()) << c["in"];
    }
    for (const auto &c : v["um_from_m"]) {
        EXPECT_EQ(cdro_fixed_um_from_m(parse(c["in"])), c["out"].get<int64_t>()) << c["in"];
    }
    for (const auto &c : v["q15_from"]) {
        EXPECT_EQ(cdro_fixed_q15_from(parse(c["in"])), c["out"].get<int64_t>()) << c["in"];
    }
    for (const auto &c : v["q16_from"]) {
        EXPECT_EQ(cdro_fixed_q16_from(parse(c["in"])), c["out"].get<int64_t>()) << c["in"];
    }
    for (const auto &c : v["covariance_from"]) {
        const auto fixed = cdro_fixed_covariance_from(c["in"][0], c["in"][1], c["in"][2]);
        EXPECT_EQ(fixed.std_x_um, c["out"][0].get<int64_t>());
        EXPECT_EQ(fixed.std_y_um, c["out"][1].get<int64_t>());
        EXPECT_EQ(fixed.correlation_q15, c["out"][2].get<int64_t>());
    }
}

// The documented error bounds hold over a sweep of values.
TEST(Fixed, RoundTripsStayWithinTheDocumentedBounds)
{
    for (double metres = -1000.0; metres <= 1000.0; metres += 0.0137) {
        EXPECT_LE(std::fabs(cdro_fixed_mm_to_m(cdro_fixed_mm_from_m(metres)) - metres), 0.0005 + 1e-12);
    }
    for (double std_m = 0.0; std_m <= 50.0; std_m += 0.00731) {
        EXPECT_LE(std::fabs(cdro_fixed_um_to_m(cdro_fixed_um_from_m(std_m)) - std_m), 0.5e-6 + 1e-12);
    }
    for (double rho = -1.0; rho <= 1.0; rho += 0.001) {
        EXPECT_LE(std::fabs(cdro_fixed_q15_to(cdro_fixed_q15_from(rho)) - rho), 1.6e-5);
    }
    for (double w = 0.0; w <= 1.0; w += 0.0007) {
        EXPECT_LE(std::fabs(cdro_fixed_q16_to(cdro_fixed_q16_from(w)) - w), 7.7e-6);
    }
}

TEST(Fixed, CovarianceRoundTripIsSymmetricPositiveSemiDefinite)
{
    double var_x = 0.0;
    double cov_xy = 0.0;
    double var_y = 0.0;
    cdro_fixed_covariance_to(cdro_fixed_covariance_from(0.04, 0.015, 0.09), &var_x, &cov_xy, &var_y);
    EXPECT_NEAR(var_x, 0.04, 1e-9);
    EXPECT_NEAR(var_y, 0.09, 1e-9);
    EXPECT_NEAR(cov_xy, 0.015, 1e-6);
    EXPECT_GE(var_x * var_y - cov_xy * cov_xy, 0.0);
    // An indefinite input (|correlation| > 1) is clamped to a semi-definite one.
    cdro_fixed_covariance_to(cdro_fixed_covariance_from(1.0, 2.0, 1.0), &var_x, &cov_xy, &var_y);
    EXPECT_GE(var_x * var_y - cov_xy * cov_xy, -1e-12);
}

} // namespace
