#include "cdro/hostd/csv_input.hpp"

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

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
    size_t start = 0;
    for (;;) {
        const size_t comma = line.find(',', start);
        fields.push_back(trim(line.substr(start, comma == std::string::npos ? std::string::npos : comma - start)));
        if (comma == std::string::npos) {
            return fields;
        }
        start = comma + 1;
    }
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

// Any number, or an id of any 16-bit value (0 included: a row naming node 0 is a data row with
// a bad id, not a header).
bool looksNumeric(const std::vector<std::string> &fields)
{
    for (const std::string &field : fields) {
        double ignored = 0.0;
        if (!parseNumber(field, &ignored)) {
            const bool hex = field.size() > 2 && field[0] == '0' && (field[1] == 'x' || field[1] == 'X') &&
                             field.find_first_not_of("0123456789abcdefABCDEF", 2) == std::string::npos;
            if (!hex) {
                return false;
            }
        }
    }
    return true;
}

// One pass over a file with a fixed buffer; lines longer than kMaxLineBytes or a 0x00 byte
// mean the file is not a CSV at all.
class LineReader {
public:
    explicit LineReader(const std::string &path) : path_(path)
    {
        struct stat st {};
        if (::stat(path.c_str(), &st) == 0 && S_ISDIR(st.st_mode)) {
            throw CsvError(path + ": is a directory, not a CSV file");
        }
        fd_ = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
        if (fd_ < 0) {
            throw CsvError(path + ": cannot open the file (" + std::strerror(errno) + ")");
        }
        buffer_.resize(1 << 16);
    }
    ~LineReader() { ::close(fd_); }
    LineReader(const LineReader &) = delete;
    LineReader &operator=(const LineReader &) = delete;

    // The next line without its end (\n or \r\n); false at the end of the file.
    bool next(std::string &line)
    {
        line.clear();
        for (;;) {
            if (begin_ == end_ && !fill()) {
                if (line.empty() && !pending_) {
                    return false;
                }
                pending_ = false;
                ++number_;
                if (!line.empty() && line.back() == '\r') {
                    line.pop_back();
                }
                return true;
            }
            pending_ = true;
            const char *start = buffer_.data() + begin_;
            const size_t available = end_ - begin_;
            const void *newline = std::memchr(start, '\n', available);
            const size_t take = newline != nullptr ? static_cast<size_t>(static_cast<const char *>(newline) - start)
                                                   : available;
            if (std::memchr(start, '\0', take) != nullptr) {
                throw CsvError(path_ + ":" + std::to_string(number_ + 1) + ": a 0x00 byte: not a CSV file");
            }
            if (line.size() + take > kMaxLineBytes) {
                throw CsvError(path_ + ":" + std::to_string(number_ + 1) + ": a line longer than " +
                               std::to_string(kMaxLineBytes) + " bytes: not a CSV file of this kind");
            }
            line.append(start, take);
            begin_ += take;
            if (newline != nullptr) {
                ++begin_;
                pending_ = false;
                ++number_;
                if (!line.empty() && line.back() == '\r') {
                    line.pop_back();
                }
                return true;
            }
        }
    }
    size_t number() const { return number_; }

private:
    bool fill()
    {
        for (;;) {
            const ssize_t n = ::read(fd_, buffer_.data(), buffer_.size());
            if (n < 0 && errno == EINTR) {
                continue;
            }
            if (n < 0) {
                throw CsvError(path_ + ": read failed after line " + std::to_string(number_) + " (" +
                               std::strerror(errno) + ")");
            }
            begin_ = 0;
            end_ = static_cast<size_t>(n);
            if (first_fill_) {
                first_fill_ = false;
                if (end_ >= 3 && std::memcmp(buffer_.data(), "\xEF\xBB\xBF", 3) == 0) {
                    begin_ = 3; // a UTF-8 byte-order mark (spreadsheets write one)
                }
            }
            return n > 0;
        }
    }

    std::string path_;
    int fd_ = -1;
    std::vector<char> buffer_;
    size_t begin_ = 0;
    size_t end_ = 0;
    size_t number_ = 0;
    bool pending_ = false; // bytes of a line without its end have been taken
    bool first_fill_ = true;
};

// The fields of one row by column name (a handful: a linear search is the fastest).
class Fields {
public:
    void clear() { entries_.clear(); }
    void set(const std::string &name, const std::string &value) { entries_.emplace_back(name, value); }
    const std::string *find(const std::string &name) const
    {
        for (const auto &entry : entries_) {
            if (entry.first == name) {
                return &entry.second;
            }
        }
        return nullptr;
    }

private:
    std::vector<std::pair<std::string, std::string>> entries_;
};

