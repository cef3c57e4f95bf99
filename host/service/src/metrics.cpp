#include "cdro/service/metrics.hpp"

#include <map>
#include <sstream>

#include <nlohmann/json.hpp>

#include "cdro/frames.h"
#include "cdro/service/counters.hpp"
#include "cdro/service/map_state.hpp"
#include "cdro/service/version.hpp"
#include "cdro/sog_layout.h"

namespace cdro::service {

namespace {

// HELP text escapes a backslash and a newline; label values also a double quote.
std::string escape(const std::string &text, bool label)
{
    std::string out;
    for (char c : text) {
        if (c == '\\') {
            out += "\\\\";
        } else if (c == '\n') {
            out += "\\n";
        } else if (label && c == '"') {
            out += "\\\"";
        } else {
            out += c;
        }
    }
    return out;
}

void family(std::ostringstream &out, const std::string &name, const char *type, const std::string &help)
{
    out << "# HELP " << name << ' ' << escape(help, false) << '\n' << "# TYPE " << name << ' ' << type << '\n';
}

std::string number(const nlohmann::json &value)
{
    if (value.is_number_unsigned()) {
        return std::to_string(value.get<uint64_t>());
    }
    if (value.is_number_integer()) {
        return std::to_string(value.get<int64_t>());
    }
    if (value.is_number()) {
        return nlohmann::json(value.get<double>()).dump(); // shortest round-trip text
    }
    return "NaN";
}

// A member's text, "" when absent or not a string (get_ref: no conversion that GCC's
// -Wnull-dereference misreads).
std::string textAt(const nlohmann::json &object, const char *key)
{
    const auto it = object.find(key);
    return it != object.end() && it->is_string() ? it->get_ref<const std::string &>() : std::string();
}

const nlohmann::json &objectAt(const nlohmann::json &object, const char *key)
{
    static const nlohmann::json empty = nlohmann::json::object();
    const auto it = object.find(key);
    return it != object.end() && it->is_object() ? *it : empty;
}

} // namespace

std::string prometheusText(const std::shared_ptr<const std::string> &map_json,
                           const std::shared_ptr<const std::string> &health_json)
{
    std::ostringstream out;
    char hash[16];
    family(out, "cdro_build_info", "gauge", "cdro-hostd's version, protocol version and layout hashes (always 1)");
    out << "cdro_build_info{version=\"" << escape(releaseVersion(), true) << "\",protocol=\"" << CDRO_PROTOCOL_VERSION
        << "\",frame_layout=\"";
    std::snprintf(hash, sizeof hash, "0x%04X", static_cast<unsigned>(CDRO_LAYOUT_HASH));
    out << hash << "\",checkpoint_layout=\"";
    std::snprintf(hash, sizeof hash, "0x%04X", static_cast<unsigned>(CDRO_SOG_LAYOUT_HASH));
    out << hash << "\"} 1\n";
    if (!health_json) {
        return out.str();
    }
    const nlohmann::json health = nlohmann::json::parse(*health_json, nullptr, false);
    if (health.is_discarded() || !health.is_object()) {
        return out.str();
    }

    family(out, "cdro_link_state", "gauge", "1 for the state of the link to the device, 0 for the others");
    const std::string link = textAt(health, "link");
    for (LinkState state : {LinkState::Disconnected, LinkState::Handshaking, LinkState::Connected,
                            LinkState::Incompatible, LinkState::Replay}) {
        const std::string name = linkStateName(state);
        out << "cdro_link_state{state=\"" << escape(name, true) << "\"} " << (name == link ? 1 : 0) << '\n';
    }

    const nlohmann::json &counters = objectAt(health, "counters");
#define CDRO_X_COUNTER_METRIC(name, doc)                                   \
    if (counters.contains(#name)) {                                        \
        family(out, "cdro_" #name "_total", "counter", doc);               \
        out << "cdro_" #name "_total " << number(counters[#name]) << '\n'; \
    }
    CDRO_SERVICE_COUNTERS(CDRO_X_COUNTER_METRIC)
#undef CDRO_X_COUNTER_METRIC

    const nlohmann::json &rates = objectAt(health, "rates");
    const struct {
        const char *json;
        const char *metric;
        const char *help;
    } rate_names[] = {
        {"frames_per_s", "cdro_frames_per_second", "good frames per second over the last seconds of event time"},
        {"ranges_per_s", "cdro_ranges_per_second", "RANGE frames delivered per second over the last seconds"},
        {"rejects_per_s", "cdro_rejects_per_second", "rejected chunks per second over the last seconds"},
        {"bytes_per_s", "cdro_received_bytes_per_second", "bytes received per second over the last seconds"},
    };
    for (const auto &rate : rate_names) {
        if (rates.contains(rate.json)) {
            family(out, rate.metric, "gauge", rate.help);
            out << rate.metric << ' ' << number(rates[rate.json]) << '\n';
        }
    }
    if (health.contains("t_s")) {
        family(out, "cdro_run_time_seconds", "gauge", "seconds of event time since the run started (the outputs' t_s)");
        out << "cdro_run_time_seconds " << number(health["t_s"]) << '\n';
    }

    if (map_json) {
        const nlohmann::json map = nlohmann::json::parse(*map_json, nullptr, false);
        if (!map.is_discarded() && map.is_object() && map.contains("nodes") && map["nodes"].is_array()) {
            std::map<std::string, uint64_t> by_status = {
                {"unplaced", 0}, {"placed", 0}, {"converged", 0}, {"moving", 0}, {"settling", 0}};
            for (const nlohmann::json &node : map["nodes"]) {
                if (node.is_object()) {
                    const std::string status = textAt(node, "status");
                    ++by_status[status.empty() ? "unknown" : status];
                }
            }
            family(out, "cdro_nodes", "gauge", "nodes of the map by status (docs/outputs.md)");
            for (const auto &[status, count] : by_status) {
                out << "cdro_nodes{status=\"" << escape(status, true) << "\"} " << count << '\n';
            }
        }
    }
    return out.str();
}

} // namespace cdro::service
