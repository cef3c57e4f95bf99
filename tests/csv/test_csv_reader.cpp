// The CSV reader (host/csv/include/cdro/csv/reader.hpp): columns by header name, the two
// policies for bad rows, and the lines every program reads the same way (CRLF, blank lines, #
// comments, a byte-order mark, quotes), node ids in decimal and 0x hex; files that are refused
// as a whole.
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <string_view>
#include <vector>

#include <gtest/gtest.h>

#include "cdro/csv/reader.hpp"

namespace cdro::csv {
namespace {

class TempDir {
public:
    TempDir()
    {
        std::string pattern = (std::filesystem::temp_directory_path() / "cdro-csv-test-XXXXXX").string();
        if (::mkdtemp(pattern.data()) == nullptr) {
            throw std::runtime_error("mkdtemp failed");
        }
        path_ = pattern;
    }
    ~TempDir()
    {
        std::error_code ignored;
        std::filesystem::remove_all(path_, ignored);
    }
    TempDir(const TempDir &) = delete;
    TempDir &operator=(const TempDir &) = delete;

    std::string write(const std::string &name, const std::string &bytes) const
    {
        std::string path = path_ + "/" + name;
        std::ofstream(path, std::ios::binary) << bytes;
        return path;
    }
    const std::string &path() const { return path_; }

private:
    std::string path_;
};

// The ranges file of cdro-hostd: from,to,range_m required, t optional, positional layouts too.
Format rangesFormat(bool headerless = false)
{
    Format format{{"from", "to", "range_m"}, {"t"}, {}};
    if (headerless) {
        format.headerless = {{"from", "to", "range_m"}, {"t", "from", "to", "range_m"}};
    }
    return format;
}

struct Range {
    size_t line = 0;
    bool has_t = false;
    double t_s = 0.0;
    uint16_t from = 0;
    uint16_t to = 0;
    double range_m = 0.0;
    bool operator==(const Range &o) const
    {
        return line == o.line && has_t == o.has_t && t_s == o.t_s && from == o.from && to == o.to &&
               range_m == o.range_m;
    }
};

std::ostream &operator<<(std::ostream &out, const Range &r)
{
    return out << "{line " << r.line << (r.has_t ? " t " + std::to_string(r.t_s) : std::string()) << ", " << r.from
               << " -> " << r.to << ", " << r.range_m << " m}";
}

struct Read {
    std::vector<Range> rows;
    Summary summary;
};

Read readRanges(const std::string &path, Policy policy, const Format &format = rangesFormat(),
                size_t kept = kKeptProblems)
{
    Read read;
    Reader reader(path, format, policy, kept);
    reader.forEach([&](const Row &row) {
        Range r;
        r.line = row.line();
        r.has_t = row.has("t");
        if ((r.has_t && !row.number("t", &r.t_s)) || !row.nodeId("from", &r.from) || !row.nodeId("to", &r.to) ||
            !row.number("range_m", &r.range_m)) {
            return;
        }
        read.rows.push_back(r);
    });
    read.summary = reader.summary();
    return read;
}

// The message of the Error reading `path` throws ("" when none is thrown).
std::string errorOf(const std::string &path, Policy policy, const Format &format = rangesFormat())
{
    try {
        readRanges(path, policy, format);
    } catch (const Error &error) {
        return error.what();
    }
    return "";
}

TEST(CsvReader, LooksColumnsUpByHeaderNameInAnyOrderAndIgnoresOthers)
{
    TempDir dir;
    const std::string path = dir.write("r.csv", "quality,range_m,to,from\ngood,2.5,7,3\nbad,4.25,0x6001,9\n");

    const Read read = readRanges(path, Policy::Strict);

    ASSERT_EQ(read.rows.size(), 2U);
    EXPECT_EQ(read.rows[0], (Range{2, false, 0.0, 3, 7, 2.5}));
    EXPECT_EQ(read.rows[1], (Range{3, false, 0.0, 9, 0x6001, 4.25}));
    EXPECT_EQ(read.summary.data_rows, 2U);
    EXPECT_EQ(read.summary.bad_rows, 0U);
}

TEST(CsvReader, TakesAnOptionalColumnWhenTheHeaderNamesIt)
{
    TempDir dir;
    const std::string path = dir.write("r.csv", "t,from,to,range_m\n0.5,1,2,3.0\n");

    const Read read = readRanges(path, Policy::Strict);

    ASSERT_EQ(read.rows.size(), 1U);
    EXPECT_EQ(read.rows[0], (Range{2, true, 0.5, 1, 2, 3.0}));
}

TEST(CsvReader, RefusesAHeaderWithoutARequiredColumnNamingFileLineAndColumn)
{
    TempDir dir;
    const std::string path = dir.write("r.csv", "# a comment first\nfrom,to,distance\n1,2,3\n");

    for (const Policy policy : {Policy::Strict, Policy::Lenient}) {
        EXPECT_EQ(errorOf(path, policy), path + ":2: the header has no column 'range_m' (expected from,to,range_m)");
    }
}

TEST(CsvReader, RefusesAHeaderThatNamesADeclaredColumnTwice)
{
    TempDir dir;
    const std::string path = dir.write("r.csv", "from,to,range_m,to\n1,2,3,4\n");

    EXPECT_EQ(errorOf(path, Policy::Lenient), path + ":1: the header names column 'to' twice");
}

TEST(CsvReader, ReadsCrLfLinesAsLfLines)
{
    TempDir dir;
    const std::string lf = dir.write("lf.csv", "from,to,range_m\n1,2,3.5\n# note\n\n2,3,4.5\n3,1,5.5");
    const std::string crlf =
        dir.write("crlf.csv", "from,to,range_m\r\n1,2,3.5\r\n# note\r\n\r\n2,3,4.5\r\n3,1,5.5\r\n");

    const Read a = readRanges(lf, Policy::Strict);
    const Read b = readRanges(crlf, Policy::Strict);

    ASSERT_EQ(a.rows.size(), 3U);
    EXPECT_EQ(a.rows, b.rows);
    EXPECT_EQ(b.rows[2], (Range{6, false, 0.0, 3, 1, 5.5})); // the last line of each: with and without its end
}

TEST(CsvReader, SkipsBlankLinesAndCommentsAnywhereAndKeepsLineNumbers)
{
    TempDir dir;
    const std::string path =
        dir.write("r.csv",
                  "\n# before the header\n  \t\nfrom,to,range_m\n  # indented comment\n1,2,3.0\n\n\t\n2,3,4.0\n#\n");

    const Read read = readRanges(path, Policy::Strict);

    ASSERT_EQ(read.rows.size(), 2U);
    EXPECT_EQ(read.rows[0].line, 6U);
    EXPECT_EQ(read.rows[1].line, 9U);
    EXPECT_EQ(read.summary.data_rows, 2U);
}

TEST(CsvReader, TrimsSpacesAndTabsAroundFieldsAndHeaderNames)
{
    TempDir dir;
    const std::string path = dir.write("r.csv", " from ,\tto , range_m\n 1 ,\t2\t, 3.25 \n");

    const Read read = readRanges(path, Policy::Strict);

    ASSERT_EQ(read.rows.size(), 1U);
    EXPECT_EQ(read.rows[0], (Range{2, false, 0.0, 1, 2, 3.25}));
}

TEST(CsvReader, SkipsAByteOrderMark)
{
    TempDir dir;
    const std::string path = dir.write("r.csv", "\xEF\xBB\xBF"
                                                "from,to,range_m\n1,2,3.0\n");

    const Read read = readRanges(path, Policy::Strict);

    ASSERT_EQ(read.rows.size(), 1U);
    EXPECT_EQ(read.rows[0], (Range{2, false, 0.0, 1, 2, 3.0}));
}

TEST(CsvReader, UnquotesQuotedFieldsAsRfc4180Says)
{
    TempDir dir;
    const std::string path = dir.write("r.csv", "\"from\",\"to\",\"range_m\",\"note\"\n"
                                                "\"1\", \"0x6001\" ,2.5,\"a, \"\"quoted\"\" note\"\n");
    std::vector<std::string> notes;

    Reader reader(path, Format{{"from", "to", "range_m"}, {"note"}, {}}, Policy::Strict);
    reader.forEach([&](const Row &row) {
        uint16_t from = 0;
        uint16_t to = 0;
        double range_m = 0.0;
        std::string_view note;
        ASSERT_TRUE(row.nodeId("from", &from) && row.nodeId("to", &to) && row.number("range_m", &range_m) &&
                    row.text("note", &note));
        EXPECT_EQ(from, 1);
        EXPECT_EQ(to, 0x6001);
        EXPECT_EQ(range_m, 2.5);
        notes.emplace_back(note);
    });

    EXPECT_EQ(notes, std::vector<std::string>{"a, \"quoted\" note"});
}

TEST(CsvReader, MakesARowWithABrokenQuoteBad)
{
    TempDir dir;
    const std::string path = dir.write("r.csv", "from,to,range_m\n1,2,\"3.0\n1,2,\"3.0\"x\n1,2,3.0\n");

    const Read read = readRanges(path, Policy::Lenient);

    ASSERT_EQ(read.rows.size(), 1U);
    ASSERT_EQ(read.summary.problems.size(), 2U);
    EXPECT_EQ(read.summary.problems[0].line, 2U);
    EXPECT_NE(read.summary.problems[0].message.find("without its closing quote"), std::string::npos);
    EXPECT_EQ(read.summary.problems[1].line, 3U);
    EXPECT_NE(read.summary.problems[1].message.find("after the closing quote"), std::string::npos);
}

TEST(CsvReader, ParsesNodeIdsInDecimalAndHexWithinOneToFfff)
{
    const std::vector<std::pair<std::string, int>> cases = {{"1", 1},          {"42", 42},
                                                            {"007", 7},        {"65535", 65535},
                                                            {"0x2A", 42},      {"0X2a", 42},
                                                            {"0xFFFF", 65535}, {"0x0001", 1},
                                                            {"0", -1},         {"0x0", -1},
                                                            {"65536", -1},     {"0x10000", -1},
                                                            {"", -1},          {"0x", -1},
                                                            {"-1", -1},        {"+5", 5},
                                                            {"+0x5", -1},      {"+", -1},
                                                            {"1.0", -1},       {"2a", -1},
                                                            {"0x2G", -1},      {"99999999999999999999", -1},
                                                            {" 5", -1}};
    for (const auto &[text, expected] : cases) {
        uint16_t id = 0;
        const bool ok = parseNodeId(text, &id);
        EXPECT_EQ(ok, expected >= 0) << "'" << text << "'";
        if (ok) {
            EXPECT_EQ(id, expected) << "'" << text << "'";
        }
    }
}

TEST(CsvReader, ParsesOnlyWholeFiniteNumbers)
{
    const std::vector<std::pair<std::string, bool>> cases = {{"1.5", true},    {"-2e3", true},  {"0", true},
                                                             {"0x1p3", true},  {"", false},     {"nan", false},
                                                             {"inf", false},   {"-inf", false}, {"1e999", false},
                                                             {"1.5 m", false}, {"1,5", false},  {"abc", false}};
    for (const auto &[text, expected] : cases) {
        double value = 0.0;
        EXPECT_EQ(parseNumber(text, &value), expected) << "'" << text << "'";
    }
    double value = 0.0;
    ASSERT_TRUE(parseNumber("-2e3", &value));
    EXPECT_EQ(value, -2000.0);
}

TEST(CsvReader, StrictStopsAtTheFirstBadRowWithFileLineColumnAndText)
{
    TempDir dir;
    const std::string path = dir.write("r.csv", "from,to,range_m\n1,2,3.0\n1,2,five\n1,2,zz\n");

    EXPECT_EQ(errorOf(path, Policy::Strict), path + ":3: range_m 'five' is not a finite number");
}

TEST(CsvReader, StrictReportsABadIdAndTooFewFieldsTheSameWay)
{
    TempDir dir;
    const std::string bad_id = dir.write("id.csv", "from,to,range_m\n0,2,3.0\n");
    const std::string short_row = dir.write("short.csv", "from,to,range_m\n1,2\n");

    EXPECT_EQ(errorOf(bad_id, Policy::Strict),
              bad_id + ":2: from '0' is not a node id (1..65535, decimal or 0x hex; 0 is not a node on the live link "
                       "either)");
    EXPECT_EQ(errorOf(short_row, Policy::Strict), short_row + ":2: too few fields (2)");
}

TEST(CsvReader, LenientSkipsAndCountsBadRowsAndKeepsTheFirstReasons)
{
    TempDir dir;
    std::string text = "from,to,range_m\n1,2,3.0\n1,2,five\n1,2\nx,2,3.0\n2,3,4.0\n1,2,nan\n";
    for (int i = 0; i < 30; ++i) {
        text += "1,2,oops\n";
    }
    const std::string path = dir.write("r.csv", text);

    const Read read = readRanges(path, Policy::Lenient, rangesFormat(), 4);

    ASSERT_EQ(read.rows.size(), 2U);
    EXPECT_EQ(read.rows[0].line, 2U);
    EXPECT_EQ(read.rows[1].line, 6U);
    EXPECT_EQ(read.summary.data_rows, 36U);
    EXPECT_EQ(read.summary.bad_rows, 34U);
    ASSERT_EQ(read.summary.problems.size(), 4U);
    EXPECT_EQ(read.summary.problems[0].line, 3U);
    EXPECT_EQ(read.summary.problems[0].message, "range_m 'five' is not a finite number");
    EXPECT_EQ(read.summary.problems[1].line, 4U);
    EXPECT_EQ(read.summary.problems[1].message, "too few fields (2)");
    EXPECT_EQ(read.summary.problems[2].line, 5U);
    EXPECT_EQ(read.summary.problems[2].message.rfind("from 'x' is not a node id", 0), 0U);
    EXPECT_EQ(read.summary.problems[3].line, 7U);
    EXPECT_EQ(read.summary.problems[3].message, "range_m 'nan' is not a finite number");
}

TEST(CsvReader, ACallersOwnCheckMakesTheRowBadLikeAnAccessor)
{
    TempDir dir;
    const std::string path = dir.write("m.csv", "t,id,moving\n1.0,5,1\n2.0,5,2\n");
    std::vector<size_t> lines;

    Reader reader(path, Format{{"t", "id", "moving"}, {}, {}}, Policy::Lenient);
    reader.forEach([&](const Row &row) {
        double moving = 0.0;
        if (!row.number("moving", &moving)) {
            return;
        }
        if (moving != 0.0 && moving != 1.0) {
            row.reject("moving must be 0 or 1");
            return;
        }
        lines.push_back(row.line());
    });

    EXPECT_EQ(lines, std::vector<size_t>{2});
    ASSERT_EQ(reader.summary().problems.size(), 1U);
    EXPECT_EQ(reader.summary().problems[0].line, 3U);
    EXPECT_EQ(reader.summary().problems[0].message, "moving must be 0 or 1");
    Reader strict(path, Format{{"t", "id", "moving"}, {}, {}}, Policy::Strict);
    try {
        strict.forEach([](const Row &row) {
            double moving = 0.0;
            if (row.number("moving", &moving) && moving > 1.0) {
                row.reject("moving must be 0 or 1");
            }
        });
        ADD_FAILURE() << "no error";
    } catch (const Error &error) {
        EXPECT_EQ(std::string(error.what()), path + ":3: moving must be 0 or 1");
    }
}

TEST(CsvReader, AnEmptyFileIsRefusedWhereAHeaderIsRequiredAndHasNoRowsWhereNot)
{
    TempDir dir;
    const std::string empty = dir.write("empty.csv", "");
    const std::string comments = dir.write("comments.csv", "# nothing here\n\n");

    for (const std::string &path : {empty, comments}) {
        EXPECT_EQ(errorOf(path, Policy::Lenient),
                  path + ": empty file (expected a header naming the columns from,to,range_m)");
        const Read read = readRanges(path, Policy::Strict, rangesFormat(true));
        EXPECT_TRUE(read.rows.empty());
        EXPECT_EQ(read.summary.data_rows, 0U);
    }
}

TEST(CsvReader, AFileWithOnlyAHeaderHasNoRows)
{
    TempDir dir;
    for (const char *text : {"from,to,range_m", "from,to,range_m\n", "from,to,range_m\r\n# end\n\n"}) {
        const std::string path = dir.write("h.csv", text);
        for (const Policy policy : {Policy::Strict, Policy::Lenient}) {
            const Read read = readRanges(path, policy);
            EXPECT_TRUE(read.rows.empty());
            EXPECT_EQ(read.summary.data_rows, 0U);
            EXPECT_EQ(read.summary.bad_rows, 0U);
        }
    }
}

TEST(CsvReader, RefusesAFirstLineOfDataWhereAHeaderIsRequired)
{
    TempDir dir;
    const std::string path = dir.write("r.csv", "# ranges\n1,2,3.0\n");

    EXPECT_EQ(errorOf(path, Policy::Lenient),
              path + ":2: no header: the first line is data (expected a header naming the columns from,to,range_m)");
}

TEST(CsvReader, ReadsHeaderlessLayoutsByFieldCount)
{
    TempDir dir;
    const std::string path = dir.write("r.csv", "1,2,3.0\n0.5,0x10,2,4.0\n1,2,3,4,5\n0x6001,7,nan\n");

    const Read read = readRanges(path, Policy::Lenient, rangesFormat(true));

    ASSERT_EQ(read.rows.size(), 2U);
    EXPECT_EQ(read.rows[0], (Range{1, false, 0.0, 1, 2, 3.0}));
    EXPECT_EQ(read.rows[1], (Range{2, true, 0.5, 16, 2, 4.0}));
    ASSERT_EQ(read.summary.problems.size(), 2U);
    EXPECT_EQ(read.summary.problems[0].message, "5 fields, expected 3 or 4");
    EXPECT_EQ(read.summary.problems[1].message, "range_m 'nan' is not a finite number");
}

TEST(CsvReader, AHeaderlessLayoutMayNamePositionsNobodyReads)
{
    TempDir dir;
    const std::string path = dir.write("h.csv", "1,0.5\n2,10.0,20.0,1.5\n3,1.0,2.0\n");
    std::vector<std::pair<uint16_t, double>> heights;

    Reader reader(path, Format{{"id", "z"}, {}, {{"id", "z"}, {"id", "x", "y", "z"}}}, Policy::Lenient);
    reader.forEach([&](const Row &row) {
        uint16_t id = 0;
        double z_m = 0.0;
        if (row.nodeId("id", &id) && row.number("z", &z_m)) {
            heights.emplace_back(id, z_m);
        }
    });

    EXPECT_EQ(heights, (std::vector<std::pair<uint16_t, double>>{{1, 0.5}, {2, 1.5}}));
    ASSERT_EQ(reader.summary().problems.size(), 1U);
    EXPECT_EQ(reader.summary().problems[0].message, "3 fields, expected 2 or 4");
}

TEST(CsvReader, AFirstRowWithABadNumberIsStillDataNotAHeader)
{
    TempDir dir;
    const std::string path = dir.write("r.csv", "1,2,nan\n1,,3.0\n2,3,4.0\n");

    const Read read = readRanges(path, Policy::Lenient, rangesFormat(true));

    ASSERT_EQ(read.rows.size(), 1U);
    EXPECT_EQ(read.rows[0].line, 3U);
    EXPECT_EQ(read.summary.bad_rows, 2U);
}

TEST(CsvReader, RefusesWhatIsNotACsvFileAtAll)
{
    TempDir dir;
    const std::string nul = dir.write("nul.csv", std::string("from,to,range_m\n1,2,3.0\n1,2\0,3\n", 30));
    const std::string long_line =
        dir.write("long.csv", "from,to,range_m\n1,2," + std::string(kMaxLineBytes, '9') + "\n");

    EXPECT_EQ(errorOf(nul, Policy::Lenient), nul + ":3: a 0x00 byte: not a CSV file");
    EXPECT_EQ(errorOf(long_line, Policy::Lenient),
              long_line + ":2: a line longer than 4096 bytes: not a CSV file of this kind");
    EXPECT_EQ(errorOf(dir.path(), Policy::Lenient), dir.path() + ": is a directory, not a CSV file");
    EXPECT_EQ(errorOf(dir.path() + "/missing.csv", Policy::Lenient)
                  .rfind(dir.path() + "/missing.csv: cannot open the file (", 0),
              0U);
}

TEST(CsvReader, SummaryInsideOnRowCountsTheRowsBeforeIt)
{
    TempDir dir;
    const std::string path = dir.write("r.csv", "from,to,range_m\n1,2,x\n1,2,3.0\n1,2,y\n2,3,4.0\n");
    std::vector<std::pair<size_t, size_t>> seen; // (data rows, bad rows) before each good row

    Reader reader(path, rangesFormat(), Policy::Lenient);
    reader.forEach([&](const Row &row) {
        double range_m = 0.0;
        if (row.number("range_m", &range_m)) {
            seen.emplace_back(reader.summary().data_rows, reader.summary().bad_rows);
        }
    });

    EXPECT_EQ(seen, (std::vector<std::pair<size_t, size_t>>{{1, 1}, {3, 2}}));
    EXPECT_EQ(reader.summary().data_rows, 4U);
}

TEST(CsvReader, AnUndeclaredColumnIsABugNotABadRow)
{
    TempDir dir;
    const std::string path = dir.write("r.csv", "from,to,range_m\n1,2,3.0\n");

    Reader reader(path, rangesFormat(), Policy::Lenient);
    double range_m = 0.0;
    EXPECT_THROW(reader.forEach([&](const Row &row) { (void)row.number("rnage_m", &range_m); }), std::logic_error);
}

TEST(CsvReader, ARowWithAFailedAccessorIsBadWhateverOnRowDidNextAndKeepsItsFirstReason)
{
    TempDir dir;
    const std::string path = dir.write("r.csv", "from,to,range_m\nx,y,3.0\n1,2,3.0\n");
    size_t calls = 0;

    Reader reader(path, rangesFormat(), Policy::Lenient);
    reader.forEach([&](const Row &row) {
        uint16_t from = 0;
        uint16_t to = 0;
        double range_m = 0.0;
        (void)row.nodeId("from", &from); // a caller that goes on regardless
        (void)row.nodeId("to", &to);
        (void)row.number("range_m", &range_m);
        ++calls;
    });

    EXPECT_EQ(calls, 2U);
    EXPECT_EQ(reader.summary().bad_rows, 1U);
    ASSERT_EQ(reader.summary().problems.size(), 1U);
    EXPECT_EQ(reader.summary().problems[0].message.rfind("from 'x' is not a node id", 0), 0U);
}

} // namespace
} // namespace cdro::csv
