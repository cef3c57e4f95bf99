// The one CSV reader (reader.hpp says what it accepts and why).
#include "cdro/csv/reader.hpp"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

namespace cdro::csv {

namespace {

constexpr size_t kNone = static_cast<size_t>(-1);

bool isBlank(char c) { return c == ' ' || c == '\t' || c == '\r'; }

std::string join(const std::vector<std::string> &names)
{
    std::string joined;
    for (const std::string &name : names) {
        joined += (joined.empty() ? "" : ",") + name;
    }
    return joined;
}

bool isHex(char c) { return (c >= '0' && c <= '9') || (c >= 'a' && c <= 'f') || (c >= 'A' && c <= 'F'); }

int hexDigit(char c)
{
    if (c >= '0' && c <= '9') {
        return c - '0';
    }
    return (c >= 'a' && c <= 'f') ? c - 'a' + 10 : c - 'A' + 10;
}

bool hasHexPrefix(std::string_view text)
{
    return text.size() > 2 && text[0] == '0' && (text[1] == 'x' || text[1] == 'X');
}

// text: NUL-terminated at text[size].
bool parseFinite(const char *text, size_t size, double *value)
{
    if (size == 0) {
        return false;
    }
    char *end = nullptr;
    errno = 0;
    const double parsed = std::strtod(text, &end);
    if (end != text + size || errno == ERANGE || !std::isfinite(parsed)) {
        return false;
    }
    *value = parsed;
    return true;
}

// A field of a first line that is data: empty, any number strtod reads (nan and inf too: a
// data row with a bad value is a bad row, not a header), or 0x hex.
bool looksLikeData(const char *text, size_t size)
{
    if (size == 0) {
        return true;
    }
    char *end = nullptr;
    (void)std::strtod(text, &end);
    if (end == text + size) {
        return true;
    }
    const std::string_view view(text, size);
    if (!hasHexPrefix(view)) {
        return false;
    }
    for (size_t i = 2; i < size; ++i) {
        if (!isHex(view[i])) {
            return false;
        }
    }
    return true;
}

} // namespace

// One pass over a file with a fixed buffer; lines longer than kMaxLineBytes or a 0x00 byte
// mean the file is not a CSV at all.
class Reader::Lines {
public:
    explicit Lines(const std::string &path) : path_(path)
    {
        struct stat st {};
        if (::stat(path.c_str(), &st) == 0 && S_ISDIR(st.st_mode)) {
            throw Error(path + ": is a directory, not a CSV file");
        }
        fd_ = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
        if (fd_ < 0) {
            throw Error(path + ": cannot open the file (" + std::strerror(errno) + ")");
        }
        buffer_.resize(1 << 16);
    }
    ~Lines() { ::close(fd_); }
    Lines(const Lines &) = delete;
    Lines &operator=(const Lines &) = delete;

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
            const size_t take =
                newline != nullptr ? static_cast<size_t>(static_cast<const char *>(newline) - start) : available;
            if (std::memchr(start, '\0', take) != nullptr) {
                throw Error(path_ + ":" + std::to_string(number_ + 1) + ": a 0x00 byte: not a CSV file");
            }
            if (line.size() + take > kMaxLineBytes) {
                throw Error(path_ + ":" + std::to_string(number_ + 1) + ": a line longer than " +
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
                throw Error(path_ + ": read failed after line " + std::to_string(number_) + " (" +
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

Reader::Reader(const std::string &path, Format format, Policy policy, size_t kept_problems)
    : path_(path), format_(std::move(format)), policy_(policy), kept_problems_(kept_problems)
{
    declared_ = format_.required;
    declared_.insert(declared_.end(), format_.optional.begin(), format_.optional.end());
    for (size_t i = 0; i < declared_.size(); ++i) {
        for (size_t j = 0; j < i; ++j) {
            if (declared_[i] == declared_[j]) {
                throw std::logic_error("csv::Format declares column '" + declared_[i] + "' twice");
            }
        }
    }
    for (const std::vector<std::string> &names : format_.headerless) {
        if (names.size() >= by_count_.size()) {
            by_count_.resize(names.size() + 1);
        }
        std::vector<size_t> &layout = by_count_[names.size()];
        if (!layout.empty()) {
            throw std::logic_error("csv::Format has two headerless layouts of " + std::to_string(names.size()) +
                                   " fields");
        }
        layout.assign(declared_.size(), kNone);
        for (size_t i = 0; i < names.size(); ++i) {
            for (size_t d = 0; d < declared_.size(); ++d) {
                if (declared_[d] == names[i]) {
                    layout[d] = i; // a name not declared: a position the caller does not read
                }
            }
        }
        for (const std::string &name : format_.required) {
            if (layout[declaredIndex(name)] == kNone) {
                throw std::logic_error("csv::Format has a headerless layout without column '" + name + "'");
            }
        }
    }
    lines_ = std::make_unique<Lines>(path_);
    row_.reader_ = this;
    readHeader();
}

Reader::~Reader() = default;

size_t Reader::declaredIndex(std::string_view column) const
{
    for (size_t i = 0; i < declared_.size(); ++i) {
        if (declared_[i] == column) {
            return i;
        }
    }
    throw std::logic_error("csv: column '" + std::string(column) + "' was not declared in the Format (" + path_ + ")");
}

// Splits line_ in place into row_.fields_: each field's end (after its text, unquoted and
// trimmed) becomes a 0x00, so that the accessors parse in place. False with why for a broken quote.
bool Reader::split(std::string &line, std::string *why)
{
    std::vector<Row::Field> &fields = row_.fields_;
    fields.clear();
    char *p = line.data();
    char *const end = p + line.size();
    for (;;) {
        while (p < end && isBlank(*p)) {
            ++p;
        }
        char *const start = p;
        char *stop = nullptr; // the field's end
        if (p < end && *p == '"') {
            char *out = p; // the unquoted text is written over the quoted one
            ++p;
            bool closed = false;
            while (p < end) {
                if (*p == '"') {
                    if (p + 1 < end && p[1] == '"') {
                        *out++ = '"';
                        p += 2;
                        continue;
                    }
                    ++p;
                    closed = true;
                    break;
                }
                *out++ = *p++;
            }
            if (!closed) {
                *why = "a quoted field without its closing quote (a field does not span lines)";
                return false;
            }
            while (p < end && isBlank(*p)) {
                ++p;
            }
            if (p < end && *p != ',') {
                *why = "text after the closing quote of a quoted field";
                return false;
            }
            stop = out; // before the closing quote's place: inside the line
        } else {
            char *comma = p < end ? static_cast<char *>(std::memchr(p, ',', static_cast<size_t>(end - p))) : nullptr;
            p = comma != nullptr ? comma : end;
            stop = p;
            while (stop > start && isBlank(stop[-1])) {
                --stop;
            }
        }
        fields.push_back(Row::Field{start, static_cast<size_t>(stop - start)});
        if (stop != end) {
            *stop = '\0'; // over the comma, a blank or a quote's place (at the end: the string's own)
        }
        if (p >= end) {
            return true;
        }
        ++p; // the comma
    }
}

void Reader::readHeader()
{
    const std::string expected = join(format_.required);
    while (lines_->next(line_)) {
        line_number_ = lines_->number();
        const size_t first = line_.find_first_not_of(" \t\r");
        if (first == std::string::npos || line_[first] == '#') {
            continue;
        }
        const std::string where = path_ + ":" + std::to_string(line_number_) + ": ";
        std::string why;
        const bool split_ok = split(line_, &why);
        bool data = split_ok;
        for (const Row::Field &field : row_.fields_) {
            data = data && looksLikeData(field.text, field.size);
        }
        if (data && !format_.headerless.empty()) {
            pending_ = true; // the first data row
            return;
        }
        if (data) {
            throw Error(where + "no header: the first line is data (expected a header naming the columns " + expected +
                        ")");
        }
        if (!split_ok) {
            throw Error(where + "the first line: " + why);
        }
        header_ = true;
        header_layout_.assign(declared_.size(), kNone);
        for (size_t i = 0; i < row_.fields_.size(); ++i) {
            const std::string_view name(row_.fields_[i].text, row_.fields_[i].size);
            for (size_t d = 0; d < declared_.size(); ++d) {
                if (declared_[d] != name) {
                    continue;
                }
                if (header_layout_[d] != kNone) {
                    throw Error(where + "the header names column '" + declared_[d] + "' twice");
                }
                header_layout_[d] = i;
            }
        }
        for (size_t d = 0; d < format_.required.size(); ++d) {
            if (header_layout_[d] == kNone) {
                throw Error(where + "the header has no column '" + declared_[d] + "' (expected " + expected + ")");
            }
            required_fields_ = std::max(required_fields_, header_layout_[d] + 1);
        }
        return;
    }
    if (format_.headerless.empty()) {
        throw Error(path_ + ": empty file (expected a header naming the columns " + expected + ")");
    }
}

void Reader::badRow(size_t line, std::string why)
{
    if (policy_ == Policy::Strict) {
        throw Error(path_ + ":" + std::to_string(line) + ": " + why);
    }
    ++summary_.bad_rows;
    if (summary_.problems.size() < kept_problems_) {
        summary_.problems.push_back(Problem{line, std::move(why)});
    }
}

void Reader::forEach(const std::function<void(const Row &)> &onRow)
{
    if (read_) {
        throw std::logic_error("csv::Reader::forEach called twice (" + path_ + ")");
    }
    read_ = true;
    std::string counts; // the headerless layouts' field counts, for the message
    for (size_t n = 0; n < by_count_.size(); ++n) {
        if (!by_count_[n].empty()) {
            counts += (counts.empty() ? "" : " or ") + std::to_string(n);
        }
    }
    bool have = pending_;
    std::string why;
    bool split_ok = true;
    for (;;) {
        if (!have) {
            if (!lines_->next(line_)) {
                return;
            }
            line_number_ = lines_->number();
            const size_t first = line_.find_first_not_of(" \t\r");
            if (first == std::string::npos || line_[first] == '#') {
                continue;
            }
            split_ok = split(line_, &why);
        }
        have = false;
        const size_t line = line_number_;
        const size_t count = row_.fields_.size();
        row_.line_ = line;
        if (!split_ok) {
            badRow(line, why);
        } else if (header_ && count < required_fields_) {
            badRow(line, "too few fields (" + std::to_string(count) + ")");
        } else if (!header_ && (count >= by_count_.size() || by_count_[count].empty())) {
            badRow(line, std::to_string(count) + " fields, expected " + counts);
        } else {
            row_.layout_ = header_ ? &header_layout_ : &by_count_[count];
            row_.bad_ = false;
            onRow(row_);
            if (row_.bad_) {
                badRow(line, std::move(row_.why_));
            }
        }
        ++summary_.data_rows;
    }
}

bool Row::fail(std::string why) const
{
    if (!bad_) {
        bad_ = true;
        why_ = std::move(why);
    }
    return false;
}

bool Row::field(std::string_view column, std::string_view *text) const
{
    const size_t index = (*layout_)[reader_->declaredIndex(column)];
    if (index == kNone) {
        return fail("no column '" + std::string(column) + "'");
    }
    if (index >= fields_.size()) {
        return fail("too few fields (" + std::to_string(fields_.size()) + ")");
    }
    *text = std::string_view(fields_[index].text, fields_[index].size); // NUL-terminated (split)
    return true;
}

bool Row::has(std::string_view column) const
{
    const size_t index = (*layout_)[reader_->declaredIndex(column)];
    return index != kNone && index < fields_.size();
}

bool Row::text(std::string_view column, std::string_view *text) const { return field(column, text); }

bool Row::number(std::string_view column, double *value) const
{
    std::string_view text;
    if (!field(column, &text)) {
        return false;
    }
    if (!parseFinite(text.data(), text.size(), value)) {
        return fail(std::string(column) + " '" + std::string(text) + "' is not a finite number");
    }
    return true;
}

bool Row::nodeId(std::string_view column, uint16_t *id) const
{
    std::string_view text;
    if (!field(column, &text)) {
        return false;
    }
    if (!parseNodeId(text, id)) {
        return fail(std::string(column) + " '" + std::string(text) +
                    "' is not a node id (1..65535, decimal or 0x hex; 0 is not a node on the live link either)");
    }
    return true;
}

bool Row::reject(const std::string &why) const { return fail(why); }

bool parseNodeId(std::string_view text, uint16_t *id)
{
    const bool hex = hasHexPrefix(text);
    const size_t first = hex ? 2 : (!text.empty() && text[0] == '+' ? 1 : 0); // "+5" as strtol reads it
    if (text.size() == first) {
        return false;
    }
    uint32_t value = 0;
    for (size_t i = first; i < text.size(); ++i) {
        const char c = text[i];
        if (hex ? !isHex(c) : (c < '0' || c > '9')) {
            return false;
        }
        value = value * (hex ? 16U : 10U) + static_cast<uint32_t>(hexDigit(c));
        if (value > 65535U) {
            return false;
        }
    }
    if (value == 0) {
        return false; // 0 is not a node (the frame check of common/src/frames.c: it means "none")
    }
    *id = static_cast<uint16_t>(value);
    return true;
}

bool parseNumber(const std::string &text, double *value) { return parseFinite(text.c_str(), text.size(), value); }

} // namespace cdro::csv
