#include "cdro/service/serial_link.hpp"

#include <algorithm>
#include <cerrno>
#include <cstring>

#include <fcntl.h>
#include <stdlib.h>
#include <sys/stat.h>
#include <poll.h>
#include <termios.h>
#include <unistd.h>

#include <libserial/SerialPort.h>

#include "cdro/service/log.hpp"

namespace cdro::service {

namespace {

struct BaudEntry {
    uint32_t baud;
    LibSerial::BaudRate rate;
};

const BaudEntry kBauds[] = {
    {9600, LibSerial::BaudRate::BAUD_9600},       {19200, LibSerial::BaudRate::BAUD_19200},
    {38400, LibSerial::BaudRate::BAUD_38400},     {57600, LibSerial::BaudRate::BAUD_57600},
    {115200, LibSerial::BaudRate::BAUD_115200},   {230400, LibSerial::BaudRate::BAUD_230400},
    {460800, LibSerial::BaudRate::BAUD_460800},   {500000, LibSerial::BaudRate::BAUD_500000},
    {921600, LibSerial::BaudRate::BAUD_921600},   {1000000, LibSerial::BaudRate::BAUD_1000000},
    {2000000, LibSerial::BaudRate::BAUD_2000000},
};

class LibSerialDevice final : public SerialDevice {
public:
    int open(const std::string &path, uint32_t baud, std::string *error) override
    {
        close();
        try {
            port_ = std::make_unique<LibSerial::SerialPort>();
            port_->Open(path);
        } catch (const std::exception &e) {
            if (error != nullptr) {
                *error = openFailureReason(path, e.what());
            }
            close();
            return -1;
        }
        const int fd = configureLibSerialPort(*port_, baud, error);
        if (fd < 0) {
            close();
        }
        return fd;
    }

    void close() override
    {
        if (!port_) {
            return;
        }
        if (port_->IsOpen()) {
            // LibSerial's Close() first restores the terminal settings it found. On a device
            // that vanished that fails (EIO), Close() throws and keeps the descriptor, and the
            // noexcept destructor would then throw again and terminate the process. So when
            // the device is gone, its descriptor number is pointed at a fresh pseudo-terminal
            // master (dup2) for Close() to restore and close harmlessly.
            const int fd = port_->GetFileDescriptor();
            termios current{};
            if (tcgetattr(fd, &current) != 0 || tcsetattr(fd, TCSANOW, &current) != 0) {
                const int stand_in = ::posix_openpt(O_RDWR | O_NOCTTY | O_CLOEXEC);
                if (stand_in < 0 || ::dup2(stand_in, fd) < 0) {
                    // Cannot make Close() safe: give the port object up (a small, bounded leak
                    // per failure) rather than risk terminate().
                    if (stand_in >= 0) {
                        ::close(stand_in);
                    }
                    ::close(fd);
                    (void)port_.release();
                    return;
                }
                ::close(stand_in);
            }
            try {
                port_->Close();
            } catch (const std::exception &) {
                (void)port_.release(); // as above: never let the destructor throw
                return;
            }
        }
        port_.reset();
    }

