// csv_input.hpp: the offline mode's input files, read strictly.
//
//   ranges   [t,]from,to,range_m      t in s (optional), ids decimal or 0x hex, range in m
//   heights  id,z                     m
//   fixed    id,x,y                   m, in the output frame
//   odometry t,distance_m,dheading_rad   (the movement stage)
//   motion   t,id,moving              moving 0/1
//
// A first line that is not numbers is a header and names the columns (in any order; other
// columns are ignored); without a header the columns are positional. A UTF-8 byte-order mark
// (spreadsheets write one) is skipped. Blank lines and lines starting with # are skipped. A row
// that cannot be read (too few fields, not a number, an id outside 1..65535, a non-finite
// value) is reported with its line number and skipped: the rest of the file is still used.
// Node ids follow the live link's rule (frames.h: 0 is not a node; it means "none" in the
// protocol), so a file and a capture of the same network name the same nodes. Semantic checks
// (a node ranging itself, an absurd range) belong to the engine, which counts them.
//
// What is not a CSV at all is refused as a whole (CsvError) before it can cost memory or time:
// a directory, a line longer than kMaxLineBytes (an endless device such as /dev/zero, a binary
// file), a 0x00 byte. Files are read in one pass with a fixed buffer (linear in their size).
#pragma once

#include <cstdint>
#include <cstdio>
#include <functional>
#include <string>
#include <vector>

namespace cdro::hostd {

class CsvError : public std::exception {
public:
    explicit CsvError(std::string message) : message_(std::move(message)) {}
    const char *what() const noexcept override { return message_.c_str(); }

private:
    std::string message_;
};

struct CsvProblem {
    size_t line = 0;      // 1-based
    std::string message;  // what is wrong, with the offending text
};

struct RangeRow {
    size_t line = 0;
    bool has_time = false;
    double t_s = 0.0;     // s
    uint16_t from = 0;
    uint16_t to = 0;
    double range_m = 0.0; // m
};

struct HeightRow {
    size_t line = 0;
    uint16_t id = 0;
    double z_m = 0.0;     // m
};

struct FixedRow {
    size_t line = 0;
    uint16_t id = 0;
    double x_m = 0.0;     // m
    double y_m = 0.0;     // m
};

struct OdometryRow {
    size_t line = 0;
    double t_s = 0.0;             // s
    double distance_m = 0.0;      // m travelled in this step
    double dheading_rad = 0.0;    // rad, heading change in this step
};

struct MotionRow {
    size_t line = 0;
    double t_s = 0.0;     // s
    uint16_t id = 0;
    bool moving = false;
};

template <typename Row> struct CsvTable {
    std::vector<Row> rows;
    std::vector<CsvProblem> problems;
    size_t data_lines = 0; // lines that held data (good or bad)
};

constexpr size_t kMaxLineBytes = 4096; // bytes; no row of these files comes near it

// Streaming: each good row to onRow as it is read (in file order), each bad one to onProblem;
// the ranges file can then be any size. Returns the number of data lines. Throws CsvError.
size_t readRangesCsv(const std::string &path, const std::function<void(const RangeRow &)> &onRow,
                     const std::function<void(const CsvProblem &)> &onProblem);

// Each throws CsvError when the file cannot be opened or a header lacks a required column.
CsvTable<RangeRow> readRangesCsv(const std::string &path);
CsvTable<HeightRow> readHeightsCsv(const std::string &path);
CsvTable<FixedRow> readFixedCsv(const std::string &path);
CsvTable<OdometryRow> readOdometryCsv(const std::string &path);
CsvTable<MotionRow> readMotionCsv(const std::string &path);

// "42" or "0x2A" -> 42 in 1..65535 (the live link's rule: 0 is not a node id); false otherwise.
bool parseNodeId(const std::string &text, uint16_t *id);

// Prints "cdro-hostd: PATH:LINE: skipped: WHY" for the first `limit` problems and a count of the
// rest, on `log`.
void reportCsvProblems(const std::string &path, const std::vector<CsvProblem> &problems, uint32_t limit,
                       std::FILE *log);

} // namespace cdro::hostd
