#include "cdro/service/log.hpp"

#include <algorithm>
#include <mutex>

#include <spdlog/sinks/basic_file_sink.h>
#include <spdlog/sinks/stdout_color_sinks.h>

#include "cdro/service/output_file.hpp"

namespace cdro::service {

namespace {
std::mutex g_logger_mutex;
std::shared_ptr<spdlog::logger> g_logger;
} // namespace

void setupLogging(const LoggingConfig &config)
{
    std::shared_ptr<spdlog::logger> logger;
    if (!config.file.empty()) {
        checkOutputPath(config.file, "logging.file"); // spdlog opens it itself (and would follow a link)
    }
    try {
        if (config.file.empty()) {
            logger = std::make_shared<spdlog::logger>("cdro", std::make_shared<spdlog::sinks::stderr_color_sink_mt>());
        } else {
            logger = std::make_shared<spdlog::logger>(
                "cdro", std::make_shared<spdlog::sinks::basic_file_sink_mt>(config.file, false));
        }
    } catch (const spdlog::spdlog_ex &error) {
        throw ConfigError("logging.file: cannot open '" + config.file + "': " + error.what());
    }
    logger->set_level(spdlog::level::from_str(config.level));
    logger->set_pattern("%Y-%m-%d %H:%M:%S.%e %^%l%$ %v");
    logger->flush_on(spdlog::level::info);
    std::lock_guard<std::mutex> lock(g_logger_mutex);
    g_logger = logger;
}

std::shared_ptr<spdlog::logger> log()
{
    std::lock_guard<std::mutex> lock(g_logger_mutex);
    if (!g_logger) {
        g_logger = std::make_shared<spdlog::logger>("cdro", std::make_shared<spdlog::sinks::stderr_color_sink_mt>());
        g_logger->set_pattern("%Y-%m-%d %H:%M:%S.%e %^%l%$ %v");
    }
    return g_logger;
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
