// csv_input.hpp: the offline mode's input files, read by the one CSV reader (cdro/csv/reader.hpp:
// lines, blank lines, # comments, CRLF, a byte-order mark, quotes, the header) with its Lenient
// policy: a row that cannot be read (too few fields, not a number, an id outside 1..65535, a
// non-finite value) is reported with its line number and skipped; the rest of the file is used.
//
//   ranges   [t,]from,to,range_m      t in s (optional), ids decimal or 0x hex, range in m
//   heights  id,z                     m
//   fixed    id,x,y                   m, in the output frame
//   odometry t,distance_m,dheading_rad   (the movement stage)
//   motion   t,id,moving              moving 0/1
//
// A header names the columns (in any order; other columns are ignored); without one the
// columns are positional (ranges: 3 or 4 fields; heights: id,z or id,x,y,z). Node ids follow the live link's rule (csv::parseNodeId: 0 is not a node; it means
// "none" in the protocol), so a file and a capture of the same network name the same nodes.
// Semantic checks (a node ranging itself, an absurd range) belong to the engine, which counts
// them.
//
// What is not a CSV at all (a directory, a line longer than csv::kMaxLineBytes such as
// /dev/zero, a binary file) or lacks a required column is refused as a whole (CsvError) before
// it can cost memory or time. Files are read in one pass with a fixed buffer.
#pragma once

#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include "cdro/csv/reader.hpp"

namespace cdro::hostd {

using CsvError = csv::Error;

struct RangeRow {
    size_t line = 0;
    bool has_time = false;
    double t_s = 0.0; // s
    uint16_t from = 0;
    uint16_t to = 0;
    double range_m = 0.0; // m
};

struct HeightRow {
    size_t line = 0;
    uint16_t id = 0;
    double z_m = 0.0; // m
};

struct FixedRow {
    size_t line = 0;
    uint16_t id = 0;
    double x_m = 0.0; // m
    double y_m = 0.0; // m
};

struct OdometryRow {
    size_t line = 0;
    double t_s = 0.0;          // s
    double distance_m = 0.0;   // m travelled in this step
    double dheading_rad = 0.0; // rad, heading change in this step
};

struct MotionRow {
    size_t line = 0;
    double t_s = 0.0; // s
    uint16_t id = 0;
    bool moving = false;
};

template <typename Row> struct CsvTable {
    std::vector<Row> rows;
    csv::Summary summary; // data rows read, bad rows skipped, the first reasons
};

// The ranges' format, and a row as the engine takes it: call inside csv::Reader::forEach; false
// when a field cannot be read (the reader counts the row bad). The ranges stream through the
// engine this way (offline.cpp), so that the file can be any size.
const csv::Format &rangesFormat();
[[nodiscard]] bool rangeRow(const csv::Row &fields, RangeRow *row);

// A whole file, its bad rows skipped (the first `kept_problems` reasons kept, all counted).
// Each throws CsvError when the file cannot be used at all (above).
CsvTable<RangeRow> readRangesCsv(const std::string &path, size_t kept_problems);
CsvTable<HeightRow> readHeightsCsv(const std::string &path, size_t kept_problems);
CsvTable<FixedRow> readFixedCsv(const std::string &path, size_t kept_problems);
CsvTable<OdometryRow> readOdometryCsv(const std::string &path, size_t kept_problems);
CsvTable<MotionRow> readMotionCsv(const std::string &path, size_t kept_problems);

// Prints "cdro-hostd: PATH:LINE: skipped: WHY" for the first `limit` bad rows and a count of
// the rest, on `log`.
void reportCsvProblems(const std::string &path, const csv::Summary &summary, uint32_t limit, std::FILE *log);

} // namespace cdro::hostd
