// reader.hpp: the one CSV reader of the C++ side. cdro-hostd's input files (csv_input.hpp), the
// benchmarks' PLANT loader (bench/common/plant_data.hpp), the engine tests' one and the FIL
// world's tests (cdro-fil's truth and ranges files) all read through it, so that a file means
// the same thing to every program that takes it. The Python tools read by the same rules
// (tools/cdro_tools/evaluation/inputs.py): the files of tests/data/csv_rules/ and the answers of
// its cases.json hold both readers to them
// (tests/csv/test_csv_rules.cpp, tests/tools/test_csv_rules.py); a rule changed here is changed
// there and in the manifest.
//
// Lines. A line ends with \n or \r\n (a file written on Windows reads as the same file); the
// last one needs no end. A UTF-8 byte-order mark at the start (spreadsheets write one) is
// skipped. Blank lines (nothing but spaces and tabs) and lines whose first other character is #
// are skipped wherever they are, before the header too; they keep their numbers, so a line
// number in a message is the one an editor shows. There are no comments after data: in
// "1,2,3 # x" the third field is "3 # x".
//
// Fields. Separated by commas; spaces and tabs around a field are not part of it ("1, 2 ,3.5").
// A field may be quoted as RFC 4180 says ("a,b" is one field, "" in it is one "), so that a
// header written by R or a spreadsheet ("from","to","range_m") reads; a quoted field does not
// span lines, and text after its closing quote makes the row bad.
//
// Columns. The caller declares the columns it requires and those it takes when they are there
// (Format). They are looked up by name in the header, the first line that is not blank or a
// comment, in any order; columns the caller did not declare are ignored, and so are fields
// beyond the header's. A header without a required column, or naming a declared one twice,
// refuses the file. A caller may also take files without a header (Format::headerless: the
// columns by position, one layout per number of fields): a first line whose every field is
// empty, 0x hex or a number to strtod (nan and inf too: a data row with a bad value is a bad row,
// not a header) is then data. Without headerless layouts a header is required, and a file
// without one (empty, only comments, or data on its first line) is refused.
//
// Rows. forEach gives the caller each data row in file order; the caller reads its fields by
// column name with typed accessors, each of which returns false when the field is not what it
// wants (they are [[nodiscard]]: a caller cannot use a value it did not get):
//   number(name, &v)  a finite double (strtod: "1.5", "-2e3", "0x1p3"; not "", "nan", "inf",
//                     "1e999", "1.5 m"; the programs keep the C locale: a . always)
//   nodeId(name, &id) a node id, 1..65535, decimal or 0x hex (parseNodeId)
//   text(name, &t)    the field as written (unquoted, without the spaces around it)
//   has(name)         whether the row has a field for an optional column
// A failed accessor makes the row bad, with a reason that names the column and shows the text:
// "range_m 'five' is not a finite number". So does a caller's own check (Row::reject: "moving
// must be 0 or 1"), and, before onRow sees the row, too few fields for a required column ("too
// few fields (2)"; without a header: "2 fields, expected 3 or 4") or a broken quote. onRow
// returns at the first false; a row with a failed accessor is bad whatever onRow did next, and
// only its first reason is kept. (No exception: a file of a million bad rows costs what a
// million good ones do.)
//
// Bad rows. What happens to them is the caller's one choice (Policy):
//   Strict   the first bad row ends the reading with Error "PATH:LINE: reason". For data that
//            must be right (PLANT in the benchmarks and the tests: a bad row there is a broken
//            checkout, and a result computed without it would be quietly wrong).
//   Lenient  bad rows are skipped and counted, and the reasons of the first kept_problems are
//            kept in file order (Summary) for the caller's report: one corrupt line in a long
//            recording does not throw the recording away (cdro-hostd's inputs).
//
// Files. What cannot be used at all is refused as a whole (Error, whatever the policy) before it
// can cost memory or time: a file that cannot be opened or read, a directory, a line longer than
// kMaxLineBytes (an endless device such as /dev/zero, a binary file), a 0x00 byte, a header as
// above. Files are read in one pass with a fixed buffer: linear in their size, any size.
//
// Error is the only exception that leaves the reader (with std::logic_error for a Format that
// contradicts itself or an accessor asked for a column that was not declared: bugs, not input),
// besides whatever onRow throws itself.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

