// scenario.hpp: what a firmware-in-the-loop run simulates around the Uno: the Pozyx nodes
// (the local one on the shield and the remote ones), their geometry, which of them are carried
// along a path and when, the faults to inject, the UWB and accelerometer models and the seed.
// Read from a YAML file, strictly: an unknown key, a wrong type or an impossible value is an
// error naming the file, the line and the key. The format is the one cdro-sim reads
// (docs/tools.md, "Scenario files"): a key only cdro-sim can act on is refused with a message
// saying so, an earlier spelling with its current name.
#pragma once

#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

#include "scenario_keys.hpp"

namespace cdro::fil {

class ScenarioError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

struct Vec3 {
    double x_m = 0.0;
    double y_m = 0.0;
    double z_m = 0.0;
};

struct NodeSpec {
    uint16_t id = 0;
    bool accelerometer = false; // a tag has one; an anchor does not
    Vec3 position;              // where it stands at t = 0
};

// One carried stretch: from where the node is at start_s, through the waypoints at a constant
// speed; it then stays at the last waypoint. Waypoints without z keep the node's height. The
// file gives the speed or the end time; the other follows from the path's length.
struct MotionSpec {
    uint16_t node = 0;
    double start_s = 0.0;
    double speed_mps = 1.0;
    double end_s = 0.0;
    std::vector<Vec3> waypoints;
};

enum class FaultKind {
    NackAddress,     // the next `count` I2C address phases are NACKed
    NackWrite,       // the next `count` written bytes are NACKed
    NoCompletion,    // the next `count` long Pozyx operations never complete
    ErrorCompletion, // the next `count` complete with ERR and `error_code`
    GarbageRange,    // the next `count` rangings store 167772160 mm
    StaleRange,      // the next `count` rangings report success but store nothing new
    DropRemoteReply, // the next `count` replies to remote requests are lost
    RefuseFunction,  // the next `count` function calls return 0
    LateReply,       // the next `count` replies / result messages arrive 400 ms late
    PowerOff,        // `node` is off (silent on UWB; the local one also on I2C) for duration_s
};

constexpr int kFaultKindCount = 10;

const char *faultKindName(FaultKind kind);

struct FaultSpec {
    FaultKind kind = FaultKind::NackAddress;
    double at_s = 0.0;
    uint32_t count = static_cast<uint32_t>(scenarioDefault("faults[].count")); // counted faults
    // error_completion: the Pozyx ERRORCODE (POZYX_ERROR_RANGING)
    uint8_t error_code = static_cast<uint8_t>(scenarioDefault("faults[].error_code"));
    uint16_t node = 0;       // power_off
    double duration_s = 0.0; // power_off
};

// The defaults are sim/scenario_keys.def's. The timings default to those of the Pozyx model in
// use (pozyx.model): realistic 40000 / 3500 / 1000 us, ideal 15000 / 3000 / 1000 us.
struct UwbSpec {
    double noise_std_m = scenarioDefault("uwb.noise_std_m"); // Gaussian noise of each distance
    double bias_m = scenarioDefault("uwb.bias_m");           // added to every distance
    double max_range_m = scenarioDefault("uwb.max_range_m"); // longer links fail
    uint32_t ranging_us = 40000;                             // one two-way ranging exchange
    uint32_t message_us = 3500;                              // one UWB message on air, turnaround included
    uint32_t processing_us = 1000;                           // a remote node's handling of a request
};

struct AccelSpec {
    double noise_std_mg = scenarioDefault("accelerometer.noise_std_mg");               // per axis
    double moving_amplitude_mg = scenarioDefault("accelerometer.moving_amplitude_mg"); // a carried node's bounce
    double moving_frequency_hz = scenarioDefault("accelerometer.moving_frequency_hz"); // step frequency
};

struct Scenario {
    std::string source; // file it came from, for messages
    std::string name;   // default: the file's name without its extension, as cdro-sim's
    std::string description;
    uint64_t seed = static_cast<uint64_t>(scenarioDefault("seed"));
    double duration_s = scenarioDefault("duration_s"); // simulated seconds; 0 = until SIGTERM/SIGINT
    uint16_t own_id = 0;                               // the Pozyx on the shield (the I2C device); one of `nodes`
    std::vector<NodeSpec> nodes;
    std::vector<MotionSpec> motion;
    std::vector<FaultSpec> faults;
    UwbSpec uwb;
    AccelSpec accel;
    uint8_t pozyx_who_am_i = static_cast<uint8_t>(scenarioDefault("pozyx.who_am_i")); // else: POZYX_ABSENT
    uint8_t pozyx_firmware_version = static_cast<uint8_t>(scenarioDefault("pozyx.firmware_version"));
    // The real device's behaviour (pozyx_sim_config_realistic: replies that raise RX_DATA with
    // FUNC, busy nodes, collisions, boot time, the real timings) or the ideal model.
    bool pozyx_realistic = true;

    const NodeSpec *node(uint16_t id) const;
};

// Reads and checks a scenario file; throws ScenarioError with file:line: key: problem.
Scenario loadScenario(const std::string &path);
// The same from YAML text (`origin` names it in messages); for the tests.
Scenario parseScenario(const std::string &yaml_text, const std::string &origin);

// What cdro-fil and cdro-sim both read from a scenario, as JSON (cdro-fil --print-scenario; the
// same as cdro-sim --print-scenario for a file both load): name, seed, duration_s, own_id, the
// nodes, the motion stretches with both speed and end, uwb noise and range, the accelerometer,
// the Pozyx firmware version.
std::string sharedViewJson(const Scenario &scenario);

} // namespace cdro::fil
