#include <cstring>
#include <string>

#include <gtest/gtest.h>

#include "cdro/crc.h"
#include "cdro/layout_descriptor.h"
#include "golden.hpp"

namespace {

uint16_t hashOf(const char *text) { return cdro_crc16(reinterpret_cast<const uint8_t *>(text), std::strlen(text)); }

// Changing frame_layout.def without recording the new hash fails here; recording a new hash
// under an old protocol version fails the history test below.
TEST(LayoutHash, FrameLayoutHashMatchesTheTable)
{
    EXPECT_EQ(hashOf(CDRO_FRAME_LAYOUT_DESCRIPTOR), CDRO_LAYOUT_HASH)
        << "frame_layout.def changed: set CDRO_LAYOUT_HASH to 0x" << std::hex << hashOf(CDRO_FRAME_LAYOUT_DESCRIPTOR)
        << ", bump CDRO_PROTOCOL_VERSION and add the pair to tests/golden/layout_history.json";
}

TEST(LayoutHash, SogLayoutHashMatchesTheTable)
{
    EXPECT_EQ(hashOf(CDRO_SOG_LAYOUT_DESCRIPTOR), CDRO_SOG_LAYOUT_HASH)
        << "sog_layout.def changed: set CDRO_SOG_LAYOUT_HASH to 0x" << std::hex << hashOf(CDRO_SOG_LAYOUT_DESCRIPTOR)
        << ", bump CDRO_SOG_LAYOUT_VERSION and add the pair to tests/golden/layout_history.json";
}

TEST(LayoutHash, CaptureLayoutHashMatchesTheTable)
{
    EXPECT_EQ(hashOf(CDRO_CAPTURE_LAYOUT_DESCRIPTOR), CDRO_CAPTURE_LAYOUT_HASH)
        << "capture_layout.def changed: set CDRO_CAPTURE_LAYOUT_HASH to 0x" << std::hex
        << hashOf(CDRO_CAPTURE_LAYOUT_DESCRIPTOR)
        << ", bump CDRO_CAPTURE_FORMAT_VERSION and add the pair to tests/golden/layout_history.json";
}

TEST(LayoutHash, CheckpointLayoutHashMatchesTheTable)
{
    EXPECT_EQ(hashOf(CDRO_CHECKPOINT_LAYOUT_DESCRIPTOR), CDRO_CHECKPOINT_LAYOUT_HASH)
        << "checkpoint_layout.def changed: set CDRO_CHECKPOINT_LAYOUT_HASH to 0x" << std::hex
        << hashOf(CDRO_CHECKPOINT_LAYOUT_DESCRIPTOR)
        << ", bump CDRO_CHECKPOINT_SERVICE_INFO_VERSION and add the pair to tests/golden/layout_history.json";
}

TEST(LayoutHash, CheckpointBlockLayoutHashesMatchTheTables)
{
    EXPECT_EQ(hashOf(CDRO_CHECKPOINT_ENGINE_LAYOUT_DESCRIPTOR), CDRO_CHECKPOINT_ENGINE_LAYOUT_HASH)
        << "checkpoint_layout.def's engine block changed: set CDRO_CHECKPOINT_ENGINE_LAYOUT_HASH to 0x" << std::hex
        << hashOf(CDRO_CHECKPOINT_ENGINE_LAYOUT_DESCRIPTOR)
        << ", bump CDRO_CHECKPOINT_ENGINE_VERSION and add the pair to tests/golden/layout_history.json";
    EXPECT_EQ(hashOf(CDRO_CHECKPOINT_MOVEMENT_LAYOUT_DESCRIPTOR), CDRO_CHECKPOINT_MOVEMENT_LAYOUT_HASH)
        << "checkpoint_layout.def's movement block changed: set CDRO_CHECKPOINT_MOVEMENT_LAYOUT_HASH to 0x" << std::hex
        << hashOf(CDRO_CHECKPOINT_MOVEMENT_LAYOUT_DESCRIPTOR)
        << ", bump CDRO_CHECKPOINT_MOVEMENT_VERSION and add the pair to tests/golden/layout_history.json";
    EXPECT_EQ(hashOf(CDRO_CHECKPOINT_FLIGHT_LAYOUT_DESCRIPTOR), CDRO_CHECKPOINT_FLIGHT_LAYOUT_HASH)
        << "checkpoint_layout.def's flight block changed: set CDRO_CHECKPOINT_FLIGHT_LAYOUT_HASH to 0x" << std::hex
        << hashOf(CDRO_CHECKPOINT_FLIGHT_LAYOUT_DESCRIPTOR)
        << ", bump CDRO_CHECKPOINT_FLIGHT_VERSION and add the pair to tests/golden/layout_history.json";
    EXPECT_EQ(hashOf(CDRO_CHECKPOINT_OUTPUT_FRAME_LAYOUT_DESCRIPTOR), CDRO_CHECKPOINT_OUTPUT_FRAME_LAYOUT_HASH)
        << "checkpoint_layout.def's output frame block changed: set CDRO_CHECKPOINT_OUTPUT_FRAME_LAYOUT_HASH to 0x"
        << std::hex << hashOf(CDRO_CHECKPOINT_OUTPUT_FRAME_LAYOUT_DESCRIPTOR)
        << ", bump CDRO_CHECKPOINT_OUTPUT_FRAME_VERSION and add the pair to tests/golden/layout_history.json";
}

TEST(LayoutHash, EachVersionHasExactlyOneLayout)
{
    const auto history = nlohmann::json::parse(golden::readFile(std::string(CDRO_GOLDEN_DIR) + "/layout_history.json"));
    const std::string frame_version = std::to_string(CDRO_PROTOCOL_VERSION);
    const std::string sog_version = std::to_string(CDRO_SOG_LAYOUT_VERSION);
    ASSERT_TRUE(history["frames"].contains(frame_version)) << "record protocol version " << frame_version;
    ASSERT_TRUE(history["sog"].contains(sog_version)) << "record SoG layout version " << sog_version;
    EXPECT_EQ(std::stoul(history["frames"][frame_version].get<std::string>(), nullptr, 16), CDRO_LAYOUT_HASH);
    EXPECT_EQ(std::stoul(history["sog"][sog_version].get<std::string>(), nullptr, 16), CDRO_SOG_LAYOUT_HASH);
    const std::string capture_version = std::to_string(CDRO_CAPTURE_FORMAT_VERSION);
    ASSERT_TRUE(history["capture"].contains(capture_version)) << "record capture format version " << capture_version;
    EXPECT_EQ(std::stoul(history["capture"][capture_version].get<std::string>(), nullptr, 16),
              CDRO_CAPTURE_LAYOUT_HASH);
    const std::string checkpoint_version = std::to_string(CDRO_CHECKPOINT_SERVICE_INFO_VERSION);
    ASSERT_TRUE(history["checkpoint"].contains(checkpoint_version))
        << "record service block version " << checkpoint_version;
    EXPECT_EQ(std::stoul(history["checkpoint"][checkpoint_version].get<std::string>(), nullptr, 16),
              CDRO_CHECKPOINT_LAYOUT_HASH);
    const std::string engine_version = std::to_string(CDRO_CHECKPOINT_ENGINE_VERSION);
    ASSERT_TRUE(history["checkpoint_engine"].contains(engine_version))
        << "record engine block version " << engine_version;
    EXPECT_EQ(std::stoul(history["checkpoint_engine"][engine_version].get<std::string>(), nullptr, 16),
              CDRO_CHECKPOINT_ENGINE_LAYOUT_HASH);
    const std::string movement_version = std::to_string(CDRO_CHECKPOINT_MOVEMENT_VERSION);
    ASSERT_TRUE(history["checkpoint_movement"].contains(movement_version))
        << "record movement block version " << movement_version;
    EXPECT_EQ(std::stoul(history["checkpoint_movement"][movement_version].get<std::string>(), nullptr, 16),
              CDRO_CHECKPOINT_MOVEMENT_LAYOUT_HASH);
    const std::string flight_version = std::to_string(CDRO_CHECKPOINT_FLIGHT_VERSION);
    ASSERT_TRUE(history["checkpoint_flight"].contains(flight_version))
        << "record flight block version " << flight_version;
    EXPECT_EQ(std::stoul(history["checkpoint_flight"][flight_version].get<std::string>(), nullptr, 16),
              CDRO_CHECKPOINT_FLIGHT_LAYOUT_HASH);
    const std::string output_frame_version = std::to_string(CDRO_CHECKPOINT_OUTPUT_FRAME_VERSION);
    ASSERT_TRUE(history["checkpoint_output_frame"].contains(output_frame_version))
        << "record output frame block version " << output_frame_version;
    EXPECT_EQ(std::stoul(history["checkpoint_output_frame"][output_frame_version].get<std::string>(), nullptr, 16),
              CDRO_CHECKPOINT_OUTPUT_FRAME_LAYOUT_HASH);
}

} // namespace
