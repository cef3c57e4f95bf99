// The C decoder against tests/golden/bounds_cases.json, the edges of every value range of
// frame_layout.def; tests/tools/test_bounds.py holds the Python decoder to the same table.
#include <cstdint>
#include <limits>
#include <map>
#include <string>
#include <utility>

#include <gtest/gtest.h>

#include "cdro/frames.h"
#include "golden.hpp"

namespace {

const nlohmann::json &cases()
{
    static const nlohmann::json parsed =
        nlohmann::json::parse(golden::readFile(std::string(CDRO_GOLDEN_DIR) + "/bounds_cases.json"));
    return parsed.at("cases");
}

TEST(Bounds, EveryEdgeGetsItsVerdict)
{
    ASSERT_FALSE(cases().empty());
    for (const auto &c : cases()) {
        const auto chunk = golden::fromHex(c.at("chunk"));
        cdro_frame_t frame;
        int result = cdro_frame_decode(chunk.data(), chunk.size(), &frame);
        if (result == CDRO_OK) {
            result = cdro_frame_validate(&frame);
        }
        EXPECT_STREQ(cdro_result_name(result), c.at("result").get<std::string>().c_str()) << c.at("name");
        if (c.contains("fields") && (result == CDRO_OK || result == CDRO_ERR_VALUE)) {
            EXPECT_EQ(golden::fieldsToJson(frame), c.at("fields")) << c.at("name"); // the chunk holds the edge
        }
    }
}

// The table's edges, by "TYPE.field" and edge name.
std::map<std::pair<std::string, std::string>, int64_t> edgesInTable()
{
    std::map<std::pair<std::string, std::string>, int64_t> edges;
    for (const auto &c : cases()) {
        if (c.contains("field")) {
            edges[{c.at("field").get<std::string>(), c.at("edge").get<std::string>()}] = c.at("value").get<int64_t>();
        }
    }
    return edges;
}

// Checks the edges of one range as the C expansion of frame_layout.def declares it; returns
// how many the table must hold for it.
template <typename T>
size_t expectEdges(const std::map<std::pair<std::string, std::string>, int64_t> &edges, const std::string &field,
                   int64_t lo, int64_t hi)
{
    const auto at = [&](const char *edge) {
        const auto found = edges.find({field, edge});
        return found == edges.end() ? std::string("missing") : std::to_string(found->second);
    };
    size_t expected = 2;
    EXPECT_EQ(at("min"), std::to_string(lo)) << field;
    EXPECT_EQ(at("max"), std::to_string(hi)) << field;
    if (lo > static_cast<int64_t>(std::numeric_limits<T>::min())) {
        EXPECT_EQ(at("min-1"), std::to_string(lo - 1)) << field;
        ++expected;
    } else {
        EXPECT_EQ(at("min-1"), "missing") << field << ": its kind cannot hold MIN - 1";
    }
    if (hi < static_cast<int64_t>(std::numeric_limits<T>::max())) {
        EXPECT_EQ(at("max+1"), std::to_string(hi + 1)) << field;
        ++expected;
    } else {
        EXPECT_EQ(at("max+1"), "missing") << field << ": its kind cannot hold MAX + 1";
    }
    return expected;
}

// The ranges as C reads them (not as the Python generator of the table parsed them): both
// readings of frame_layout.def must agree, and the table must cover every range.
TEST(Bounds, TheTableHoldsTheEdgesOfEveryRangeCDeclares)
{
    const auto edges = edgesInTable();
    size_t expected = 0;
    std::string record;
#define BOUNDS_X_ANY(KIND, field, unit, doc)
#define BOUNDS_X_RANGE(KIND, field, unit, lo, hi, doc) \
    expected += expectEdges<CDRO_CTYPE_##KIND>(edges, record + "." #field, (lo), (hi));
#define BOUNDS_X_ARRAY(KIND, field, max, unit, lo, hi, doc)                                    \
    expected += expectEdges<CDRO_CTYPE_##KIND>(edges, record + "." #field, (lo), (hi));        \
    expected += 3; /* its count: 0 and MAX accepted, MAX + 1 refused */                        \
    EXPECT_EQ(edges.count({record + "." #field "_count", "min"}), 1U) << record << "." #field; \
    EXPECT_EQ(edges.at({record + "." #field "_count", "max"}), (max)) << record << "." #field; \
    EXPECT_EQ(edges.at({record + "." #field "_count", "max+1"}), (max) + 1) << record << "." #field;
#define BOUNDS_X_RECORD(NAME, name, id, doc) \
    record = #NAME;                          \
    CDRO_FIELDS_##NAME(BOUNDS_X_ANY, BOUNDS_X_RANGE, BOUNDS_X_ARRAY)
    CDRO_FRAME_LIST(BOUNDS_X_RECORD)
#undef BOUNDS_X_RECORD
#undef BOUNDS_X_ARRAY
#undef BOUNDS_X_RANGE
#undef BOUNDS_X_ANY
    EXPECT_EQ(edges.size(), expected) << "the table has edges of a range that C does not declare";
}

} // namespace