namespace cdro::csv {

// A file that cannot be used at all, or (Strict) its first bad row: "PATH[:LINE]: why".
class Error : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

constexpr size_t kMaxLineBytes = 4096; // bytes; no row of the files read here comes near it
constexpr size_t kKeptProblems = 20;   // reasons kept by default (Lenient); every bad row is counted

enum class Policy {
    Strict,  // the first bad row is an Error
    Lenient, // bad rows are skipped, counted, the first reasons kept
};

struct Format {
    std::vector<std::string> required; // a header must name them; a row must have them
    std::vector<std::string> optional; // taken when there (Row::has)
    // Accepted without a header: the columns by position, one layout per number of fields (each
    // with every required column; other names are positions nobody reads, as in a header). None:
    // a header is required.
    std::vector<std::vector<std::string>> headerless;
};

struct Problem {
    size_t line = 0;     // 1-based, as an editor counts (comments and blank lines included)
    std::string message; // what is wrong, with the offending text
};

struct Summary {
    size_t data_rows = 0;          // rows of data read, good and bad (not the header, comments, blanks)
    size_t bad_rows = 0;           // Lenient: rows skipped
    std::vector<Problem> problems; // the first kept_problems bad rows' reasons, in file order
};

class Reader;

// One data row, valid inside onRow only. The accessors take a declared column's name.
class Row {
public:
    Row(const Row &) = delete;
    Row &operator=(const Row &) = delete;

    size_t line() const { return line_; }
    bool has(std::string_view column) const;
    [[nodiscard]] bool number(std::string_view column, double *value) const;
    [[nodiscard]] bool nodeId(std::string_view column, uint16_t *id) const;
    [[nodiscard]] bool text(std::string_view column, std::string_view *text) const;
    // The row is bad for the caller's own reason. Returns false (return row.reject("...")).
    bool reject(const std::string &why) const;

private:
    friend class Reader;
    Row() = default;
    bool fail(std::string why) const; // the first reason is kept; false
    bool field(std::string_view column, std::string_view *text) const;

    struct Field {
        const char *text = nullptr; // NUL-terminated, in the reader's line buffer
        size_t size = 0;
    };
    const Reader *reader_ = nullptr;
    const std::vector<size_t> *layout_ = nullptr; // declared column -> field index (npos: none)
    std::vector<Field> fields_;
    size_t line_ = 0;
    mutable bool bad_ = false;
    mutable std::string why_;
};

class Reader {
public:
    // Opens the file and reads up to its header (or first data row). Throws Error.
    Reader(const std::string &path, Format format, Policy policy, size_t kept_problems = kKeptProblems);
    ~Reader();
    Reader(const Reader &) = delete;
    Reader &operator=(const Reader &) = delete;

    // Calls onRow for each data row, in file order, with the policy above for bad rows. Throws
    // Error (a file that turns out unusable further on; Strict: the first bad row). Once only.
    void forEach(const std::function<void(const Row &)> &onRow);

    const std::string &path() const { return path_; }
    bool hasHeader() const { return header_; }
    // So far (inside onRow: up to the row before this one, bad rows included), then in total.
    const Summary &summary() const { return summary_; }

private:
    friend class Row;
    class Lines;
    size_t declaredIndex(std::string_view column) const; // throws std::logic_error
    bool split(std::string &line, std::string *why);
    void readHeader();
    void badRow(size_t line, std::string why);

    std::string path_;
    Format format_;
    Policy policy_;
    size_t kept_problems_;
    std::unique_ptr<Lines> lines_;
    std::vector<std::string> declared_;         // required, then optional
    std::vector<size_t> header_layout_;         // declared column -> field index (npos: none)
    std::vector<std::vector<size_t>> by_count_; // headerless: field count -> layout (empty: none)
    size_t required_fields_ = 0;                // with a header: the fields a row needs
    bool header_ = false;
    bool pending_ = false; // a first data line is already in line_
    bool read_ = false;
    std::string line_;
    size_t line_number_ = 0;
    Row row_;
    Summary summary_;
};

// "42" (or "+42") or "0x2A" (or "0X2a") -> 42, in 1..65535; false otherwise. Ids follow the live link's
// rule (common/include/cdro/frames.h): 0 is not a node (it means "none" in the protocol), so a file
// and a capture of the same network name the same nodes.
bool parseNodeId(std::string_view text, uint16_t *id);
// The whole text as a finite double (strtod); false otherwise.
bool parseNumber(const std::string &text, double *value);

} // namespace cdro::csv
