// Capture files: one record per chunk, rotation, a previous run kept, a file cut at any byte
// loses at most its last record, corrupt bytes are skipped.
#include <fstream>
#include <iterator>
#include <random>
#include <sstream>

#include <csignal>

#include <gtest/gtest.h>
#include <sys/resource.h>
#include <sys/stat.h>

#include "cdro/service/capture.hpp"
#include "cdro/service/log.hpp"
#include "support.hpp"

using namespace cdro::service;

namespace {
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
std::vector<CaptureRecord> readAll(const std::string &path, CaptureReader **keep = nullptr)
{
    static std::unique_ptr<CaptureReader> reader;
    reader = std::make_unique<CaptureReader>(path);
    std::vector<CaptureRecord> records;
    CaptureRecord record;
    while (reader->next(record)) {
        records.push_back(record);
    }
    if (keep != nullptr) {
        *keep = reader.get();
    }
    return records;
}
bool exists(const std::string &path)
{
    struct stat st {};
    return ::stat(path.c_str(), &st) == 0;
}
} // namespace

TEST(Capture, RecordsRoundTripWithFlagsTimesAndSource)
{
    cdro::test::TempDir dir;
    ServiceCounters counters;
    CaptureConfig config;
    config.path = dir.file("a.cdrocap");
    {
        CaptureWriter writer(config, "serial:/dev/ttyACM0@115200", counters);
        writer.open(123);
        const uint8_t a[] = {1, 2, 3};
        writer.append(0, 1000, a, sizeof a);
        writer.append(CDRO_CAPTURE_FLAG_TO_DEVICE, 2000, a, 2);
        std::vector<uint8_t> long_chunk(5000, 7);
        writer.append(0, 3000, long_chunk.data(), long_chunk.size());
    }
    CaptureReader *reader = nullptr;
    const auto records = readAll(config.path, &reader);
    EXPECT_EQ(reader->source(), "serial:/dev/ttyACM0@115200");
    EXPECT_EQ(reader->header().created_unix_us, 123);
    ASSERT_EQ(records.size(), 3U);
    EXPECT_EQ(records[0].data, std::vector<uint8_t>({1, 2, 3}));
    EXPECT_FALSE(records[0].toDevice());
    EXPECT_TRUE(records[1].toDevice());
    EXPECT_EQ(records[1].host_time_us, 2000);
    EXPECT_EQ(records[2].data.size(), CDRO_CAPTURE_MAX_DATA);
    EXPECT_TRUE(records[2].flags & CDRO_CAPTURE_FLAG_TRUNCATED);
    EXPECT_EQ(counters.capture_records, 3U);
}

TEST(Capture, RotatesBySizeAndKeepsN)
{
    cdro::test::TempDir dir;
    ServiceCounters counters;
    CaptureConfig config;
    config.path = dir.file("r.cdrocap");
    config.rotate_mib = 2000.0 / (1024.0 * 1024.0); // 2000 bytes
    config.keep = 2;
    CaptureWriter writer(config, "test", counters);
    writer.open(1);
    std::vector<uint8_t> chunk(86, 0x55); // 100-byte records
    for (int i = 0; i < 100; ++i) {
        chunk[0] = static_cast<uint8_t>(i);
        writer.append(0, i, chunk.data(), chunk.size());
    }
    writer.close();
    EXPECT_TRUE(exists(config.path));
    EXPECT_TRUE(exists(config.path + ".1"));
    EXPECT_TRUE(exists(config.path + ".2"));
    EXPECT_FALSE(exists(config.path + ".3"));
    EXPECT_GE(counters.capture_rotations, 4U);
    // Each file stays under the limit, and the newest records are in order across the files.
    std::vector<int> firsts;
    for (const std::string &name : std::vector<std::string>{config.path + ".2", config.path + ".1", config.path}) {
        EXPECT_LE(readFile(name).size(), 2000U);
        for (const auto &record : readAll(name)) {
            firsts.push_back(record.data[0]);
        }
    }
    for (size_t i = 1; i < firsts.size(); ++i) {
        EXPECT_EQ(firsts[i], firsts[i - 1] + 1);
    }
    EXPECT_EQ(firsts.back(), 99);
}