    ~LibSerialDevice() override { close(); }

private:
    std::unique_ptr<LibSerial::SerialPort> port_;
};

} // namespace

std::unique_ptr<SerialDevice> makeLibSerialDevice() { return std::make_unique<LibSerialDevice>(); }

std::string openFailureReason(const std::string &path, const std::string &fallback)
{
    const int fd = ::open(path.c_str(), O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
    if (fd >= 0) {
        ::close(fd);
        return fallback;
    }
    switch (errno) {
    case EACCES:
    case EPERM:
        return "permission denied (add yourself to the dialout group: sudo usermod -aG dialout $USER, then log in "
               "again; or install config/udev/99-cdro-pozyx.rules)";
    case ENOENT: return "no such device (is the board plugged in? ls /dev/ttyACM* /dev/ttyUSB*)";
    case EBUSY: return "device busy (another program has it open?)";
    default: return std::strerror(errno);
    }
}

int configureLibSerialPort(LibSerial::SerialPort &port, uint32_t baud, std::string *error)
{
    const BaudEntry *entry =
        std::find_if(std::begin(kBauds), std::end(kBauds), [baud](const BaudEntry &e) { return e.baud == baud; });
    if (entry == std::end(kBauds)) {
        if (error != nullptr) {
            *error = "unsupported baud " + std::to_string(baud);
        }
        return -1;
    }
    try {
        port.SetBaudRate(entry->rate);
        port.SetCharacterSize(LibSerial::CharacterSize::CHAR_SIZE_8);
        port.SetParity(LibSerial::Parity::PARITY_NONE);
        port.SetStopBits(LibSerial::StopBits::STOP_BITS_1);
        // Not SetFlowControl(): it discards the input that has arrived (see the header).
        port.SetVMin(0);
        port.SetVTime(0);
    } catch (const std::exception &e) {
        if (error != nullptr) {
            *error = e.what();
        }
        return -1;
    }
    const int fd = port.GetFileDescriptor();
    // Raw mode in full (LibSerial's defaults are raw already; this makes sure that no byte is
    // translated, echoed or taken as a signal or as XON/XOFF), no hardware flow control, and
    // non-blocking for the loop. TCSANOW: nothing that has arrived is dropped.
    termios tio{};
    if (tcgetattr(fd, &tio) == 0) {
        cfmakeraw(&tio);
        tio.c_iflag &= ~static_cast<tcflag_t>(IXON | IXOFF | IXANY);
        tio.c_cflag &= ~static_cast<tcflag_t>(CRTSCTS);
        tio.c_cflag |= CLOCAL | CREAD;
        tio.c_cc[VMIN] = 0;
        tio.c_cc[VTIME] = 0;
        tcsetattr(fd, TCSANOW, &tio);
    }
    const int flags = fcntl(fd, F_GETFL);
    if (flags < 0 || fcntl(fd, F_SETFL, flags | O_NONBLOCK) != 0) {
        if (error != nullptr) {
            *error = std::string("cannot make the port non-blocking: ") + std::strerror(errno);
        }
        return -1;
    }
    return fd;
}

bool isSupportedBaud(uint32_t baud)
{
    return std::any_of(std::begin(kBauds), std::end(kBauds), [baud](const BaudEntry &e) { return e.baud == baud; });
}

SerialLink::SerialLink(EventLoop &loop, const SerialConfig &config, Listener &listener, ServiceCounters &counters,
                       std::unique_ptr<SerialDevice> device)
    : loop_(loop), config_(config), listener_(listener), counters_(counters), device_(std::move(device)),
      backoff_us_(secondsToUs(config.reconnect_min_s)), diagnostics_(config.device, config.baud)
{
    if (!isSupportedBaud(config_.baud)) {
        throw ConfigError("serial.baud: " + std::to_string(config_.baud) +
                          " bit/s is not a supported rate (9600 ... 2000000, standard rates)");
    }
}

SerialLink::~SerialLink() { shutdown(); }

std::string SerialLink::description() const { return "serial:" + config_.device + "@" + std::to_string(config_.baud); }

void SerialLink::start()
{
    running_ = true;
    tryOpen();
}

void SerialLink::shutdown()
{
    running_ = false;
    if (retry_timer_ != 0) {
        loop_.cancelTimer(retry_timer_);
        retry_timer_ = 0;
    }
    if (verdict_timer_ != 0) {
        loop_.cancelTimer(verdict_timer_);
        verdict_timer_ = 0;
    }
    if (fd_ >= 0) {
        loop_.unwatchFd(fd_);
        device_->close();
        fd_ = -1;
    }
}

void SerialLink::tryOpen()
{
    retry_timer_ = 0;
    if (!running_ || fd_ >= 0) {
        return;
    }
    std::string error;
    const int fd = device_->open(config_.device, config_.baud, &error);
    if (fd < 0) {
        ++counters_.link_open_failures;
        // Logged once per outage; the retries are quiet (debug) until the port comes back.
        if (failed_opens_in_a_row_++ == 0) {
            log()->warn("serial: cannot open {}: {}; retrying with backoff ({:.3g} s up to {:.3g} s)", config_.device,
                        error, config_.reconnect_min_s, config_.reconnect_max_s);
        } else {
            log()->debug("serial: open {} failed again ({}): {}", config_.device, failed_opens_in_a_row_, error);
        }
        scheduleRetry();
        return;
    }
    if (failed_opens_in_a_row_ > 1) {
        log()->info("serial: {} is back after {} failed attempts", config_.device, failed_opens_in_a_row_);
    }
    failed_opens_in_a_row_ = 0;
    fd_ = fd;
    out_queue_.clear();
    diagnostics_.reset(loop_.clock().monotonicUs());
    ++counters_.link_connects;
    log()->info("serial: opened {} at {} bit/s, raw 8N1", config_.device, config_.baud);
    loop_.watchFd(fd_, POLLIN, [this](short revents) { onEvents(revents); });
    listener_.onLinkUp();
}

void SerialLink::scheduleRetry()
{
    if (!running_ || retry_timer_ != 0) {
        return;
    }
    const int64_t delay_us = backoff_us_;
    backoff_us_ = std::min(backoff_us_ * 2, secondsToUs(config_.reconnect_max_s));
    retry_timer_ = loop_.addTimerAfter(delay_us, [this] { tryOpen(); });
}

void SerialLink::resetBackoff() { backoff_us_ = secondsToUs(config_.reconnect_min_s); }

void SerialLink::goDown(const std::string &reason)
{
    if (fd_ < 0) {
        return;
    }
    loop_.unwatchFd(fd_);
    device_->close();
    fd_ = -1;
    out_queue_.clear();
    if (verdict_timer_ != 0) {
        loop_.cancelTimer(verdict_timer_);
        verdict_timer_ = 0;
    }
    ++counters_.link_disconnects;
    failed_opens_in_a_row_ = 1; // the coming retries are part of this outage: log it once
    log()->warn("serial: lost {}: {}; keeping the map, retrying with backoff", config_.device, reason);
    listener_.onLinkDown(reason);
    scheduleRetry();
}

void SerialLink::reopen(const std::string &reason) { goDown(reason); }

void SerialLink::onEvents(short revents)
{
    if (revents & POLLNVAL) {
        goDown("descriptor invalid");
        return;
    }
    if (revents & POLLOUT) {
        flushQueue();
        if (fd_ < 0) {
            return;
        }
    }
    if (revents & (POLLIN | POLLHUP | POLLERR)) {
        // Drain what is there (bounded, so a flood cannot starve the rest of the loop), then
        // act on a hang-up: the bytes that arrived before it still count.
        uint8_t buffer[4096];
        for (int reads = 0; reads < 64; ++reads) {
            const ssize_t n = ::read(fd_, buffer, sizeof buffer);
            if (n > 0) {
                counters_.bytes_received += static_cast<uint64_t>(n);
                const bool first = !diagnostics_.sawFirstByte();
                diagnostics_.onBytes(buffer, static_cast<size_t>(n), loop_.clock().monotonicUs());
                if (first) { // the verdict on what the port streams, kVerdictUs after its first byte
                    verdict_timer_ = loop_.addTimerAfter(LinkDiagnostics::kVerdictUs, [this] {
                        verdict_timer_ = 0;
                        (void)diagnostics_.check(loop_.clock().monotonicUs());
                    });
                }
                listener_.onLinkBytes(buffer, static_cast<size_t>(n), loop_.clock().unixUs());
                if (fd_ < 0) {
                    return; // the listener closed the link
                }
                continue;
            }
            if (n < 0 && errno == EINTR) {
                continue;
            }
            if (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK) {
                goDown(std::string("read failed: ") + std::strerror(errno));
                return;
            }
            break; // 0 (VMIN 0: nothing now) or EAGAIN
        }
        if (revents & (POLLHUP | POLLERR)) {
            goDown((revents & POLLHUP) ? "hang-up (device unplugged or closed)" : "I/O error on the port");
        }
    }
}

bool SerialLink::send(const uint8_t *bytes, size_t len)
{
    if (fd_ < 0 || out_queue_.size() + len > kMaxQueuedBytes) {
        ++counters_.write_errors;
        return false;
    }
    out_queue_.insert(out_queue_.end(), bytes, bytes + len);
    flushQueue();
    return true;
}

void SerialLink::flushQueue()
{
    while (fd_ >= 0 && !out_queue_.empty()) {
        const ssize_t n = ::write(fd_, out_queue_.data(), out_queue_.size());
        if (n > 0) {
            counters_.bytes_sent += static_cast<uint64_t>(n);
            out_queue_.erase(out_queue_.begin(), out_queue_.begin() + n);
            continue;
        }
        if (n < 0 && errno == EINTR) {
            continue;
        }
        if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
            break;
        }
        ++counters_.write_errors;
        goDown(std::string("write failed: ") + std::strerror(errno));
        return;
    }
    if (fd_ >= 0) {
        loop_.setFdEvents(fd_, static_cast<short>(out_queue_.empty() ? POLLIN : (POLLIN | POLLOUT)));
    }
}

} // namespace cdro::service
