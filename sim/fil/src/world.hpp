// world.hpp: the firmware-in-the-loop harness around the simulated Pozyx network of a run. It
// owns the simulated Pozyx (cdro_pozyx_sim) set up from a Scenario: the local device first, then
// the remote nodes, each moving along its host/netgen track (cdro/netgen/track.hpp: where a node
// is and what its accelerometer reads; this file only wires the tracks to the simulator). It
// applies the scenario's faults at their times, accounts for every ranging the simulator
// performs (by kind and pair, with the true distance at that moment) and for every fault it
// actually injected, and writes the truth files.
//
// Time is simulated microseconds since the AVR started, supplied by the caller (the simavr
// board), and only moves forward.
#pragma once

#include <array>
#include <cstdio>
#include <deque>
#include <map>
#include <memory>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "cdro/netgen/track.hpp"
#include "pozyx_sim/pozyx_sim.h"
#include "scenario.hpp"

namespace cdro::fil {

// A node's track as the scenario gives it: where it stands, its motion[] stretches, the gait of
// the accelerometer section.
netgen::Track trackOf(const NodeSpec &node, const std::vector<MotionSpec> &motion, const AccelSpec &accel);

struct RangingRecord {
    uint64_t at_us;
    bool remote;      // ranged by a remote node (remote-to-remote), else by the local device
    uint16_t from_id; // the ranging node
    uint16_t to_id;
    uint32_t distance_mm;
    double true_distance_m;
    bool garbage;
};

class World {
public:
    explicit World(const Scenario &scenario);
    ~World();
    World(const World &) = delete;
    World &operator=(const World &) = delete;

    pozyx_sim_t *sim() { return sim_.get(); }
    const Scenario &scenario() const { return scenario_; }

    // Bus events, in bus order; each first brings the network to now_us.
    pozyx_sim_bus_t i2cStart(uint8_t address7, bool read, uint64_t now_us);
    pozyx_sim_bus_t i2cWrite(uint8_t byte, uint64_t now_us);
    uint8_t i2cRead(bool master_ack, uint64_t now_us);
    void i2cStop(uint64_t now_us);

    // Applies the faults due, completes what the simulator has due, accounts for rangings and
    // injected faults, writes truth samples. Cheap when nothing is due.
    void advance(uint64_t now_us);
    // The earliest time something happens without a bus event (UINT64_MAX if never).
    uint64_t nextDueUs() const;

    // Optional outputs (the files stay owned by the caller).
    void setTruthCsv(std::FILE *file, uint64_t period_us);
    void setRangesCsv(std::FILE *file);

    // Counters and per-kind tallies for the run's summary.
    void report(nlohmann::ordered_json &out, double simulated_s) const;

    uint64_t rangingsDirect() const { return rangings_direct_; }
    uint64_t rangingsRemote() const { return rangings_remote_; }
    uint64_t rangingsGarbage() const { return rangings_garbage_; }
    uint64_t rangingsStale() const { return rangings_stale_; }
    uint64_t injected(FaultKind kind) const { return injected_[static_cast<size_t>(kind)]; }

private:
    struct FaultState {
        FaultSpec spec;
        bool armed = false;
        bool ended = false; // power_off: power is back
        uint32_t injected = 0;
        double first_s = -1.0, last_s = -1.0; // s: when it was first / last injected
    };
    uint32_t *counterOf(FaultKind kind);
    void applyFaultsDue(uint64_t now_us);
    void accountFaults(uint64_t now_us);
    void accountRangings(uint64_t now_us, uint32_t rangings_before);
    void writeTruth(uint64_t now_us);

    Scenario scenario_;
    std::unique_ptr<pozyx_sim_t> sim_;
    std::vector<std::unique_ptr<netgen::Track>> tracks_; // by sim node index

    // Shadow of each node's stored range entries, to see which one a ranging changed.
    std::vector<std::vector<pozyx_sim_range_entry_t>> shadow_;

    std::vector<FaultState> faults_;
    size_t next_fault_ = 0;                                   // into faults_ (sorted by at_s)
    std::vector<std::pair<uint64_t, size_t>> power_on_due_;   // (time, fault index)
    std::array<std::deque<size_t>, kFaultKindCount> pending_; // armed counted faults, FIFO
    std::array<uint32_t, kFaultKindCount> last_counter_{};    // sim->faults counters seen last
    std::array<uint64_t, kFaultKindCount> injected_{};
    std::array<uint64_t, kFaultKindCount> armed_{};

    uint64_t rangings_direct_ = 0, rangings_remote_ = 0, rangings_garbage_ = 0, rangings_stale_ = 0;
    std::map<std::pair<uint16_t, uint16_t>, uint64_t> per_pair_;
    double worst_range_error_m_ = 0.0; // |measured - true| over the non-garbage rangings

    std::FILE *truth_ = nullptr;
    uint64_t truth_period_us_ = 0;
    uint64_t next_truth_us_ = 0;
    std::FILE *ranges_csv_ = nullptr;
    uint64_t now_us_ = 0;
};

} // namespace cdro::fil
