#include "cdro/service/replay.hpp"

#include <cmath>

#include "cdro/service/log.hpp"

namespace cdro::service {

ReplaySource::ReplaySource(EventLoop &loop, std::vector<std::string> paths, double speed, FrameIntake &intake,
                           ServiceCounters &counters)
    : loop_(loop), paths_(std::move(paths)), speed_(speed), intake_(intake), counters_(counters)
{
}

std::string ReplaySource::source() const { return paths_.empty() ? "replay:" : "replay:" + paths_.front(); }

void ReplaySource::open()
{
    if (paths_.empty()) {
        throw CaptureError("replay: no capture file given");
    }
    reader_ = std::make_unique<CaptureReader>(paths_[0]);
    run_start_unix_us_ = reader_->header().created_unix_us;
    log()->info("replay: {} (recorded from {}), speed {}", paths_[0], reader_->source(),
                speed_ > 0.0 ? std::to_string(speed_) + "x" : std::string("max"));
}

void ReplaySource::start(std::function<void()> after_batch, std::function<void()> on_finished)
{
    after_batch_ = std::move(after_batch);
    on_finished_ = std::move(on_finished);
    start_monotonic_us_ = loop_.clock().monotonicUs();
    timer_ = loop_.addTimerAfter(0, [this] { step(); });
}

void ReplaySource::stop()
{
    stopped_ = true;
    if (timer_ != 0) {
        loop_.cancelTimer(timer_);
        timer_ = 0;
    }
}

bool ReplaySource::nextRecord(CaptureRecord &record)
{
    while (reader_) {
        if (reader_->next(record)) {
            return true;
        }
        counters_.replay_corrupt_bytes += reader_->corruptBytes();
        counters_.replay_truncated_bytes += reader_->truncatedTailBytes();
        if (reader_->corruptBytes() > 0 || reader_->truncatedTailBytes() > 0) {
            log()->warn("replay: {}: {} corrupt bytes skipped, {} bytes of a cut-short last record",
                        paths_[path_index_], reader_->corruptBytes(), reader_->truncatedTailBytes());
        }
        reader_.reset();
        if (++path_index_ < paths_.size()) {
            reader_ = std::make_unique<CaptureReader>(paths_[path_index_]);
        }
    }
    return false;
}

void ReplaySource::feed(const CaptureRecord &record)
{
    if ((record.flags & CDRO_CAPTURE_FLAG_ODOMETRY) != 0) {
        ++counters_.replay_odometry_records;
        if (odometry_ != nullptr) {
            odometry_->pushRecorded(record.data.data(), record.data.size(), record.host_time_us);
        }
        return;
    }
    if (record.hostEvent()) {
        ++counters_.replay_host_events;
        intake_.pushHostEvent(record.data.data(), record.data.size(), record.host_time_us);
        return;
    }
    if (record.toDevice()) {
        ++counters_.replay_to_device_records;
        cdro_frame_t frame;
        if (cdro_frame_decode(record.data.data(), record.data.size(), &frame) == CDRO_OK) {
            intake_.noteSentFrame(frame.type);
        }
        return;
    }
    ++counters_.replay_records;
    intake_.push(record.data.data(), record.data.size(), record.host_time_us);
    const uint8_t delimiter = 0x00;
    intake_.push(&delimiter, 1, record.host_time_us);
}

void ReplaySource::step()
{
    timer_ = 0;
    if (stopped_ || finished_) {
        return;
    }
    if (gate_ && !gate_()) {
        constexpr int64_t kGatePollUs = 2'000; // us; only while an output catches up
        timer_ = loop_.addTimerAfter(kGatePollUs, [this] { step(); });
        return;
    }
    try {
        for (size_t fed = 0; fed < kBatchRecords; ++fed) {
            if (!have_pending_) {
                if (!nextRecord(pending_)) {
                    finish();
                    return;
                }
                have_pending_ = true;
            }
            if (speed_ > 0.0) {
                if (!have_first_record_) {
                    have_first_record_ = true;
                    first_record_unix_us_ = pending_.host_time_us;
                }
                const double offset_us = static_cast<double>(pending_.host_time_us - first_record_unix_us_) / speed_;
                const int64_t due_us = start_monotonic_us_ + static_cast<int64_t>(std::llround(offset_us));
                if (loop_.clock().monotonicUs() < due_us) {
                    if (after_batch_) {
                        after_batch_();
                    }
                    timer_ = loop_.addTimerAt(due_us, [this] { step(); });
                    return;
                }
            }
            have_pending_ = false;
            feed(pending_);
        }
    } catch (const CaptureError &error) {
        log()->error("replay: {}; stopping the replay", error.what());
        finish();
        return;
    }
    if (after_batch_) {
        after_batch_();
    }
    timer_ = loop_.addTimerAfter(0, [this] { step(); });
}

void ReplaySource::finish()
{
    if (finished_) {
        return;
    }
    finished_ = true;
    if (after_batch_) {
        after_batch_();
    }
    log()->info("replay: finished ({} device records, {} odometry records and {} host events fed, {} host-to-device "
                "records skipped)",
                counters_.replay_records, counters_.replay_odometry_records, counters_.replay_host_events,
                counters_.replay_to_device_records);
    if (on_finished_) {
        on_finished_();
    }
}

} // namespace cdro::service
