// counters.hpp: every counter the service keeps, defined once (name and meaning) so that the
// health JSON, the live map and docs/service.md use the same names.
//
// Threading: ServiceCounters is a plain value. The event loop thread owns the live instance;
// other threads only ever see copies inside a published MapState.
#pragma once

#include <cstdint>

#include <nlohmann/json_fwd.hpp>

namespace cdro::service {

// X(name, "meaning"): all are counts since the service started (bytes where the name says so).
#define CDRO_SERVICE_COUNTERS(X)                                                                                   \
    X(bytes_received, "bytes read from the device (or fed from a capture)")                                        \
    X(frames_ok, "chunks that decoded and validated: good frames")                                                 \
    X(chunks_rejected, "chunks rejected by the decoder (resyncs): the sum of the *_errors below")                  \
    X(cobs_errors, "rejected: invalid COBS")                                                                       \
    X(short_errors, "rejected: fewer bytes than a header and a CRC")                                               \
    X(crc_errors, "rejected: CRC mismatch")                                                                        \
    X(version_errors, "rejected: another protocol version")                                                        \
    X(type_errors, "rejected: unknown frame type")                                                                 \
    X(length_errors, "rejected: length field or payload size wrong")                                               \
    X(value_errors, "rejected: a field out of its documented range (never reaches the consumer)")                  \
    X(too_long_errors, "rejected: no delimiter within the longest frame")                                          \
    X(bytes_discarded, "bytes of rejected chunks")                                                                 \
    X(frames_delivered, "validated device frames handed to the consumer")                                          \
    X(unexpected_frames, "host-to-device frame types received from the device (dropped)")                          \
    X(duplicate_frames, "frames whose sequence number repeats the previous one (dropped)")                         \
    X(sequence_gaps, "places where sequence numbers jumped forward")                                               \
    X(frames_lost, "device frames missing in those gaps")                                                          \
    X(device_resets, "device resets detected (time backwards, sequence restart, unexpected HELLO)")                \
    X(unknown_node_frames, "frames naming a node id that was not known")                                           \
    X(nodes_learned, "unknown node ids that became nodes (policy learn, seen often enough)")                       \
    X(frames_rejected_unknown_node, "frames dropped for a node id not known or not confirmed")                     \
    X(frames_dropped_incompatible, "data frames dropped while the device is incompatible")                         \
    X(handshakes, "handshakes completed (HELLO checked, configured, START acknowledged)")                          \
    X(hello_requests, "HELLO_REQUEST frames sent")                                                                 \
    X(commands_sent, "host frames sent (every command, including retries and PINGs)")                              \
    X(command_timeouts, "commands that got no ACK/NACK in time")                                                   \
    X(nacks, "commands the device NACKed")                                                                         \
    X(pings_missed, "keepalive PINGs that got no ACK in time")                                                     \
    X(incompatible_devices, "HELLOs from a device with another protocol version or layout")                        \
    X(link_connects, "serial port opened")                                                                         \
    X(link_disconnects, "serial device vanished or failed (EIO, hang-up, read error)")                             \
    X(link_open_failures, "attempts to open the serial port that failed")                                          \
    X(bytes_sent, "bytes written to the device")                                                                   \
    X(write_errors, "writes to the device that failed or were dropped")                                            \
    X(capture_records, "records appended to the capture")                                                          \
    X(capture_bytes, "bytes appended to the capture, headers included")                                            \
    X(capture_rotations, "capture files rotated")                                                                  \
    X(capture_write_errors, "capture records that could not be written (disk full, ...)")                          \
    X(replay_records, "device-to-host records fed from a capture")                                                 \
    X(replay_to_device_records, "host-to-device records in the capture (skipped on replay)")                       \
    X(replay_corrupt_bytes, "capture bytes skipped as corrupt on replay")                                          \
    X(replay_truncated_bytes, "bytes of a cut-short last record on replay")                                        \
    X(replay_odometry_records, "odometry records fed from a capture")                                              \
    X(replay_host_events, "host events fed from a capture (cdro-hostd: solves adopted where the live run did)")    \
    X(host_events, "host events of the estimator recorded live (cdro-hostd: solves adopted when done)")            \
    X(odometry_received, "odometry messages received (UDP, MQTT, or fed from a capture)")                          \
    X(odometry_accepted, "odometry messages handed to the consumer (as steps)")                                    \
    X(odometry_clock_starts, "velocity messages that only started their source's clock (no step)")                 \
    X(odometry_clock_steps, "accepted messages whose t was over 1 s before the last one taken")                    \
    X(odometry_rejected_not_json, "odometry dropped: not JSON (or empty)")                                         \
    X(odometry_rejected_not_object, "odometry dropped: JSON, but not an object")                                   \
    X(odometry_rejected_field, "odometry dropped: a field missing, not a number or not finite")                    \
    X(odometry_rejected_both_forms, "odometry dropped: a step and velocities in one message")                      \
    X(odometry_rejected_absurd, "odometry dropped: a value beyond its documented bound")                           \
    X(odometry_rejected_out_of_order, "odometry dropped: t up to 1 s before the last one taken")                   \
    X(odometry_rejected_too_long, "odometry dropped: a message longer than 1024 bytes")                            \
    X(jsonl_lines, "JSON lines written")                                                                           \
    X(jsonl_write_errors, "JSON lines that could not be written")                                                  \
    X(jsonl_rotations, "JSON Lines files rotated (jsonl.rotate_mib)")                                              \
    X(jsonl_lines_held, "node and robot updates held back by jsonl.max_node_rate_hz")                              \
    X(mqtt_published, "MQTT messages handed to the broker connection")                                             \
    X(mqtt_dropped, "MQTT messages not sent because the broker was unreachable")                                   \
    X(mqtt_connects, "MQTT connections established")                                                               \
    X(mqtt_disconnects, "MQTT connections lost")                                                                   \
    X(mqtt_received, "MQTT messages received on the subscribed topics (odometry)")                                 \
    X(http_requests, "live map requests answered (200, or 404 for an unknown path or node)")                       \
    X(http_refused, "live map requests refused (400, 405, 408, 413, 431, 503) or connections closed to make room") \
    X(checkpoints_written, "checkpoints written")                                                                  \
    X(checkpoint_errors, "checkpoints that could not be written")

struct ServiceCounters {
#define CDRO_X_COUNTER_MEMBER(name, doc) uint64_t name = 0;
    CDRO_SERVICE_COUNTERS(CDRO_X_COUNTER_MEMBER)
#undef CDRO_X_COUNTER_MEMBER
};

// {"bytes_received": 123, ...} in the order of the list above.
nlohmann::ordered_json toJson(const ServiceCounters &counters);

// Rates over a sliding window of event time (so that they replay identically).
struct Rates {
    double frames_per_s = 0.0;  // good frames
    double ranges_per_s = 0.0;  // RANGE frames delivered
    double rejects_per_s = 0.0; // rejected chunks
    double bytes_per_s = 0.0;   // bytes received
};
nlohmann::ordered_json toJson(const Rates &rates);

// Counts events into 1 s buckets of event time; rates over the last window_s seconds.
class RateMeter {
public:
    explicit RateMeter(int window_s = 5) : window_s_(window_s) {}
    void add(int64_t event_unix_us, uint64_t count);
    double ratePerS(int64_t now_unix_us) const;

private:
    static constexpr int kBuckets = 64;
    int window_s_;
    int64_t bucket_second_[kBuckets] = {};
    uint64_t bucket_count_[kBuckets] = {};
};

} // namespace cdro::service
