// serial_link.hpp: the serial port to the Pozyx tag, opened with LibSerial (raw 8N1 at the
// configured baud) and then read and written through its file descriptor in the event loop.
//
// LibSerial does the termios work (open, baud, 8N1, raw); its blocking Read/Write calls are
// not used, because one poll()-based loop must serve the port, MQTT, timers and signals.
//
// When the device vanishes (POLLHUP, EIO, a read error) or cannot be opened, the link logs it
// once, closes the port and retries with exponential backoff (reconnect_min_s doubling up to
// reconnect_max_s), forever; nothing else stops. resetBackoff() is called by the owner once the
// device is known healthy again (the session reached running).
//
// First errors that help: a port the user may not open says "permission denied (add yourself to
// the dialout group)"; a port that streams bytes that are not CDRO frames says so within 2 s
// (LinkDiagnostics), as do the device's Pozyx set-up reports.
//
// Threading: loop thread only.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "cdro/service/config.hpp"
#include "cdro/service/counters.hpp"
#include "cdro/service/event_loop.hpp"
#include "cdro/service/link_diagnostics.hpp"

namespace LibSerial {
class SerialPort;
}

namespace cdro::service {

// The hardware seam: opens a serial device and hands back its descriptor. The real one uses
// LibSerial; tests may substitute another (e.g. one that fails on demand). Its error says what a
// person can do about it (openFailureReason).
class SerialDevice {
public:
    virtual ~SerialDevice() = default;
    // Opens path at baud, raw 8N1, non-blocking. Returns the descriptor, or -1 with *error set.
    virtual int open(const std::string &path, uint32_t baud, std::string *error) = 0;
    virtual void close() = 0; // never throws; safe when not open
};

std::unique_ptr<SerialDevice> makeLibSerialDevice();

// Why a serial device cannot be opened, in words a person can act on: tries open(2) itself
// (LibSerial's own messages can be vague, e.g. "Bad file descriptor"): "permission denied (add
// yourself to the dialout group ...)" for EACCES/EPERM, "no such device ..." for ENOENT, ...
// `fallback` if open(2) works (the failure was elsewhere).
std::string openFailureReason(const std::string &path, const std::string &fallback);

// The configuration makeLibSerialDevice's open() applies to a port LibSerial has opened: baud,
// 8N1, raw, no flow control, VMIN/VTIME 0, non-blocking. Returns the descriptor, or -1 with
// *error set. It never discards what has arrived since the port was opened: LibSerial's
// SetFlowControl() does (it flushes the input), which cut the first frame a device sent while
// the port was being configured; flow control is switched off in the termios settings instead.
int configureLibSerialPort(LibSerial::SerialPort &port, uint32_t baud, std::string *error);
bool isSupportedBaud(uint32_t baud);

class SerialLink {
public:
    class Listener {
    public:
        virtual ~Listener() = default;
        virtual void onLinkUp() = 0;
        // Bytes as they came, with the wall-clock time of the read (the capture's time base).
        virtual void onLinkBytes(const uint8_t *bytes, size_t len, int64_t received_unix_us) = 0;
        virtual void onLinkDown(const std::string &reason) = 0;
    };

    // Throws ConfigError for an unsupported baud rate.
    SerialLink(EventLoop &loop, const SerialConfig &config, Listener &listener, ServiceCounters &counters,
               std::unique_ptr<SerialDevice> device = makeLibSerialDevice());
    ~SerialLink();
    SerialLink(const SerialLink &) = delete;
    SerialLink &operator=(const SerialLink &) = delete;

    void start();    // first open attempt now; retries on its own after that
    void shutdown(); // closes and stops retrying
    bool isOpen() const { return fd_ >= 0; }

    // Queues bytes for the device; false (counted in write_errors) if the port is closed or
    // more than kMaxQueuedBytes are already waiting.
    bool send(const uint8_t *bytes, size_t len);

    // Closes the port and retries after the backoff (e.g. the device stopped answering).
    void reopen(const std::string &reason);
    void resetBackoff();
    int64_t currentBackoffUs() const { return backoff_us_; }

    std::string description() const; // "serial:<path>@<baud>"
    const LinkDiagnostics &diagnostics() const { return diagnostics_; }

    static constexpr size_t kMaxQueuedBytes = 64 * 1024;

private:
    void tryOpen();
    void onEvents(short revents);
    void flushQueue();
    void goDown(const std::string &reason);
    void scheduleRetry();

    EventLoop &loop_;
    SerialConfig config_;
    Listener &listener_;
    ServiceCounters &counters_;
    std::unique_ptr<SerialDevice> device_;
    int fd_ = -1;
    bool running_ = false;
    int64_t backoff_us_ = 0;
    EventLoop::TimerId retry_timer_ = 0;
    uint64_t failed_opens_in_a_row_ = 0;
    std::vector<uint8_t> out_queue_;
    LinkDiagnostics diagnostics_;
    EventLoop::TimerId verdict_timer_ = 0;
};

} // namespace cdro::service
