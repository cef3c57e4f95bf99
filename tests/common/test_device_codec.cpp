// The device-side frame codec (common/src/frames.c built with CDRO_FRAMES_DEVICE_SIDE, as in the
// firmware image): against the golden vectors, it encodes every device-to-host frame to the same
// bytes as the full codec, refuses to encode host-to-device ones, decodes host-to-device frames
// to the same fields, and answers a device-to-host frame as the device must (UNKNOWN_TYPE via
// CDRO_ERR_TYPE whatever its values, MALFORMED via CDRO_ERR_LENGTH for a wrong length) without
// decoding its fields. Linked against cdro_common_device_codec only.
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "cdro/cobs.h"
#include "cdro/crc.h"
#include "cdro/frames.h"
#include "golden.hpp"

namespace {

bool hostToDevice(uint8_t type) { return type >= 0x40; }

TEST(DeviceCodec, DeviceFramesEncodeAsTheFullCodecAndHostFramesDoNot)
{
    for (const auto &v : golden::vectors()["frames"]) {
        const cdro_frame_t frame = golden::frameFromJson(v);
        std::vector<uint8_t> out(CDRO_MAX_ENCODED_FRAME);
        out.resize(cdro_frame_encode(&frame, out.data(), out.size()));
        if (hostToDevice(frame.type)) {
            EXPECT_TRUE(out.empty()) << v["name"] << ": a device never sends a host frame";
        } else {
            EXPECT_EQ(golden::toHex(out), v["bytes"].get<std::string>()) << v["name"];
        }
    }
}

TEST(DeviceCodec, HostFramesDecodeAsTheFullCodecDeviceFramesAreRefusedByType)
{
    for (const auto &v : golden::vectors()["frames"]) {
        const auto bytes = golden::fromHex(v["bytes"]);
        cdro_frame_t frame;
        const cdro_result_t result = cdro_frame_decode(bytes.data(), bytes.size() - 1, &frame);
        const uint8_t type = golden::frameTypeId(v["type"]);
        EXPECT_EQ(frame.type, type) << v["name"];
        EXPECT_EQ(frame.sequence, v["sequence"].get<uint16_t>()) << v["name"];
        if (hostToDevice(type) || type == CDRO_FRAME_NODE_LIST) { // NODE_LIST: its length depends on its count
            ASSERT_EQ(result, CDRO_OK) << v["name"];
            EXPECT_EQ(golden::fieldsToJson(frame), v["fields"]) << v["name"];
        } else {
            EXPECT_EQ(result, CDRO_ERR_TYPE) << v["name"] << ": the device NACKs it UNKNOWN_TYPE";
        }
    }
}

TEST(DeviceCodec, RejectionsOfHostFramesAreTheFullCodecsAndDeviceFramesStayByType)
{
    for (const auto &v : golden::vectors()["decode_errors"]) {
        const auto chunk = golden::fromHex(v["chunk"]);
        cdro_frame_t frame;
        int result = cdro_frame_decode(chunk.data(), chunk.size(), &frame);
        if (result == CDRO_OK) {
            result = cdro_frame_validate(&frame);
        }
        const std::string expected = v["result"];
        const bool device_type = v.contains("type") && !hostToDevice(v["type"].get<uint8_t>()) &&
                                 v["type"].get<uint8_t>() != CDRO_FRAME_NODE_LIST && expected == "value";
        if (device_type) {
            // A device-to-host frame with a bad value: never decoded on the device, refused by type.
            EXPECT_STREQ(cdro_result_name(result), "type") << v["name"];
        } else {
            EXPECT_STREQ(cdro_result_name(result), expected.c_str()) << v["name"];
        }
    }
    // A device-to-host frame of the wrong length is still MALFORMED (CDRO_ERR_LENGTH).
    cdro_frame_t ack{};
    ack.type = CDRO_FRAME_ACK;
    std::vector<uint8_t> bytes(CDRO_MAX_ENCODED_FRAME);
    bytes.resize(cdro_frame_encode(&ack, bytes.data(), bytes.size()));
    ASSERT_FALSE(bytes.empty());
    uint8_t raw[CDRO_MAX_RAW_FRAME];
    const long n = cdro_cobs_decode(bytes.data(), bytes.size() - 1, raw, sizeof raw);
    ASSERT_GT(n, 0);
    raw[4] = static_cast<uint8_t>(raw[4] - 1); // one payload byte less, and the CRC redone
    const size_t shorter = static_cast<size_t>(n) - 1;
    raw[shorter - 2] = static_cast<uint8_t>(cdro_crc16(raw, shorter - 2) & 0xFF);
    raw[shorter - 1] = static_cast<uint8_t>(cdro_crc16(raw, shorter - 2) >> 8);
    uint8_t wire[CDRO_MAX_ENCODED_FRAME];
    const size_t m = cdro_cobs_encode(raw, shorter, wire, sizeof wire);
    cdro_frame_t out;
    EXPECT_EQ(cdro_frame_decode(wire, m, &out), CDRO_ERR_LENGTH);
}

// The edges of the value ranges (tests/golden/bounds_cases.json): a host-to-device frame gets the
// full codec's verdict; a device-to-host one is refused by type unless its length is wrong.
TEST(DeviceCodec, RangeEdgesOfHostFramesGetTheFullCodecsVerdict)
{
    const auto table = nlohmann::json::parse(golden::readFile(std::string(CDRO_GOLDEN_DIR) + "/bounds_cases.json"));
    size_t host_cases = 0;
    for (const auto &c : table.at("cases")) {
        const auto chunk = golden::fromHex(c.at("chunk"));
        cdro_frame_t frame;
        int result = cdro_frame_decode(chunk.data(), chunk.size(), &frame);
        if (result == CDRO_OK) {
            result = cdro_frame_validate(&frame);
        }
        const std::string full = c.at("result");
        if (hostToDevice(golden::frameTypeId(c.at("type")))) {
            ++host_cases;
            EXPECT_STREQ(cdro_result_name(result), full.c_str()) << c.at("name");
        } else {
            EXPECT_STREQ(cdro_result_name(result), full == "length" ? "length" : "type") << c.at("name");
        }
    }
    EXPECT_GT(host_cases, 0U);
}

} // namespace
