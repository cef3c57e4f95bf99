// link_diagnostics.hpp: what the serial link's bytes tell a person setting up a board, before
// and besides the session (which needs a compatible HELLO to say anything):
//   - bytes that are not CDRO frames, within kVerdictUs of the first one: the port streams
//     something else (another sketch, the Pozyx's USB port, a wrong baud rate), said once per
//     connection with what the bytes look like;
//   - the device's HELLO (CDRO and Pozyx firmware, how many tries it took to find the Pozyx);
//   - the Pozyx set-up reports of the firmware: no Pozyx (each try), a Pozyx firmware it cannot
//     drive, a device list it could not read past its first page, and every node's UWB settings
//     (NODE_INFO), with what differs between nodes.
// It decodes the bytes itself (a cdro_decoder_t of its own): the session and the intake are
// not involved. Threading: loop thread only.
#pragma once

#include <cstdint>
#include <string>

#include "cdro/frames.h"

namespace cdro::service {

class LinkDiagnostics {
public:
    static constexpr int64_t kVerdictUs = 2'000'000; // us after the first byte
    static constexpr uint64_t kMinForeignBytes = 8;  // fewer is line noise, not a stream

    LinkDiagnostics(std::string device, uint32_t baud) : device_(std::move(device)), baud_(baud) { reset(0); }

    // A new connection at monotonic time now_us.
    void reset(int64_t now_us);
    // Bytes as they came, at monotonic time now_us; logs what the frames among them say.
    void onBytes(const uint8_t *bytes, size_t len, int64_t now_us);
    // The "not our frames" verdict, due kVerdictUs after the first byte (call it then, or any
    // time after): logs once per connection. True if it said so now.
    bool check(int64_t now_us);

    bool sawFirstByte() const { return bytes_ > 0; }
    int64_t firstByteUs() const { return first_byte_us_; }
    bool foreignReported() const { return foreign_reported_; }
    const std::string &foreignMessage() const { return foreign_message_; }

private:
    void onFrame(const cdro_frame_t &frame);

    std::string device_;
    uint32_t baud_;
    cdro_decoder_t decoder_{};
    uint64_t bytes_ = 0;
    int64_t first_byte_us_ = 0;
    uint8_t head_[40] = {}; // the first bytes of the connection, for the message
    size_t head_len_ = 0;
    bool foreign_reported_ = false;
    std::string foreign_message_;
};

// "1.1" from a Pozyx FIRMWARE_VER byte (major << 4 | minor).
std::string pozyxFirmwareText(uint8_t version);

} // namespace cdro::service
