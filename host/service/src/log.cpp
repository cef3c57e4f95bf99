#include "cdro/service/log.hpp"

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <mutex>
#include <string>
#include <utility>

#include <sys/ioctl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <spdlog/sinks/base_sink.h>
#include <spdlog/sinks/basic_file_sink.h>
#include <spdlog/sinks/stdout_color_sinks.h>

#include "cdro/service/output_file.hpp"

namespace cdro::service {

namespace {
std::mutex g_logger_mutex;
std::shared_ptr<spdlog::logger> g_logger;

// The status line on stderr, and the lock every write to stderr by the log and by the status
// line takes, so that a log line cannot land in the middle of the line's erase and redraw.
std::mutex g_stderr_mutex;
std::string g_status_text; // shown when g_status_rows > 0
int g_status_rows = 0;     // terminal rows the shown status line takes (it wraps on a narrow one)

int terminalColumns()
{
    struct winsize size {};
    return ::ioctl(STDERR_FILENO, TIOCGWINSZ, &size) == 0 ? size.ws_col : 0;
}

// Back to the start of the status line and erase it, with the cursor left there.
void eraseStatusLocked()
{
    if (g_status_rows == 0) {
        return;
    }
    if (g_status_rows == 1) {
        std::fputs("\r\x1b[K", stderr);
    } else {
        std::fprintf(stderr, "\r\x1b[%dA\x1b[J", g_status_rows - 1);
    }
}

// Drawn from the start of an erased line whatever came before (the cursor is at a line's start
// after the erase or a log line, so this only makes every draw look the same on the wire).
void drawStatusLocked(const std::string &text)
{
    std::fputs("\r\x1b[K", stderr);
    std::fputs(text.c_str(), stderr);
    const int columns = terminalColumns();
    const int length = static_cast<int>(text.size());
    g_status_rows = columns > 0 && length > columns ? (length + columns - 1) / columns : 1;
}

// syslog(3) priorities, as sd-daemon.h's SD_ERR etc. spell them for stderr: "<3>text".
int journalPriority(spdlog::level::level_enum level)
{
    switch (level) {
    case spdlog::level::critical: return 2; // SD_CRIT
    case spdlog::level::err: return 3;      // SD_ERR
    case spdlog::level::warn: return 4;     // SD_WARNING
    case spdlog::level::info: return 6;     // SD_INFO
    default: return 7;                      // SD_DEBUG (debug, trace)
    }
}

// stderr for journald: every line starts with its priority, and without a time stamp or level
// name (the journal records both), so that `journalctl -p warning` finds the warnings.
class JournalStderrSink final : public spdlog::sinks::base_sink<std::mutex> {
protected:
    void sink_it_(const spdlog::details::log_msg &message) override
    {
        spdlog::memory_buf_t text;
        formatter_->format(message, text);
        std::string line = "<" + std::to_string(journalPriority(message.level)) + ">";
        line.append(text.data(), text.size());
        std::fwrite(line.data(), 1, line.size(), stderr);
    }
    void flush_() override { std::fflush(stderr); }
};

// stderr elsewhere: spdlog's (coloured on a terminal), with the status line erased before a log
// line and drawn again under it.
class StatusAwareStderrSink final : public spdlog::sinks::sink {
public:
    void log(const spdlog::details::log_msg &message) override
    {
        std::lock_guard<std::mutex> lock(g_stderr_mutex);
        const bool status = g_status_rows > 0;
        eraseStatusLocked();
        inner_.log(message);
        if (status) {
            drawStatusLocked(g_status_text);
        }
        std::fflush(stderr);
    }
    void flush() override
    {
        std::lock_guard<std::mutex> lock(g_stderr_mutex);
        inner_.flush();
    }
    void set_pattern(const std::string &pattern) override
    {
        std::lock_guard<std::mutex> lock(g_stderr_mutex);
        inner_.set_pattern(pattern);
    }
    void set_formatter(std::unique_ptr<spdlog::formatter> formatter) override
    {
        std::lock_guard<std::mutex> lock(g_stderr_mutex);
        inner_.set_formatter(std::move(formatter));
    }

private:
    spdlog::sinks::stderr_color_sink_st inner_;
};

std::shared_ptr<spdlog::logger> stderrLogger()
{
    if (stderrIsJournal()) {
        auto logger = std::make_shared<spdlog::logger>("cdro", std::make_shared<JournalStderrSink>());
        logger->set_pattern("%v");
        return logger;
    }
    auto logger = std::make_shared<spdlog::logger>("cdro", std::make_shared<StatusAwareStderrSink>());
    logger->set_pattern("%Y-%m-%d %H:%M:%S.%e %^%l%$ %v");
    return logger;
}
} // namespace

bool stderrIsJournal()
{
    // systemd sets $JOURNAL_STREAM to "<device>:<inode>" of the stream it connected to stdout and
    // stderr; a process whose stderr was redirected since (a shell in ExecStart=) keeps the
    // variable but not the stream, so both are compared (sd_journal_stream_fd(3)).
    const char *stream = std::getenv("JOURNAL_STREAM");
    if (stream == nullptr) {
        return false;
    }
    unsigned long long device = 0;
    unsigned long long inode = 0;
    if (std::sscanf(stream, "%llu:%llu", &device, &inode) != 2) {
        return false;
    }
    struct stat st {};
    if (::fstat(STDERR_FILENO, &st) != 0) {
        return false;
    }
    return static_cast<unsigned long long>(st.st_dev) == device && static_cast<unsigned long long>(st.st_ino) == inode;
}

void setupLogging(const LoggingConfig &config)
{
    std::shared_ptr<spdlog::logger> logger;
    if (!config.file.empty()) {
        checkOutputPath(config.file, "logging.file"); // spdlog opens it itself (and would follow a link)
    }
    try {
        if (config.file.empty()) {
            logger = stderrLogger();
        } else {
            logger = std::make_shared<spdlog::logger>("cdro",
                                                      std::make_shared<spdlog::sinks::basic_file_sink_mt>(config.file,
                                                                                                          false));
            logger->set_pattern("%Y-%m-%d %H:%M:%S.%e %^%l%$ %v");
        }
    } catch (const spdlog::spdlog_ex &error) {
        throw ConfigError("logging.file: cannot open '" + config.file + "': " + error.what());
    }
    logger->set_level(spdlog::level::from_str(config.level));
    logger->flush_on(spdlog::level::info);
    std::lock_guard<std::mutex> lock(g_logger_mutex);
    g_logger = logger;
}

std::shared_ptr<spdlog::logger> log()
{
    std::lock_guard<std::mutex> lock(g_logger_mutex);
    if (!g_logger) {
        g_logger = stderrLogger();
    }
    return g_logger;
}

void showStatusLine(const std::string &text)
{
    std::lock_guard<std::mutex> lock(g_stderr_mutex);
    eraseStatusLocked();
    g_status_text = text;
    drawStatusLocked(text);
    std::fflush(stderr);
}

void endStatusLine()
{
    std::lock_guard<std::mutex> lock(g_stderr_mutex);
    if (g_status_rows > 0) {
        std::fputs("\n", stderr);
        std::fflush(stderr);
    }
    g_status_rows = 0;
    g_status_text.clear();
}

bool RateLimiter::allow(const std::string &key, int64_t now_monotonic_us, uint64_t *suppressed)
{
    Bucket &b = buckets_[key];
    const double burst = std::max(1.0, per_s_);
    if (!b.started) {
        b.started = true;
        b.tokens = burst;
        b.last_us = now_monotonic_us;
    }
    const double elapsed_s = static_cast<double>(now_monotonic_us - b.last_us) * 1e-6;
    b.last_us = now_monotonic_us;
    b.tokens = std::min(burst, b.tokens + std::max(0.0, elapsed_s) * per_s_);
    if (b.tokens >= 1.0) {
        b.tokens -= 1.0;
        if (suppressed != nullptr) {
            *suppressed = b.suppressed;
        }
        b.suppressed = 0;
        return true;
    }
    ++b.suppressed;
    return false;
}

} // namespace cdro::service
