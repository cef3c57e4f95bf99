#include "cdro/hostd/csv_input.hpp"

#include <cstdio>

#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <map>
#include <sstream>

namespace cdro::hostd {

namespace {

std::string trim(const std::string &text)
{
    const size_t first = text.find_first_not_of(" \t\r\n");
    if (first == std::string::npos) {
        return "";
    }
    const size_t last = text.find_last_not_of(" \t\r\n");
    return text.substr(first, last - first + 1);
}

std::vector<std::string> split(const std::string &line)
{
    std::vector<std::string> fields;
    std::string field;
    std::stringstream stream(line);
    while (std::getline(stream, field, ',')) {
        fields.push_back(trim(field));
    }
    if (!line.empty() && line.back() == ',') {
        fields.emplace_back();
    }
    return fields;
}

bool parseNumber(const std::string &text, double *value)
{
    if (text.empty()) {
        return false;
    }
    char *end = nullptr;
    errno = 0;
    const double parsed = std::strtod(text.c_str(), &end);
    if (*end != '\0' || errno == ERANGE || !std::isfinite(parsed)) {
        return false;
    }
    *value = parsed;
    return true;
}

bool looksNumeric(const std::vector<std::string> &fields)
{
    for (const std::string &field : fields) {
        double ignored = 0.0;
        uint16_t id = 0;
        if (!parseNumber(field, &ignored) && !parseNodeId(field, &id)) {
            return false;
        }
    }
    return true;
}

// Reads a CSV whose columns are `wanted` (optional ones marked), calling row(fields-by-column).
// Positional without a header: `positional` lists the layouts accepted by field count.
template <typename Row, typename Make>
CsvTable<Row> readTable(const std::string &path, const std::vector<std::string> &required,
                        const std::vector<std::string> &optional,
                        const std::map<size_t, std::vector<std::string>> &positional, Make make)
{
    std::ifstream in(path);
    if (!in) {
        throw CsvError(path + ": cannot open the file");
    }
    CsvTable<Row> table;
    std::map<std::string, size_t> column; // name -> index
    bool have_layout = false;
    std::string line;
    size_t number = 0;
    while (std::getline(in, line)) {
        ++number;
        const std::string text = trim(line);
        if (text.empty() || text[0] == '#') {
            continue;
        }
        const std::vector<std::string> fields = split(text);
        if (!have_layout) {
            have_layout = true;
            if (!looksNumeric(fields)) {
                for (size_t i = 0; i < fields.size(); ++i) {
                    column[fields[i]] = i;
                }
                for (const std::string &name : required) {
                    if (column.count(name) == 0) {
                        std::string expected;
                        for (const std::string &n : required) {
                            expected += (expected.empty() ? "" : ",") + n;
                        }
                        throw CsvError(path + ":" + std::to_string(number) + ": the header has no column '" + name +
                                       "' (expected " + expected + ")");
                    }
                }
                continue;
            }
        }
        ++table.data_lines;
        std::map<std::string, std::string> values;
        if (!column.empty()) {
            for (const auto &[name, index] : column) {
                if (index < fields.size()) {
                    values[name] = fields[index];
                }
            }
            bool complete = true;
            for (const std::string &name : required) {
                complete = complete && values.count(name) != 0;
            }
            if (!complete) {
                table.problems.push_back({number, "too few fields (" + std::to_string(fields.size()) + ")"});
                continue;
            }
        } else {
            const auto layout = positional.find(fields.size());
            if (layout == positional.end()) {
                std::string counts;
                for (const auto &entry : positional) {
                    counts += (counts.empty() ? "" : " or ") + std::to_string(entry.first);
                }
                table.problems.push_back({number, std::to_string(fields.size()) + " fields, expected " + counts});
                continue;
            }
            for (size_t i = 0; i < fields.size(); ++i) {
                values[layout->second[i]] = fields[i];
            }
        }
        (void)optional;
        Row row{};
        row.line = number;
        std::string problem;
        if (make(values, row, problem)) {
            table.rows.push_back(row);
        } else {
            table.problems.push_back({number, problem});
        }
    }
    return table;
}

bool numberField(const std::map<std::string, std::string> &values, const char *name, double *out, std::string &problem)
{
    const auto found = values.find(name);
    if (found == values.end() || !parseNumber(found->second, out)) {
        problem = std::string(name) + " '" + (found == values.end() ? "" : found->second) + "' is not a finite number";
        return false;
    }
    return true;
}

bool idField(const std::map<std::string, std::string> &values, const char *name, uint16_t *out, std::string &problem)
{
    const auto found = values.find(name);
    if (found == values.end() || !parseNodeId(found->second, out)) {
        problem = std::string(name) + " '" + (found == values.end() ? "" : found->second) +
                  "' is not a node id (0..65535, decimal or 0x hex)";
        return false;
    }
    return true;
}

} // namespace

bool parseNodeId(const std::string &text, uint16_t *id)
{
    if (text.empty()) {
        return false;
    }
    char *end = nullptr;
    errno = 0;
    const bool hex = text.size() > 2 && text[0] == '0' && (text[1] == 'x' || text[1] == 'X');
    const long long value = std::strtoll(text.c_str(), &end, hex ? 16 : 10);
    if (*end != '\0' || errno == ERANGE || value < 0 || value > 65535) {
        return false;
    }
    *id = static_cast<uint16_t>(value);
    return true;
}

CsvTable<RangeRow> readRangesCsv(const std::string &path)
{
    return readTable<RangeRow>(
        path, {"from", "to", "range_m"}, {"t"}, {{3, {"from", "to", "range_m"}}, {4, {"t", "from", "to", "range_m"}}},
        [](const std::map<std::string, std::string> &values, RangeRow &row, std::string &problem) {
            if (values.count("t") != 0) {
                row.has_time = true;
                if (!numberField(values, "t", &row.t_s, problem)) {
                    return false;
                }
            }
            return idField(values, "from", &row.from, problem) && idField(values, "to", &row.to, problem) &&
                   numberField(values, "range_m", &row.range_m, problem);
        });
}

CsvTable<HeightRow> readHeightsCsv(const std::string &path)
{
    return readTable<HeightRow>(path, {"id", "z"}, {}, {{2, {"id", "z"}}, {4, {"id", "x", "y", "z"}}},
                                [](const std::map<std::string, std::string> &values, HeightRow &row, std::string &problem) {
                                    return idField(values, "id", &row.id, problem) &&
                                           numberField(values, "z", &row.z_m, problem);
                                });
}

CsvTable<FixedRow> readFixedCsv(const std::string &path)
{
    return readTable<FixedRow>(path, {"id", "x", "y"}, {}, {{3, {"id", "x", "y"}}},
                               [](const std::map<std::string, std::string> &values, FixedRow &row, std::string &problem) {
                                   return idField(values, "id", &row.id, problem) &&
                                          numberField(values, "x", &row.x_m, problem) &&
                                          numberField(values, "y", &row.y_m, problem);
                               });
}

CsvTable<OdometryRow> readOdometryCsv(const std::string &path)
{
    return readTable<OdometryRow>(
        path, {"t", "distance_m", "dheading_rad"}, {}, {{3, {"t", "distance_m", "dheading_rad"}}},
        [](const std::map<std::string, std::string> &values, OdometryRow &row, std::string &problem) {
            return numberField(values, "t", &row.t_s, problem) &&
                   numberField(values, "distance_m", &row.distance_m, problem) &&
                   numberField(values, "dheading_rad", &row.dheading_rad, problem);
        });
}

CsvTable<MotionRow> readMotionCsv(const std::string &path)
{
    return readTable<MotionRow>(path, {"t", "id", "moving"}, {}, {{3, {"t", "id", "moving"}}},
                                [](const std::map<std::string, std::string> &values, MotionRow &row, std::string &problem) {
                                    double moving = 0.0;
                                    if (!numberField(values, "t", &row.t_s, problem) ||
                                        !idField(values, "id", &row.id, problem) ||
                                        !numberField(values, "moving", &moving, problem)) {
                                        return false;
                                    }
                                    if (moving != 0.0 && moving != 1.0) {
                                        problem = "moving must be 0 or 1";
                                        return false;
                                    }
                                    row.moving = moving == 1.0;
                                    return true;
                                });
}

void reportCsvProblems(const std::string &path, const std::vector<CsvProblem> &problems, uint32_t limit,
                       std::FILE *log)
{
    size_t shown = 0;
    for (const CsvProblem &problem : problems) {
        if (shown++ < limit) {
            std::fprintf(log, "cdro-hostd: %s:%zu: skipped: %s\n", path.c_str(), problem.line, problem.message.c_str());
        }
    }
    if (problems.size() > limit) {
        std::fprintf(log, "cdro-hostd: %s: %zu more bad rows skipped (not shown)\n", path.c_str(),
                     problems.size() - limit);
    }
}

} // namespace cdro::hostd
