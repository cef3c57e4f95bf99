// checkpoint_layout.def's engine and movement blocks through the structs and the one reader and
// writer generated from the table (cdro/hostd/checkpoint_blocks.hpp): the bytes cdro-hostd wrote
// when it serialized the blocks field by field by hand (tests/golden/checkpoint_engine_blocks.json,
// also read by tests/tools/test_checkpoint_blocks.py) decode into their named fields and encode
// to the same bytes.
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "cdro/hostd/checkpoint_blocks.hpp"
#include "golden.hpp"

namespace {

using cdro::hostd::blocks::decode;
using cdro::hostd::blocks::encode;
using cdro::hostd::blocks::engine_block;
using cdro::hostd::blocks::movement_block;
using cdro::service::CheckpointError;

const nlohmann::json &vector()
{
    static const nlohmann::json parsed =
        nlohmann::json::parse(golden::readFile(std::string(CDRO_GOLDEN_DIR) + "/checkpoint_engine_blocks.json"));
    return parsed;
}

TEST(CheckpointBlocks, TheGoldenEngineBlockReadsIntoItsFieldsAndWritesTheSameBytes)
{
    const nlohmann::json &golden = vector()["engine"];
    EXPECT_EQ(golden["tag"].get<unsigned>(), CDRO_CHECKPOINT_TAG_ENGINE);
    const std::vector<uint8_t> bytes = golden::fromHex(golden["bytes"].get<std::string>());
    const auto block = decode<engine_block>(bytes, "engine", CDRO_CHECKPOINT_ENGINE_VERSION);
    std::vector<unsigned> ids;
    for (const auto &node : block.nodes) {
        ids.push_back(node.id);
    }
    EXPECT_EQ(ids, golden["node_ids"].get<std::vector<unsigned>>());
    EXPECT_EQ(block.links.size(), golden["link_count"].get<size_t>());
    EXPECT_EQ(block.ring_update_counts.size(), golden["ring_count"].get<size_t>());
    EXPECT_EQ(block.counters.size(), golden["counter_count"].get<size_t>());
    const nlohmann::json &first = golden["first_link"];
    EXPECT_EQ(block.links.at(0).a_id, first["a_id"].get<unsigned>());
    EXPECT_EQ(block.links.at(0).b_id, first["b_id"].get<unsigned>());
    EXPECT_EQ(block.links.at(0).range_count, first["range_count"].get<unsigned>());
    EXPECT_EQ(block.links.at(0).last_range_mm, first["last_range_mm"].get<unsigned>());
    EXPECT_EQ(block.nodes.at(0).x_m, golden["first_node_x_m"].get<double>()); // exactly: doubles as their bits
    EXPECT_EQ(golden::toHex(encode(block)), golden::toHex(bytes));
}

TEST(CheckpointBlocks, TheGoldenMovementBlockReadsIntoItsFieldsAndWritesTheSameBytes)
{
    const nlohmann::json &golden = vector()["movement"];
    EXPECT_EQ(golden["tag"].get<unsigned>(), CDRO_CHECKPOINT_TAG_MOVEMENT);
    const std::vector<uint8_t> bytes = golden::fromHex(golden["bytes"].get<std::string>());
    const auto block = decode<movement_block>(bytes, "movement", CDRO_CHECKPOINT_MOVEMENT_VERSION);
    EXPECT_EQ(block.robot_id, golden["robot_id"].get<unsigned>());
    EXPECT_EQ(block.flags, golden["flags"].get<unsigned>());
    EXPECT_EQ(block.moved_m, golden["moved_m"].get<double>());
    std::vector<size_t> sizes;
    for (const auto &hypothesis : block.hypotheses) {
        sizes.push_back(hypothesis.state.size());
        EXPECT_EQ(hypothesis.covariance.size(), hypothesis.state.size() * hypothesis.state.size());
    }
    EXPECT_EQ(sizes, golden["hypothesis_state_sizes"].get<std::vector<size_t>>());
    EXPECT_EQ(block.links.size(), golden["link_count"].get<size_t>());
    EXPECT_EQ(block.revision, golden["revision"].get<uint64_t>());
    EXPECT_EQ(block.counters.size(), golden["counter_count"].get<size_t>());
    EXPECT_EQ(golden::toHex(encode(block)), golden::toHex(bytes));
}

TEST(CheckpointBlocks, ADamagedBlockIsRefusedSayingWhatIsWrong)
{
    const std::vector<uint8_t> bytes = golden::fromHex(vector()["engine"]["bytes"].get<std::string>());
    const auto refusal = [](const std::vector<uint8_t> &damaged) {
        try {
            (void)decode<engine_block>(damaged, "engine", CDRO_CHECKPOINT_ENGINE_VERSION);
        } catch (const CheckpointError &error) {
            return std::string(error.what());
        }
        return std::string("accepted");
    };
    EXPECT_EQ(refusal({bytes.begin(), bytes.end() - 1}), "the engine block of the checkpoint is cut short");
    std::vector<uint8_t> longer = bytes;
    longer.push_back(0);
    EXPECT_EQ(refusal(longer), "the checkpoint's engine block has bytes after its end");
    std::vector<uint8_t> version = bytes;
    version[0] = CDRO_CHECKPOINT_ENGINE_VERSION + 1;
    EXPECT_EQ(refusal(version), "the checkpoint's engine block is of another version");
    std::vector<uint8_t> frame = bytes;
    frame[1] = 2; // ENGINE_BLOCK.has_frame: 0..1
    EXPECT_EQ(refusal(frame), "the checkpoint's engine block has has_frame 2, outside 0..1");
    std::vector<uint8_t> absurd = bytes;
    const uint32_t too_many = CDRO_CHECKPOINT_MAX_LIST_COUNT + 1U; // ENGINE_BLOCK.nodes' count, bytes 8..11
    for (size_t i = 0; i < 4; ++i) {
        absurd[8 + i] = static_cast<uint8_t>(too_many >> (8U * i));
    }
    EXPECT_EQ(refusal(absurd).rfind("the checkpoint's engine block gives nodes a count of ", 0), 0U) << refusal(absurd);
}

} // namespace
