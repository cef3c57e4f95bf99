// log.hpp: the service's spdlog logger and a rate limiter for messages that bad input could
// otherwise repeat thousands of times per second (dropped frames).
//
// Logs go to stderr or a file, never to stdout, which may carry the JSON Lines stream. Under
// systemd (stderr is the journal stream named by $JOURNAL_STREAM), a stderr line is
// "<N>message" with N the syslog priority (3 error, 4 warning, 6 info, 7 debug), which journald
// stores as the line's priority; elsewhere it is "date time level message".
// The logger is thread-safe (spdlog _mt sinks); RateLimiter is not (one per owner thread).
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <string>

#include <spdlog/spdlog.h>

#include "cdro/service/config.hpp"

namespace cdro::service {

// Installs the "cdro" logger from the logging: section (level, file). Throws ConfigError if
// the file cannot be opened. Safe to call again (replaces the logger).
void setupLogging(const LoggingConfig &config);

// True when stderr is the journal stream systemd gave the process ($JOURNAL_STREAM matches it).
bool stderrIsJournal();

// The "cdro" logger (a stderr logger at info until setupLogging is called).
std::shared_ptr<spdlog::logger> log();

// A status line kept under the log on a terminal (cdro-hostd's progress): each call redraws it
// in place on stderr (carriage return, erase, the text, no newline), and a log line written to
// stderr meanwhile erases it first and redraws it after itself, so that the two never share a
// line. Thread-safe with the logger. Only for a stderr that is a terminal; elsewhere (journald,
// a file) a line that is overwritten only garbles the output, and the caller prints ordinary
// lines there.
void showStatusLine(const std::string &text);
// Leaves the status line on the screen as an ordinary line (a newline) and stops redrawing it.
void endStatusLine();

// At most `per_s` messages per key per second of the given clock; the first message after a
// quiet spell says how many were suppressed.
class RateLimiter {
public:
    explicit RateLimiter(double per_s) : per_s_(per_s) {}
    // True if a message for key may be logged now; *suppressed is set to the number held back
    // since the last one that was allowed.
    bool allow(const std::string &key, int64_t now_monotonic_us, uint64_t *suppressed);

private:
    struct Bucket {
        double tokens = 0.0;
        int64_t last_us = 0;
        uint64_t suppressed = 0;
        bool started = false;
    };
    double per_s_;
    std::map<std::string, Bucket> buckets_;
};

} // namespace cdro::service
