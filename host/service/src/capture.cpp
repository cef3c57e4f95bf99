#include "cdro/service/capture.hpp"

#include <cerrno>
#include <cmath>
#include <cstring>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include "cdro/service/log.hpp"
#include "cdro/service/output_file.hpp"

namespace cdro::service {

namespace {

// One write() for the whole buffer; loops only if the kernel took part of it (not expected for
// regular files, but then the rest must still go out in order).
bool writeAll(int fd, const uint8_t *bytes, size_t len, std::string *error)
{
    while (len > 0) {
        const ssize_t n = ::write(fd, bytes, len);
        if (n < 0) {
            if (errno == EINTR) {
                continue;
            }
            *error = std::strerror(errno);
            return false;
        }
        bytes += n;
        len -= static_cast<size_t>(n);
    }
    return true;
}

bool fileExists(const std::string &path)
{
    struct stat st {};
    return ::lstat(path.c_str(), &st) == 0; // a link counts, whatever it points at
}

constexpr size_t kMaxRecordBytes = CDRO_CAPTURE_RECORD_OVERHEAD + CDRO_CAPTURE_MAX_DATA;
constexpr int64_t kReopenPeriodUs = 1'000'000; // us of record time between attempts at a new file

} // namespace

// ---- writer --------------------------------------------------------------------------------

CaptureWriter::CaptureWriter(const CaptureConfig &config, std::string source, ServiceCounters &counters,
                             std::string context)
    : config_(config), source_(std::move(source)), context_(std::move(context)), counters_(counters),
      rotate_bytes_(static_cast<uint64_t>(std::llround(config.rotate_mib * 1024.0 * 1024.0)))
{
    if (source_.size() > CDRO_CAPTURE_MAX_SOURCE) {
        source_.resize(CDRO_CAPTURE_MAX_SOURCE);
    }
    if (context_.size() > CDRO_CAPTURE_MAX_CONTEXT) {
        throw CaptureError("capture: the run's context is " + std::to_string(context_.size()) + " bytes, at most " +
                           std::to_string(CDRO_CAPTURE_MAX_CONTEXT) + " fit in a capture header");
    }
}

CaptureWriter::~CaptureWriter() { close(); }

std::string CaptureWriter::rotatedName(const std::string &path, uint32_t index) { return rotatedFileName(path, index); }

void CaptureWriter::open(int64_t created_unix_us)
{
    close();
    try {
        checkOutputPath(config_.path, "capture");
    } catch (const ConfigError &error) {
        if (std::string(error.what()).find("symbolic link") == std::string::npos) {
            throw CaptureError(error.what());
        }
        // A link at the path is rotated away like a previous run's file (rename moves the link
        // itself, never its target), and a new file is created in its place.
    }
    if (fileExists(config_.path)) {
        rotate(created_unix_us); // keeps the previous run's capture as path.1
        return;
    }
    openFresh(created_unix_us);
}

void CaptureWriter::openFresh(int64_t created_unix_us)
{
    // O_EXCL: whatever was at the path has just been rotated away; something that appeared
    // there since (a planted link) makes this fail instead of being written through.
    try {
        fd_ = openOutputFile(config_.path, O_WRONLY | O_CREAT | O_EXCL | O_APPEND, "capture");
    } catch (const ConfigError &error) {
        throw CaptureError(error.what());
    }
    cdro_capture_header_t header{};
    header.format_version = CDRO_CAPTURE_FORMAT_VERSION;
    header.created_unix_us = created_unix_us;
    header.source_len = static_cast<uint8_t>(source_.size());
    std::memcpy(header.source, source_.data(), source_.size());
    header.context_len = static_cast<uint16_t>(context_.size());
    header.context = reinterpret_cast<const uint8_t *>(context_.data());
    std::vector<uint8_t> bytes(CDRO_CAPTURE_HEADER_FIXED + CDRO_CAPTURE_MAX_SOURCE + 2 + context_.size());
    const size_t size = cdro_capture_header_encode(&header, bytes.data(), bytes.size());
    std::string error;
    if (size == 0 || !writeAll(fd_, bytes.data(), size, &error)) {
        ::close(fd_);
        fd_ = -1;
        ::unlink(config_.path.c_str()); // a header cut short (full disk): the next attempt starts clean
        throw CaptureError("capture: cannot write the header of " + config_.path + ": " + error);
    }
    file_bytes_ = size;
    header_bytes_ = size;
    counters_.capture_bytes += size;
}

void CaptureWriter::rotate(int64_t created_unix_us)
{
    if (fd_ >= 0) {
        ::close(fd_);
        fd_ = -1;
    }
    rotateFiles(config_.path, config_.keep);
    ++counters_.capture_rotations;
    log()->info("capture: rotated {} (keeping {} older files)", config_.path, config_.keep);
    openFresh(created_unix_us);
}

void CaptureWriter::append(uint8_t flags, int64_t host_time_us, const uint8_t *data, size_t len)
{
    if (fd_ < 0) {
        if (!reopen_pending_) {
            return; // not opened, or closed
        }
        // A rotation failed (a full disk): a new file is tried again once a second of record
        // time, and the records until then are lost and counted.
        if (host_time_us < reopen_at_us_) {
            ++counters_.capture_write_errors;
            ++lost_in_outage_;
            return;
        }
        try {
            openFresh(host_time_us);
            reopen_pending_ = false;
        } catch (const CaptureError &) {
            reopen_at_us_ = host_time_us + kReopenPeriodUs;
            ++counters_.capture_write_errors;
            ++lost_in_outage_;
            return;
        }
    }
    if (len > CDRO_CAPTURE_MAX_DATA) {
        len = CDRO_CAPTURE_MAX_DATA;
        flags = static_cast<uint8_t>(flags | CDRO_CAPTURE_FLAG_TRUNCATED);
    }
    uint8_t bytes[kMaxRecordBytes];
    cdro_capture_record_t record{};
    record.flags = flags;
    record.host_time_us = host_time_us;
    record.data_len = static_cast<uint16_t>(len);
    record.data = data;
    const size_t size = cdro_capture_record_encode(&record, bytes, sizeof bytes);
    if (file_bytes_ + size > rotate_bytes_ && file_bytes_ > header_bytes_) {
        try {
            rotate(host_time_us);
        } catch (const CaptureError &error) {
            ++counters_.capture_write_errors;
            ++lost_in_outage_;
            reopen_pending_ = true;
            reopen_at_us_ = host_time_us + kReopenPeriodUs;
            log()->error("{}; records are lost and counted in capture_write_errors until a new file can be "
                         "started (tried every second; it will be logged)",
                         error.what());
            return;
        }
    }
    std::string error;
    if (!writeAll(fd_, bytes, size, &error)) {
        ++counters_.capture_write_errors;
        ++lost_in_outage_;
        // A record cut by the full disk would read as corrupt bytes: the file goes back to
        // its last whole record.
        [[maybe_unused]] const int rc = ::ftruncate(fd_, static_cast<off_t>(file_bytes_));
        if (lost_in_outage_ == 1) {
            log()->error("capture: cannot append to {}: {} (records are lost and counted in capture_write_errors "
                         "until writing works again, which will be logged)",
                         config_.path, error);
        }
        return;
    }
    if (lost_in_outage_ > 0) {
        log()->warn("capture: writing again to {}; {} records were lost while it could not be written "
                    "(capture_write_errors)",
                    config_.path, lost_in_outage_);
        lost_in_outage_ = 0;
    }
    file_bytes_ += size;
    ++counters_.capture_records;
    counters_.capture_bytes += size;
}

void CaptureWriter::close()
{
    reopen_pending_ = false;
    if (fd_ >= 0) {
        ::fsync(fd_);
        ::close(fd_);
        fd_ = -1;
    }
}

// ---- reader --------------------------------------------------------------------------------

CaptureReader::CaptureReader(const std::string &path) : path_(path), buffer_(1 << 20)
{
    fd_ = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd_ < 0) {
        throw CaptureError(path + ": cannot open: " + std::strerror(errno));
    }
    size_t consumed = 0;
    cdro_result_t status = CDRO_PENDING;
    // The header's size is in the header: read until it is all there (a context can make it
    // up to 64 KiB), or the file ends.
    while (status == CDRO_PENDING) {
        status = cdro_capture_header_decode(buffer_.data(), end_, &header_, &consumed);
        if (status == CDRO_PENDING && !fill()) {
            break;
        }
    }
    switch (status) {
    case CDRO_OK: break;
    case CDRO_PENDING: throw CaptureError(path + ": not a capture file (it ends inside the header)");
    case CDRO_ERR_TYPE: throw CaptureError(path + ": not a capture file (bad magic)");
    case CDRO_ERR_VERSION:
        throw CaptureError(path + ": capture format version is newer than this build reads (" +
                           std::to_string(CDRO_CAPTURE_FORMAT_VERSION) + ")");
    case CDRO_ERR_CRC: throw CaptureError(path + ": corrupt capture header (CRC mismatch)");
    default: throw CaptureError(path + ": inconsistent capture header (" + cdro_result_name(status) + ")");
    }
    begin_ = consumed;
    if (header_.context_len > 0) {
        context_.assign(reinterpret_cast<const char *>(header_.context), header_.context_len);
    }
    header_.context = nullptr; // it pointed into the buffer, which moves on
    header_.context_len = 0;
}

