#include "cdro/service/link_diagnostics.hpp"

#include <cctype>
#include <cstdio>

#include "cdro/service/log.hpp"

namespace cdro::service {

namespace {

std::string hex16(uint16_t v)
{
    char text[8];
    std::snprintf(text, sizeof text, "0x%04X", v);
    return text;
}

// UWB_RATES bits 5..0, UWB_PLEN codes (docs/protocol.md, SET_UWB).
std::string uwbText(uint8_t channel, uint8_t rates, uint8_t plen, uint8_t gain_half_db, uint8_t protocol)
{
    static const char *const kBitrates[] = {"110 kbit/s", "850 kbit/s", "6.8 Mbit/s"};
    const uint8_t bitrate = rates & 0x3FU;
    const uint8_t prf = rates >> 6;
    int preamble = 0;
    switch (plen) {
    case 0x04: preamble = 64; break;
    case 0x14: preamble = 128; break;
    case 0x24: preamble = 256; break;
    case 0x34: preamble = 512; break;
    case 0x08: preamble = 1024; break;
    case 0x18: preamble = 1536; break;
    case 0x28: preamble = 2048; break;
    case 0x0C: preamble = 4096; break;
    default: break;
    }
    char text[160];
    std::snprintf(text, sizeof text, "channel %u, %s, PRF %s, preamble %s, gain %.1f dB, %s", channel,
                  bitrate < 3 ? kBitrates[bitrate] : "bitrate ?",
                  prf == 1   ? "16 MHz"
                  : prf == 2 ? "64 MHz"
                             : "?",
                  preamble != 0 ? std::to_string(preamble).c_str() : "?", gain_half_db / 2.0,
                  protocol == 0   ? "precision"
                  : protocol == 1 ? "fast"
                                  : "protocol ?");
    return text;
}

std::string mismatchText(uint8_t mismatch)
{
    static const char *const kNames[] = {"channel",          "bitrate/PRF",
                                         "preamble",         "gain",
                                         "ranging protocol", "Pozyx firmware (one the CDRO firmware cannot drive)"};
    std::string out;
    for (unsigned i = 0; i < 6; ++i) {
        if ((mismatch & (1U << i)) != 0U) {
            out += (out.empty() ? "" : ", ") + std::string(kNames[i]);
        }
    }
    return out;
}

} // namespace

std::string pozyxFirmwareText(uint8_t version)
{
    return std::to_string(version >> 4) + "." + std::to_string(version & 0x0FU);
}

void LinkDiagnostics::reset(int64_t now_us)
{
    cdro_decoder_init(&decoder_);
    bytes_ = 0;
    first_byte_us_ = now_us;
    head_len_ = 0;
    foreign_reported_ = false;
    foreign_message_.clear();
}

void LinkDiagnostics::onBytes(const uint8_t *bytes, size_t len, int64_t now_us)
{
    if (len > 0 && bytes_ == 0) {
        first_byte_us_ = now_us;
    }
    for (size_t i = 0; i < len; ++i) {
        if (head_len_ < sizeof head_) {
            head_[head_len_++] = bytes[i];
        }
        cdro_frame_t frame;
        if (cdro_decoder_push(&decoder_, bytes[i], &frame) == CDRO_OK) {
            onFrame(frame);
        }
    }
    bytes_ += len;
}

bool LinkDiagnostics::check(int64_t now_us)
{
    const cdro_decoder_counters_t &c = decoder_.counters;
    // A chunk with a good CRC is ours, whatever its version or type (the intake says the rest).
    const uint32_t ours = c.frames_ok + c.version_errors + c.type_errors + c.length_errors + c.value_errors;
    if (foreign_reported_ || bytes_ < kMinForeignBytes || ours > 0 || now_us - first_byte_us_ < kVerdictUs) {
        return false;
    }
    size_t printable = 0;
    for (size_t i = 0; i < head_len_; ++i) {
        printable += (std::isprint(head_[i]) != 0 || head_[i] == '\r' || head_[i] == '\n') ? 1U : 0U;
    }
    std::string look;
    if (printable * 10 >= head_len_ * 9) {
        look = "text \"";
        for (size_t i = 0; i < head_len_; ++i) {
            look += head_[i] == '\r'   ? std::string("\\r")
                    : head_[i] == '\n' ? std::string("\\n")
                                       : std::string(1, static_cast<char>(head_[i]));
        }
        look += "\"";
    } else {
        look = "bytes";
        char byte[4];
        for (size_t i = 0; i < head_len_; ++i) {
            std::snprintf(byte, sizeof byte, " %02X", head_[i]);
            look += byte;
        }
    }
    char seconds[16];
    std::snprintf(seconds, sizeof seconds, "%.1f", static_cast<double>(now_us - first_byte_us_) / 1e6);
    foreign_message_ = "bytes that are not our frames (wrong firmware or baud?): " + device_ + " sent " +
                       std::to_string(bytes_) + " bytes in " + seconds + " s and not one CDRO frame; they begin with " +
                       look + ". The CDRO firmware sends binary frames at " + std::to_string(baud_) +
                       " bit/s (serial.baud): flash it (README, \"Hardware quickstart\") or check the port";
    foreign_reported_ = true;
    log()->error("serial: {}", foreign_message_);
    return true;
}

void LinkDiagnostics::onFrame(const cdro_frame_t &frame)
{
    switch (frame.type) {
    case CDRO_FRAME_HELLO: {
        const cdro_hello_t &h = frame.as.hello;
        if (h.node_id == 0xFFFFU) {
            log()->warn("serial: the device says HELLO without a Pozyx (CDRO firmware {}.{}); it keeps trying",
                        h.firmware_version >> 8, h.firmware_version & 0xFFU);
            return;
        }
        log()->info("serial: the device says HELLO: CDRO firmware {}.{}, node {}, Pozyx firmware {}{}",
                    h.firmware_version >> 8, h.firmware_version & 0xFFU, hex16(h.node_id),
                    pozyxFirmwareText(h.pozyx_firmware),
                    h.pozyx_tries > 1 ? ", found at try " + std::to_string(h.pozyx_tries) : std::string());
        return;
    }
    case CDRO_FRAME_ERROR: {
        const cdro_error_t &e = frame.as.error;
        if (e.code == CDRO_DEVICE_ERROR_POZYX_ABSENT) {
            log()->warn("serial: no Pozyx answers on the shield's I2C (WHO_AM_I read: 0x{:02X}); check the shield "
                        "and its power; the firmware tries again",
                        e.detail);
        } else if (e.code == CDRO_DEVICE_ERROR_POZYX_FIRMWARE) {
            log()->error("serial: the Pozyx runs firmware {}, which the CDRO firmware cannot drive (1.0 to 1.2): "
                         "it will not range; flash a supported Pozyx firmware",
                         pozyxFirmwareText(static_cast<uint8_t>(e.detail)));
        } else if (e.code == CDRO_DEVICE_ERROR_SELF_TEST) {
            log()->error("serial: the Pozyx failed its self-test (ST_RESULT 0x{:02X}); it will not range", e.detail);
        } else if (e.code == CDRO_DEVICE_ERROR_DEVICE_LIST) {
            log()->warn("serial: the Pozyx lists {} devices but ignored the offset of the list's second page: the "
                        "nodes past the first 15 are unknown; list them in nodes.ids (SET_NODES)",
                        e.detail);
        }
        return;
    }
    case CDRO_FRAME_NODE_INFO: {
        const cdro_node_info_t &n = frame.as.node_info;
        if (n.result == CDRO_NODE_INFO_NO_ANSWER) {
            log()->warn("serial: node {} does not answer (out of reach, off, or on other UWB settings)",
                        hex16(n.node_id));
            return;
        }
        const std::string settings = uwbText(n.uwb_channel, n.uwb_rates, n.uwb_plen, n.uwb_gain, n.range_protocol);
        if (n.mismatch != 0U) {
            log()->warn("serial: node {} (Pozyx firmware {}: {}) differs from the device's own node in: {}",
                        hex16(n.node_id), pozyxFirmwareText(n.pozyx_firmware), settings, mismatchText(n.mismatch));
        } else {
            log()->info("serial: node {}: Pozyx firmware {}, {}", hex16(n.node_id), pozyxFirmwareText(n.pozyx_firmware),
                        settings);
        }
        return;
    }
    default: return;
    }
}

} // namespace cdro::service
