// replay.hpp: --replay FILE [--speed X|max]. Feeds the device-to-host records of one or more
// capture files through the same FrameIntake as the live link, with each record's host time
// as the event time. The host-to-device records are not sent anywhere; their frame types go to
// FrameIntake::noteSentFrame, exactly as the session's did when they were captured. Odometry
// records (capture format version 2) go to the OdometryIntake (pushRecorded) in their place
// among the frames, so the OdometryConsumer gets them between the same frames as live.
//
// The consumer therefore sees identical calls in identical order whatever the speed: speed X
// only decides when, in monotonic time, each record is fed (record time / X after the first);
// max feeds records as fast as the loop allows, in batches, so that signals and HTTP requests
// are still served between batches.
//
// Threading: loop thread only.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "cdro/service/capture.hpp"
#include "cdro/service/event_loop.hpp"
#include "cdro/service/intake.hpp"
#include "cdro/service/odometry_intake.hpp"

namespace cdro::service {

class ReplaySource {
public:
    // speed: 0 = as fast as possible, else a factor of real time (> 0).
    ReplaySource(EventLoop &loop, std::vector<std::string> paths, double speed, FrameIntake &intake,
                 ServiceCounters &counters);

    // Where odometry records go; without it they are counted (replay_odometry_records) and
    // skipped.
    void setOdometryIntake(OdometryIntake *odometry) { odometry_ = odometry; }
    // Asked before each batch: false holds the replay back (polled every few ms) until true,
    // so that an output which must keep up (MQTT at full speed) is waited for. Event times
    // come from the records, so waiting changes nothing the consumer or the outputs see.
    void setGate(std::function<bool()> ready) { gate_ = std::move(ready); }
    // Opens the first file (throws CaptureError) so that its header is known before start().
    void open();
    // Starts feeding; after_batch runs after each batch, on_finished once at the end.
    void start(std::function<void()> after_batch, std::function<void()> on_finished);
    void stop();

    int64_t runStartUnixUs() const { return run_start_unix_us_; } // the first header's creation time
    std::string source() const;                                   // "replay:<first path>"
    bool finished() const { return finished_; }

    static constexpr size_t kBatchRecords = 2048;

private:
    void step();
    bool nextRecord(CaptureRecord &record);
    void feed(const CaptureRecord &record);
    void finish();

    EventLoop &loop_;
    std::vector<std::string> paths_;
    double speed_;
    FrameIntake &intake_;
    OdometryIntake *odometry_ = nullptr;
    ServiceCounters &counters_;
    std::unique_ptr<CaptureReader> reader_;
    size_t path_index_ = 0;
    int64_t run_start_unix_us_ = 0;
    bool have_first_record_ = false;
    int64_t first_record_unix_us_ = 0;
    int64_t start_monotonic_us_ = 0;
    CaptureRecord pending_;
    bool have_pending_ = false;
    bool finished_ = false;
    bool stopped_ = false;
    EventLoop::TimerId timer_ = 0;
    std::function<void()> after_batch_;
    std::function<void()> on_finished_;
    std::function<bool()> gate_;
};

} // namespace cdro::service
