#include <cstring>
#include <vector>

#include <gtest/gtest.h>

#include "cdro/frames.h"
#include "golden.hpp"

namespace {

std::vector<uint8_t> encode(const cdro_frame_t &frame)
{
    std::vector<uint8_t> out(CDRO_MAX_ENCODED_FRAME);
    out.resize(cdro_frame_encode(&frame, out.data(), out.size()));
    return out;
}

TEST(Frames, GoldenFramesEncodeToTheGoldenBytes)
{
    for (const auto &v : golden::vectors()["frames"]) {
        const cdro_frame_t frame = golden::frameFromJson(v);
        EXPECT_EQ(golden::toHex(encode(frame)), v["bytes"].get<std::string>()) << v["name"];
    }
}

TEST(Frames, GoldenBytesDecodeToTheGoldenFields)
{
    for (const auto &v : golden::vectors()["frames"]) {
        const auto bytes = golden::fromHex(v["bytes"]);
        ASSERT_FALSE(bytes.empty());
        ASSERT_EQ(bytes.back(), 0x00) << "frames end with the delimiter";
        cdro_frame_t frame;
        ASSERT_EQ(cdro_frame_decode(bytes.data(), bytes.size() - 1, &frame), CDRO_OK) << v["name"];
        EXPECT_EQ(frame.version, CDRO_PROTOCOL_VERSION);
        EXPECT_EQ(frame.type, golden::frameTypeId(v["type"]));
        EXPECT_EQ(frame.sequence, v["sequence"].get<uint16_t>());
        EXPECT_EQ(golden::fieldsToJson(frame), v["fields"]) << v["name"];
        EXPECT_EQ(cdro_frame_validate(&frame), CDRO_OK) << v["name"];
    }
}

TEST(Frames, GoldenRejectionsGiveTheirDistinctResult)
{
    for (const auto &v : golden::vectors()["decode_errors"]) {
        const auto chunk = golden::fromHex(v["chunk"]);
        cdro_frame_t frame;
        int result = cdro_frame_decode(chunk.data(), chunk.size(), &frame);
        if (result == CDRO_OK) {
            result = cdro_frame_validate(&frame);
        }
        EXPECT_STREQ(cdro_result_name(result), v["result"].get<std::string>().c_str()) << v["name"];
        if (v.contains("type")) { // after a good CRC the header is reported
            EXPECT_EQ(frame.version, v["version"].get<uint8_t>()) << v["name"];
            EXPECT_EQ(frame.type, v["type"].get<uint8_t>()) << v["name"];
            EXPECT_EQ(frame.sequence, v["sequence"].get<uint16_t>()) << v["name"];
        }
    }
}

TEST(Frames, EveryTypeHasANameAndUnknownOnesDoNot)
{
    EXPECT_STREQ(cdro_frame_type_name(CDRO_FRAME_RANGE), "RANGE");
    EXPECT_STREQ(cdro_frame_type_name(CDRO_FRAME_HELLO_REQUEST), "HELLO_REQUEST");
    EXPECT_EQ(cdro_frame_type_name(0x7E), nullptr);
}

TEST(Frames, EncodeRefusesTooSmallBuffersUnknownTypesAndOverfullArrays)
{
    cdro_frame_t frame{};
    frame.type = CDRO_FRAME_PING;
    frame.as.ping.nonce = 1;
    uint8_t small[8];
    EXPECT_EQ(cdro_frame_encode(&frame, small, sizeof small), 0U);

    frame.type = 0x7E;
    uint8_t big[CDRO_MAX_ENCODED_FRAME];
    EXPECT_EQ(cdro_frame_encode(&frame, big, sizeof big), 0U);

    frame.type = CDRO_FRAME_SET_NODES;
    frame.as.set_nodes.node_ids_count = CDRO_MAX_NODES + 1;
    EXPECT_EQ(cdro_frame_encode(&frame, big, sizeof big), 0U);
}

TEST(Frames, LargestFrameFitsTheDocumentedMaximum)
{
    cdro_frame_t frame{};
    frame.type = CDRO_FRAME_STATUS;
    std::memset(&frame.as.status, 0xFF, sizeof frame.as.status); // no zero bytes: worst case for COBS
    uint8_t out[CDRO_MAX_ENCODED_FRAME];
    const size_t n = cdro_frame_encode(&frame, out, sizeof out);
    ASSERT_GT(n, 0U);
    EXPECT_LE(n, static_cast<size_t>(CDRO_MAX_ENCODED_FRAME));
    EXPECT_LE(CDRO_STATUS_MAX_SIZE, CDRO_MAX_PAYLOAD);
    EXPECT_LE(CDRO_NODE_LIST_MAX_SIZE, CDRO_MAX_PAYLOAD);
}

} // namespace