// Reads a CSV whose columns are `required` (and optional ones), calling make(fields) per data
// line, then onRow or onProblem. Positional without a header: `positional` lists the layouts
// accepted by field count. Returns the number of data lines.
template <typename Row, typename Make>
size_t readRows(const std::string &path, const std::vector<std::string> &required,
                const std::map<size_t, std::vector<std::string>> &positional, Make make,
                const std::function<void(const Row &)> &onRow, const std::function<void(const CsvProblem &)> &onProblem)
{
    LineReader in(path);
    std::vector<std::pair<std::string, size_t>> column; // name -> index
    bool have_layout = false;
    std::string line;
    size_t data_lines = 0;
    Fields values;
    while (in.next(line)) {
        const size_t number = in.number();
        const std::string text = trim(line);
        if (text.empty() || text[0] == '#') {
            continue;
        }
        const std::vector<std::string> fields = split(text);
        if (!have_layout) {
            have_layout = true;
            if (!looksNumeric(fields)) {
                for (size_t i = 0; i < fields.size(); ++i) {
                    column.emplace_back(fields[i], i);
                }
                for (const std::string &name : required) {
                    bool found = false;
                    for (const auto &entry : column) {
                        found = found || entry.first == name;
                    }
                    if (!found) {
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
        ++data_lines;
        values.clear();
        if (!column.empty()) {
            for (const auto &[name, index] : column) {
                if (index < fields.size()) {
                    values.set(name, fields[index]);
                }
            }
            bool complete = true;
            for (const std::string &name : required) {
                complete = complete && values.find(name) != nullptr;
            }
            if (!complete) {
                onProblem({number, "too few fields (" + std::to_string(fields.size()) + ")"});
                continue;
            }
        } else {
            const auto layout = positional.find(fields.size());
            if (layout == positional.end()) {
                std::string counts;
                for (const auto &entry : positional) {
                    counts += (counts.empty() ? "" : " or ") + std::to_string(entry.first);
                }
                onProblem({number, std::to_string(fields.size()) + " fields, expected " + counts});
                continue;
            }
            for (size_t i = 0; i < fields.size(); ++i) {
                values.set(layout->second[i], fields[i]);
            }
        }
        Row row{};
        row.line = number;
        std::string problem;
        if (make(values, row, problem)) {
            onRow(row);
        } else {
            onProblem({number, problem});
        }
    }
    return data_lines;
}

template <typename Row, typename Make>
CsvTable<Row> readTable(const std::string &path, const std::vector<std::string> &required,
                        const std::map<size_t, std::vector<std::string>> &positional, Make make)
{
    CsvTable<Row> table;
    table.data_lines = readRows<Row>(
        path, required, positional, make, [&table](const Row &row) { table.rows.push_back(row); },
        [&table](const CsvProblem &problem) { table.problems.push_back(problem); });
    return table;
}

bool numberField(const Fields &values, const char *name, double *out, std::string &problem)
{
    const std::string *found = values.find(name);
    if (found == nullptr || !parseNumber(*found, out)) {
        problem = std::string(name) + " '" + (found == nullptr ? "" : *found) + "' is not a finite number";
        return false;
    }
    return true;
}

bool idField(const Fields &values, const char *name, uint16_t *out, std::string &problem)
{
    const std::string *found = values.find(name);
    if (found == nullptr || !parseNodeId(*found, out)) {
        problem = std::string(name) + " '" + (found == nullptr ? "" : *found) +
                  "' is not a node id (1..65535, decimal or 0x hex; 0 is not a node on the live link either)";
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
    if (*end != '\0' || errno == ERANGE || value < 1 || value > 65535) {
        return false; // 0 is not a node (the frame check of common/frames.c: it means "none")
    }
    *id = static_cast<uint16_t>(value);
    return true;
}

namespace {
bool makeRange(const Fields &values, RangeRow &row, std::string &problem)
{
    if (values.find("t") != nullptr) {
        row.has_time = true;
        if (!numberField(values, "t", &row.t_s, problem)) {
            return false;
        }
    }
    return idField(values, "from", &row.from, problem) && idField(values, "to", &row.to, problem) &&
           numberField(values, "range_m", &row.range_m, problem);
}
const std::map<size_t, std::vector<std::string>> kRangeLayouts = {{3, {"from", "to", "range_m"}},
                                                                   {4, {"t", "from", "to", "range_m"}}};
} // namespace

CsvTable<RangeRow> readRangesCsv(const std::string &path)
{
    return readTable<RangeRow>(path, {"from", "to", "range_m"}, kRangeLayouts, makeRange);
}

size_t readRangesCsv(const std::string &path, const std::function<void(const RangeRow &)> &onRow,
                     const std::function<void(const CsvProblem &)> &onProblem)
{
    return readRows<RangeRow>(path, {"from", "to", "range_m"}, kRangeLayouts, makeRange, onRow, onProblem);
}

CsvTable<HeightRow> readHeightsCsv(const std::string &path)
{
    return readTable<HeightRow>(path, {"id", "z"}, {{2, {"id", "z"}}, {4, {"id", "x", "y", "z"}}},
                                [](const Fields &values, HeightRow &row, std::string &problem) {
                                    return idField(values, "id", &row.id, problem) &&
                                           numberField(values, "z", &row.z_m, problem);
                                });
}

CsvTable<FixedRow> readFixedCsv(const std::string &path)
{
    return readTable<FixedRow>(path, {"id", "x", "y"}, {{3, {"id", "x", "y"}}},
                               [](const Fields &values, FixedRow &row, std::string &problem) {
                                   return idField(values, "id", &row.id, problem) &&
                                          numberField(values, "x", &row.x_m, problem) &&
                                          numberField(values, "y", &row.y_m, problem);
                               });
}

CsvTable<OdometryRow> readOdometryCsv(const std::string &path)
{
    return readTable<OdometryRow>(
        path, {"t", "distance_m", "dheading_rad"}, {{3, {"t", "distance_m", "dheading_rad"}}},
        [](const Fields &values, OdometryRow &row, std::string &problem) {
            return numberField(values, "t", &row.t_s, problem) &&
                   numberField(values, "distance_m", &row.distance_m, problem) &&
                   numberField(values, "dheading_rad", &row.dheading_rad, problem);
        });
}

CsvTable<MotionRow> readMotionCsv(const std::string &path)
{
    return readTable<MotionRow>(path, {"t", "id", "moving"}, {{3, {"t", "id", "moving"}}},
                                [](const Fields &values, MotionRow &row, std::string &problem) {
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
