#include "scenario.hpp"

#include <cctype>
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>

#include <nlohmann/json.hpp>
#include <yaml-cpp/yaml.h>

#include "pozyx_sim/pozyx_sim.h"

namespace cdro::fil {

namespace {

const char *const kFaultNames[kFaultKindCount] = {"nack_address",      "nack_write",      "no_completion",
                                                  "error_completion",  "garbage_range",   "stale_range",
                                                  "drop_remote_reply", "refuse_function", "late_reply",
                                                  "power_off"};

// The fault kinds of cdro-sim: faults of the serial stream between the device and the host and of
// the device itself, which cdro-fil's unmodified firmware and simulated Pozyx cannot produce.
const char *const kSimFaultNames[] = {"garbage", "bit_flip", "cut_frame", "absurd", "vanish", "reset"};

struct KeyNote {
    const char *pattern; // path of the key, list indices written []
    const char *note;
};

// Spellings of earlier scenario files (cdro-fil's and cdro-sim's) and what they are called now
// (sim/scenario_keys.def). The keys are refused rather than read, so that a file has one spelling.
#define CDRO_RENAMED_KEY(OLD, NOW) KeyNote{OLD, NOW},
const KeyNote kRenamedKeys[] = {CDRO_SCENARIO_RENAMED_KEYS(CDRO_RENAMED_KEY)};
#undef CDRO_RENAMED_KEY

std::string where(const YAML::Node &node, const std::string &origin)
{
    const YAML::Mark mark = node.Mark();
    return mark.line < 0 ? origin : origin + ":" + std::to_string(mark.line + 1);
}

std::string text(const YAML::Node &node)
{
    return node.IsScalar() ? node.Scalar() : std::string(node.IsSequence() ? "a list" : "a map");
}

// A YAML map read key by key; finish() rejects the keys nobody asked for, so that a typo is an
// error instead of a silent default.
class Map {
public:
    Map(const YAML::Node &node, std::string path, const std::string &origin)
        : node_(node), path_(std::move(path)), origin_(origin)
    {
        if (!node_.IsMap()) {
            throw ScenarioError(where(node_, origin_) + ": " + path_ + ": expected a map of keys, got " + text(node_));
        }
        // Before a required key is missed: `x` where `x_m` is required says that it is renamed.
        for (const auto &entry : node_) {
            const std::string key = entry.first.as<std::string>();
            const std::string generic = pattern(key);
            for (const KeyNote &renamed : kRenamedKeys) {
                if (generic == renamed.pattern) {
                    fail(entry.first, key, std::string("this key is now called ") + renamed.note);
                }
            }
        }
    }

    // The key's path with list indices written [], as the tables above have it ("nodes[3].x_m" ->
    // "nodes[].x_m"). By hand: <regex> under GCC 12's -O1 sanitizer build warns inside libstdc++.
    std::string pattern(const std::string &key) const
    {
        const std::string path = path_ == "scenario" ? key : path_ + "." + key;
        std::string out;
        for (size_t i = 0; i < path.size(); ++i) {
            size_t end = i + 1;
            while (path[i] == '[' && end < path.size() && std::isdigit(static_cast<unsigned char>(path[end])) != 0) {
                ++end;
            }
            if (path[i] == '[' && end > i + 1 && end < path.size() && path[end] == ']') {
                out += "[]";
                i = end;
            } else {
                out += path[i];
            }
        }
        return out;
    }

    [[noreturn]] void fail(const YAML::Node &at, const std::string &key, const std::string &message) const
    {
        throw ScenarioError(where(at, origin_) + ": " + path_ + (key.empty() ? "" : "." + key) + ": " + message);
    }

    // What a key left out reads as: the .def's default, or an error for a required key.
    double defaultOf(const std::string &key)
    {
        used_.insert(key);
        const ScenarioKey &k = spec(key);
        if (!std::isnan(k.fallback)) {
            return k.fallback;
        }
        if (k.required()) {
            fail(node_, key, "missing");
        }
        throw std::logic_error("scenario.cpp reads " + pattern(key) + ", which has no default, without a fallback");
    }

