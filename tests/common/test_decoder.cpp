#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "cdro/frames.h"
#include "golden.hpp"

namespace {

struct Fed {
    std::vector<std::string> results;
    std::vector<cdro_frame_t> frames;
};

Fed feed(cdro_decoder_t &decoder, const std::vector<uint8_t> &bytes)
{
    Fed fed;
    for (const uint8_t byte : bytes) {
        cdro_frame_t frame;
        const cdro_result_t result = cdro_decoder_push(&decoder, byte, &frame);
        if (result != CDRO_PENDING) {
            fed.results.emplace_back(cdro_result_name(result));
            if (result == CDRO_OK) {
                fed.frames.push_back(frame);
            }
        }
    }
    return fed;
}

TEST(Decoder, GoldenStreamGivesTheGoldenResultsAndCounters)
{
    const auto &v = golden::vectors()["stream"];
    cdro_decoder_t decoder;
    cdro_decoder_init(&decoder);
    const Fed fed = feed(decoder, golden::fromHex(v["bytes"]));
    EXPECT_EQ(nlohmann::json(fed.results), v["results"]);
    const auto &c = decoder.counters;
    const auto &expected = v["counters"];
    EXPECT_EQ(c.frames_ok, expected["frames_ok"].get<uint32_t>());
    EXPECT_EQ(c.cobs_errors, expected["cobs_errors"].get<uint32_t>());
    EXPECT_EQ(c.short_errors, expected["short_errors"].get<uint32_t>());
    EXPECT_EQ(c.crc_errors, expected["crc_errors"].get<uint32_t>());
    EXPECT_EQ(c.version_errors, expected["version_errors"].get<uint32_t>());
    EXPECT_EQ(c.type_errors, expected["type_errors"].get<uint32_t>());
    EXPECT_EQ(c.length_errors, expected["length_errors"].get<uint32_t>());
    EXPECT_EQ(c.value_errors, expected["value_errors"].get<uint32_t>());
    EXPECT_EQ(c.too_long_errors, expected["too_long_errors"].get<uint32_t>());
    EXPECT_EQ(c.bytes_discarded, expected["bytes_discarded"].get<uint32_t>());
}

TEST(Decoder, KeepsTheLastChunkForCaptureFiles)
{
    const auto bytes = golden::fromHex(golden::vectors()["frames"][1]["bytes"]);
    cdro_decoder_t decoder;
    cdro_decoder_init(&decoder);
    cdro_frame_t frame;
    cdro_result_t result = CDRO_PENDING;
    for (const uint8_t byte : bytes) {
        result = cdro_decoder_push(&decoder, byte, &frame);
    }
    ASSERT_EQ(result, CDRO_OK);
    ASSERT_EQ(decoder.last_chunk_len, bytes.size() - 1);
    EXPECT_EQ(golden::toHex(decoder.chunk, decoder.last_chunk_len),
              golden::toHex(bytes).substr(0, 2 * (bytes.size() - 1)));
}

// Valid frames survive any garbage around them: every frame that follows a delimiter is
// recovered, and the counters account for every rejected chunk.
TEST(Decoder, RecoversEveryFrameFromSeededGarbage)
{
    const unsigned seed = 12345;
    std::printf("seed %u\n", seed);
    std::mt19937 rng(seed);
    const auto &golden_frames = golden::vectors()["frames"];
    for (int trial = 0; trial < 50; ++trial) {
        std::vector<uint8_t> stream;
        std::vector<uint16_t> expected_sequences;
        for (int k = 0; k < 40; ++k) {
            const size_t garbage = rng() % 90;
            for (size_t g = 0; g < garbage; ++g) {
                stream.push_back(static_cast<uint8_t>(rng()));
            }
            stream.push_back(0x00); // a sender may prefix a delimiter to resynchronise quickly
            const auto &entry = golden_frames[rng() % golden_frames.size()];
            cdro_frame_t frame = golden::frameFromJson(entry);
            frame.sequence = static_cast<uint16_t>(k);
            std::vector<uint8_t> encoded(CDRO_MAX_ENCODED_FRAME);
            encoded.resize(cdro_frame_encode(&frame, encoded.data(), encoded.size()));
            stream.insert(stream.end(), encoded.begin(), encoded.end());
            expected_sequences.push_back(static_cast<uint16_t>(k));
        }
        cdro_decoder_t decoder;
        cdro_decoder_init(&decoder);
        const Fed fed = feed(decoder, stream);
        // Garbage may by chance form a valid frame only with probability ~2^-16 per chunk; the
        // seeded stream has none, so the recovered frames are exactly ours, in order.
        std::vector<uint16_t> sequences;
        for (const auto &f : fed.frames) {
            sequences.push_back(f.sequence);
        }
        EXPECT_EQ(sequences, expected_sequences) << "trial " << trial;
        const auto &c = decoder.counters;
        const uint32_t rejected = c.cobs_errors + c.short_errors + c.crc_errors + c.version_errors + c.type_errors +
                                  c.length_errors + c.value_errors + c.too_long_errors;
        EXPECT_EQ(c.frames_ok + rejected, fed.results.size());
    }
}

TEST(Decoder, AnOverlongRunIsOneErrorAndTheNextFrameDecodes)
{
    std::vector<uint8_t> stream(5000, 0x55);
    stream.push_back(0x00);
    const auto frame = golden::fromHex(golden::vectors()["frames"][0]["bytes"]);
    stream.insert(stream.end(), frame.begin(), frame.end());
    cdro_decoder_t decoder;
    cdro_decoder_init(&decoder);
    const Fed fed = feed(decoder, stream);
    EXPECT_EQ(fed.results, (std::vector<std::string>{"too_long", "ok"}));
    EXPECT_EQ(decoder.counters.bytes_discarded, 5000U);
}

} // namespace
