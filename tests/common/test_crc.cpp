#include <cstring>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "cdro/crc.h"
#include "golden.hpp"

namespace {

std::vector<uint8_t> ascii(const std::string &text) { return {text.begin(), text.end()}; }

TEST(Crc16, GoldenCheckValues)
{
    for (const auto &v : golden::vectors()["checksums"]["crc16_ccitt_false"]) {
        const auto data = ascii(v["ascii"].get<std::string>());
        EXPECT_EQ(cdro_crc16(data.data(), data.size()), v["crc"].get<uint16_t>()) << v["ascii"];
    }
}

TEST(Crc16, CheckValueOf123456789Is0x29B1)
{
    const auto data = ascii("123456789");
    EXPECT_EQ(cdro_crc16(data.data(), data.size()), 0x29B1);
}

TEST(Crc32, GoldenCheckValues)
{
    for (const auto &v : golden::vectors()["checksums"]["crc32_iso_hdlc"]) {
        const auto data = ascii(v["ascii"].get<std::string>());
        EXPECT_EQ(cdro_crc32(data.data(), data.size()), v["crc"].get<uint32_t>()) << v["ascii"];
    }
}

// Incremental computation over any chunking equals the one-shot result.
TEST(Crc, IncrementalEqualsOneShotForRandomChunking)
{
    const unsigned seed = 20261122;
    std::printf("seed %u\n", seed);
    std::mt19937 rng(seed);
    for (int trial = 0; trial < 200; ++trial) {
        std::vector<uint8_t> data(rng() % 300);
        for (auto &b : data) {
            b = static_cast<uint8_t>(rng());
        }
        uint16_t crc16 = CDRO_CRC16_INIT;
        uint32_t crc32 = CDRO_CRC32_INIT;
        size_t offset = 0;
        while (offset < data.size()) {
            const size_t chunk = std::min<size_t>(rng() % 17, data.size() - offset);
            crc16 = cdro_crc16_update(crc16, data.data() + offset, chunk);
            crc32 = cdro_crc32_update(crc32, data.data() + offset, chunk);
            offset += chunk;
        }
        EXPECT_EQ(crc16, cdro_crc16(data.data(), data.size()));
        EXPECT_EQ(cdro_crc32_final(crc32), cdro_crc32(data.data(), data.size()));
    }
}

TEST(Crc16, DetectsEverySingleBitFlip)
{
    const auto data = ascii("CDRO frame header and payload");
    const uint16_t reference = cdro_crc16(data.data(), data.size());
    for (size_t bit = 0; bit < data.size() * 8; ++bit) {
        auto flipped = data;
        flipped[bit / 8] = static_cast<uint8_t>(flipped[bit / 8] ^ (1U << (bit % 8)));
        EXPECT_NE(cdro_crc16(flipped.data(), flipped.size()), reference) << "bit " << bit;
    }
}

} // namespace