    YAML::Node get(const std::string &key)
    {
        used_.insert(key);
        const YAML::Node &lookup = node_; // the const operator[] never adds the key
        return lookup[key];
    }

    bool has(const std::string &key) const
    {
        const YAML::Node &lookup = node_;
        return static_cast<bool>(lookup[key]);
    }

    // The key's entry in sim/scenario_keys.def.
    const ScenarioKey &spec(const std::string &key) const { return scenarioKey(pattern(key)); }

    // A number with the .def's default and range; a required key left out is an error. A key
    // whose default depends on other keys takes it as `fallback`.
    double number(const std::string &key) { return has(key) ? number(key, 0.0) : defaultOf(key); }

    double number(const std::string &key, double fallback)
    {
        const YAML::Node item = get(key);
        if (!item) {
            return fallback;
        }
        double value = 0.0;
        try {
            value = item.as<double>();
        } catch (const YAML::Exception &) {
            fail(item, key, "expected a number, got '" + text(item) + "'");
        }
        check(item, key, value);
        return value;
    }

    int64_t integer(const std::string &key)
    {
        return has(key) ? integer(key, 0) : static_cast<int64_t>(defaultOf(key));
    }

    int64_t integer(const std::string &key, int64_t fallback)
    {
        const YAML::Node item = get(key);
        if (!item) {
            return fallback;
        }
        return integerOf(item, key);
    }

    int64_t integerOf(const YAML::Node &item, const std::string &key) const
    {
        int64_t value = 0;
        try {
            value = item.as<int64_t>(); // decimal or 0x hex
        } catch (const YAML::Exception &) {
            fail(item, key, "expected an integer (decimal or 0x hex), got '" + text(item) + "'");
        }
        check(item, key, static_cast<double>(value));
        return value;
    }

    // A value outside the .def's range, in the words cdro-sim uses.
    void check(const YAML::Node &item, const std::string &key, double value) const
    {
        const ScenarioKey &k = spec(key);
        if (!k.admits(value)) {
            fail(item, key, "must be " + k.requirement() + ", got " + text(item));
        }
    }

    // A key whose need depends on other keys (a power_off's node and duration_s): the key, if given.
    const std::string &require(const std::string &key) const
    {
        if (!has(key)) {
            fail(node_, key, "missing");
        }
        return key;
    }

    // A list's number of entries, against the .def's range.
    void count(const YAML::Node &list, const std::string &key) const
    {
        const ScenarioKey &k = spec(key);
        if (!k.admits(static_cast<double>(list.size()))) {
            fail(list, key,
                 "the number of entries must be " + k.requirement() + ", got " + std::to_string(list.size()));
        }
    }

    bool boolean(const std::string &key)
    {
        const YAML::Node item = get(key);
        if (!item) {
            return spec(key).default_text == "true";
        }
        try {
            return item.as<bool>();
        } catch (const YAML::Exception &) {
            fail(item, key, "expected true or false, got '" + text(item) + "'");
        }
    }

    std::string string(const std::string &key, const std::string &fallback)
    {
        const YAML::Node item = get(key);
        if (!item) {
            return fallback;
        }
        if (!item.IsScalar()) {
            fail(item, key, "expected a string");
        }
        return item.Scalar();
    }

    void finish() const
    {
        for (const auto &entry : node_) {
            const std::string key = entry.first.as<std::string>();
            if (used_.count(key) == 0) {
                const std::string generic = pattern(key);
                // A key only cdro-sim acts on (sim/scenario_keys.def): refused with its meaning.
                for (const ScenarioKey &k : scenario_keys::kKeys) {
                    if (generic == k.path && k.tool == scenario_keys::Tool::SIM) {
                        fail(entry.first, key,
                             "only cdro-sim supports this key (" + std::string(k.meaning) +
                                 "); cdro-fil cannot act on it");
                    }
                }
                std::string known;
                for (const std::string &k : used_) {
                    known += (known.empty() ? "" : ", ") + k;
                }
                fail(entry.first, key, "unknown key (known here: " + known + ")");
            }
        }
    }

