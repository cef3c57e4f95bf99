// consumer.hpp: how validated frames reach the estimator.
//
// The engine adapter (host/hostd/src/engine_adapter.cpp) implements FrameConsumer. The intake
// calls it on the event loop thread,
// in the order the frames arrived, with frames that passed COBS, CRC, version, length
// and value checks (cdro_frame_validate) and the node-id policy: a value out of range never
// gets here. The same calls, with the same arguments in the same order, happen when a capture
// is replayed (at any speed), which is what makes replay deterministic: a consumer must not
// read any clock of its own, only FrameContext::host_unix_us.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "cdro/frames.h"

namespace cdro::service {

struct FrameContext {
    int64_t host_unix_us = 0; // event time: when the frame's delimiter arrived (live), or the
                              // capture record's time (replay); us since the Unix epoch
    uint16_t sequence = 0;    // the device's sequence number of this frame
};

enum class DeviceResetReason {
    TimeBackwards,   // device_time_ms went backwards (beyond a 32-bit wrap)
    SequenceRestart, // sequence numbers restarted (HELLO with sequence 0, or a jump backwards)
    UnexpectedHello, // a HELLO that nobody asked for, after other frames
};
const char *deviceResetReasonName(DeviceResetReason reason);

class FrameConsumer {
public:
    virtual ~FrameConsumer() = default;
    virtual void onRange(const cdro_range_t &range, const FrameContext &context) = 0;
    virtual void onMotion(const cdro_motion_t &motion, const FrameContext &context) = 0;
    virtual void onHello(const cdro_hello_t &, const FrameContext &) {}
    virtual void onStatus(const cdro_status_t &, const FrameContext &) {}
    virtual void onNodeList(const cdro_node_list_t &, const FrameContext &) {}
    virtual void onDeviceError(const cdro_error_t &, const FrameContext &) {}
    // The device restarted: its clock (device_time_ms) and sequence numbers start again.
    // Called before the frame that revealed the reset is delivered.
    virtual void onDeviceReset(DeviceResetReason, const FrameContext &) {}

    // Host events: what the consumer does on its own timing (cdro-hostd: a global solve's map,
    // adopted once its worker thread is done, so that no frame waits for it), which a replay
    // must repeat at the same place of the frame stream to reach the same estimates. Live, after
    // every frame delivered (and every 20 ms between frames, so that work done after the last
    // frame of a burst is not left waiting for the next): the consumer does such work now and
    // describes it (empty: none); the service records the description in the capture after the
    // last record (its time is `context`'s). On --replay this is not called; instead each
    // recorded description comes back to onHostEvent in its place among the frames. At most
    // CDRO_CAPTURE_MAX_DATA bytes.
    virtual std::vector<uint8_t> hostEventAfterFrame(const FrameContext &) { return {}; }
    virtual void onHostEvent(const uint8_t *, size_t, const FrameContext &) {}
};

} // namespace cdro::service
