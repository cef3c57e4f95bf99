// SerialLink on real pseudo-terminals: raw 8N1, bytes both ways, a vanished device is noticed,
// retried with exponential backoff, and resumed when it comes back at the same path; the first
// errors a person setting up a board sees (a port they may not open, foreign bytes).
#include <pty.h>
#include <sys/ioctl.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <termios.h>
#include <unistd.h>

#include <cstdint>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <libserial/SerialPort.h>

#include "cdro/cobs.h"
#include "cdro/crc.h"
#include "cdro/service/link_diagnostics.hpp"
#include "cdro/service/serial_link.hpp"
#include "support.hpp"

using namespace cdro::service;

namespace {
struct Listener final : SerialLink::Listener {
    int ups = 0, downs = 0;
    std::vector<uint8_t> bytes;
    std::string last_reason;
    void onLinkUp() override { ++ups; }
    void onLinkBytes(const uint8_t *b, size_t n, int64_t) override { bytes.insert(bytes.end(), b, b + n); }
    void onLinkDown(const std::string &reason) override
    {
        ++downs;
        last_reason = reason;
    }
};

// Runs the loop until done() (each iteration blocks in poll; 2000 iterations of at most 10 ms
// each are a deadlock guard, not a speed assumption).
template <typename Done> void runUntil(EventLoop &loop, Done done)
{
    for (int i = 0; i < 2000 && !done(); ++i) {
        loop.runOnce(10'000);
    }
    ASSERT_TRUE(done());
}
} // namespace

class SerialLinkTest : public ::testing::Test {
protected:
    cdro::test::TempDir dir;
    SystemClock clock;
    ServiceCounters counters;
    Listener listener;
    SerialConfig config;
    void SetUp() override
    {
        config.device = dir.file("ttyPOZYX");
        config.reconnect_min_s = 0.05;
        config.reconnect_max_s = 0.4;
    }
};

TEST_F(SerialLinkTest, OpensRawAndMovesBytesBothWays)
{
    cdro::test::FakeDevicePty device(config.device);
    EventLoop loop(clock);
    SerialLink link(loop, config, listener, counters);
    link.start();
    ASSERT_TRUE(link.isOpen());
    EXPECT_EQ(listener.ups, 1);
    // Bytes a cooked tty would mangle: CR, ^C, ^D, XOFF, DEL, 0x00.
    const std::vector<uint8_t> tricky = {0x0D, 0x03, 0x04, 0x13, 0x7F, 0x00, 0x0A, 0xFF};
    device.write(tricky);
    runUntil(loop, [&] { return listener.bytes.size() >= tricky.size(); });
    EXPECT_EQ(listener.bytes, tricky);
    const uint8_t out[] = {0x11, 0x0D, 0x00, 0x0A};
    ASSERT_TRUE(link.send(out, sizeof out));
    std::vector<uint8_t> got;
    for (int i = 0; i < 50 && got.size() < sizeof out; ++i) {
        const auto part = device.read(100);
        got.insert(got.end(), part.begin(), part.end());
    }
    EXPECT_EQ(got, std::vector<uint8_t>(out, out + sizeof out));
    EXPECT_EQ(counters.bytes_sent, sizeof out);
    EXPECT_EQ(link.description(), "serial:" + config.device + "@115200");
}

TEST_F(SerialLinkTest, BackoffDoublesWhileTheDeviceIsAbsentThenTheLinkComesBack)
{
    EventLoop loop(clock);
    SerialLink link(loop, config, listener, counters);
    link.start(); // nothing at the path yet
    EXPECT_FALSE(link.isOpen());
    EXPECT_EQ(counters.link_open_failures, 1U);
    // Let a few retries fail: the backoff grows 0.05 -> 0.1 -> 0.2 -> 0.4 (max).
    runUntil(loop, [&] { return counters.link_open_failures >= 5; });
    EXPECT_EQ(link.currentBackoffUs(), secondsToUs(config.reconnect_max_s));
    cdro::test::FakeDevicePty device(config.device);
    runUntil(loop, [&] { return link.isOpen(); });
    EXPECT_EQ(listener.ups, 1);
    EXPECT_EQ(counters.link_connects, 1U);
    device.write({1, 2, 3});
    runUntil(loop, [&] { return listener.bytes.size() >= 3; });
    // The device vanishes and a new one appears at the same path: the link follows it.
    device.vanish();
    runUntil(loop, [&] { return listener.downs > 0; });
    EXPECT_NE(listener.last_reason.find("hang-up"), std::string::npos) << listener.last_reason;
    cdro::test::FakeDevicePty again(config.device);
    runUntil(loop, [&] { return link.isOpen(); });
    EXPECT_EQ(listener.ups, 2);
    again.write({4, 5});
    runUntil(loop, [&] { return listener.bytes.size() >= 5; });
    EXPECT_EQ(listener.bytes, std::vector<uint8_t>({1, 2, 3, 4, 5}));
}

TEST_F(SerialLinkTest, UnsupportedBaudIsAConfigError)
{
    EventLoop loop(clock);
    config.baud = 12345;
    EXPECT_THROW(SerialLink(loop, config, listener, counters), ConfigError);
}

// A device that streams from the moment the port opens: what arrives while the port is being
// configured is kept. (LibSerial's SetFlowControl() discards the input; the configuration used
// it once, and firmware-in-the-loop runs then lost the first frame's bytes, seen as a COBS
// error and fewer bytes received than the UART sent.)
TEST(LibSerialConfiguration, BytesThatArriveWhileThePortIsConfiguredAreKept)
{
    int master = -1;
    int slave = -1;
    char name[256] = {};
    ASSERT_EQ(openpty(&master, &slave, name, nullptr, nullptr), 0);
    ::close(slave);
    LibSerial::SerialPort port;
    port.Open(name);
    const uint8_t sent[] = {0x00, 0x11, 0x13, 0x0d, 0x0a, 0x7f, 0x03, 0x1c, 0xff, 0x00};
    ASSERT_EQ(::write(master, sent, sizeof sent), static_cast<ssize_t>(sizeof sent));
    // The pty layer hands the bytes to the slave's queue asynchronously: wait until all are
    // there (a deadlock guard of 5 s, not a speed assumption).
    int queued = 0;
    for (int i = 0; i < 500 && queued < static_cast<int>(sizeof sent); ++i) {
        ASSERT_EQ(::ioctl(port.GetFileDescriptor(), FIONREAD, &queued), 0);
        if (queued < static_cast<int>(sizeof sent)) {
            ::usleep(10000);
        }
    }
    ASSERT_EQ(queued, static_cast<int>(sizeof sent));

    std::string error;
    const int fd = configureLibSerialPort(port, 115200, &error);
    ASSERT_GE(fd, 0) << error;

    std::vector<uint8_t> received(64);
    const ssize_t n = ::read(fd, received.data(), received.size());
    ASSERT_EQ(n, static_cast<ssize_t>(sizeof sent)) << "bytes discarded by the configuration";
    received.resize(static_cast<size_t>(n));
    EXPECT_EQ(received, std::vector<uint8_t>(std::begin(sent), std::end(sent)));
    termios tio{};
    ASSERT_EQ(tcgetattr(fd, &tio), 0);
    EXPECT_EQ(tio.c_iflag & (IXON | IXOFF | ICRNL | ISTRIP), 0U);
    EXPECT_EQ(tio.c_cflag & CRTSCTS, 0U);
    EXPECT_EQ(configureLibSerialPort(port, 12345, &error), -1);
    EXPECT_NE(error.find("unsupported baud 12345"), std::string::npos) << error;
    port.Close();
    ::close(master);
}

// ---- first errors that help ------------------------------------------------------------------

// A port the user may not open: the reason says what to do, not LibSerial's "Bad file
// descriptor". On a real pseudo-terminal whose node the user has no rights to (as root the test
// drops to nobody in a child process, since root may open anything).
TEST(SerialOpen, APortTheUserMayNotOpenSaysPermissionDeniedAndTheDialoutGroup)
{
    int master = -1;
    int slave = -1;
    char name[256] = {};
    ASSERT_EQ(openpty(&master, &slave, name, nullptr, nullptr), 0);
    ::close(slave);
    ASSERT_EQ(::chmod(name, 0600), 0); // the owner only (root, or the user then losing it below)
    const pid_t child = ::fork();
    ASSERT_GE(child, 0);
    if (child == 0) {
        if (::getuid() == 0) {
            if (::setgid(65534) != 0 || ::setuid(65534) != 0) { // nobody
                ::_exit(3);
            }
        } else if (::chmod(name, 0) != 0) {
            ::_exit(3);
        }
        std::string error;
        auto device = makeLibSerialDevice();
        const int fd = device->open(name, 115200, &error);
        ::_exit(fd < 0 && error.find("permission denied (add yourself to the dialout group") == 0 ? 0 : 1);
    }
    int status = 0;
    ASSERT_EQ(::waitpid(child, &status, 0), child);
    ASSERT_TRUE(WIFEXITED(status));
    EXPECT_EQ(WEXITSTATUS(status), 0) << "the child's open error did not name the dialout group";
    ::close(master);
    // And a path with nothing behind it says so.
    EXPECT_EQ(openFailureReason("/dev/cdro-no-such-port", "?").rfind("no such device", 0), 0U);
}

// The verdict on what a port streams, in its own time base: text from another sketch is named
// 2 s after its first byte (not before), once; our frames, even of another protocol version,
// never are (the intake says what is wrong with those).
TEST(LinkDiagnostics, BytesThatAreNotOurFramesAreNamedTwoSecondsAfterTheFirst)
{
    LinkDiagnostics d("/dev/ttyACM0", 115200);
    d.reset(0);
    const std::string text = "Pozyx ready_to_range: 4235 mm\r\n";
    d.onBytes(reinterpret_cast<const uint8_t *>(text.data()), text.size(), 100'000);
    EXPECT_FALSE(d.check(100'000 + LinkDiagnostics::kVerdictUs - 1));
    EXPECT_TRUE(d.check(100'000 + LinkDiagnostics::kVerdictUs));
    EXPECT_EQ(d.foreignMessage().rfind("bytes that are not our frames (wrong firmware or baud?)", 0), 0U);
    EXPECT_NE(d.foreignMessage().find("text \"Pozyx ready_to_range"), std::string::npos) << d.foreignMessage();
    EXPECT_NE(d.foreignMessage().find("115200"), std::string::npos);
    EXPECT_FALSE(d.check(10'000'000)) << "once per connection";

    d.reset(20'000'000);
    const std::vector<uint8_t> binary = {0x81, 0x9F, 0xE0, 0x13, 0x37, 0xFE, 0x42, 0x99, 0x10};
    d.onBytes(binary.data(), binary.size(), 20'000'000);
    EXPECT_TRUE(d.check(22'000'000));
    EXPECT_NE(d.foreignMessage().find("bytes 81 9F E0"), std::string::npos) << d.foreignMessage();

    for (const uint8_t version :
         {static_cast<uint8_t>(CDRO_PROTOCOL_VERSION), static_cast<uint8_t>(CDRO_PROTOCOL_VERSION + 1)}) {
        d.reset(30'000'000);
        std::vector<uint8_t> bytes = {0x13, 0x37, 0x00}; // garbage first, as after a reset
        cdro_frame_t hello = cdro::test::helloFrame(0, 250);
        std::vector<uint8_t> frame = cdro::test::encode(hello);
        if (version != CDRO_PROTOCOL_VERSION) {
            uint8_t raw[CDRO_MAX_RAW_FRAME];
            const long n = cdro_cobs_decode(frame.data(), frame.size() - 1, raw, sizeof raw);
            ASSERT_GT(n, 0);
            raw[0] = version;
            const uint16_t crc = cdro_crc16(raw, static_cast<size_t>(n) - 2);
            raw[n - 2] = static_cast<uint8_t>(crc & 0xFF);
            raw[n - 1] = static_cast<uint8_t>(crc >> 8);
            uint8_t wire[CDRO_MAX_ENCODED_FRAME];
            const size_t m = cdro_cobs_encode(raw, static_cast<size_t>(n), wire, sizeof wire);
            frame.assign(wire, wire + m);
            frame.push_back(0);
        }
        bytes.insert(bytes.end(), frame.begin(), frame.end());
        d.onBytes(bytes.data(), bytes.size(), 30'000'000);
        EXPECT_FALSE(d.check(40'000'000)) << "version " << int(version);
    }
    // A few stray bytes are line noise, not a stream.
    d.reset(50'000'000);
    d.onBytes(binary.data(), 3, 50'000'000);
    EXPECT_FALSE(d.check(60'000'000));
}

// End to end on a pseudo-terminal: the link names the foreign stream within 2 s of its first
// byte (the session would only time out its HELLO after 12 s).
TEST_F(SerialLinkTest, APortStreamingForeignBytesIsNamedWithinTwoSeconds)
{
    cdro::test::FakeDevicePty device(config.device);
    EventLoop loop(clock);
    SerialLink link(loop, config, listener, counters);
    link.start();
    ASSERT_TRUE(link.isOpen());
    const std::string text = "Hello from another sketch\r\n";
    device.write(std::vector<uint8_t>(text.begin(), text.end()));
    runUntil(loop, [&] { return link.diagnostics().sawFirstByte(); });
    const int64_t first_us = link.diagnostics().firstByteUs();
    runUntil(loop, [&] { return link.diagnostics().foreignReported(); });
    const int64_t said_us = clock.monotonicUs();
    EXPECT_GE(said_us - first_us, LinkDiagnostics::kVerdictUs);
    EXPECT_NE(link.diagnostics().foreignMessage().find("Hello from another sketch"), std::string::npos);
    EXPECT_TRUE(link.isOpen()) << "the port stays open: the right firmware may come (a reflash, a reset)";
}
