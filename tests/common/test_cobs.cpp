#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "cdro/cobs.h"
#include "golden.hpp"

namespace {

TEST(Cobs, GoldenVectorsEncodeAndDecode)
{
    for (const auto &v : golden::vectors()["cobs"]) {
        const auto decoded = golden::fromHex(v["decoded"]);
        const auto encoded = golden::fromHex(v["encoded"]);
        std::vector<uint8_t> out(CDRO_COBS_MAX_ENCODED(decoded.size()));
        const size_t n = cdro_cobs_encode(decoded.data(), decoded.size(), out.data(), out.size());
        out.resize(n);
        EXPECT_EQ(golden::toHex(out), v["encoded"].get<std::string>()) << v["name"];

        std::vector<uint8_t> back(decoded.size() + 1);
        const long m = cdro_cobs_decode(encoded.data(), encoded.size(), back.data(), back.size());
        ASSERT_GE(m, 0) << v["name"];
        back.resize(static_cast<size_t>(m));
        EXPECT_EQ(back, decoded) << v["name"];
    }
}

TEST(Cobs, EncodingNeverContainsZeroAndRoundTrips)
{
    const unsigned seed = 7;
    std::printf("seed %u\n", seed);
    std::mt19937 rng(seed);
    for (int trial = 0; trial < 500; ++trial) {
        std::vector<uint8_t> data(rng() % 700);
        const unsigned zero_chance = rng() % 4;
        for (auto &b : data) {
            b = (rng() % 4 < zero_chance) ? 0 : static_cast<uint8_t>(1 + rng() % 255);
        }
        std::vector<uint8_t> encoded(CDRO_COBS_MAX_ENCODED(data.size()));
        const size_t n = cdro_cobs_encode(data.data(), data.size(), encoded.data(), encoded.size());
        ASSERT_GT(n, 0U);
        ASSERT_LE(n, CDRO_COBS_MAX_ENCODED(data.size()));
        for (size_t i = 0; i < n; ++i) {
            ASSERT_NE(encoded[i], 0);
        }
        std::vector<uint8_t> back(data.size());
        ASSERT_EQ(cdro_cobs_decode(encoded.data(), n, back.data(), back.size()), static_cast<long>(data.size()));
        EXPECT_EQ(back, data);
    }
}

TEST(Cobs, EncodeRefusesATooSmallBuffer)
{
    const std::vector<uint8_t> data(10, 0x55);
    std::vector<uint8_t> out(10); // needs 11
    EXPECT_EQ(cdro_cobs_encode(data.data(), data.size(), out.data(), out.size()), 0U);
}

TEST(Cobs, DecodeRejectsInvalidInput)
{
    std::vector<uint8_t> out(16);
    const std::vector<std::vector<uint8_t>> invalid = {
        {},                 // empty: an encoding is never empty
        {0x05, 0x01, 0x02}, // block runs past the end
        {0x03, 0x00, 0x01}, // zero inside
        {0x00},             // zero code
    };
    for (const auto &bytes : invalid) {
        EXPECT_EQ(cdro_cobs_decode(bytes.data(), bytes.size(), out.data(), out.size()), -1) << golden::toHex(bytes);
    }
    const std::vector<uint8_t> long_block = {0x05, 0x01, 0x02, 0x03, 0x04};
    EXPECT_EQ(cdro_cobs_decode(long_block.data(), long_block.size(), out.data(), 3), -1) << "output too small";
}

} // namespace
