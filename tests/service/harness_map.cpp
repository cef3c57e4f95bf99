#include "harness_map.hpp"

#include <algorithm>
#include <cinttypes>
#include <vector>
#include <cmath>

#include "cdro/fixed.h"
#include "cdro/wire.h"

using namespace cdro::service;

namespace {
constexpr double kCircleRadiusM = 5.0; // m, the placeholder layout
constexpr double kPi = 3.14159265358979323846;
constexpr uint16_t kHarnessExtensionTag = 0x0E01;
constexpr size_t kRecentRanges = 9; // ranges a link's median is taken over
} // namespace

HarnessEngine::HarnessEngine(const std::string &received_path)
{
    if (!received_path.empty()) {
        received_ = std::fopen(received_path.c_str(), "w");
    }
}

HarnessEngine::~HarnessEngine()
{
    if (received_ != nullptr) {
        std::fclose(received_);
    }
}

void HarnessEngine::record(const std::string &line)
{
    if (received_ != nullptr) {
        std::fputs(line.c_str(), received_);
        std::fputc('\n', received_);
        std::fflush(received_);
    }
}

void HarnessEngine::onRange(const cdro_range_t &r, const FrameContext &c)
{
    char line[200];
    std::snprintf(line, sizeof line,
                  "{\"kind\":\"range\",\"t_us\":%" PRId64 ",\"seq\":%u,\"from\":%u,\"to\":%u,\"distance_mm\":%lu,"
                  "\"device_time_ms\":%lu}",
                  c.host_unix_us, c.sequence, r.from_id, r.to_id, static_cast<unsigned long>(r.distance_mm),
                  static_cast<unsigned long>(r.device_time_ms));
    record(line);
    ++nodes_[r.from_id].ranges;
    ++nodes_[r.to_id].ranges;
    Link &link = links_[{std::min(r.from_id, r.to_id), std::max(r.from_id, r.to_id)}];
    link.last_range_m = static_cast<double>(r.distance_mm) * 1e-3;
    link.recent_m.push_back(link.last_range_m);
    if (link.recent_m.size() > kRecentRanges) {
        link.recent_m.erase(link.recent_m.begin());
    }
    ++link.count;
    ++ranges_;
    ++revision_;
}

void HarnessEngine::onMotion(const cdro_motion_t &m, const FrameContext &c)
{
    char line[160];
    std::snprintf(line, sizeof line, "{\"kind\":\"motion\",\"t_us\":%" PRId64 ",\"seq\":%u,\"node\":%u,\"moving\":%u}",
                  c.host_unix_us, c.sequence, m.node_id, m.moving);
    record(line);
    nodes_[m.node_id].moving = m.moving != 0;
    ++revision_;
}

void HarnessEngine::onHello(const cdro_hello_t &h, const FrameContext &c)
{
    char line[160];
    std::snprintf(line, sizeof line, "{\"kind\":\"hello\",\"t_us\":%" PRId64 ",\"seq\":%u,\"node\":%u}", c.host_unix_us,
                  c.sequence, h.node_id);
    record(line);
    own_id_ = h.node_id;
}

void HarnessEngine::onOdometry(const OdometryMessage &m)
{
    char line[200];
    // %.17g: every double reads back as itself, so live and replayed lines compare exactly.
    std::snprintf(line, sizeof line,
                  "{\"kind\":\"odometry\",\"t_s\":%.17g,\"distance_m\":%.17g,\"dheading_rad\":%.17g}", m.t_s,
                  m.distance_m, m.dheading_rad);
    record(line);
    // Plaza convention: advance along the mid-point heading.
    const double mid_rad = robot_heading_rad_ + 0.5 * m.dheading_rad;
    robot_x_m_ += m.distance_m * std::cos(mid_rad);
    robot_y_m_ += m.distance_m * std::sin(mid_rad);
    robot_heading_rad_ += m.dheading_rad;
    have_robot_ = true;
    ++odometry_steps_;
    ++revision_;
}

