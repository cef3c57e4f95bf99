#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "cdro/sog_layout.h"
#include "golden.hpp"

namespace {

#define SOG_X_FILL(KIND, field, unit, doc) \
    if (j.contains(#field))                \
        m.field = static_cast<CDRO_CTYPE_##KIND>(j.at(#field).get<int64_t>());
#define SOG_X_FILL_RANGED(KIND, field, unit, lo, hi, doc) SOG_X_FILL(KIND, field, unit, doc)
#define SOG_X_TO(KIND, field, unit, doc) out[#field] = static_cast<int64_t>(m.field);
#define SOG_X_TO_RANGED(KIND, field, unit, lo, hi, doc) SOG_X_TO(KIND, field, unit, doc)
#define SOG_X_NO_ARRAY(KIND, field, max, unit, lo, hi, doc)
#define SOG_X_CONVERT(NAME, name, id, doc)                                          \
    [[maybe_unused]] cdro_##name##_t name##FromJson(const nlohmann::json &j)        \
    {                                                                               \
        cdro_##name##_t m{};                                                        \
        CDRO_FIELDS_##NAME(SOG_X_FILL, SOG_X_FILL_RANGED, SOG_X_NO_ARRAY) return m; \
    }                                                                               \
    [[maybe_unused]] nlohmann::json name##ToJson(const cdro_##name##_t &m)          \
    {                                                                               \
        nlohmann::json out = nlohmann::json::object();                              \
        CDRO_FIELDS_##NAME(SOG_X_TO, SOG_X_TO_RANGED, SOG_X_NO_ARRAY) return out;   \
    }
CDRO_SOG_RECORD_LIST(SOG_X_CONVERT)

int appendToVector(void *context, const uint8_t *bytes, size_t len)
{
    auto *out = static_cast<std::vector<uint8_t> *>(context);
    out->insert(out->end(), bytes, bytes + len);
    return 1;
}

std::vector<uint8_t> writeGolden()
{
    const auto &v = golden::vectors()["sog"];
    std::vector<uint8_t> out;
    cdro_sog_writer_t writer;
    cdro_sog_writer_init(&writer, appendToVector, &out);
    cdro_sog_header_t header = sog_headerFromJson(v["header"]);
    header.layout_version = CDRO_SOG_LAYOUT_VERSION;
    header.layout_hash = CDRO_SOG_LAYOUT_HASH;
    header.node_count = static_cast<uint16_t>(v["nodes"].size());
    header.pair_count = static_cast<uint32_t>(v["pairs"].size());
    header.component_count = 0;
    for (const auto &p : v["pairs"]) {
        header.component_count += static_cast<uint32_t>(p["components"].size());
    }
    EXPECT_EQ(cdro_sog_write_header(&writer, &header), CDRO_OK);
    for (const auto &n : v["nodes"]) {
        const cdro_sog_node_t node = sog_nodeFromJson(n);
        EXPECT_EQ(cdro_sog_write_node(&writer, &node), CDRO_OK);
    }
    for (const auto &p : v["pairs"]) {
        cdro_sog_pair_t pair = sog_pairFromJson(p["fields"]);
        pair.component_count = static_cast<uint16_t>(p["components"].size());
        EXPECT_EQ(cdro_sog_write_pair(&writer, &pair), CDRO_OK);
        for (const auto &c : p["components"]) {
            const cdro_sog_component_t component = sog_componentFromJson(c);
            EXPECT_EQ(cdro_sog_write_component(&writer, &component), CDRO_OK);
        }
    }
    for (const auto &e : v["extensions"]) {
        const auto data = golden::fromHex(e["data"]);
        EXPECT_EQ(cdro_sog_write_extension(&writer, e["tag"].get<uint16_t>(), data.data(),
                                           static_cast<uint32_t>(data.size())),
                  CDRO_OK);
    }
    EXPECT_EQ(cdro_sog_write_end(&writer), CDRO_OK);
    return out;
}

TEST(SogLayout, GoldenSnapshotWritesTheGoldenBytes)
{
    EXPECT_EQ(golden::toHex(writeGolden()), golden::vectors()["sog"]["bytes"].get<std::string>());
}

TEST(SogLayout, GoldenBytesReadBackToTheGoldenRecords)
{
    const auto &v = golden::vectors()["sog"];
    const auto bytes = golden::fromHex(v["bytes"]);
    cdro_sog_reader_t reader;
    cdro_sog_header_t header;
    ASSERT_EQ(cdro_sog_reader_init(&reader, bytes.data(), bytes.size(), &header), CDRO_OK);
    EXPECT_EQ(header.ranges_processed, v["header"]["ranges_processed"].get<uint32_t>());
    ASSERT_EQ(header.node_count, v["nodes"].size());
    for (const auto &expected : v["nodes"]) {
        cdro_sog_node_t node;
        ASSERT_EQ(cdro_sog_read_node(&reader, &node), CDRO_OK);
        EXPECT_EQ(sog_nodeToJson(node), expected);
    }
    ASSERT_EQ(header.pair_count, v["pairs"].size());
    for (const auto &expected : v["pairs"]) {
        cdro_sog_pair_t pair;
        ASSERT_EQ(cdro_sog_read_pair(&reader, &pair), CDRO_OK);
        auto fields = sog_pairToJson(pair);
        fields.erase("component_count");
        EXPECT_EQ(fields, expected["fields"]);
        ASSERT_EQ(pair.component_count, expected["components"].size());
        for (const auto &c : expected["components"]) {
            cdro_sog_component_t component;
            ASSERT_EQ(cdro_sog_read_component(&reader, &component), CDRO_OK);
            EXPECT_EQ(sog_componentToJson(component), c);
        }
    }
    uint16_t tag = 0;
    const uint8_t *data = nullptr;
    uint32_t len = 0;
    ASSERT_EQ(cdro_sog_read_extension(&reader, &tag, &data, &len), CDRO_OK);
    EXPECT_EQ(tag, v["extensions"][0]["tag"].get<uint16_t>());
    EXPECT_EQ(golden::toHex(data, len), v["extensions"][0]["data"].get<std::string>());
    ASSERT_EQ(cdro_sog_read_extension(&reader, &tag, &data, &len), CDRO_OK);
    EXPECT_EQ(tag, 0) << "end marker";
}

TEST(SogLayout, RejectsCorruptCutShortForeignAndOtherLayouts)
{
    const auto good = golden::fromHex(golden::vectors()["sog"]["bytes"]);
    cdro_sog_reader_t reader;
    cdro_sog_header_t header;

    auto corrupt = good;
    corrupt[40] ^= 0x04;
    EXPECT_EQ(cdro_sog_reader_init(&reader, corrupt.data(), corrupt.size(), &header), CDRO_ERR_CRC);
    EXPECT_EQ(cdro_sog_reader_init(&reader, good.data(), good.size() - 1, &header), CDRO_ERR_CRC);
    auto foreign = good;
    foreign[0] = 'X';
    EXPECT_EQ(cdro_sog_reader_init(&reader, foreign.data(), foreign.size(), &header), CDRO_ERR_TYPE);
}

} // namespace
