// intake.hpp: bytes in, validated frames out. Every byte goes through cdro_decoder_push (with
// resynchronisation); every chunk that ends is appended to the capture; every rejection is
// counted by reason and logged (rate-limited) with what was dropped and why; accepted frames
// then pass the sequence checks (duplicates, gaps, resets) and the node-id policy before the
// FrameConsumer sees them.
//
// Everything here is driven by the bytes and the event time passed in, never by a clock, so
// that a live run and the replay of its capture give the consumer identical calls. The only
// other input is noteSentFrame(): the frames the host sent (from the session live, from the
// to-device records on replay), so that a HELLO answering a HELLO_REQUEST is not taken for
// a reset (every request sent and not yet answered makes one HELLO expected: on a slow link
// the answers to two requests arrive one after the other).
//
// What one corrupted frame that passed the CRC can do is bounded: a frame of another protocol
// version is dropped and counted, and only kVersionErrorsForIncompatible of them in a row make
// the device incompatible (a HELLO naming another version or layout does at once: it is the
// handshake); an unknown node id becomes a node only with evidence (docs/service.md, "Node ids").
//
// Threading: loop thread only.
#pragma once

#include <cstdint>
#include <map>
#include <set>
#include <string>
#include <vector>

#include "cdro/frames.h"
#include "cdro/service/clock.hpp"
#include "cdro/service/config.hpp"
#include "cdro/service/consumer.hpp"
#include "cdro/service/counters.hpp"
#include "cdro/service/log.hpp"

namespace cdro::service {

class CaptureWriter;

// The session's view of the stream (it drives the handshake from these).
class IntakeObserver {
public:
    virtual ~IntakeObserver() = default;
    // Every accepted device frame, including ACK, NACK and HELLO.
    virtual void onDeviceFrame(const cdro_frame_t &frame, int64_t host_unix_us) = 0;
    virtual void onDeviceReset(DeviceResetReason reason, int64_t host_unix_us) = 0;
    // The device speaks another protocol version or layout; message names both.
    virtual void onIncompatible(const std::string &message) = 0;
};

class FrameIntake {
public:
    // Frames of another protocol version in a row (no good frame between them) that make the
    // device incompatible. One such frame is a corruption that happened to pass the CRC (it is
    // counted and dropped); a firmware of another build sends nothing else.
    static constexpr uint32_t kVersionErrorsForIncompatible = 4;
    // Frames naming an id that make it a node under policy learn while the device's node list
    // is not known yet (no nodes.ids, no NODE_LIST). A corrupted id that passed the CRC is
    // another random id each time; a real node keeps coming back.
    static constexpr uint32_t kFramesToConfirmNode = 3;

    // clock: only for rate-limiting log lines (never for anything a consumer sees).
    FrameIntake(const NodesConfig &nodes, double drop_log_per_s, ServiceCounters &counters, const Clock &clock);

    void setConsumer(FrameConsumer *consumer) { consumer_ = consumer; }
    void setObserver(IntakeObserver *observer) { observer_ = observer; }
    void setCapture(CaptureWriter *capture) { capture_ = capture; }

    // A host event recorded in a capture (consumer.hpp, onHostEvent), on --replay.
    void pushHostEvent(const uint8_t *data, size_t len, int64_t host_unix_us);
    // Received bytes, all with the same event time.
    void push(const uint8_t *bytes, size_t len, int64_t host_unix_us);
    // The byte source ended (device vanished): a partial chunk is ended as if a delimiter had
    // come, so it is captured and counted like any cut frame, and replays the same way.
    void endOfStream(int64_t host_unix_us);
    // A frame the host sent to the device (its type), in stream order.
    void noteSentFrame(uint8_t type);

    bool incompatible() const { return incompatible_; }
    const std::string &incompatibleMessage() const { return incompatible_message_; }
    const std::set<uint16_t> &knownNodes() const { return known_nodes_; }
    // Nodes known from elsewhere: those of the map a run resumes from (they were accepted when
    // it was built), so that `nodes.unknown: reject` does not drop them before the device lists
    // them again.
    void addKnownNodes(const std::vector<uint16_t> &ids) { known_nodes_.insert(ids.begin(), ids.end()); }
    uint16_t deviceNodeId() const { return device_node_id_; }
    uint16_t deviceFirmware() const { return device_firmware_; }
    int64_t lastEventUnixUs() const { return last_event_unix_us_; }
    Rates rates(int64_t now_unix_us) const;

    // Frames delivered to the consumer since the last call (the service publishes outputs
    // after each one; see Service).
    uint64_t deliveredCount() const { return counters_.frames_delivered; }

private:
    void endChunk(int64_t host_unix_us);
    void onRejected(cdro_result_t result, const cdro_frame_t &partial, size_t chunk_len, int64_t host_unix_us);
    void onAccepted(const cdro_frame_t &frame, int64_t host_unix_us);
    bool checkSequenceAndReset(const cdro_frame_t &frame, int64_t host_unix_us);
    bool checkNodes(const cdro_frame_t &frame);
    bool nodeKnown(uint16_t id, std::string *why); // false: *why says why it is not
    void checkHello(const cdro_hello_t &hello);
    void markIncompatible(const std::string &message);
    // Logs a dropped frame unless the rate limit holds it back; message() is only built when
    // it is logged, so that a flood of garbage costs no formatting.
    template <typename Message> void logDrop(const char *key, Message message);

    ServiceCounters &counters_;
    const Clock &clock_;
    FrameConsumer *consumer_ = nullptr;
    IntakeObserver *observer_ = nullptr;
    CaptureWriter *capture_ = nullptr;
    UnknownNodePolicy policy_;
    RateLimiter drop_log_;

    cdro_decoder_t decoder_{};
    std::vector<uint8_t> chunk_; // the current chunk for the capture (up to its max data)
    size_t chunk_len_ = 0;       // its full length in bytes

    bool have_sequence_ = false;
    uint16_t last_sequence_ = 0;
    bool have_device_time_ = false;
    uint32_t last_device_time_ms_ = 0;
    uint32_t hello_requests_outstanding_ = 0; // HELLO_REQUESTs sent and not answered yet
    uint32_t version_errors_in_a_row_ = 0;    // since the last good frame
    uint64_t accepted_frames_ = 0;
    bool incompatible_ = false;
    std::string incompatible_message_;
    std::set<uint16_t> known_nodes_;
    // True once the device's node list is known (nodes.ids, or a NODE_LIST): then an id
    // outside the known set is rejected under either policy.
    bool node_list_known_ = false;
    std::map<uint16_t, uint32_t> candidates_; // policy learn, list unknown: id -> frames seen
    uint16_t device_node_id_ = 0;
    uint16_t device_firmware_ = 0;
    int64_t last_event_unix_us_ = 0;

    RateMeter frame_rate_;
    RateMeter range_rate_;
    RateMeter reject_rate_;
    RateMeter byte_rate_;
};

// "RANGE seq 12: 0x6069 -> 0x6A11 4235 mm" and the like, for logs.
std::string describeFrame(const cdro_frame_t &frame);

} // namespace cdro::service