void HarnessEngine::onStatus(const cdro_status_t &s, const FrameContext &c)
{
    char line[160];
    std::snprintf(line, sizeof line, "{\"kind\":\"status\",\"t_us\":%" PRId64 ",\"seq\":%u,\"running\":%u}",
                  c.host_unix_us, c.sequence, s.running);
    record(line);
}

void HarnessEngine::onNodeList(const cdro_node_list_t &l, const FrameContext &c)
{
    char line[160];
    std::snprintf(line, sizeof line, "{\"kind\":\"node_list\",\"t_us\":%" PRId64 ",\"seq\":%u,\"count\":%u}",
                  c.host_unix_us, c.sequence, l.node_ids_count);
    record(line);
}

void HarnessEngine::onDeviceError(const cdro_error_t &e, const FrameContext &c)
{
    char line[160];
    std::snprintf(line, sizeof line, "{\"kind\":\"error\",\"t_us\":%" PRId64 ",\"seq\":%u,\"code\":%u}", c.host_unix_us,
                  c.sequence, e.code);
    record(line);
}

void HarnessEngine::onDeviceReset(DeviceResetReason reason, const FrameContext &c)
{
    char line[200];
    std::snprintf(line, sizeof line, "{\"kind\":\"reset\",\"t_us\":%" PRId64 ",\"seq\":%u,\"reason\":\"%s\"}",
                  c.host_unix_us, c.sequence, deviceResetReasonName(reason));
    record(line);
}

void HarnessEngine::position(uint16_t id, double *x_m, double *y_m) const
{
    size_t index = 0;
    for (const auto &entry : nodes_) {
        if (entry.first == id) {
            break;
        }
        ++index;
    }
    const double angle =
        2.0 * kPi * static_cast<double>(index) / static_cast<double>(std::max<size_t>(1, nodes_.size()));
    *x_m = kCircleRadiusM * std::cos(angle);
    *y_m = kCircleRadiusM * std::sin(angle);
}

void HarnessEngine::fill(MapState &map) const
{
    // The stand-in's fold rule: a node linked to a single other node hangs on it (the engine's
    // rule, foldable.hpp, for that simplest case), so the outputs and the live map show one.
    std::map<uint16_t, int> neighbours;
    for (const auto &[pair, link] : links_) {
        ++neighbours[pair.first];
        ++neighbours[pair.second];
    }
    for (const auto &[id, node] : nodes_) {
        NodeEstimate estimate;
        estimate.id = id;
        position(id, &estimate.x_m, &estimate.y_m);
        const double variance_m2 = 1.0 / (1.0 + static_cast<double>(node.ranges));
        estimate.var_x_m2 = variance_m2;
        estimate.var_y_m2 = 0.5 * variance_m2;
        estimate.cov_xy_m2 = 0.2 * variance_m2;
        estimate.converged = node.ranges >= 10;
        estimate.moving = node.moving;
        estimate.placed = true;
        const auto linked = neighbours.find(id);
        estimate.foldable = nodes_.size() > 2 && linked != neighbours.end() && linked->second == 1;
        if (estimate.foldable) {
            estimate.converged = false;
            estimate.reason = "foldable";
            for (const auto &[pair, link] : links_) {
                if (pair.first == id || pair.second == id) {
                    estimate.hinge.push_back(pair.first == id ? pair.second : pair.first);
                }
            }
        }
        estimate.status = estimate.moving ? "moving" : (estimate.converged ? "converged" : "placed");
        if (!estimate.converged && !estimate.moving && estimate.reason.empty()) {
            estimate.reason = "unsettled";
        }
        map.nodes.push_back(estimate);
    }
    for (const auto &[pair, link] : links_) {
        LinkEstimate out;
        out.a = pair.first;
        out.b = pair.second;
        out.last_range_m = link.last_range_m;
        out.range_count = link.count;
        if (!link.recent_m.empty()) {
            std::vector<double> sorted = link.recent_m;
            std::sort(sorted.begin(), sorted.end());
            const size_t half = sorted.size() / 2;
            out.range_median_m = sorted.size() % 2 == 1 ? sorted[half] : 0.5 * (sorted[half - 1] + sorted[half]);
        }
        map.links.push_back(out);
    }
    if (have_robot_) {
        // The variance grows with the steps taken, as dead reckoning's does.
        const double variance_m2 = 0.01 * static_cast<double>(odometry_steps_);
        RobotPose robot;
        robot.id = own_id_;
        robot.x_m = robot_x_m_;
        robot.y_m = robot_y_m_;
        robot.heading_rad = robot_heading_rad_;
        robot.var_x_m2 = variance_m2;
        robot.var_y_m2 = variance_m2;
        map.robot = robot;
    }
}

