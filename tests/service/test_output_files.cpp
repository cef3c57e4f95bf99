// Output and temporary files that cannot be hijacked (docs/service.md, "Security model"): JSON Lines, checkpoints and
// captures are opened without following a symbolic link, temporary names cannot be predicted,
// and a directory that every user may write to is refused with a message that says why.
#include <fstream>
#include <sstream>

#include <gtest/gtest.h>

#include <sys/stat.h>
#include <unistd.h>

#include "cdro/service/capture.hpp"
#include "cdro/service/checkpoint.hpp"
#include "cdro/service/json_output.hpp"
#include "cdro/service/output_file.hpp"
#include "support.hpp"

using namespace cdro::service;

namespace {

std::string readFile(const std::string &path)
{
    std::ifstream in(path, std::ios::binary);
    std::ostringstream text;
    text << in.rdbuf();
    return text.str();
}

void writeFile(const std::string &path, const std::string &text) { std::ofstream(path, std::ios::binary) << text; }

// A file someone else cares about, and a link to it planted where the service writes.
struct Planted {
    explicit Planted(const cdro::test::TempDir &dir, const std::string &link_name)
        : victim(dir.file("victim.txt")), link(dir.file(link_name))
    {
        writeFile(victim, "precious\n");
        EXPECT_EQ(::symlink(victim.c_str(), link.c_str()), 0);
    }
    bool intact() const { return readFile(victim) == "precious\n"; }
    std::string victim;
    std::string link;
};

SogSnapshot smallSnapshot()
{
    SogSnapshot snapshot;
    cdro_sog_node_t node{};
    node.id = 0x6001;
    snapshot.nodes.push_back(node);
    return snapshot;
}

} // namespace

TEST(OutputFiles, JsonLinesRefusesToFollowALinkAndLeavesItsTargetAlone)
{
    cdro::test::TempDir dir;
    Planted planted(dir, "estimates.jsonl");
    ServiceCounters counters;
    OutputConfig config;
    config.jsonl = planted.link;
    JsonLinesWriter writer(config, counters);
    try {
        writer.open();
        FAIL() << "a symbolic link was opened";
    } catch (const ConfigError &error) {
        EXPECT_NE(std::string(error.what()).find("symbolic link"), std::string::npos) << error.what();
        EXPECT_NE(std::string(error.what()).find(planted.link), std::string::npos) << error.what();
    }
    EXPECT_TRUE(planted.intact());
}

TEST(OutputFiles, APlantedCheckpointTempLinkIsNotWrittenThrough)
{
    cdro::test::TempDir dir;
    const std::string path = dir.file("checkpoint.cdrosog");
    Planted planted(dir, "checkpoint.cdrosog.tmp");
    writeCheckpointFile(path, smallSnapshot());
    EXPECT_TRUE(planted.intact());
    EXPECT_EQ(loadCheckpointFile(path).nodes.size(), 1U);
    // The checkpoint itself a link: refused, its target untouched.
    Planted second(dir, "second.cdrosog");
    EXPECT_THROW(writeCheckpointFile(second.link, smallSnapshot()), CheckpointError);
    EXPECT_TRUE(second.intact());
}

TEST(OutputFiles, CheckpointWritesLeaveNoTemporaryFileBehind)
{
    cdro::test::TempDir dir;
    const std::string path = dir.file("c.cdrosog");
    writeCheckpointFile(path, smallSnapshot());
    writeCheckpointFile(path, smallSnapshot());
    std::vector<std::string> names;
    for (const std::string &name : cdro::test::listDirectory(dir.path())) {
        names.push_back(name);
    }
    EXPECT_EQ(names, (std::vector<std::string>{"c.cdrosog"}));
}

TEST(OutputFiles, ACaptureLinkIsRotatedAwayNotWrittenThrough)
{
    cdro::test::TempDir dir;
    Planted planted(dir, "run.cdrocap");
    ServiceCounters counters;
    CaptureConfig config;
    config.path = planted.link;
    CaptureWriter writer(config, "test", counters);
    writer.open(1'700'000'000'000'000);
    const uint8_t bytes[] = {1, 2, 3};
    writer.append(0, 1'700'000'000'000'001, bytes, sizeof bytes);
    writer.close();
    EXPECT_TRUE(planted.intact());
}

TEST(OutputFiles, WorldWritableDirectoriesAreRefusedWithTheReason)
{
    cdro::test::TempDir dir;
    const std::string open_dir = dir.file("shared");
    ASSERT_EQ(::mkdir(open_dir.c_str(), 0700), 0);
    ASSERT_EQ(::chmod(open_dir.c_str(), 01777), 0); // like /tmp
    ServiceCounters counters;
    OutputConfig jsonl;
    jsonl.jsonl = open_dir + "/estimates.jsonl";
    JsonLinesWriter writer(jsonl, counters);
    try {
        writer.open();
        FAIL() << "opened in a world-writable directory";
    } catch (const ConfigError &error) {
        const std::string message = error.what();
        EXPECT_NE(message.find(open_dir), std::string::npos) << message;
        EXPECT_NE(message.find("every user"), std::string::npos) << message;
        EXPECT_NE(message.find("output.jsonl"), std::string::npos) << message;
    }
    EXPECT_THROW(writeCheckpointFile(open_dir + "/c.cdrosog", smallSnapshot()), CheckpointError);
    CaptureConfig capture;
    capture.path = open_dir + "/run.cdrocap";
    CaptureWriter capture_writer(capture, "test", counters);
    EXPECT_THROW(capture_writer.open(1), CaptureError);
    EXPECT_EQ(cdro::test::listDirectory(open_dir).size(), 0U);
}

TEST(OutputFiles, AnOrdinaryFileIsAppendedTo)
{
    cdro::test::TempDir dir;
    const std::string path = dir.file("estimates.jsonl");
    writeFile(path, "old run\n");
    ServiceCounters counters;
    OutputConfig config;
    config.jsonl = path;
    JsonLinesWriter writer(config, counters);
    writer.open();
    writer.writeHealth(Health{}, {1.0, 1700000001.0});
    writer.close();
    EXPECT_EQ(readFile(path).find("old run\n"), 0U); // a restart continues the file (docs/service.md)
    EXPECT_NE(readFile(path).find("\"type\":\"health\""), std::string::npos);
    EXPECT_NO_THROW(checkOutputPath("/dev/null", "output.jsonl")); // a device is not a directory entry we write
}
