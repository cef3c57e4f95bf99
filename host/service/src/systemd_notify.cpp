#include "cdro/service/systemd_notify.hpp"

#include <cstring>

#include <systemd/sd-daemon.h>

#include "cdro/service/log.hpp"

namespace cdro::service {

namespace {
// A STATUS= line stays one line: a newline would start another assignment.
std::string oneLine(std::string text)
{
    for (char &c : text) {
        if (c == '\n' || c == '\r') {
            c = ' ';
        }
    }
    return text;
}
} // namespace

SystemdNotifier::SystemdNotifier()
{
    uint64_t watchdog_us = 0;
    // 0: keep $WATCHDOG_USEC for sd_notify's own checks; > 0 only when it is meant for this pid.
    if (sd_watchdog_enabled(0, &watchdog_us) > 0 && watchdog_us > 0) {
        watchdog_period_us_ = static_cast<int64_t>(watchdog_us / 2);
    }
}

void SystemdNotifier::send(const std::string &state)
{
    const int rc = sd_notify(0, state.c_str());
    if (rc < 0) {
        log()->warn("systemd: cannot notify the service manager ({}): {}", state.substr(0, state.find('\n')),
                    std::strerror(-rc));
    }
}

void SystemdNotifier::ready(const std::string &status)
{
    last_status_ = oneLine(status);
    send("READY=1\nSTATUS=" + last_status_);
}

void SystemdNotifier::status(const std::string &status)
{
    const std::string line = oneLine(status);
    if (line == last_status_) {
        return;
    }
    last_status_ = line;
    send("STATUS=" + line);
}

void SystemdNotifier::watchdog() { send("WATCHDOG=1"); }

void SystemdNotifier::stopping(const std::string &status)
{
    last_status_ = oneLine(status);
    send("STOPPING=1\nSTATUS=" + last_status_);
}

} // namespace cdro::service
