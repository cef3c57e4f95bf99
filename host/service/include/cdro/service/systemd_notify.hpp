// systemd_notify.hpp: the service's side of systemd's notification protocol (sd_notify(3)),
// for a unit with Type=notify and WatchdogSec= (config/systemd/cdro-hostd.service.in):
//   READY=1     once the service is up: outputs open, the live map listening, the serial port
//               open or being retried (a missing board is a state the service reports, not a
//               failed start), so that units ordered after it start when it can serve;
//   STATUS=...  a short progress line (`systemctl status cdro-hostd` shows it);
//   WATCHDOG=1  from a timer of the event loop at half of WatchdogSec, so that a loop that
//               hangs stops the pings and systemd restarts the service;
//   STOPPING=1  when the shutdown begins.
// Without $NOTIFY_SOCKET (not started by systemd) every call does nothing.
//
// Threading: loop thread only.
#pragma once

#include <cstdint>
#include <string>

namespace cdro::service {

class SystemdNotifier {
public:
    SystemdNotifier();
    // us between WATCHDOG=1 pings (half of $WATCHDOG_USEC); 0 = the watchdog is off.
    int64_t watchdogPeriodUs() const { return watchdog_period_us_; }
    void ready(const std::string &status);
    void status(const std::string &status); // sent only when it differs from the last one
    void watchdog();
    void stopping(const std::string &status);

private:
    void send(const std::string &state);
    int64_t watchdog_period_us_ = 0;
    std::string last_status_;
};

} // namespace cdro::service