std::optional<NodeComponents> HarnessEngine::components(uint16_t id) const
{
    if (nodes_.count(id) == 0) {
        return std::nullopt;
    }
    NodeComponents out;
    out.id = id;
    std::vector<std::pair<uint16_t, double>> neighbours;
    for (const auto &[pair, link] : links_) {
        if (pair.first == id || pair.second == id) {
            neighbours.emplace_back(pair.first == id ? pair.second : pair.first, link.last_range_m);
        }
    }
    for (const auto &[other, range_m] : neighbours) {
        double cx = 0.0, cy = 0.0;
        position(other, &cx, &cy);
        for (int k = 0; k < 8; ++k) {
            const double angle = 2.0 * kPi * k / 8.0;
            out.components.push_back({other, cx + range_m * std::cos(angle), cy + range_m * std::sin(angle), 0.04, 0.0,
                                      0.04, 1.0 / (8.0 * static_cast<double>(neighbours.size()))});
        }
    }
    return out;
}

SogSnapshot HarnessEngine::snapshot()
{
    SogSnapshot s;
    s.header.ranges_processed = ranges_;
    std::vector<uint8_t> counts;
    for (const auto &[id, node] : nodes_) {
        cdro_sog_node_t record{};
        record.id = id;
        double x = 0.0, y = 0.0;
        position(id, &x, &y);
        record.flags = CDRO_SOG_NODE_PLACED | (node.moving ? CDRO_SOG_NODE_MOVING : 0U) |
                       (node.ranges >= 10 ? CDRO_SOG_NODE_CONVERGED : 0U);
        record.x_mm = cdro_fixed_mm_from_m(x);
        record.y_mm = cdro_fixed_mm_from_m(y);
        s.nodes.push_back(record);
        uint8_t bytes[6];
        cdro_put_u16(bytes, id);
        cdro_put_u32(bytes + 2, node.ranges);
        counts.insert(counts.end(), bytes, bytes + 6);
    }
    for (const auto &[pair, link] : links_) {
        SogSnapshot::Pair p;
        p.pair.center_id = pair.first;
        p.pair.target_id = pair.second;
        p.pair.last_range_mm = static_cast<uint32_t>(std::llround(link.last_range_m * 1000.0));
        p.pair.range_count = static_cast<uint16_t>(std::min<uint32_t>(link.count, 65535));
        s.pairs.push_back(p);
    }
    s.extensions.push_back({kHarnessExtensionTag, counts});
    return s;
}

void HarnessEngine::restore(const SogSnapshot &s)
{
    nodes_.clear();
    links_.clear();
    ranges_ = s.header.ranges_processed;
    const SogSnapshot::Extension *counts = s.findExtension(kHarnessExtensionTag);
    for (const cdro_sog_node_t &record : s.nodes) {
        nodes_[record.id].moving = (record.flags & CDRO_SOG_NODE_MOVING) != 0;
    }
    if (counts != nullptr) {
        for (size_t i = 0; i + 6 <= counts->bytes.size(); i += 6) {
            nodes_[cdro_get_u16(counts->bytes.data() + i)].ranges = cdro_get_u32(counts->bytes.data() + i + 2);
        }
    }
    for (const SogSnapshot::Pair &p : s.pairs) {
        Link &link = links_[{p.pair.center_id, p.pair.target_id}];
        link.last_range_m = static_cast<double>(p.pair.last_range_mm) * 1e-3;
        link.count = p.pair.range_count;
        link.recent_m = {link.last_range_m};
    }
    ++revision_;
}
