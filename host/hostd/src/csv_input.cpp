#include "cdro/hostd/csv_input.hpp"

#include <algorithm>

namespace cdro::hostd {

namespace {

// Reads a whole file in the format, a row of type Row from each good data row (make).
template <typename Row, typename Make>
CsvTable<Row> readTable(const std::string &path, const csv::Format &format, size_t kept_problems, Make make)
{
    CsvTable<Row> table;
    csv::Reader reader(path, format, csv::Policy::Lenient, kept_problems);
    reader.forEach([&](const csv::Row &fields) {
        Row row;
        row.line = fields.line();
        if (make(fields, row)) {
            table.rows.push_back(row);
        }
    });
    table.summary = reader.summary();
    return table;
}

const csv::Format kHeights{{"id", "z"}, {}, {{"id", "z"}, {"id", "x", "y", "z"}}};
const csv::Format kFixed{{"id", "x", "y"}, {}, {{"id", "x", "y"}}};
const csv::Format kOdometry{{"t", "distance_m", "dheading_rad"}, {}, {{"t", "distance_m", "dheading_rad"}}};
const csv::Format kMotion{{"t", "id", "moving"}, {}, {{"t", "id", "moving"}}};

bool makeRange(const csv::Row &fields, RangeRow &row)
{
    row.has_time = fields.has("t");
    return (!row.has_time || fields.number("t", &row.t_s)) && fields.nodeId("from", &row.from) &&
           fields.nodeId("to", &row.to) && fields.number("range_m", &row.range_m);
}

} // namespace

const csv::Format &rangesFormat()
{
    static const csv::Format format{{"from", "to", "range_m"},
                                    {"t"},
                                    {{"from", "to", "range_m"}, {"t", "from", "to", "range_m"}}};
    return format;
}

bool rangeRow(const csv::Row &fields, RangeRow *row)
{
    row->line = fields.line();
    return makeRange(fields, *row);
}

CsvTable<RangeRow> readRangesCsv(const std::string &path, size_t kept_problems)
{
    return readTable<RangeRow>(path, rangesFormat(), kept_problems, makeRange);
}

CsvTable<HeightRow> readHeightsCsv(const std::string &path, size_t kept_problems)
{
    return readTable<HeightRow>(path, kHeights, kept_problems, [](const csv::Row &fields, HeightRow &row) {
        return fields.nodeId("id", &row.id) && fields.number("z", &row.z_m);
    });
}

CsvTable<FixedRow> readFixedCsv(const std::string &path, size_t kept_problems)
{
    return readTable<FixedRow>(path, kFixed, kept_problems, [](const csv::Row &fields, FixedRow &row) {
        return fields.nodeId("id", &row.id) && fields.number("x", &row.x_m) && fields.number("y", &row.y_m);
    });
}

CsvTable<OdometryRow> readOdometryCsv(const std::string &path, size_t kept_problems)
{
    return readTable<OdometryRow>(path, kOdometry, kept_problems, [](const csv::Row &fields, OdometryRow &row) {
        return fields.number("t", &row.t_s) && fields.number("distance_m", &row.distance_m) &&
               fields.number("dheading_rad", &row.dheading_rad);
    });
}

CsvTable<MotionRow> readMotionCsv(const std::string &path, size_t kept_problems)
{
    return readTable<MotionRow>(path, kMotion, kept_problems, [](const csv::Row &fields, MotionRow &row) {
        double moving = 0.0;
        if (!fields.number("t", &row.t_s) || !fields.nodeId("id", &row.id) || !fields.number("moving", &moving)) {
            return false;
        }
        if (moving != 0.0 && moving != 1.0) {
            return fields.reject("moving must be 0 or 1");
        }
        row.moving = moving == 1.0;
        return true;
    });
}
void reportCsvProblems(const std::string &path, const csv::Summary &summary, uint32_t limit, std::FILE *log)
{
    size_t shown = 0;
    for (const csv::Problem &problem : summary.problems) {
        if (shown++ < limit) {
            std::fprintf(log, "cdro-hostd: %s:%zu: skipped: %s\n", path.c_str(), problem.line, problem.message.c_str());
        }
    }
    const size_t printed = std::min<size_t>(summary.problems.size(), limit);
    if (summary.bad_rows > printed) {
        std::fprintf(log, "cdro-hostd: %s: %zu more bad rows skipped (not shown)\n", path.c_str(),
                     summary.bad_rows - printed);
    }
}

} // namespace cdro::hostd
