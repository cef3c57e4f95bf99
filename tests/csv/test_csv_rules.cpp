// The CSV reading rules where the two languages meet: the files of tests/data/csv_rules/ and the
// answers of its cases.json, which tests/tools/test_csv_rules.py asserts for the Python reader
// (cdro_tools.evaluation.inputs). Each case's file is read by csv::Reader with the manifest's
// format and accessors, and must give exactly the case's rows and problems, or its error.
#include <algorithm>
#include <cctype>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "cdro/csv/reader.hpp"

namespace cdro::csv {
namespace {

const std::string kRulesDir = CDRO_CSV_RULES_DIR;

// cases.json (null when it cannot be read: ManifestNamesEveryFixture says so).
const nlohmann::json &manifest()
{
    static const nlohmann::json parsed = [] {
        std::ifstream in(kRulesDir + "/cases.json");
        if (!in) {
            return nlohmann::json();
        }
        std::stringstream text;
        text << in.rdbuf();
        return nlohmann::json::parse(text.str());
    }();
    return parsed;
}

std::vector<std::string> names(const nlohmann::json &array) { return array.get<std::vector<std::string>>(); }

Format formatOf(const nlohmann::json &kind)
{
    Format format{names(kind["required"]), names(kind["optional"]), {}};
    for (const nlohmann::json &layout : kind["headerless"]) {
        format.headerless.push_back(names(layout));
    }
    return format;
}

// One accessor of cases.json on one column: the value, or false with the row made bad.
bool readField(const Row &row, const std::string &column, const std::string &accessor, nlohmann::json *value)
{
    if (accessor == "number") {
        double number = 0.0;
        if (!row.number(column, &number)) {
            return false;
        }
        *value = number;
        return true;
    }
    if (accessor == "node_id") {
        uint16_t id = 0;
        if (!row.nodeId(column, &id)) {
            return false;
        }
        *value = id;
        return true;
    }
    if (accessor == "flag") { // a number that is 0 or 1, as cdro-hostd reads `moving` (csv_input.cpp)
        double number = 0.0;
        if (!row.number(column, &number)) {
            return false;
        }
        if (number != 0.0 && number != 1.0) {
            return row.reject(column + " must be 0 or 1");
        }
        *value = number == 1.0;
        return true;
    }
    throw std::logic_error("cases.json: unknown accessor '" + accessor + "'");
}

struct Outcome {
    nlohmann::json rows = nlohmann::json::array();
    Summary summary;
    std::string error; // the Error's message ("" when none)
};

// The case's file through csv::Reader, each row read with its kind's accessors in order (an
// optional column only when the row has it; the first that fails makes the row bad).
Outcome readCase(const nlohmann::json &c)
{
    const nlohmann::json &kind = manifest()["kinds"][c["kind"].get<std::string>()];
    const std::vector<std::string> optional = names(kind["optional"]);
    const Policy policy = c["mode"] == "strict" ? Policy::Strict : Policy::Lenient;
    Outcome outcome;
    try {
        Reader reader(kRulesDir + "/" + c["file"].get<std::string>(), formatOf(kind), policy);
        reader.forEach([&](const Row &row) {
            nlohmann::json values = {{"line", row.line()}};
            for (const nlohmann::json &field : kind["fields"]) {
                const std::string column = field[0].get<std::string>();
                if (std::find(optional.begin(), optional.end(), column) != optional.end() && !row.has(column)) {
                    continue;
                }
                if (!readField(row, column, field[1].get<std::string>(), &values[column])) {
                    return;
                }
            }
            outcome.rows.push_back(values);
        });
        outcome.summary = reader.summary();
    } catch (const Error &error) {
        outcome.error = error.what();
    }
    return outcome;
}

std::vector<size_t> caseIndices()
{
    std::vector<size_t> indices;
    const nlohmann::json &m = manifest();
    for (size_t i = 0; !m.is_null() && i < m["cases"].size(); ++i) {
        indices.push_back(i);
    }
    return indices;
}

TEST(CsvRules, ManifestNamesEveryFixture)
{
    ASSERT_FALSE(manifest().is_null()) << kRulesDir << "/cases.json cannot be read";
    std::set<std::string> files;
    for (const auto &entry : std::filesystem::directory_iterator(kRulesDir)) {
        if (entry.path().extension() == ".csv") {
            files.insert(entry.path().filename().string());
        }
    }
    std::set<std::string> named;
    for (const nlohmann::json &c : manifest()["cases"]) {
        named.insert(c["file"].get<std::string>());
    }
    EXPECT_EQ(files, named);
}

class CsvRulesCase : public testing::TestWithParam<size_t> {};

TEST_P(CsvRulesCase, ReadsAsTheManifestSays)
{
    const nlohmann::json &c = manifest()["cases"][GetParam()];
    SCOPED_TRACE(c["file"].get<std::string>() + ": " + c["rule"].get<std::string>());

    const Outcome outcome = readCase(c);

    if (c.contains("error")) {
        const nlohmann::json &error = c["error"];
        const std::string where = kRulesDir + "/" + c["file"].get<std::string>() +
                                  (error["line"].is_null() ? "" : ":" + std::to_string(error["line"].get<size_t>()));
        EXPECT_EQ(outcome.error, where + ": " + error["message"].get<std::string>());
        return;
    }
    ASSERT_EQ(outcome.error, "");
    EXPECT_EQ(outcome.rows, c["rows"]);
    EXPECT_EQ(outcome.summary.data_rows, c["data_rows"].get<size_t>());
    EXPECT_EQ(outcome.summary.bad_rows, c["problems"].size());
    nlohmann::json problems = nlohmann::json::array();
    for (const Problem &problem : outcome.summary.problems) {
        problems.push_back({{"line", problem.line}, {"message", problem.message}});
    }
    EXPECT_EQ(problems, c["problems"]);
}

// A test's name: the case's file, kind and mode ("bom_csv_ranges_strict").
std::string caseName(const testing::TestParamInfo<size_t> &param)
{
    const nlohmann::json &c = manifest()["cases"][param.param];
    std::string name =
        c["file"].get<std::string>() + "_" + c["kind"].get<std::string>() + "_" + c["mode"].get<std::string>();
    std::replace_if(
        name.begin(), name.end(), [](char ch) { return std::isalnum(static_cast<unsigned char>(ch)) == 0; }, '_');
    return name;
}

INSTANTIATE_TEST_SUITE_P(Cases, CsvRulesCase, testing::ValuesIn(caseIndices()), caseName);

TEST(CsvRules, NumbersAndNodeIdsParseAsTheManifestSays)
{
    ASSERT_FALSE(manifest().is_null());
    for (const nlohmann::json &item : manifest()["numbers"]) {
        const std::string text = item[0].get<std::string>();
        double value = 0.0;
        const bool ok = parseNumber(text, &value);
        EXPECT_EQ(ok, !item[1].is_null()) << "'" << text << "'";
        if (ok && !item[1].is_null()) {
            EXPECT_EQ(value, item[1].get<double>()) << "'" << text << "'";
        }
    }
    for (const nlohmann::json &item : manifest()["node_ids"]) {
        const std::string text = item[0].get<std::string>();
        uint16_t id = 0;
        const bool ok = parseNodeId(text, &id);
        EXPECT_EQ(ok, !item[1].is_null()) << "'" << text << "'";
        if (ok && !item[1].is_null()) {
            EXPECT_EQ(id, item[1].get<int>()) << "'" << text << "'";
        }
    }
}

} // namespace
} // namespace cdro::csv