TEST(Capture, APreviousRunIsRotatedAwayNotOverwritten)
{
    cdro::test::TempDir dir;
    ServiceCounters counters;
    CaptureConfig config;
    config.path = dir.file("p.cdrocap");
    const uint8_t a[] = {9};
    {
        CaptureWriter first(config, "first", counters);
        first.open(1);
        first.append(0, 1, a, 1);
    }
    {
        CaptureWriter second(config, "second", counters);
        second.open(2);
    }
    CaptureReader previous(config.path + ".1");
    EXPECT_EQ(previous.source(), "first");
    CaptureReader current(config.path);
    EXPECT_EQ(current.source(), "second");
}

TEST(Capture, CutAtEveryByteLosesAtMostTheLastRecord)
{
    cdro::test::TempDir dir;
    ServiceCounters counters;
    CaptureConfig config;
    config.path = dir.file("k.cdrocap");
    {
        CaptureWriter writer(config, "test", counters);
        writer.open(1);
        for (uint8_t i = 0; i < 10; ++i) {
            const uint8_t data[] = {i, 1, 2, 3, 4, 5};
            writer.append(0, i, data, sizeof data);
        }
    }
    const std::vector<uint8_t> whole = readFile(config.path);
    const size_t header = whole.size() - 10 * (CDRO_CAPTURE_RECORD_OVERHEAD + 6);
    for (size_t cut = header; cut <= whole.size(); ++cut) {
        const std::string path = dir.file("cut.cdrocap");
        writeFile(path, std::vector<uint8_t>(whole.begin(), whole.begin() + static_cast<long>(cut)));
        CaptureReader *reader = nullptr;
        const auto records = readAll(path, &reader);
        const size_t complete = (cut - header) / (CDRO_CAPTURE_RECORD_OVERHEAD + 6);
        ASSERT_EQ(records.size(), complete) << "cut at " << cut;
        EXPECT_EQ(reader->truncatedTailBytes(), (cut - header) % (CDRO_CAPTURE_RECORD_OVERHEAD + 6));
    }
}

TEST(Capture, CorruptBytesAreSkippedAndCounted)
{
    const uint32_t seed = cdro::test::testSeed("CorruptBytesAreSkippedAndCounted");
    std::mt19937 rng(seed);
    cdro::test::TempDir dir;
    ServiceCounters counters;
    CaptureConfig config;
    config.path = dir.file("c.cdrocap");
    {
        CaptureWriter writer(config, "test", counters);
        writer.open(1);
        for (uint16_t i = 0; i < 200; ++i) {
            std::vector<uint8_t> data(1 + rng() % 60, static_cast<uint8_t>(i));
            writer.append(0, i, data.data(), data.size());
        }
    }
    std::vector<uint8_t> bytes = readFile(config.path);
    const size_t header = 23 + 4;
    for (int flips = 0; flips < 20; ++flips) {
        bytes[header + rng() % (bytes.size() - header)] ^= static_cast<uint8_t>(1U << (rng() % 8));
    }
    writeFile(config.path, bytes);
    CaptureReader *reader = nullptr;
    const auto records = readAll(config.path, &reader);
    EXPECT_GE(records.size(), 200U - 20U);
    EXPECT_LT(records.size(), 200U);
    EXPECT_GT(reader->corruptBytes() + reader->truncatedTailBytes(), 0U);
    for (const auto &record : records) { // everything read is intact
        for (const uint8_t b : record.data) {
            EXPECT_EQ(b, static_cast<uint8_t>(record.host_time_us));
        }
    }
}

TEST(Capture, NotACaptureIsAClearError)
{
    cdro::test::TempDir dir;
    writeFile(dir.file("x"), {'h', 'e', 'l', 'l', 'o'});
    try {
        CaptureReader reader(dir.file("x"));
        FAIL();
    } catch (const CaptureError &error) {
        EXPECT_NE(std::string(error.what()).find("not a capture file"), std::string::npos);
    }
    EXPECT_THROW(CaptureReader(dir.file("missing")), CaptureError);
}

