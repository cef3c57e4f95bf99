#include "pty_port.hpp"

#include <fcntl.h>
#include <poll.h>
#include <pty.h>
#include <sys/ioctl.h>
#include <sys/stat.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <ctime>

namespace cdro::fil {

PtyPort::PtyPort(const std::string &link_path) : link_path_(link_path)
{
    int slave = -1;
    char name[256] = {};
    if (openpty(&master_, &slave, name, nullptr, nullptr) != 0) {
        throw PtyError(std::string("cannot open a pseudo-terminal: ") + std::strerror(errno));
    }
    slave_path_ = name;
    // Raw 8N1 on the slave, so that a host that does not configure the port still gets the
    // binary frames untouched. The settings stay with the terminal after the slave is closed.
    termios attributes;
    if (tcgetattr(slave, &attributes) == 0) {
        cfmakeraw(&attributes);
        cfsetispeed(&attributes, B115200);
        cfsetospeed(&attributes, B115200);
        (void)tcsetattr(slave, TCSANOW, &attributes);
    }
    // The slave is not kept open: then the master sees when a host has the port open (no
    // POLLHUP), and bytes sent while nobody listens are dropped rather than queued.
    close(slave);
    const int flags = fcntl(master_, F_GETFL);
    (void)fcntl(master_, F_SETFL, flags | O_NONBLOCK);
    (void)fcntl(master_, F_SETFD, FD_CLOEXEC);

    if (!link_path_.empty()) {
        struct stat st;
        if (lstat(link_path_.c_str(), &st) == 0) {
            if (!S_ISLNK(st.st_mode)) {
                close(master_);
                throw PtyError(link_path_ + ": exists and is not a symlink; not replacing it");
            }
            (void)unlink(link_path_.c_str());
        }
        if (symlink(slave_path_.c_str(), link_path_.c_str()) != 0) {
            const std::string reason = std::strerror(errno);
            close(master_);
            throw PtyError(link_path_ + ": cannot create the symlink to " + slave_path_ + ": " + reason);
        }
    }
}

PtyPort::~PtyPort()
{
    if (!link_path_.empty()) {
        char target[256] = {};
        const ssize_t n = readlink(link_path_.c_str(), target, sizeof target - 1);
        if (n > 0 && slave_path_ == std::string(target, static_cast<size_t>(n))) {
            (void)unlink(link_path_.c_str());
        }
    }
    if (master_ >= 0) {
        close(master_);
    }
}

bool PtyPort::hostConnected() const
{
    pollfd p = {master_, POLLIN, 0};
    if (poll(&p, 1, 0) < 0) {
        return false;
    }
    return (p.revents & POLLHUP) == 0;
}

size_t PtyPort::readHost(uint8_t *buffer, size_t capacity)
{
    if (capacity == 0) {
        return 0;
    }
    const ssize_t n = read(master_, buffer, capacity);
    return n > 0 ? static_cast<size_t>(n) : 0; // EAGAIN: nothing; EIO: no host
}

void PtyPort::send(uint8_t byte)
{
    if (out_.size() >= kMaxPendingBytes) {
        ++dropped_;
        return;
    }
    out_.push_back(byte);
}

void PtyPort::flush()
{
    if (out_.empty()) {
        return;
    }
    if (!hostConnected()) {
        dropped_ += out_.size(); // nobody has the port open: the bytes go nowhere
        out_.clear();
        return;
    }
    uint8_t chunk[1024];
    while (!out_.empty()) {
        size_t n = 0;
        for (auto it = out_.begin(); it != out_.end() && n < sizeof chunk; ++it) {
            chunk[n++] = *it;
        }
        const ssize_t written = write(master_, chunk, n);
        if (written <= 0) {
            return; // the terminal is full (the host is not reading): keep them for later
        }
        out_.erase(out_.begin(), out_.begin() + written);
    }
}

bool PtyPort::drain(int timeout_ms)
{
    timespec start;
    clock_gettime(CLOCK_MONOTONIC, &start);
    for (;;) {
        flush();
        if (!hostConnected()) {
            return out_.empty();
        }
        int unread = 0;
        const int probe = open(slave_path_.c_str(), O_RDONLY | O_NOCTTY | O_NONBLOCK);
        if (probe >= 0) {
            if (ioctl(probe, FIONREAD, &unread) != 0) {
                unread = 0;
            }
            close(probe);
        }
        if (out_.empty() && unread == 0) {
            return true;
        }
        timespec now;
        clock_gettime(CLOCK_MONOTONIC, &now);
        const long elapsed_ms = (now.tv_sec - start.tv_sec) * 1000L + (now.tv_nsec - start.tv_nsec) / 1000000L;
        if (elapsed_ms >= timeout_ms) {
            return false;
        }
        usleep(5000);
    }
}

} // namespace cdro::fil
