#include "cdro/service/counters.hpp"

#include <nlohmann/json.hpp>

namespace cdro::service {

nlohmann::ordered_json toJson(const ServiceCounters &c)
{
    nlohmann::ordered_json out = nlohmann::ordered_json::object();
#define CDRO_X_COUNTER_JSON(name, doc) out[#name] = c.name;
    CDRO_SERVICE_COUNTERS(CDRO_X_COUNTER_JSON)
#undef CDRO_X_COUNTER_JSON
    return out;
}

nlohmann::ordered_json toJson(const Rates &r)
{
    nlohmann::ordered_json out = nlohmann::ordered_json::object();
    out["frames_per_s"] = r.frames_per_s;
    out["ranges_per_s"] = r.ranges_per_s;
    out["rejects_per_s"] = r.rejects_per_s;
    out["bytes_per_s"] = r.bytes_per_s;
    return out;
}

void RateMeter::add(int64_t event_unix_us, uint64_t count)
{
    const int64_t second = event_unix_us / 1'000'000;
    const int index = static_cast<int>(((second % kBuckets) + kBuckets) % kBuckets);
    if (bucket_second_[index] != second) {
        bucket_second_[index] = second;
        bucket_count_[index] = 0;
    }
    bucket_count_[index] += count;
}

double RateMeter::ratePerS(int64_t now_unix_us) const
{
    // The current second is still filling: use the window_s complete seconds before it.
    const int64_t now_second = now_unix_us / 1'000'000;
    uint64_t total = 0;
    for (int i = 0; i < kBuckets; ++i) {
        const int64_t age = now_second - bucket_second_[i];
        if (age >= 1 && age <= window_s_) {
            total += bucket_count_[i];
        }
    }
    return static_cast<double>(total) / static_cast<double>(window_s_);
}

} // namespace cdro::service