// A full disk. The file-size limit (RLIMIT_FSIZE) makes write() fail with EFBIG
// exactly as ENOSPC would, for this process only, and can be lifted again as freeing space
// would: records written while it holds are lost and counted, the file stays readable (a record
// cut by the limit is removed again), and once writes succeed again the log says so.
TEST(Capture, AFullDiskLosesOnlyTheRecordsThatDidNotFitAndWritingResumes)
{
    cdro::test::TempDir dir;
    LoggingConfig logging;
    logging.file = dir.file("service.log");
    setupLogging(logging);
    ServiceCounters counters;
    CaptureConfig config;
    config.path = dir.file("full.cdrocap");
    CaptureWriter writer(config, "serial:/dev/ttyX", counters);
    writer.open(1000);
    const std::vector<uint8_t> data(100, 0x5A);
    for (int i = 0; i < 10; ++i) {
        writer.append(0, 2000 + i, data.data(), data.size());
    }
    const uint64_t size_before = writer.currentFileBytes();

    rlimit saved{};
    ASSERT_EQ(::getrlimit(RLIMIT_FSIZE, &saved), 0);
    const auto previous = std::signal(SIGXFSZ, SIG_IGN);
    rlimit full = saved;
    full.rlim_cur = static_cast<rlim_t>(size_before + 50); // half a record still fits
    ASSERT_EQ(::setrlimit(RLIMIT_FSIZE, &full), 0);
    for (int i = 0; i < 5; ++i) {
        writer.append(0, 3000 + i, data.data(), data.size());
    }
    ASSERT_EQ(::setrlimit(RLIMIT_FSIZE, &saved), 0); // space freed
    std::signal(SIGXFSZ, previous);
    for (int i = 0; i < 3; ++i) {
        writer.append(0, 4000 + i, data.data(), data.size());
    }
    writer.close();
    setupLogging(LoggingConfig{});

    EXPECT_EQ(counters.capture_write_errors, 5U);
    EXPECT_EQ(counters.capture_records, 13U);
    CaptureReader *reader = nullptr;
    const std::vector<CaptureRecord> records = readAll(config.path, &reader);
    ASSERT_EQ(records.size(), 13U);
    EXPECT_EQ(reader->corruptBytes(), 0U); // no half record left behind by the full disk
    EXPECT_EQ(reader->truncatedTailBytes(), 0U);
    EXPECT_EQ(records[10].host_time_us, 4000);
    std::ifstream in(logging.file);
    // Through a stringstream: gcc 12 sees a null dereference in istreambuf_iterator into a string.
    std::stringstream text;
    text << in.rdbuf();
    const std::string log = text.str();
    EXPECT_NE(log.find("cannot append"), std::string::npos) << log;
    EXPECT_NE(log.find("writing again"), std::string::npos) << log;
    EXPECT_NE(log.find("5 records were lost"), std::string::npos) << log;
}

TEST(Capture, ARotationOnAFullDiskStartsItsNewFileOnceThereIsSpace)
{
    cdro::test::TempDir dir;
    ServiceCounters counters;
    CaptureConfig config;
    config.path = dir.file("rot.cdrocap");
    config.rotate_mib = 0.01; // 10486 bytes
    CaptureWriter writer(config, "serial:/dev/ttyX", counters);
    writer.open(1000);
    const std::vector<uint8_t> data(1000, 0x5A);
    int64_t t_us = 2000;
    for (int i = 0; i < 10; ++i) { // what fits before the next record would rotate the file
        writer.append(0, t_us += 1000, data.data(), data.size());
    }
    ASSERT_EQ(counters.capture_rotations, 0U);
    rlimit saved{};
    ASSERT_EQ(::getrlimit(RLIMIT_FSIZE, &saved), 0);
    const auto previous = std::signal(SIGXFSZ, SIG_IGN);
    rlimit full = saved;
    full.rlim_cur = 10; // not even a header fits
    ASSERT_EQ(::setrlimit(RLIMIT_FSIZE, &full), 0);
    for (int i = 0; i < 5; ++i) {
        writer.append(0, t_us += 1000, data.data(), data.size()); // the rotation comes, its new file fails
    }
    ASSERT_EQ(::setrlimit(RLIMIT_FSIZE, &saved), 0);
    std::signal(SIGXFSZ, previous);
    const uint64_t errors = counters.capture_write_errors;
    EXPECT_GE(errors, 4U);
    writer.append(0, t_us += 2'000'000, data.data(), data.size()); // a second later: a new file
    writer.close();
    EXPECT_EQ(counters.capture_write_errors, errors);
    EXPECT_EQ(readAll(config.path).size(), 1U);
    EXPECT_EQ(readAll(config.path + ".1").size(), 10U);
    EXPECT_EQ(counters.capture_rotations, 1U);
}
