#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "cdro/capture.h"
#include "golden.hpp"

namespace {

struct Parsed {
    std::vector<cdro_capture_record_t> records;
    size_t corrupt_bytes = 0;
    size_t tail_bytes = 0;
};

Parsed parse(const std::vector<uint8_t> &file, cdro_capture_header_t &header)
{
    size_t offset = 0;
    EXPECT_EQ(cdro_capture_header_decode(file.data(), file.size(), &header, &offset), CDRO_OK);
    Parsed parsed;
    while (offset < file.size()) {
        cdro_capture_record_t record;
        size_t skipped = 0;
        size_t consumed = 0;
        if (cdro_capture_next_record(file.data() + offset, file.size() - offset, &record, &skipped, &consumed) !=
            CDRO_OK) {
            parsed.tail_bytes = file.size() - offset;
            break;
        }
        parsed.corrupt_bytes += skipped;
        parsed.records.push_back(record);
        offset += skipped + consumed;
    }
    return parsed;
}

TEST(Capture, GoldenFileEncodesToTheGoldenBytes)
{
    const auto &v = golden::vectors()["capture"];
    cdro_capture_header_t header{};
    header.created_unix_us = v["header"]["created_unix_us"].get<int64_t>();
    const std::string source = v["header"]["source"];
    header.source_len = static_cast<uint8_t>(source.size());
    source.copy(header.source, source.size());
    std::vector<uint8_t> file(CDRO_CAPTURE_HEADER_FIXED + CDRO_CAPTURE_MAX_SOURCE);
    file.resize(cdro_capture_header_encode(&header, file.data(), file.size()));
    for (const auto &r : v["records"]) {
        const auto data = golden::fromHex(r["data"]);
        cdro_capture_record_t record{r["flags"].get<uint8_t>(), r["host_time_us"].get<int64_t>(),
                                     static_cast<uint16_t>(data.size()), data.data()};
        std::vector<uint8_t> bytes(CDRO_CAPTURE_RECORD_OVERHEAD + data.size());
        ASSERT_EQ(cdro_capture_record_encode(&record, bytes.data(), bytes.size()), bytes.size());
        file.insert(file.end(), bytes.begin(), bytes.end());
    }
    EXPECT_EQ(golden::toHex(file), v["bytes"].get<std::string>());
}

TEST(Capture, GoldenBytesDecodeToTheGoldenRecords)
{
    const auto &v = golden::vectors()["capture"];
    cdro_capture_header_t header;
    const auto file = golden::fromHex(v["bytes"]); // records point into it
    const Parsed parsed = parse(file, header);
    EXPECT_EQ(header.created_unix_us, v["header"]["created_unix_us"].get<int64_t>());
    EXPECT_EQ(std::string(header.source, header.source_len), v["header"]["source"].get<std::string>());
    ASSERT_EQ(parsed.records.size(), v["records"].size());
    for (size_t i = 0; i < parsed.records.size(); ++i) {
        EXPECT_EQ(parsed.records[i].host_time_us, v["records"][i]["host_time_us"].get<int64_t>());
        EXPECT_EQ(parsed.records[i].flags, v["records"][i]["flags"].get<uint8_t>());
        EXPECT_EQ(golden::toHex(parsed.records[i].data, parsed.records[i].data_len),
                  v["records"][i]["data"].get<std::string>());
    }
    EXPECT_EQ(parsed.corrupt_bytes, 0U);
    EXPECT_EQ(parsed.tail_bytes, 0U);
}

TEST(Capture, AFileCutShortLosesOnlyItsLastRecord)
{
    const auto &v = golden::vectors()["capture"]["cut_short"];
    cdro_capture_header_t header;
    const Parsed parsed = parse(golden::fromHex(v["bytes"]), header);
    EXPECT_EQ(parsed.records.size(), v["records"].get<size_t>());
    EXPECT_EQ(parsed.tail_bytes, v["truncated_tail_bytes"].get<size_t>());
}

TEST(Capture, ACorruptRecordIsSkippedAndTheRestIsRead)
{
    const auto &v = golden::vectors()["capture"]["corrupt_middle"];
    cdro_capture_header_t header;
    const Parsed parsed = parse(golden::fromHex(v["bytes"]), header);
    EXPECT_EQ(parsed.records.size(), v["records"].get<size_t>());
    EXPECT_EQ(parsed.corrupt_bytes, v["corrupt_bytes"].get<size_t>());
}

TEST(Capture, HeaderRejectsOtherFilesAndNewerVersions)
{
    const auto good = golden::fromHex(golden::vectors()["capture"]["bytes"]);
    cdro_capture_header_t header;
    size_t consumed = 0;
    auto not_capture = good;
    not_capture[0] = 'X';
    EXPECT_EQ(cdro_capture_header_decode(not_capture.data(), not_capture.size(), &header, &consumed), CDRO_ERR_TYPE);
    auto newer = good;
    newer[8] = CDRO_CAPTURE_FORMAT_VERSION + 1U;
    EXPECT_EQ(cdro_capture_header_decode(newer.data(), newer.size(), &header, &consumed), CDRO_ERR_VERSION);
    auto corrupt = good;
    corrupt[13] ^= 0x01;
    EXPECT_EQ(cdro_capture_header_decode(corrupt.data(), corrupt.size(), &header, &consumed), CDRO_ERR_CRC);
    EXPECT_EQ(cdro_capture_header_decode(good.data(), 10, &header, &consumed), CDRO_PENDING);
}

TEST(Capture, TheGoldenFileIsVersion3WithAnOdometryRecordAndAHostEvent)
{
    const auto &v = golden::vectors()["capture"];
    cdro_capture_header_t header;
    const auto file = golden::fromHex(v["bytes"]);
    const Parsed parsed = parse(file, header);
    EXPECT_EQ(header.format_version, 3U);
    EXPECT_EQ(header.format_version, v["header"]["format_version"].get<uint16_t>());
    const size_t index = v["odometry"]["record"].get<size_t>();
    ASSERT_LT(index, parsed.records.size());
    const cdro_capture_record_t &odometry = parsed.records[index];
    EXPECT_EQ(odometry.flags, CDRO_CAPTURE_FLAG_ODOMETRY);
    const std::string text(reinterpret_cast<const char *>(odometry.data), odometry.data_len);
    EXPECT_EQ(nlohmann::json::parse(text), v["odometry"]["message"]);
    const size_t event = v["host_event"]["record"].get<size_t>();
    ASSERT_LT(event, parsed.records.size());
    EXPECT_EQ(parsed.records[event].flags, CDRO_CAPTURE_FLAG_HOST_EVENT);
    EXPECT_EQ(golden::toHex(parsed.records[event].data, parsed.records[event].data_len),
              v["host_event"]["data"].get<std::string>());
    for (size_t i = 0; i < parsed.records.size(); ++i) {
        if (i != index) {
            EXPECT_EQ(parsed.records[i].flags & CDRO_CAPTURE_FLAG_ODOMETRY, 0U) << i;
        }
        if (i != event) {
            EXPECT_EQ(parsed.records[i].flags & CDRO_CAPTURE_FLAG_HOST_EVENT, 0U) << i;
        }
    }
}

// Files of versions 1 (before odometry records) and 2 (before host events) read as before, and
// encode to the same bytes.
TEST(Capture, OlderVersionsStillReadAndEncode)
{
    for (const auto &[name, version] : {std::pair<const char *, uint16_t>{"capture_v1", 1U}, {"capture_v2", 2U}}) {
        SCOPED_TRACE(name);
        const auto &v = golden::vectors()[name];
        cdro_capture_header_t header;
        const auto file = golden::fromHex(v["bytes"]);
        const Parsed parsed = parse(file, header);
        EXPECT_EQ(header.format_version, version);
        EXPECT_EQ(header.created_unix_us, v["header"]["created_unix_us"].get<int64_t>());
        ASSERT_EQ(parsed.records.size(), v["records"].size());
        for (size_t i = 0; i < parsed.records.size(); ++i) {
            EXPECT_EQ(parsed.records[i].flags, v["records"][i]["flags"].get<uint8_t>());
            EXPECT_EQ(golden::toHex(parsed.records[i].data, parsed.records[i].data_len),
                      v["records"][i]["data"].get<std::string>());
        }
        EXPECT_EQ(parsed.corrupt_bytes + parsed.tail_bytes, 0U);

        std::vector<uint8_t> encoded(CDRO_CAPTURE_HEADER_FIXED + CDRO_CAPTURE_MAX_SOURCE);
        encoded.resize(cdro_capture_header_encode(&header, encoded.data(), encoded.size()));
        ASSERT_GT(encoded.size(), 0U);
        EXPECT_EQ(golden::toHex(encoded), v["bytes"].get<std::string>().substr(0, 2 * encoded.size()));
    }
}

// The run's context in the header (an addition to its layout, read by every version): decoded,
// encoded to the same bytes, and skipped by whoever does not look at it.
TEST(Capture, AHeaderWithAContextReadsAndEncodes)
{
    const auto &v = golden::vectors()["capture_context"];
    cdro_capture_header_t header;
    const auto file = golden::fromHex(v["bytes"]);
    const Parsed parsed = parse(file, header);
    ASSERT_EQ(header.context_len * 2U, v["header"]["context"].get<std::string>().size());
    EXPECT_EQ(golden::toHex(header.context, header.context_len), v["header"]["context"].get<std::string>());
    ASSERT_EQ(parsed.records.size(), 1U);
    EXPECT_EQ(golden::toHex(parsed.records[0].data, parsed.records[0].data_len),
              v["records"][0]["data"].get<std::string>());
    std::vector<uint8_t> encoded(v["header"]["size"].get<size_t>());
    EXPECT_EQ(cdro_capture_header_encode(&header, encoded.data(), encoded.size() - 1), 0U); // too small
    encoded.resize(cdro_capture_header_encode(&header, encoded.data(), encoded.size()));
    EXPECT_EQ(golden::toHex(encoded), v["bytes"].get<std::string>().substr(0, 2 * encoded.size()));
    // A damaged context is a damaged header.
    std::vector<uint8_t> damaged = file;
    damaged[60] ^= 0x01;
    size_t consumed = 0;
    EXPECT_EQ(cdro_capture_header_decode(damaged.data(), damaged.size(), &header, &consumed), CDRO_ERR_CRC);
}

TEST(Capture, HeaderRefusesToEncodeAnUnknownVersion)
{
    cdro_capture_header_t header{};
    header.format_version = CDRO_CAPTURE_FORMAT_VERSION + 1U;
    uint8_t out[CDRO_CAPTURE_HEADER_FIXED + CDRO_CAPTURE_MAX_SOURCE];
    EXPECT_EQ(cdro_capture_header_encode(&header, out, sizeof out), 0U);
}

TEST(Capture, RecordRefusesDataAboveTheMaximum)
{
    std::vector<uint8_t> data(CDRO_CAPTURE_MAX_DATA + 1);
    cdro_capture_record_t record{0, 0, static_cast<uint16_t>(data.size()), data.data()};
    std::vector<uint8_t> out(data.size() + CDRO_CAPTURE_RECORD_OVERHEAD);
    EXPECT_EQ(cdro_capture_record_encode(&record, out.data(), out.size()), 0U);
}

} // namespace
