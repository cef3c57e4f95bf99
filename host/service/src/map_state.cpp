#include "cdro/service/map_state.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <iterator>
#include <map>

#include <nlohmann/json.hpp>

namespace cdro::service {

const char *linkStateName(LinkState state)
{
    switch (state) {
    case LinkState::Disconnected: return "disconnected";
    case LinkState::Handshaking: return "handshaking";
    case LinkState::Connected: return "connected";
    case LinkState::Incompatible: return "incompatible";
    case LinkState::Replay: return "replay";
    }
    return "disconnected";
}

std::string nodeIdHex(uint16_t id)
{
    char text[8];
    std::snprintf(text, sizeof text, "0x%04X", static_cast<unsigned>(id));
    return text;
}

namespace {
// Bit for bit on purpose: -0.0 differs from 0.0 and a NaN equals itself.
// NOLINTNEXTLINE(bugprone-suspicious-memory-comparison)
bool sameBits(double a, double b) { return std::memcmp(&a, &b, sizeof a) == 0; }
bool sameBits(const std::optional<double> &a, const std::optional<double> &b)
{
    return a.has_value() == b.has_value() && (!a || sameBits(*a, *b));
}

// A value that may be unknown: JSON null rather than a number that looks like a measurement.
nlohmann::ordered_json orNull(const std::optional<double> &value)
{
    return value ? nlohmann::ordered_json(*value) : nlohmann::ordered_json(nullptr);
}

void putTime(nlohmann::ordered_json &j, OutputTime time)
{
    j["schema"] = kOutputSchemaVersion;
    j["t_s"] = time.t_s;
    j["t_unix_s"] = time.t_unix_s;
}

nlohmann::ordered_json idList(const std::vector<uint16_t> &ids)
{
    nlohmann::ordered_json list = nlohmann::ordered_json::array();
    for (uint16_t id : ids) {
        list.push_back(nodeIdHex(id));
    }
    return list;
}
} // namespace

bool sameEstimate(const NodeEstimate &a, const NodeEstimate &b)
{
    return a.id == b.id && sameBits(a.x_m, b.x_m) && sameBits(a.y_m, b.y_m) && sameBits(a.var_x_m2, b.var_x_m2) &&
           sameBits(a.cov_xy_m2, b.cov_xy_m2) && sameBits(a.var_y_m2, b.var_y_m2) && a.converged == b.converged &&
           a.moving == b.moving && a.placed == b.placed && a.foldable == b.foldable && a.status == b.status &&
           a.reason == b.reason && a.hinge == b.hinge && sameBits(a.z_m, b.z_m) && sameBits(a.var_z_m2, b.var_z_m2) &&
           sameBits(a.cov_xz_m2, b.cov_xz_m2) && sameBits(a.cov_yz_m2, b.cov_yz_m2);
}

std::vector<size_t> changedNodes(const std::vector<NodeEstimate> &before, const std::vector<NodeEstimate> &after)
{
    std::vector<size_t> changed;
    size_t old = 0;
    for (size_t i = 0; i < after.size(); ++i) {
        while (old < before.size() && before[old].id < after[i].id) {
            ++old;
        }
        if (old == before.size() || !sameEstimate(before[old], after[i])) {
            changed.push_back(i);
        }
    }
    return changed;
}

std::vector<size_t> allNodes(const MapState &map)
{
    std::vector<size_t> all(map.nodes.size());
    for (size_t i = 0; i < all.size(); ++i) {
        all[i] = i;
    }
    return all;
}

std::vector<size_t> nodesToLookAt(const MapState &map, const std::vector<size_t> &changed,
                                  const std::vector<uint16_t> &held_ids)
{
    if (held_ids.empty()) {
        return changed;
    }
    std::vector<size_t> held;
    held.reserve(held_ids.size());
    for (const uint16_t id : held_ids) {
        const auto found = std::lower_bound(map.nodes.begin(), map.nodes.end(), id,
                                            [](const NodeEstimate &node, uint16_t key) { return node.id < key; });
        if (found != map.nodes.end() && found->id == id) {
            held.push_back(static_cast<size_t>(found - map.nodes.begin()));
        }
    }
    std::vector<size_t> out;
    out.reserve(changed.size() + held.size());
    std::set_union(changed.begin(), changed.end(), held.begin(), held.end(), std::back_inserter(out));
    return out;
}

void MapSource::updateEstimates(MapState &map, std::vector<size_t> &changed)
{
    MapState fresh;
    fill(fresh);
    changed = changedNodes(map.nodes, fresh.nodes);
    map.nodes = std::move(fresh.nodes);
    map.robot = std::move(fresh.robot);
}

bool sameEstimate(const RobotPose &a, const RobotPose &b)
{
    return a.id == b.id && sameBits(a.x_m, b.x_m) && sameBits(a.y_m, b.y_m) && sameBits(a.heading_rad, b.heading_rad) &&
           sameBits(a.var_x_m2, b.var_x_m2) && sameBits(a.cov_xy_m2, b.cov_xy_m2) && sameBits(a.var_y_m2, b.var_y_m2) &&
           a.frame == b.frame && sameBits(a.var_heading_rad2, b.var_heading_rad2) &&
           sameBits(a.cov_x_heading_m_rad, b.cov_x_heading_m_rad) &&
           sameBits(a.cov_y_heading_m_rad, b.cov_y_heading_m_rad) && a.heading_hypotheses == b.heading_hypotheses &&
           sameBits(a.range_scale, b.range_scale) && sameBits(a.range_scale_sigma, b.range_scale_sigma) &&
           sameBits(a.range_offset_m, b.range_offset_m) && sameBits(a.range_offset_sigma_m, b.range_offset_sigma_m);
}

nlohmann::ordered_json nodeJson(const NodeEstimate &n, OutputTime time)
{
    // An unplaced node has no position: null, so that a consumer that does not read `placed`
    // does not see a certain node at the origin.
    const auto placedOnly = [&n](double value) {
        return n.placed ? nlohmann::ordered_json(value) : nlohmann::ordered_json(nullptr);
    };
    nlohmann::ordered_json j;
    j["type"] = "node";
    putTime(j, time);
    j["id"] = n.id;
    j["id_hex"] = nodeIdHex(n.id);
    j["x_m"] = placedOnly(n.x_m);
    j["y_m"] = placedOnly(n.y_m);
    j["z_m"] = orNull(n.z_m);
    j["var_x_m2"] = placedOnly(n.var_x_m2);
    j["cov_xy_m2"] = placedOnly(n.cov_xy_m2);
    j["var_y_m2"] = placedOnly(n.var_y_m2);
    j["converged"] = n.converged;
    j["moving"] = n.moving;
    j["placed"] = n.placed;
    j["foldable"] = n.foldable;
    j["status"] = n.status;
    j["reason"] = n.reason;
    j["hinge"] = n.hinge;
    j["hinge_hex"] = idList(n.hinge);
    // A 3D track's covariance: only on the nodes that have one, so 2D consumers see nothing new.
    if (n.var_z_m2) {
        j["var_z_m2"] = *n.var_z_m2;
        j["cov_xz_m2"] = orNull(n.cov_xz_m2);
        j["cov_yz_m2"] = orNull(n.cov_yz_m2);
    }
    return j;
}

nlohmann::ordered_json robotJson(const RobotPose &r, OutputTime time)
{
    nlohmann::ordered_json j;
    j["type"] = "robot";
    putTime(j, time);
    j["id"] = r.id;
    j["id_hex"] = nodeIdHex(r.id);
    j["frame"] = r.frame;
    j["x_m"] = r.x_m;
    j["y_m"] = r.y_m;
    j["heading_rad"] = r.heading_rad;
    j["var_x_m2"] = r.var_x_m2;
    j["cov_xy_m2"] = r.cov_xy_m2;
    j["var_y_m2"] = r.var_y_m2;
    j["var_heading_rad2"] = r.var_heading_rad2;
    j["cov_x_heading_m_rad"] = r.cov_x_heading_m_rad;
    j["cov_y_heading_m_rad"] = r.cov_y_heading_m_rad;
    j["heading_hypotheses"] = r.heading_hypotheses;
    j["range_scale"] = orNull(r.range_scale);
    j["range_scale_sigma"] = orNull(r.range_scale_sigma);
    j["range_offset_m"] = orNull(r.range_offset_m);
    j["range_offset_sigma_m"] = orNull(r.range_offset_sigma_m);
    return j;
}

nlohmann::ordered_json healthJson(const Health &h, OutputTime time)
{
    nlohmann::ordered_json j;
    j["type"] = "health";
    putTime(j, time);
    j["link"] = linkStateName(h.link);
    j["counters"] = toJson(h.counters);
    j["rates"] = toJson(h.rates);
    j["device"] = h.device;
    j["device_node_id"] = h.device_node_id;
    j["device_node_id_hex"] =
        h.device_node_id != 0 ? nlohmann::ordered_json(nodeIdHex(h.device_node_id)) : nlohmann::ordered_json(nullptr);
    j["device_firmware"] = h.device_firmware;
    j["detail"] = h.detail;
    return j;
}

nlohmann::ordered_json linkJson(const LinkEstimate &l)
{
    nlohmann::ordered_json j;
    j["a"] = l.a;
    j["b"] = l.b;
    j["a_hex"] = nodeIdHex(l.a);
    j["b_hex"] = nodeIdHex(l.b);
    j["last_range_m"] = l.last_range_m;
    j["range_count"] = l.range_count;
    return j;
}

nlohmann::ordered_json mapLinkJson(const LinkEstimate &l, const NodeEstimate *a, const NodeEstimate *b)
{
    nlohmann::ordered_json j = linkJson(l);
    j["range_median_m"] = orNull(l.range_median_m);
    j["inlier_probability"] = orNull(l.inlier_probability);
    std::optional<double> fitted_m;
    std::optional<double> residual_m;
    if (a != nullptr && b != nullptr && a->placed && b->placed) {
        fitted_m = std::hypot(a->x_m - b->x_m, a->y_m - b->y_m);
        if (l.range_median_m) {
            residual_m = *l.range_median_m - *fitted_m;
        }
    }
    j["fitted_distance_m"] = orNull(fitted_m);
    j["residual_m"] = orNull(residual_m);
    return j;
}

nlohmann::ordered_json mapJson(const MapState &map)
{
    nlohmann::ordered_json j;
    putTime(j, outputTimeOf(map));
    j["nodes"] = nlohmann::ordered_json::array();
    std::map<uint16_t, const NodeEstimate *> by_id;
    for (const NodeEstimate &node : map.nodes) {
        nlohmann::ordered_json one = nodeJson(node, outputTimeOf(map));
        const auto updated = map.updated_unix_s.find(node.id);
        one["t_updated_unix_s"] = updated != map.updated_unix_s.end() ? nlohmann::ordered_json(updated->second)
                                                                      : nlohmann::ordered_json(nullptr);
        j["nodes"].push_back(std::move(one));
        by_id[node.id] = &node;
    }
    j["robot"] = map.robot ? robotJson(*map.robot, outputTimeOf(map)) : nlohmann::ordered_json(nullptr);
    j["links"] = nlohmann::ordered_json::array();
    const auto find = [&by_id](uint16_t id) -> const NodeEstimate * {
        const auto it = by_id.find(id);
        return it == by_id.end() ? nullptr : it->second;
    };
    for (const LinkEstimate &link : map.links) {
        j["links"].push_back(mapLinkJson(link, find(link.a), find(link.b)));
    }
    j["health"] = healthJson(map.health, outputTimeOf(map));
    return j;
}

nlohmann::ordered_json componentsJson(const NodeComponents &c)
{
    nlohmann::ordered_json j;
    j["schema"] = kOutputSchemaVersion;
    j["id"] = c.id;
    j["id_hex"] = nodeIdHex(c.id);
    j["components"] = nlohmann::ordered_json::array();
    for (const SogComponent &g : c.components) {
        nlohmann::ordered_json one;
        one["center_id"] = g.center_id;
        one["center_id_hex"] = nodeIdHex(g.center_id);
        one["x_m"] = g.x_m;
        one["y_m"] = g.y_m;
        one["var_x_m2"] = g.var_x_m2;
        one["cov_xy_m2"] = g.cov_xy_m2;
        one["var_y_m2"] = g.var_y_m2;
        one["weight"] = g.weight;
        j["components"].push_back(one);
    }
    return j;
}

} // namespace cdro::service