    const YAML::Node &node() const { return node_; }
    const std::string &path() const { return path_; }

private:
    YAML::Node node_;
    std::string path_;
    const std::string &origin_;
    std::set<std::string> used_;
};

// An id key: its range (1..0xFFFE) is the .def's.
uint16_t nodeId(Map &map, const std::string &key) { return static_cast<uint16_t>(map.integer(key)); }

std::vector<Vec3> waypoints(Map &map, const std::string &key, double default_z_m)
{
    const YAML::Node list = map.get(key);
    if (!list || !list.IsSequence() || list.size() == 0) {
        map.fail(list ? list : map.node(), key, "expected a non-empty list of [x, y] or [x, y, z] points in metres");
    }
    std::vector<Vec3> points;
    for (const YAML::Node &point : list) {
        if (!point.IsSequence() || point.size() < 2 || point.size() > 3) {
            map.fail(point, key, "each waypoint is [x, y] or [x, y, z] in metres, got " + text(point));
        }
        double v[3] = {0.0, 0.0, default_z_m};
        for (size_t i = 0; i < point.size(); ++i) {
            try {
                v[i] = point[i].as<double>();
            } catch (const YAML::Exception &) {
                map.fail(point[i], key, "waypoint coordinate '" + text(point[i]) + "' is not a number");
            }
            if (!std::isfinite(v[i]) || !map.spec(key).admits(v[i])) {
                map.fail(point[i], key,
                         "each coordinate must be " + map.spec(key).requirement() + ", got " + text(point[i]));
            }
        }
        points.push_back({v[0], v[1], v[2]});
    }
    return points;
}

double pathLength(const Vec3 &from, const std::vector<Vec3> &points)
{
    double length_m = 0.0;
    Vec3 at = from;
    for (const Vec3 &p : points) {
        length_m += std::sqrt((p.x_m - at.x_m) * (p.x_m - at.x_m) + (p.y_m - at.y_m) * (p.y_m - at.y_m) +
                              (p.z_m - at.z_m) * (p.z_m - at.z_m));
        at = p;
    }
    return length_m;
}

} // namespace

const char *faultKindName(FaultKind kind) { return kFaultNames[static_cast<int>(kind)]; }

bool ScenarioKey::admits(double value) const
{
    using scenario_keys::Bounds;
    const bool open_min = bounds == Bounds::OPEN_MIN || bounds == Bounds::OPEN;
    const bool open_max = bounds == Bounds::OPEN_MAX || bounds == Bounds::OPEN;
    return std::isfinite(value) && (open_min ? value > minimum : value >= minimum) &&
           (open_max ? value < maximum : value <= maximum);
}

std::string ScenarioKey::requirement() const
{
    using scenario_keys::Bounds;
    const bool open_min = bounds == Bounds::OPEN_MIN || bounds == Bounds::OPEN;
    const bool open_max = bounds == Bounds::OPEN_MAX || bounds == Bounds::OPEN;
    const std::string low(minimum_text);
    const std::string high(maximum_text);
    const std::string in_unit = unit.empty() ? "" : " " + std::string(unit);
    if (low != "-INF" && high != "INF") {
        return "in " + std::string(open_min ? "(" : "[") + low + ", " + high + (open_max ? ")" : "]") + in_unit;
    }
    if (low != "-INF") {
        return std::string(open_min ? "above " : "at least ") + low + in_unit;
    }
    if (high != "INF") {
        return std::string(open_max ? "below " : "at most ") + high + in_unit;
    }
    return "a finite number";
}

const NodeSpec *Scenario::node(uint16_t id) const
{
    for (const NodeSpec &n : nodes) {
        if (n.id == id) {
            return &n;
        }
    }
    return nullptr;
}

Scenario parseScenario(const std::string &yaml_text, const std::string &origin)
{
    YAML::Node root;
    try {
        root = YAML::Load(yaml_text);
    } catch (const YAML::Exception &error) {
        throw ScenarioError(origin + ": not valid YAML: " + error.what());
    }
    if (!root || root.IsNull()) {
        throw ScenarioError(origin + ": empty scenario");
    }
    Scenario s;
    s.source = origin;
    Map top(root, "scenario", origin);
    s.name = top.string("name", std::filesystem::path(origin).stem().string());
    s.description = top.string("description", "");
    s.seed = static_cast<uint64_t>(top.integer("seed"));
    s.duration_s = top.number("duration_s");

    // ---- nodes
    const YAML::Node nodes = top.get("nodes");
    if (!nodes || !nodes.IsSequence()) {
        top.fail(nodes ? nodes : root, "nodes", "expected a list of nodes (the shield's and remote ones)");
    }
    top.count(nodes, "nodes");
    for (size_t i = 0; i < nodes.size(); ++i) {
        Map n(nodes[i], "nodes[" + std::to_string(i) + "]", origin);
        NodeSpec spec;
        spec.id = nodeId(n, "id");
        spec.accelerometer = n.boolean("accelerometer");
        spec.position.x_m = n.number("x_m");
        spec.position.y_m = n.number("y_m");
        spec.position.z_m = n.number("z_m");
        n.finish();
        if (s.node(spec.id) != nullptr) {
            n.fail(nodes[i], "id", "node id " + std::to_string(spec.id) + " is listed twice");
        }
        s.nodes.push_back(spec);
    }
    s.own_id = nodeId(top, "own_id");
    if (s.node(s.own_id) == nullptr) {
        top.fail(top.get("own_id"), "own_id", "node " + std::to_string(s.own_id) + " is not in nodes");
    }

    // ---- motion
    if (const YAML::Node motion = top.get("motion")) {
        if (!motion.IsSequence()) {
            top.fail(motion, "motion", "expected a list of carried stretches");
        }
        for (size_t i = 0; i < motion.size(); ++i) {
            Map m(motion[i], "motion[" + std::to_string(i) + "]", origin);
            MotionSpec spec;
            spec.node = nodeId(m, "node");
            const NodeSpec *node = s.node(spec.node);
            if (node == nullptr) {
                m.fail(m.get("node"), "node", "node " + std::to_string(spec.node) + " is not in nodes");
            }
            spec.start_s = m.number("start_s");
            if (m.has("speed_mps") == m.has("end_s")) {
                m.fail(motion[i], "", "give exactly one of speed_mps and end_s");
            }
            if (m.has("speed_mps")) {
                spec.speed_mps = m.number("speed_mps");
            } else {
                spec.end_s = m.number("end_s");
                if (spec.end_s <= spec.start_s) {
                    m.fail(m.get("end_s"), "end_s", "must be after start_s");
                }
                spec.speed_mps = 0.0; // follows from the path, below
            }
            spec.waypoints = waypoints(m, "waypoints_m", node->position.z_m);
            m.finish();
            s.motion.push_back(spec);
        }
        // Stretches of one node must not overlap: each starts where the previous one ended.
        for (const NodeSpec &node : s.nodes) {
            std::vector<size_t> mine;
            for (size_t i = 0; i < s.motion.size(); ++i) {
                if (s.motion[i].node == node.id) {
                    mine.push_back(i);
                }
            }
            std::stable_sort(mine.begin(), mine.end(),
                             [&](size_t a, size_t b) { return s.motion[a].start_s < s.motion[b].start_s; });
            Vec3 at = node.position;
            double free_s = 0.0;
            for (const size_t i : mine) {
                MotionSpec &m = s.motion[i];
                if (m.start_s < free_s) {
                    throw ScenarioError(origin + ": motion: node " + std::to_string(node.id) + " starts a stretch at " +
                                        std::to_string(m.start_s) + " s before its previous one ends at " +
                                        std::to_string(free_s) + " s");
                }
                const double length_m = pathLength(at, m.waypoints);
                if (m.speed_mps == 0.0) {
                    m.speed_mps = length_m / (m.end_s - m.start_s);
                    const ScenarioKey &speed = scenarioKey("motion[].speed_mps");
                    if (!speed.admits(m.speed_mps)) {
                        std::ostringstream message;
                        message << origin << ": motion[" << i << "].end_s: " << length_m << " m in "
                                << m.end_s - m.start_s << " s is " << m.speed_mps << " m/s; the speed must be "
                                << speed.requirement();
                        throw ScenarioError(message.str());
                    }
                } else {
                    m.end_s = m.start_s + length_m / m.speed_mps;
                }
                free_s = m.end_s;
                at = m.waypoints.back();
            }
        }
    }

    // ---- faults
    if (const YAML::Node faults = top.get("faults")) {
        if (!faults.IsSequence()) {
            top.fail(faults, "faults", "expected a list of faults");
        }
        for (size_t i = 0; i < faults.size(); ++i) {
            Map f(faults[i], "faults[" + std::to_string(i) + "]", origin);
            FaultSpec spec;
            const std::string kind = f.string("kind", "");
            if (kind == "hang") {
                f.fail(f.get("kind"), "kind",
                       "'hang' cannot be simulated here: simavr's TWI completes every byte on its own timer, so a "
                       "slave cannot hold the clock low (the native tests cover the hung bus)");
            }
            for (const char *sim_kind : kSimFaultNames) {
                if (kind == sim_kind) {
                    std::string names;
                    for (const char *name : kFaultNames) {
                        names += (names.empty() ? "" : ", ") + std::string(name);
                    }
                    f.fail(f.get("kind"), "kind",
                           "only cdro-sim supports the fault kind '" + kind +
                               "' (faults of the serial stream and of the device); cdro-fil's kinds are " + names);
                }
            }
            bool known = false;
            for (int k = 0; k < kFaultKindCount; ++k) {
                if (kind == kFaultNames[k]) {
                    spec.kind = static_cast<FaultKind>(k);
                    known = true;
                }
            }
            if (!known) {
                std::string names;
                for (const char *name : kFaultNames) {
                    names += (names.empty() ? "" : ", ") + std::string(name);
                }
                f.fail(f.has("kind") ? f.get("kind") : faults[i], "kind", "'" + kind + "' is not one of: " + names);
            }
            spec.at_s = f.number("at_s");
            if (spec.kind == FaultKind::PowerOff) {
                spec.node = nodeId(f, f.require("node"));
                if (s.node(spec.node) == nullptr) {
                    f.fail(f.get("node"), "node", "node " + std::to_string(spec.node) + " is not in nodes");
                }
                spec.duration_s = f.number(f.require("duration_s"));
                spec.count = 1;
            } else {
                spec.count = static_cast<uint32_t>(f.integer("count"));
                if (spec.kind == FaultKind::ErrorCompletion) {
                    spec.error_code = static_cast<uint8_t>(f.integer("error_code"));
                }
            }
            f.finish();
            s.faults.push_back(spec);
        }
        // Power-off windows of one node must not overlap (the second "on" would end the first).
        for (size_t i = 0; i < s.faults.size(); ++i) {
            for (size_t j = i + 1; j < s.faults.size(); ++j) {
                const FaultSpec &a = s.faults[i];
                const FaultSpec &b = s.faults[j];
                if (a.kind == FaultKind::PowerOff && b.kind == FaultKind::PowerOff && a.node == b.node &&
                    a.at_s < b.at_s + b.duration_s && b.at_s < a.at_s + a.duration_s) {
                    throw ScenarioError(origin + ": faults[" + std::to_string(i) + "] and faults[" + std::to_string(j) +
                                        "]: overlapping power_off of node " + std::to_string(a.node));
                }
            }
        }
        std::stable_sort(s.faults.begin(), s.faults.end(),
                         [](const FaultSpec &a, const FaultSpec &b) { return a.at_s < b.at_s; });
    }

    // ---- models (the Pozyx model first: the UWB timings default to its own)
    if (top.has("pozyx")) {
        Map p(top.get("pozyx"), "pozyx", origin);
        s.pozyx_who_am_i = static_cast<uint8_t>(p.integer("who_am_i"));
        s.pozyx_firmware_version = static_cast<uint8_t>(p.integer("firmware_version"));
        const std::string model = p.string("model", std::string(scenarioKey("pozyx.model").default_text));
        if (model != "realistic" && model != "ideal") {
            p.fail(p.get("model"), "model", "'" + model + "' is not one of: realistic, ideal");
        }
        s.pozyx_realistic = model == "realistic";
        p.finish();
    }
    {
        pozyx_sim_config_t model;
        if (s.pozyx_realistic) {
            pozyx_sim_config_realistic(&model);
        } else {
            pozyx_sim_config_default(&model);
        }
        s.uwb.ranging_us = model.ranging_duration_us;
        s.uwb.message_us = model.uwb_message_us;
        s.uwb.processing_us = model.remote_processing_us;
    }
    if (top.has("uwb")) {
        Map u(top.get("uwb"), "uwb", origin);
        s.uwb.noise_std_m = u.number("noise_std_m");
        s.uwb.bias_m = u.number("bias_m");
        s.uwb.max_range_m = u.number("max_range_m");
        s.uwb.ranging_us = static_cast<uint32_t>(u.integer("ranging_us", s.uwb.ranging_us));
        s.uwb.message_us = static_cast<uint32_t>(u.integer("message_us", s.uwb.message_us));
        s.uwb.processing_us = static_cast<uint32_t>(u.integer("processing_us", s.uwb.processing_us));
        u.finish();
    }
    if (top.has("accelerometer")) {
        Map a(top.get("accelerometer"), "accelerometer", origin);
        s.accel.noise_std_mg = a.number("noise_std_mg");
        s.accel.moving_amplitude_mg = a.number("moving_amplitude_mg");
        s.accel.moving_frequency_hz = a.number("moving_frequency_hz");
        a.finish();
    }
    top.finish();
    return s;
}

std::string sharedViewJson(const Scenario &scenario)
{
    nlohmann::ordered_json view;
    view["name"] = scenario.name;
    view["seed"] = scenario.seed;
    view["duration_s"] = scenario.duration_s;
    view["own_id"] = scenario.own_id;
    view["nodes"] = nlohmann::ordered_json::array();
    for (const NodeSpec &n : scenario.nodes) {
        view["nodes"].push_back({{"id", n.id},
                                 {"x_m", n.position.x_m},
                                 {"y_m", n.position.y_m},
                                 {"z_m", n.position.z_m},
                                 {"accelerometer", n.accelerometer}});
    }
    view["motion"] = nlohmann::ordered_json::array();
    for (const MotionSpec &m : scenario.motion) {
        nlohmann::ordered_json points = nlohmann::ordered_json::array();
        for (const Vec3 &p : m.waypoints) {
            points.push_back({p.x_m, p.y_m, p.z_m});
        }
        view["motion"].push_back({{"node", m.node},
                                  {"start_s", m.start_s},
                                  {"end_s", m.end_s},
                                  {"speed_mps", m.speed_mps},
                                  {"waypoints_m", points}});
    }
    view["uwb"] = {{"noise_std_m", scenario.uwb.noise_std_m}, {"max_range_m", scenario.uwb.max_range_m}};
    view["accelerometer"] = {{"noise_std_mg", scenario.accel.noise_std_mg},
                             {"moving_amplitude_mg", scenario.accel.moving_amplitude_mg},
                             {"moving_frequency_hz", scenario.accel.moving_frequency_hz}};
    view["pozyx"] = {{"firmware_version", scenario.pozyx_firmware_version}};
    return view.dump(1);
}

Scenario loadScenario(const std::string &path)
{
    std::ifstream in(path);
    if (!in) {
        throw ScenarioError(path + ": cannot open the scenario file");
    }
    std::stringstream buffer;
    buffer << in.rdbuf();
    return parseScenario(buffer.str(), path);
}

} // namespace cdro::fil
