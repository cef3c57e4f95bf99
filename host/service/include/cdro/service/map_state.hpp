// map_state.hpp: what the outputs publish (JSON Lines, MQTT, live map), as a plain value, and
// the MapSource interface through which the engine adapter (host/hostd/src/engine_adapter.cpp)
// provides it.
//
// Ownership and threads: the event loop thread asks the MapSource for the map (fill) and for
// a node's SoG components (components), so the engine is only ever touched on that thread.
// The outputs receive MapState by value; the HTTP threads see only copies published under a
// mutex (http_server.hpp).
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json_fwd.hpp>

#include "cdro/service/counters.hpp"

namespace cdro::service {

// Link states as they appear in JSON (`link`): docs/outputs.md lists connected, handshaking,
// disconnected and replay; incompatible is added for a device of another protocol build.
enum class LinkState { Disconnected, Handshaking, Connected, Incompatible, Replay };
const char *linkStateName(LinkState state);

// The version of the output objects (`schema` in every JSON object, docs/outputs.md). Keys are
// only ever added within a version; a key that changes meaning or goes away makes a new one.
constexpr int kOutputSchemaVersion = 2;

// Node ids as Pozyx users see them on devices and in every log line: "0x6001".
std::string nodeIdHex(uint16_t id);

struct NodeEstimate {
    uint16_t id = 0;        // Pozyx network id
    double x_m = 0.0;       // m; written as null while the node is not placed
    double y_m = 0.0;       // m; likewise
    double var_x_m2 = 0.0;  // m^2
    double cov_xy_m2 = 0.0; // m^2
    double var_y_m2 = 0.0;  // m^2
    bool converged = false;
    bool moving = false;
    bool placed = false;         // has an estimate at all; x/y are meaningless otherwise
    bool foldable = false;       // placed in a part that hangs on one or two nodes: its side is undecided
    std::string status;          // unplaced, placed, converged, moving, settling (the engine's lifecycle)
    std::string reason;          // why placed but not converged: "too few links", "ambiguous", "foldable",
                                 // "flexible", "unsettled"; empty otherwise
    std::vector<uint16_t> hinge; // foldable: the one or two nodes its part hangs on
    std::optional<double> z_m;   // m, the node's height where it is known (heights CSV, config), or its 3D track's z
    // m^2, the rest of a 3D track's position covariance (a node tracked in 3D, map.moving); unset
    // for every other node, and then not written
    std::optional<double> var_z_m2;
    std::optional<double> cov_xz_m2;
    std::optional<double> cov_yz_m2;
};

struct RobotPose {
    uint16_t id = 0;                  // the node carried by the robot
    double x_m = 0.0;                 // m
    double y_m = 0.0;                 // m
    double heading_rad = 0.0;         // rad, counter-clockwise from +x
    double var_x_m2 = 0.0;            // m^2
    double cov_xy_m2 = 0.0;           // m^2
    double var_y_m2 = 0.0;            // m^2
    std::string frame = "odometry";   // the frame of the pose: "odometry" or "map" (docs/engine.md, "Stage 2")
    double var_heading_rad2 = 0.0;    // rad^2
    double cov_x_heading_m_rad = 0.0; // m rad
    double cov_y_heading_m_rad = 0.0; // m rad
    uint32_t heading_hypotheses = 0;  // heading hypotheses alive (1 once decided)
    // The range model the robot's filter estimates: measured = scale x true + offset.
    std::optional<double> range_scale;          // dimensionless
    std::optional<double> range_scale_sigma;    // dimensionless, 1 sigma
    std::optional<double> range_offset_m;       // m
    std::optional<double> range_offset_sigma_m; // m, 1 sigma
};

// A pair of nodes that ranged to each other, with the last range.
struct LinkEstimate {
    uint16_t a = 0;            // smaller id
    uint16_t b = 0;            // larger id
    double last_range_m = 0.0; // m, as measured (3D)
    uint32_t range_count = 0;  // ranges seen on this link
    // m, the range the map fits on this link: the median of its recent ranges, projected onto
    // the plane where both heights are known; unset where the source has none
    std::optional<double> range_median_m;
    // [0, 1], how likely the link is line of sight at the map's last refinement; unset likewise
    std::optional<double> inlier_probability;
};

// One Gaussian of a node's sum of Gaussians (the ring SoG_ij centred on node i).
struct SogComponent {
    uint16_t center_id = 0; // node i whose ring this component belongs to
    double x_m = 0.0;       // m, mean
    double y_m = 0.0;       // m
    double var_x_m2 = 0.0;  // m^2
    double cov_xy_m2 = 0.0; // m^2
    double var_y_m2 = 0.0;  // m^2
    double weight = 0.0;    // normalised within its SoG, [0, 1]
};

struct NodeComponents {
    uint16_t id = 0; // the node j these SoGs describe
    std::vector<SogComponent> components;
};

struct Health {
    LinkState link = LinkState::Disconnected;
    std::string device;           // e.g. "serial:/dev/ttyACM0@115200" or "replay:run.cdrocap"
    std::string detail;           // last notable event, e.g. the incompatibility message
    uint16_t device_node_id = 0;  // from HELLO, 0 = not known yet
    uint16_t device_firmware = 0; // HELLO firmware_version, major << 8 | minor
    ServiceCounters counters;
    Rates rates;
};

struct MapState {
    double t_s = 0.0;                // s, event time since the run started
    double t_unix_s = 0.0;           // s since the Unix epoch: the same event time, absolute
    std::vector<NodeEstimate> nodes; // sorted by id
    std::optional<RobotPose> robot;
    std::vector<LinkEstimate> links; // sorted by (a, b)
    Health health;
    // Per node id: s since the Unix epoch, the event time at which its estimate last changed in
    // this run (the service keeps it, for the live map's `t_updated_unix_s`)
    std::map<uint16_t, double> updated_unix_s;
};

// Implemented by the engine adapter (host/hostd/src/engine_adapter.cpp) and by the test harness.
class MapSource {
public:
    virtual ~MapSource() = default;
    // Bumped whenever an estimate changed; the outputs publish only when it moved.
    virtual uint64_t revision() const = 0;
    // Fills nodes, robot and links (not t_s or health, which the service sets): the whole map,
    // for the live map and the end of a run.
    virtual void fill(MapState &map) const = 0;
    // After each update: brings map.nodes and map.robot up to date (not links, t_s or health)
    // and sets `changed` to the positions in map.nodes (ascending) of the nodes that are new or
    // whose estimate may differ from the one map held; the outputs look at those alone, so that
    // an update costs what it changed, not the size of the map. `map` is the one this source
    // last updated, untouched since, or an empty one. A superset is allowed (the outputs compare
    // what they last wrote); a node left out is an output missed. This default fills a whole map
    // and compares every node (changedNodes); the engine adapter looks only at what moved.
    virtual void updateEstimates(MapState &map, std::vector<size_t> &changed);
    // The SoG components describing node id, or nullopt if the node is unknown.
    virtual std::optional<NodeComponents> components(uint16_t id) const = 0;
};

// Bit-for-bit equality of estimates (the outputs write a node again only when it changed).
bool sameEstimate(const NodeEstimate &a, const NodeEstimate &b);
bool sameEstimate(const RobotPose &a, const RobotPose &b);

// The positions in `after` (sorted by id, as `before`) of the nodes that are not in `before`
// or differ from their estimate there (sameEstimate).
std::vector<size_t> changedNodes(const std::vector<NodeEstimate> &before, const std::vector<NodeEstimate> &after);
// Every position of map.nodes: what an output looks at without a list of changes.
std::vector<size_t> allNodes(const MapState &map);
// What an output looks at after an update: the positions of the changed nodes and of the nodes
// it held back before (held_ids, sorted), each once, ascending. A held node no longer in the
// map is dropped.
std::vector<size_t> nodesToLookAt(const MapState &map, const std::vector<size_t> &changed,
                                  const std::vector<uint16_t> &held_ids);

// The event time every line carries: since the run started, and since the Unix epoch. Both come
// from the event time (the frames' receive time, on replay the capture's), never from a clock read
// when the line is written, so a replay writes the live run's times.
struct OutputTime {
    double t_s = 0.0;      // s since the run started
    double t_unix_s = 0.0; // s since the Unix epoch (UTC)
};
inline OutputTime outputTimeOf(const MapState &map) { return {map.t_s, map.t_unix_s}; }

// The JSON objects of docs/outputs.md (keys in its order).
nlohmann::ordered_json nodeJson(const NodeEstimate &node, OutputTime time);
nlohmann::ordered_json robotJson(const RobotPose &robot, OutputTime time);
nlohmann::ordered_json healthJson(const Health &health, OutputTime time);
nlohmann::ordered_json linkJson(const LinkEstimate &link);
// A link of the live map: linkJson plus what the map makes of it, from the two nodes' positions
// (a or b null when not placed): `fitted_distance_m` (their distance in the plane) and
// `residual_m` (range_median_m minus that distance: a link that reads long, as a link without
// line of sight does, has a positive residual). Both null when either end is not placed or
// the link has no median range.
nlohmann::ordered_json mapLinkJson(const LinkEstimate &link, const NodeEstimate *a, const NodeEstimate *b);
// The whole map for the JSON API: {"schema", "t_s", "t_unix_s", "nodes": [...], "robot": {...}|null,
// "links": [...], "health": {...}}; nodes carry `t_updated_unix_s`, links are mapLinkJson's.
nlohmann::ordered_json mapJson(const MapState &map);
nlohmann::ordered_json componentsJson(const NodeComponents &components);

} // namespace cdro::service
