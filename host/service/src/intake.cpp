#include "cdro/service/intake.hpp"

#include <cstdio>

#include "cdro/capture.h"
#include "cdro/service/capture.hpp"

namespace cdro::service {

namespace {

// Device time may only go back this far without meaning a reset (ms). The firmware stamps
// frames from one millis() clock in sending order, so anything beyond jitter is a restart.
constexpr uint32_t kBackstepToleranceMs = 1000;
// A 32-bit millis() wraps after 49.7 days: a step from the last minute before the wrap to the
// first minute after it, with sequence numbers in order, is a wrap and not a reset (ms).
constexpr uint32_t kWrapWindowMs = 60000;

bool deviceTimeOf(const cdro_frame_t &f, uint32_t *time_ms)
{
    switch (f.type) {
    case CDRO_FRAME_HELLO: *time_ms = f.as.hello.device_time_ms; return true;
    case CDRO_FRAME_RANGE: *time_ms = f.as.range.device_time_ms; return true;
    case CDRO_FRAME_MOTION: *time_ms = f.as.motion.device_time_ms; return true;
    case CDRO_FRAME_STATUS: *time_ms = f.as.status.uptime_ms; return true;
    case CDRO_FRAME_ERROR: *time_ms = f.as.error.device_time_ms; return true;
    default: return false;
    }
}

std::string hex16(unsigned value)
{
    char text[8];
    std::snprintf(text, sizeof text, "0x%04X", value & 0xFFFFU);
    return text;
}

} // namespace

const char *deviceResetReasonName(DeviceResetReason reason)
{
    switch (reason) {
    case DeviceResetReason::TimeBackwards: return "device time went backwards";
    case DeviceResetReason::SequenceRestart: return "sequence numbers restarted";
    case DeviceResetReason::UnexpectedHello: return "unexpected HELLO";
    }
    return "reset";
}

std::string describeFrame(const cdro_frame_t &f)
{
    const char *name = cdro_frame_type_name(f.type);
    std::string text = (name != nullptr ? std::string(name) : "type " + hex16(f.type).substr(4)) + " seq " +
                       std::to_string(f.sequence);
    char detail[160] = "";
    switch (f.type) {
    case CDRO_FRAME_HELLO:
        std::snprintf(detail, sizeof detail, ": node %s, protocol %u, layout 0x%04X, firmware %u.%u",
                      hex16(f.as.hello.node_id).c_str(), f.as.hello.protocol_version, f.as.hello.layout_hash,
                      f.as.hello.firmware_version >> 8, f.as.hello.firmware_version & 0xFFU);
        break;
    case CDRO_FRAME_RANGE:
        std::snprintf(detail, sizeof detail, ": %s -> %s, distance_mm %lu, rss_dbm %d, device_time_ms %lu",
                      hex16(f.as.range.from_id).c_str(), hex16(f.as.range.to_id).c_str(),
                      static_cast<unsigned long>(f.as.range.distance_mm), f.as.range.rss_dbm,
                      static_cast<unsigned long>(f.as.range.device_time_ms));
        break;
    case CDRO_FRAME_MOTION:
        std::snprintf(detail, sizeof detail, ": node %s, moving %u, accel_norm_mg %u, reason %u",
                      hex16(f.as.motion.node_id).c_str(), f.as.motion.moving, f.as.motion.accel_norm_mg,
                      f.as.motion.reason);
        break;
    case CDRO_FRAME_STATUS:
        std::snprintf(detail, sizeof detail, ": running %u, node_count %u", f.as.status.running,
                      f.as.status.node_count);
        break;
    case CDRO_FRAME_NODE_LIST:
        std::snprintf(detail, sizeof detail, ": source %u, %u nodes", f.as.node_list.source,
                      f.as.node_list.node_ids_count);
        break;
    case CDRO_FRAME_NACK:
        std::snprintf(detail, sizeof detail, ": %s seq %u, reason %u",
                      cdro_frame_type_name(f.as.nack.nacked_type) ? cdro_frame_type_name(f.as.nack.nacked_type) : "?",
                      f.as.nack.nacked_sequence, f.as.nack.reason);
        break;
    case CDRO_FRAME_ERROR:
        std::snprintf(detail, sizeof detail, ": code %u, detail %u, node %s", f.as.error.code, f.as.error.detail,
                      hex16(f.as.error.node_id).c_str());
        break;
    default: break;
    }
    return text + detail;
}

FrameIntake::FrameIntake(const NodesConfig &nodes, double drop_log_per_s, ServiceCounters &counters, const Clock &clock)
    : counters_(counters), clock_(clock), policy_(nodes.unknown), drop_log_(drop_log_per_s),
      known_nodes_(nodes.ids.begin(), nodes.ids.end()), node_list_known_(!nodes.ids.empty())
{
    cdro_decoder_init(&decoder_);
    chunk_.reserve(CDRO_CAPTURE_MAX_DATA);
}

void FrameIntake::noteSentFrame(uint8_t type)
{
    // A bound, so that requests a device never answered (it was unplugged) cannot hide an
    // unexpected HELLO for ever; more than this are never outstanding in a working session.
    constexpr uint32_t kMaxOutstandingHelloRequests = 64;
    if (type == CDRO_FRAME_HELLO_REQUEST && hello_requests_outstanding_ < kMaxOutstandingHelloRequests) {
        ++hello_requests_outstanding_;
    }
}

void FrameIntake::pushHostEvent(const uint8_t *data, size_t len, int64_t host_unix_us)
{
    last_event_unix_us_ = host_unix_us;
    if (consumer_ != nullptr) {
        consumer_->onHostEvent(data, len, FrameContext{host_unix_us, 0});
    }
}

void FrameIntake::push(const uint8_t *bytes, size_t len, int64_t host_unix_us)
{
    last_event_unix_us_ = host_unix_us;
    byte_rate_.add(host_unix_us, len);
    for (size_t i = 0; i < len; ++i) {
        const uint8_t byte = bytes[i];
        if (byte != 0x00U) {
            if (chunk_.size() < CDRO_CAPTURE_MAX_DATA) {
                chunk_.push_back(byte);
            }
            ++chunk_len_;
            cdro_frame_t ignored;
            cdro_decoder_push(&decoder_, byte, &ignored); // always CDRO_PENDING for a non-zero byte
            continue;
        }
        endChunk(host_unix_us);
    }
}

void FrameIntake::endOfStream(int64_t host_unix_us)
{
    if (chunk_len_ > 0) {
        endChunk(host_unix_us);
    }
}

void FrameIntake::endChunk(int64_t host_unix_us)
{
    if (chunk_len_ > 0 && capture_ != nullptr) {
        const uint8_t flags = chunk_len_ > chunk_.size() ? CDRO_CAPTURE_FLAG_TRUNCATED : 0;
        capture_->append(flags, host_unix_us, chunk_.data(), chunk_.size());
    }
    const size_t chunk_len = chunk_len_;
    chunk_.clear();
    chunk_len_ = 0;
    cdro_frame_t frame;
    const cdro_result_t result = cdro_decoder_push(&decoder_, 0x00U, &frame);
    if (result == CDRO_PENDING) {
        return; // an empty chunk: repeated delimiters carry nothing
    }
    if (result == CDRO_OK) {
        ++counters_.frames_ok;
        frame_rate_.add(host_unix_us, 1);
        onAccepted(frame, host_unix_us);
    } else {
        onRejected(result, frame, chunk_len, host_unix_us);
    }
}

template <typename Message> void FrameIntake::logDrop(const char *key, Message message)
{
    uint64_t suppressed = 0;
    if (drop_log_.allow(key, clock_.monotonicUs(), &suppressed)) {
        if (suppressed > 0) {
            log()->warn("intake: dropped {} ({} more like it not logged)", message(), suppressed);
        } else {
            log()->warn("intake: dropped {}", message());
        }
    }
}

void FrameIntake::onRejected(cdro_result_t result, const cdro_frame_t &partial, size_t chunk_len, int64_t host_unix_us)
{
    ++counters_.chunks_rejected;
    counters_.bytes_discarded += chunk_len;
    reject_rate_.add(host_unix_us, 1);
    switch (result) {
    case CDRO_ERR_COBS: ++counters_.cobs_errors; break;
    case CDRO_ERR_SHORT: ++counters_.short_errors; break;
    case CDRO_ERR_CRC: ++counters_.crc_errors; break;
    case CDRO_ERR_VERSION: ++counters_.version_errors; break;
    case CDRO_ERR_TYPE: ++counters_.type_errors; break;
    case CDRO_ERR_LENGTH: ++counters_.length_errors; break;
    case CDRO_ERR_VALUE: ++counters_.value_errors; break;
    case CDRO_ERR_TOO_LONG: ++counters_.too_long_errors; break;
    case CDRO_PENDING:
    case CDRO_OK:
    case CDRO_ERR_ARGUMENT:
    default: break;
    }
    const std::string reason = cdro_result_name(result);
    switch (result) {
    case CDRO_ERR_VALUE:
        logDrop("value", [&] { return describeFrame(partial) + " (a field is out of its documented range)"; });
        break;
    case CDRO_ERR_VERSION:
        logDrop("version", [&] {
            return "a " + std::to_string(chunk_len) + "-byte chunk of protocol version " +
                   std::to_string(partial.version) + " (this host speaks " + std::to_string(CDRO_PROTOCOL_VERSION) +
                   ")";
        });
        // One such frame is a corruption the CRC missed; a firmware of another build sends
        // nothing else, so only a run of them, with no good frame between, means that.
        if (++version_errors_in_a_row_ == kVersionErrorsForIncompatible) {
            markIncompatible("the device sends protocol version " + std::to_string(partial.version) + " frames (" +
                             std::to_string(version_errors_in_a_row_) +
                             " in a row); this host speaks protocol version " + std::to_string(CDRO_PROTOCOL_VERSION) +
                             " (layout hash " + hex16(CDRO_LAYOUT_HASH) + ")");
        }
        break;
    case CDRO_ERR_TYPE:
        logDrop("type", [&] {
            return "a frame of unknown type " + hex16(partial.type) + ", seq " + std::to_string(partial.sequence);
        });
        break;
    case CDRO_ERR_LENGTH:
        logDrop("length", [&] { return describeFrame(partial) + ": length does not match its layout"; });
        break;
    default:
        logDrop(reason.c_str(), [&] {
            return "a " + std::to_string(chunk_len) + "-byte chunk: " + reason +
                   (result == CDRO_ERR_CRC ? " (corrupted in transit)" : "");
        });
        break;
    }
}

bool FrameIntake::checkSequenceAndReset(const cdro_frame_t &f, int64_t host_unix_us)
{
    uint32_t time_ms = 0;
    const bool has_time = deviceTimeOf(f, &time_ms);
    const bool is_hello = f.type == CDRO_FRAME_HELLO;
    const bool hello_was_requested = hello_requests_outstanding_ > 0;
    if (is_hello && hello_requests_outstanding_ > 0) {
        --hello_requests_outstanding_;
    }

    bool reset = false;
    DeviceResetReason reason = DeviceResetReason::SequenceRestart;
    uint16_t step = 1;
    if (have_sequence_) {
        step = static_cast<uint16_t>(f.sequence - last_sequence_);
        if (is_hello && f.sequence == 0 && step != 1) {
            reset = true; // the boot HELLO always carries sequence 0
        } else if (step > 0x8000U) {
            reset = true; // sequence numbers only move forward on one boot
        }
    }
    if (!reset && has_time && have_device_time_ && time_ms + kBackstepToleranceMs < last_device_time_ms_) {
        const bool wrapped = last_device_time_ms_ > UINT32_MAX - kWrapWindowMs && time_ms < kWrapWindowMs &&
                             step >= 1 && step <= 0x8000U;
        if (!wrapped) {
            reset = true;
            reason = DeviceResetReason::TimeBackwards;
        }
    }
    if (!reset && is_hello && !hello_was_requested && accepted_frames_ > 0) {
        reset = true;
        reason = DeviceResetReason::UnexpectedHello;
    }

    if (reset) {
        ++counters_.device_resets;
        log()->warn("intake: device reset detected ({}): {}", deviceResetReasonName(reason), describeFrame(f));
        const FrameContext context{host_unix_us, f.sequence};
        if (consumer_ != nullptr) {
            consumer_->onDeviceReset(reason, context);
        }
        if (observer_ != nullptr) {
            observer_->onDeviceReset(reason, host_unix_us);
        }
    } else if (have_sequence_) {
        if (step == 0) {
            ++counters_.duplicate_frames;
            logDrop("duplicate", [&] { return describeFrame(f) + ": duplicate sequence number"; });
            return false;
        }
        if (step > 1) {
            ++counters_.sequence_gaps;
            counters_.frames_lost += static_cast<uint64_t>(step - 1U);
        }
    }
    have_sequence_ = true;
    last_sequence_ = f.sequence;
    if (has_time) {
        have_device_time_ = true;
        last_device_time_ms_ = time_ms;
    }
    return true;
}

bool FrameIntake::nodeKnown(uint16_t id, std::string *why)
{
    if (known_nodes_.count(id) != 0) {
        return true;
    }
    if (policy_ == UnknownNodePolicy::Reject) {
        *why = "unknown node id " + hex16(id) + " (nodes.unknown: reject)";
        return false;
    }
    if (node_list_known_) {
        // The device ranges the nodes of its list and no other: an id outside it is a
        // corruption that passed the CRC, however often it comes.
        *why = "node id " + hex16(id) + " is not in the device's node list";
        return false;
    }
    // No list yet (a host that started against a running device, before its NODE_LIST): a
    // real node keeps coming back, a corrupted id is another random one each time.
    const uint32_t seen = ++candidates_[id];
    if (seen < kFramesToConfirmNode) {
        *why = "node id " + hex16(id) + " not confirmed yet (seen in " + std::to_string(seen) + " of " +
               std::to_string(kFramesToConfirmNode) + " frames, and no node list from the device)";
        return false;
    }
    candidates_.erase(id);
    known_nodes_.insert(id);
    ++counters_.nodes_learned;
    log()->info("intake: learned node {} (seen in {} frames; the device has not listed its nodes yet)", hex16(id),
                kFramesToConfirmNode);
    return true;
}

bool FrameIntake::checkNodes(const cdro_frame_t &f)
{
    uint16_t ids[2] = {0, 0};
    switch (f.type) {
    case CDRO_FRAME_RANGE:
        ids[0] = f.as.range.from_id;
        ids[1] = f.as.range.to_id;
        break;
    case CDRO_FRAME_MOTION: ids[0] = f.as.motion.node_id; break;
    case CDRO_FRAME_ERROR: ids[0] = f.as.error.node_id; break; // 0 = the device itself
    default: return true;
    }
    const bool unknown =
        (ids[0] != 0 && known_nodes_.count(ids[0]) == 0) || (ids[1] != 0 && known_nodes_.count(ids[1]) == 0);
    if (!unknown) {
        return true;
    }
    ++counters_.unknown_node_frames;
    std::string why;
    bool ok = true;
    for (const uint16_t id : ids) {
        if (id != 0 && ok) {
            ok = nodeKnown(id, &why);
        }
    }
    if (!ok) {
        ++counters_.frames_rejected_unknown_node;
        logDrop("unknown_node", [&] { return describeFrame(f) + ": " + why; });
    }
    return ok;
}

void FrameIntake::markIncompatible(const std::string &message)
{
    if (incompatible_ && message == incompatible_message_) {
        return;
    }
    incompatible_ = true;
    incompatible_message_ = message;
    ++counters_.incompatible_devices;
    log()->error("intake: incompatible device: {}. Not talking to it until a compatible HELLO arrives; "
                 "the service keeps running.",
                 message);
    if (observer_ != nullptr) {
        observer_->onIncompatible(message);
    }
}

void FrameIntake::checkHello(const cdro_hello_t &hello)
{
    device_node_id_ = hello.node_id;
    device_firmware_ = hello.firmware_version;
    if (hello.protocol_version != CDRO_PROTOCOL_VERSION || hello.layout_hash != CDRO_LAYOUT_HASH) {
        markIncompatible("device firmware speaks protocol version " + std::to_string(hello.protocol_version) +
                         " with layout hash " + hex16(hello.layout_hash) + "; this host speaks protocol version " +
                         std::to_string(CDRO_PROTOCOL_VERSION) + " with layout hash " + hex16(CDRO_LAYOUT_HASH));
        return;
    }
    if (incompatible_) {
        log()->info("intake: the device is compatible again (protocol version {}, layout hash {})",
                    hello.protocol_version, hex16(hello.layout_hash));
    }
    incompatible_ = false;
    incompatible_message_.clear();
    known_nodes_.insert(hello.node_id);
}

void FrameIntake::onAccepted(const cdro_frame_t &f, int64_t host_unix_us)
{
    version_errors_in_a_row_ = 0;
    if (f.type >= 0x40U) {
        ++counters_.unexpected_frames;
        logDrop("unexpected", [&] { return describeFrame(f) + ": a host-to-device frame type from the device"; });
        return;
    }
    if (!checkSequenceAndReset(f, host_unix_us)) {
        return;
    }
    ++accepted_frames_;
    if (f.type == CDRO_FRAME_HELLO) {
        checkHello(f.as.hello);
    } else if (f.type == CDRO_FRAME_NODE_LIST && !incompatible_) {
        for (uint8_t i = 0; i < f.as.node_list.node_ids_count; ++i) {
            known_nodes_.insert(f.as.node_list.node_ids[i]);
        }
        node_list_known_ = true;
        candidates_.clear();
    }
    if (observer_ != nullptr) {
        observer_->onDeviceFrame(f, host_unix_us);
    }
    if (f.type == CDRO_FRAME_ACK || f.type == CDRO_FRAME_NACK) {
        return; // the session's business only
    }
    if (incompatible_) {
        if (f.type != CDRO_FRAME_HELLO) {
            ++counters_.frames_dropped_incompatible;
            logDrop("incompatible", [&] { return describeFrame(f) + ": the device is incompatible"; });
        }
        return;
    }
    if (!checkNodes(f)) {
        return;
    }
    if (consumer_ == nullptr) {
        return;
    }
    const FrameContext context{host_unix_us, f.sequence};
    ++counters_.frames_delivered;
    switch (f.type) {
    case CDRO_FRAME_HELLO: consumer_->onHello(f.as.hello, context); break;
    case CDRO_FRAME_RANGE:
        range_rate_.add(host_unix_us, 1);
        consumer_->onRange(f.as.range, context);
        break;
    case CDRO_FRAME_MOTION: consumer_->onMotion(f.as.motion, context); break;
    case CDRO_FRAME_STATUS: consumer_->onStatus(f.as.status, context); break;
    case CDRO_FRAME_NODE_LIST: consumer_->onNodeList(f.as.node_list, context); break;
    case CDRO_FRAME_ERROR: consumer_->onDeviceError(f.as.error, context); break;
    default: --counters_.frames_delivered; break;
    }
}

Rates FrameIntake::rates(int64_t now_unix_us) const
{
    Rates r;
    r.frames_per_s = frame_rate_.ratePerS(now_unix_us);
    r.ranges_per_s = range_rate_.ratePerS(now_unix_us);
    r.rejects_per_s = reject_rate_.ratePerS(now_unix_us);
    r.bytes_per_s = byte_rate_.ratePerS(now_unix_us);
    return r;
}

} // namespace cdro::service
