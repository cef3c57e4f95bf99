#include "cdro/service/map_state.hpp"

#include <cstring>

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

namespace {
bool sameBits(double a, double b) { return std::memcmp(&a, &b, sizeof a) == 0; }
} // namespace

bool sameEstimate(const NodeEstimate &a, const NodeEstimate &b)
{
    return a.id == b.id && sameBits(a.x_m, b.x_m) && sameBits(a.y_m, b.y_m) && sameBits(a.var_x_m2, b.var_x_m2) &&
           sameBits(a.cov_xy_m2, b.cov_xy_m2) && sameBits(a.var_y_m2, b.var_y_m2) && a.converged == b.converged &&
           a.moving == b.moving && a.placed == b.placed && a.foldable == b.foldable && a.status == b.status &&
           a.reason == b.reason && a.hinge == b.hinge;
}

bool sameEstimate(const RobotPose &a, const RobotPose &b)
{
    return a.id == b.id && sameBits(a.x_m, b.x_m) && sameBits(a.y_m, b.y_m) &&
           sameBits(a.heading_rad, b.heading_rad) && sameBits(a.var_x_m2, b.var_x_m2) &&
           sameBits(a.cov_xy_m2, b.cov_xy_m2) && sameBits(a.var_y_m2, b.var_y_m2);
}

nlohmann::ordered_json nodeJson(const NodeEstimate &n, double t_s)
{
    nlohmann::ordered_json j;
    j["type"] = "node";
    j["t_s"] = t_s;
    j["id"] = n.id;
    j["x_m"] = n.x_m;
    j["y_m"] = n.y_m;
    j["var_x_m2"] = n.var_x_m2;
    j["cov_xy_m2"] = n.cov_xy_m2;
    j["var_y_m2"] = n.var_y_m2;
    j["converged"] = n.converged;
    j["moving"] = n.moving;
    j["placed"] = n.placed;
    j["foldable"] = n.foldable;
    j["status"] = n.status;
    j["reason"] = n.reason;
    j["hinge"] = n.hinge;
    return j;
}

nlohmann::ordered_json robotJson(const RobotPose &r, double t_s)
{
    nlohmann::ordered_json j;
    j["type"] = "robot";
    j["t_s"] = t_s;
    j["id"] = r.id;
    j["x_m"] = r.x_m;
    j["y_m"] = r.y_m;
    j["heading_rad"] = r.heading_rad;
    j["var_x_m2"] = r.var_x_m2;
    j["cov_xy_m2"] = r.cov_xy_m2;
    j["var_y_m2"] = r.var_y_m2;
    return j;
}

nlohmann::ordered_json healthJson(const Health &h, double t_s)
{
    nlohmann::ordered_json j;
    j["type"] = "health";
    j["t_s"] = t_s;
    j["link"] = linkStateName(h.link);
    j["counters"] = toJson(h.counters);
    j["rates"] = toJson(h.rates);
    j["device"] = h.device;
    j["device_node_id"] = h.device_node_id;
    j["device_firmware"] = h.device_firmware;
    j["detail"] = h.detail;
    return j;
}

nlohmann::ordered_json linkJson(const LinkEstimate &l)
{
    nlohmann::ordered_json j;
    j["a"] = l.a;
    j["b"] = l.b;
    j["last_range_m"] = l.last_range_m;
    j["range_count"] = l.range_count;
    return j;
}

nlohmann::ordered_json mapJson(const MapState &map)
{
    nlohmann::ordered_json j;
    j["t_s"] = map.t_s;
    j["nodes"] = nlohmann::ordered_json::array();
    for (const NodeEstimate &node : map.nodes) {
        j["nodes"].push_back(nodeJson(node, map.t_s));
    }
    j["robot"] = map.robot ? robotJson(*map.robot, map.t_s) : nlohmann::ordered_json(nullptr);
    j["links"] = nlohmann::ordered_json::array();
    for (const LinkEstimate &link : map.links) {
        j["links"].push_back(linkJson(link));
    }
    j["health"] = healthJson(map.health, map.t_s);
    return j;
}

nlohmann::ordered_json componentsJson(const NodeComponents &c)
{
    nlohmann::ordered_json j;
    j["id"] = c.id;
    j["components"] = nlohmann::ordered_json::array();
    for (const SogComponent &g : c.components) {
        nlohmann::ordered_json one;
        one["center_id"] = g.center_id;
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
