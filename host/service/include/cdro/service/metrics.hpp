// metrics.hpp: the live map's GET /metrics, in the Prometheus text exposition format (0.0.4),
// made from the same snapshot as /api/map and /api/health (so it is as fresh as they are:
// http.update_period_s). Names follow Prometheus' conventions: the cdro_ prefix, _total on
// counters, the unit in the name (_bytes, _seconds, _per_second); every family has HELP and TYPE.
//
//   cdro_build_info{version,protocol,frame_layout,checkpoint_layout}  gauge, always 1
//   cdro_link_state{state}            gauge, 1 for the link's state, 0 for the others
//   cdro_<counter>_total              counter, one per counters.hpp entry, its meaning as HELP
//   cdro_frames_per_second, cdro_ranges_per_second, cdro_rejects_per_second,
//   cdro_received_bytes_per_second    gauges, the health line's rates
//   cdro_nodes{status}                gauge, map nodes by status (unplaced, placed, ...)
//   cdro_run_time_seconds             gauge, the health line's t_s
// docs/service.md lists them with the counters.
#pragma once

#include <memory>
#include <string>

namespace cdro::service {

// The exposition text; map_json and health_json may be null (nothing published yet): then only
// cdro_build_info.
std::string prometheusText(const std::shared_ptr<const std::string> &map_json,
                           const std::shared_ptr<const std::string> &health_json);

} // namespace cdro::service
