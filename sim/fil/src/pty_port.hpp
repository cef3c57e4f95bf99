// pty_port.hpp: the serial port the host opens: a pseudo-terminal whose slave side is what
// the host sees (/dev/pts/N, optionally behind a symlink), and whose master side carries the
// simulated UART0's bytes. Like the Uno's USB bridge, bytes the firmware sends while no host
// has the port open are lost; bytes the host wrote wait in the kernel until the UART takes them.
#pragma once

#include <cstddef>
#include <cstdint>
#include <deque>
#include <stdexcept>
#include <string>

namespace cdro::fil {

class PtyError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

class PtyPort {
public:
    // Opens the pseudo-terminal (raw, 8N1) and, if link_path is not empty, creates the symlink
    // (replacing an old symlink there, never a file).
    explicit PtyPort(const std::string &link_path);
    ~PtyPort(); // removes the symlink if it still points at this terminal
    PtyPort(const PtyPort &) = delete;
    PtyPort &operator=(const PtyPort &) = delete;

    const std::string &slavePath() const { return slave_path_; }
    const std::string &linkPath() const { return link_path_; }
    int masterFd() const { return master_; }

    // True while some process has the slave side open.
    bool hostConnected() const;
    // Reads what the host wrote, without blocking: at most `capacity` bytes; 0 if none.
    size_t readHost(uint8_t *buffer, size_t capacity);
    // The firmware's bytes for the host: written at once if the terminal takes them, else kept
    // (up to kMaxPendingBytes; beyond that, and while no host is connected, they are dropped).
    void send(uint8_t byte);
    void flush();
    size_t pendingBytes() const { return out_.size(); }
    uint64_t droppedBytes() const { return dropped_; }
    // Waits (up to timeout_ms of wall-clock time) until the host has read everything sent.
    bool drain(int timeout_ms);

    static constexpr size_t kMaxPendingBytes = 65536;

private:
    int master_ = -1;
    std::string slave_path_;
    std::string link_path_;
    std::deque<uint8_t> out_;
    uint64_t dropped_ = 0;
};

} // namespace cdro::fil