CaptureReader::~CaptureReader()
{
    if (fd_ >= 0) {
        ::close(fd_);
    }
}

bool CaptureReader::fill()
{
    if (eof_) {
        return false;
    }
    if (begin_ > 0) {
        std::memmove(buffer_.data(), buffer_.data() + begin_, end_ - begin_);
        end_ -= begin_;
        begin_ = 0;
    }
    for (;;) {
        const ssize_t n = ::read(fd_, buffer_.data() + end_, buffer_.size() - end_);
        if (n < 0 && errno == EINTR) {
            continue;
        }
        if (n < 0) {
            throw CaptureError(path_ + ": read failed: " + std::strerror(errno));
        }
        if (n == 0) {
            eof_ = true;
            return false;
        }
        end_ += static_cast<size_t>(n);
        return true;
    }
}

bool CaptureReader::next(CaptureRecord &record)
{
    for (;;) {
        cdro_capture_record_t raw{};
        size_t skipped = 0;
        size_t consumed = 0;
        const size_t available = end_ - begin_;
        const cdro_result_t status =
            cdro_capture_next_record(buffer_.data() + begin_, available, &raw, &skipped, &consumed);
        if (status == CDRO_OK) {
            corrupt_bytes_ += skipped;
            record.flags = raw.flags;
            record.host_time_us = raw.host_time_us;
            record.data.assign(raw.data, raw.data + raw.data_len);
            begin_ += skipped + consumed;
            ++records_;
            return true;
        }
        if (eof_) {
            // No good record in what is left: a cut-short last record (or trailing garbage).
            truncated_bytes_ += available;
            begin_ = end_;
            return false;
        }
        // No complete good record starts before the last kMaxRecordBytes: those bytes are
        // corrupt, the rest may be the start of a record that the next read completes.
        if (available > kMaxRecordBytes) {
            const size_t drop = available - kMaxRecordBytes;
            corrupt_bytes_ += drop;
            begin_ += drop;
        }
        fill();
    }
}

} // namespace cdro::service
