// Checkpoints: round trip through common/'s SoG codec, atomic replacement, and refusal of
// anything cut or corrupt (never half-loaded).
#include <fstream>
#include <iterator>

#include <gtest/gtest.h>
#include <sys/stat.h>

#include "cdro/service/checkpoint.hpp"
#include "support.hpp"

using namespace cdro::service;

namespace {
SogSnapshot sample(int32_t x_mm)
{
    SogSnapshot s;
    s.header.created_unix_us = 1'700'000'000'000'000;
    s.header.ranges_processed = 1234;
    cdro_sog_node_t node{};
    node.id = 0x6069;
    node.flags = CDRO_SOG_NODE_PLACED | CDRO_SOG_NODE_CONVERGED;
    node.x_mm = x_mm;
    node.y_mm = -250;
    node.std_x_um = 20000;
    node.std_y_um = 30000;
    node.correlation_q15 = -1200;
    s.nodes.push_back(node);
    node.id = 0x6A11;
    s.nodes.push_back(node);
    SogSnapshot::Pair pair;
    pair.pair.center_id = 0x6069;
    pair.pair.target_id = 0x6A11;
    pair.pair.last_range_mm = 4235;
    pair.pair.range_count = 17;
    for (int i = 0; i < 3; ++i) {
        cdro_sog_component_t c{};
        c.x_mm = 1000 * i;
        c.weight_q16 = 21845;
        pair.components.push_back(c);
    }
    s.pairs.push_back(pair);
    s.extensions.push_back({0x0101, {1, 2, 3, 4}});
    return s;
}
std::vector<uint8_t> readFile(const std::string &path)
{
    std::ifstream in(path, std::ios::binary);
    return std::vector<uint8_t>((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}
void writeFile(const std::string &path, const std::vector<uint8_t> &bytes)
{
    std::ofstream(path, std::ios::binary)
        .write(reinterpret_cast<const char *>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
}
} // namespace

TEST(Checkpoint, RoundTripsEveryRecord)
{
    cdro::test::TempDir dir;
    const std::string path = dir.file("state.cdrosog");
    writeCheckpointFile(path, sample(3214));
    const SogSnapshot loaded = loadCheckpointFile(path);
    EXPECT_EQ(loaded.header.ranges_processed, 1234U);
    EXPECT_EQ(loaded.header.node_count, 2);
    ASSERT_EQ(loaded.nodes.size(), 2U);
    EXPECT_EQ(loaded.nodes[0].x_mm, 3214);
    EXPECT_EQ(loaded.nodes[0].correlation_q15, -1200);
    ASSERT_EQ(loaded.pairs.size(), 1U);
    EXPECT_EQ(loaded.pairs[0].pair.range_count, 17);
    ASSERT_EQ(loaded.pairs[0].components.size(), 3U);
    EXPECT_EQ(loaded.pairs[0].components[2].x_mm, 2000);
    ASSERT_NE(loaded.findExtension(0x0101), nullptr);
    EXPECT_EQ(loaded.findExtension(0x0101)->bytes, std::vector<uint8_t>({1, 2, 3, 4}));
    struct stat st {};
    EXPECT_NE(::stat((path + ".tmp").c_str(), &st), 0); // no temporary left behind
}

TEST(Checkpoint, ServiceInfoRoundTrips)
{
    ServiceCheckpointInfo info{11, -22, 33};
    ServiceCheckpointInfo back;
    ASSERT_TRUE(decodeServiceInfo(encodeServiceInfo(info), &back));
    EXPECT_EQ(back.run_start_unix_us, 11);
    EXPECT_EQ(back.last_event_unix_us, -22);
    EXPECT_EQ(back.frames_delivered, 33U);
    EXPECT_FALSE(decodeServiceInfo({2, 0}, &back));
}

TEST(Checkpoint, ReplacementIsAtomicAndAFailedWriteKeepsTheOldOne)
{
    cdro::test::TempDir dir;
    const std::string path = dir.file("state.cdrosog");
    writeCheckpointFile(path, sample(1));
    // A crash mid-write leaves a stray temporary: the checkpoint itself is still the old one.
    writeFile(path + ".tmp", {1, 2, 3});
    EXPECT_EQ(loadCheckpointFile(path).nodes[0].x_mm, 1);
    writeCheckpointFile(path, sample(2)); // and the next write goes through
    EXPECT_EQ(loadCheckpointFile(path).nodes[0].x_mm, 2);
    // A write that cannot happen (the directory became writable by every user, so the
    // checkpoint is refused there) throws and keeps it.
    ASSERT_EQ(::chmod(dir.path().c_str(), 0777), 0);
    EXPECT_THROW(writeCheckpointFile(path, sample(3)), CheckpointError);
    ASSERT_EQ(::chmod(dir.path().c_str(), 0700), 0);
    EXPECT_EQ(loadCheckpointFile(path).nodes[0].x_mm, 2);
}

TEST(Checkpoint, EveryTruncationIsRefused)
{
    cdro::test::TempDir dir;
    const std::string path = dir.file("state.cdrosog");
    writeCheckpointFile(path, sample(7));
    const std::vector<uint8_t> whole = readFile(path);
    for (size_t cut = 0; cut < whole.size(); ++cut) {
        writeFile(path, std::vector<uint8_t>(whole.begin(), whole.begin() + static_cast<long>(cut)));
        EXPECT_THROW(loadCheckpointFile(path), CheckpointError) << "cut at " << cut;
    }
}

TEST(Checkpoint, EveryBitFlipIsRefusedWithAClearMessage)
{
    cdro::test::TempDir dir;
    const std::string path = dir.file("state.cdrosog");
    writeCheckpointFile(path, sample(7));
    const std::vector<uint8_t> whole = readFile(path);
    for (size_t i = 0; i < whole.size(); ++i) {
        std::vector<uint8_t> bytes = whole;
        bytes[i] ^= 0x10;
        writeFile(path, bytes);
        try {
            loadCheckpointFile(path);
            ADD_FAILURE() << "flip at byte " << i << " was accepted";
        } catch (const CheckpointError &error) {
            const std::string message = error.what();
            EXPECT_NE(message.find(path), std::string::npos);
            if (i >= 4) {
                EXPECT_NE(message.find("CRC-32"), std::string::npos) << message;
            } else {
                EXPECT_NE(message.find("not a SoG snapshot"), std::string::npos) << message;
            }
        }
    }
}

TEST(Checkpoint, MissingFileIsAClearError)
{
    try {
        loadCheckpointFile("/nonexistent/state.cdrosog");
        FAIL();
    } catch (const CheckpointError &error) {
        EXPECT_NE(std::string(error.what()).find("cannot read"), std::string::npos);
    }
}
