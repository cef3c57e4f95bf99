// capture.hpp: capture files (format in common/include/cdro/capture.h) written by the live
// service and read back by --replay.
//
// CaptureWriter appends one record per chunk received (and per frame sent, flagged
// to-device, per odometry message accepted, flagged odometry, and per host event of the
// estimator, flagged host event: consumer.hpp), each with a single write() on an O_APPEND descriptor and no user-space
// buffering: a kill -9 at any moment loses at most the record being written, which readers
// report as a truncated tail. Before a record would take the file past rotate_mib, the file is
// rotated: path -> path.1 -> path.2 ... up to path.<keep> (older ones are deleted), and a new
// file with a fresh header is started. An existing file at path is rotated away at open, so a
// restart never overwrites a previous run's capture.
//
// CaptureReader streams a file with common/'s resynchronising policy
// (cdro_capture_next_record): corrupt bytes are skipped and counted, a cut-short last record
// is reported as a truncated tail; it never loads the whole file.
//
// Threading: each object belongs to one thread (the loop thread for the writer).
#pragma once

#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

#include "cdro/capture.h"
#include "cdro/service/config.hpp"
#include "cdro/service/counters.hpp"

namespace cdro::service {

class CaptureError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

class CaptureWriter {
public:
    // source: e.g. "serial:/dev/ttyACM0@115200" (at most 255 bytes; longer is cut). context:
    // what a replay needs to reach the live run's result (the map's heights, fixed nodes and
    // settings: cdro-hostd's JSON), written into every file's header; "" = none. Throws
    // CaptureError if it is longer than CDRO_CAPTURE_MAX_CONTEXT.
    CaptureWriter(const CaptureConfig &config, std::string source, ServiceCounters &counters, std::string context = "");
    ~CaptureWriter();
    CaptureWriter(const CaptureWriter &) = delete;
    CaptureWriter &operator=(const CaptureWriter &) = delete;

    // Creates the file (rotating an existing one away) with its header. Throws CaptureError.
    void open(int64_t created_unix_us);
    bool isOpen() const { return fd_ >= 0; }

    // Appends one record; data longer than CDRO_CAPTURE_MAX_DATA is cut and flagged
    // CDRO_CAPTURE_FLAG_TRUNCATED. A failed write is logged (rate-limited by the caller's
    // counters) and counted in capture_write_errors; the service keeps running.
    void append(uint8_t flags, int64_t host_time_us, const uint8_t *data, size_t len);

    void close();
    const std::string &path() const { return config_.path; }
    uint64_t currentFileBytes() const { return file_bytes_; }

    // path.<index> (index 0 = path itself).
    static std::string rotatedName(const std::string &path, uint32_t index);

private:
    void rotate(int64_t created_unix_us);
    void openFresh(int64_t created_unix_us);

    CaptureConfig config_;
    std::string source_;
    std::string context_;
    ServiceCounters &counters_;
    int fd_ = -1;
    uint64_t file_bytes_ = 0;
    uint64_t header_bytes_ = 0; // of the current file
    uint64_t rotate_bytes_ = 0;
    uint64_t lost_in_outage_ = 0; // records not written since the last one that was
    bool reopen_pending_ = false; // a rotation could not start its new file: retried
    int64_t reopen_at_us_ = 0;    // us (record time) of the next attempt
};

struct CaptureRecord {
    uint8_t flags = 0;         // CDRO_CAPTURE_FLAG_*
    int64_t host_time_us = 0;  // us since the Unix epoch
    std::vector<uint8_t> data; // one chunk as on the wire, without the delimiter (odometry:
                               // the message as normalised JSON)
    bool toDevice() const { return (flags & CDRO_CAPTURE_FLAG_TO_DEVICE) != 0; }
    bool odometry() const { return (flags & CDRO_CAPTURE_FLAG_ODOMETRY) != 0; }
    bool hostEvent() const { return (flags & CDRO_CAPTURE_FLAG_HOST_EVENT) != 0; }
};

class CaptureReader {
public:
    // Opens and checks the header. Throws CaptureError naming the file and the problem.
    explicit CaptureReader(const std::string &path);
    ~CaptureReader();
    CaptureReader(const CaptureReader &) = delete;
    CaptureReader &operator=(const CaptureReader &) = delete;

    // The header (its context pointer cleared: the bytes are in context()).
    const cdro_capture_header_t &header() const { return header_; }
    std::string source() const { return std::string(header_.source, header_.source_len); }
    // The run's context the writer put in the header ("" when the file has none).
    const std::string &context() const { return context_; }

    // The next good record, or false at the end of the file. Throws CaptureError on a read error.
    bool next(CaptureRecord &record);

    uint64_t records() const { return records_; }
    uint64_t corruptBytes() const { return corrupt_bytes_; }         // skipped between records
    uint64_t truncatedTailBytes() const { return truncated_bytes_; } // a cut-short last record

private:
    bool fill();

    std::string path_;
    int fd_ = -1;
    cdro_capture_header_t header_{};
    std::string context_;
    std::vector<uint8_t> buffer_;
    size_t begin_ = 0;
    size_t end_ = 0;
    bool eof_ = false;
    uint64_t records_ = 0;
    uint64_t corrupt_bytes_ = 0;
    uint64_t truncated_bytes_ = 0;
};

} // namespace cdro::service
