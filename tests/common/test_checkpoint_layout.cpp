#include <string>

#include <gtest/gtest.h>

#include "cdro/checkpoint_layout.h"
#include "golden.hpp"

namespace {

// tests/golden/checkpoint_service_info.json is read by the Python codec too (tests/tools/test_layout.py).
nlohmann::json serviceInfoVector()
{
    return nlohmann::json::parse(golden::readFile(std::string(CDRO_GOLDEN_DIR) + "/checkpoint_service_info.json"));
}

TEST(CheckpointLayout, ServiceInfoEncodesToTheGoldenBytes)
{
    const auto v = serviceInfoVector();
    EXPECT_EQ(v["tag"].get<unsigned>(), CDRO_CHECKPOINT_TAG_SERVICE);
    cdro_service_info_t block{};
    block.version = 0; // the encoder writes this build's version whatever it is given
    block.run_start_unix_us = v["fields"]["run_start_unix_us"].get<int64_t>();
    block.last_event_unix_us = v["fields"]["last_event_unix_us"].get<int64_t>();
    block.frames_delivered = v["fields"]["frames_delivered"].get<uint64_t>();
    std::vector<uint8_t> bytes(CDRO_SERVICE_INFO_MAX_SIZE);
    ASSERT_EQ(cdro_service_info_encode(&block, bytes.data()), bytes.size());
    EXPECT_EQ(golden::toHex(bytes), v["bytes"].get<std::string>());
}

TEST(CheckpointLayout, ServiceInfoDecodesTheGoldenBytesAndIgnoresAppendedOnes)
{
    const auto v = serviceInfoVector();
    std::vector<uint8_t> bytes = golden::fromHex(v["bytes"]);
    bytes.push_back(0xAB); // a later version's field
    cdro_service_info_t block{};
    ASSERT_EQ(cdro_service_info_decode(bytes.data(), bytes.size(), &block), CDRO_OK);
    EXPECT_EQ(block.version, CDRO_CHECKPOINT_SERVICE_INFO_VERSION);
    EXPECT_EQ(block.run_start_unix_us, v["fields"]["run_start_unix_us"].get<int64_t>());
    EXPECT_EQ(block.last_event_unix_us, v["fields"]["last_event_unix_us"].get<int64_t>());
    EXPECT_EQ(block.frames_delivered, v["fields"]["frames_delivered"].get<uint64_t>());
}

TEST(CheckpointLayout, ServiceInfoRefusesShortBlocksAndOtherVersions)
{
    std::vector<uint8_t> bytes = golden::fromHex(serviceInfoVector()["bytes"]);
    cdro_service_info_t block{};
    EXPECT_EQ(cdro_service_info_decode(bytes.data(), bytes.size() - 1, &block), CDRO_ERR_LENGTH);
    bytes[0] = CDRO_CHECKPOINT_SERVICE_INFO_VERSION + 1U;
    EXPECT_EQ(cdro_service_info_decode(bytes.data(), bytes.size(), &block), CDRO_ERR_VERSION);
}

} // namespace
