#include "world.hpp"

#include <algorithm>
#include <cinttypes>
#include <cmath>
#include <cstring>
#include <limits>
#include <utility>

#include "cdro_fw/pozyx_regs.h"

namespace cdro::fil {

namespace {

uint64_t toUs(double t_s) { return static_cast<uint64_t>(std::llround(t_s * 1e6)); }

pozyx_sim_vec3_t trackPosition(void *context, double t_s)
{
    const netgen::Vector3 p = static_cast<const netgen::Track *>(context)->positionM(t_s);
    return {p.x(), p.y(), p.z()};
}

pozyx_sim_vec3_t trackAccel(void *context, double t_s)
{
    const netgen::Vector3 a = static_cast<const netgen::Track *>(context)->accelMg(t_s);
    return {a.x(), a.y(), a.z()}; // mg
}

} // namespace

netgen::Track trackOf(const NodeSpec &node, const std::vector<MotionSpec> &motion, const AccelSpec &accel)
{
    // The reader has filled in every waypoint's z and every stretch's speed (docs/tools.md,
    // "Scenario files"): the track walks exactly what --print-scenario shows.
    std::vector<netgen::Stretch> stretches;
    for (const MotionSpec &m : motion) {
        if (m.node != node.id) {
            continue;
        }
        netgen::Stretch stretch;
        stretch.start_s = m.start_s;
        stretch.speed_mps = m.speed_mps;
        stretch.end_s = m.end_s;
        for (const Vec3 &p : m.waypoints) {
            stretch.waypoints.push_back({p.x_m, p.y_m, p.z_m});
        }
        stretches.push_back(std::move(stretch));
    }
    const netgen::Vector3 start_m(node.position.x_m, node.position.y_m, node.position.z_m);
    return netgen::Track(start_m, std::move(stretches), {accel.moving_amplitude_mg, accel.moving_frequency_hz});
}

// ---- World ------------------------------------------------------------------------------------

World::World(const Scenario &scenario) : scenario_(scenario), sim_(std::make_unique<pozyx_sim_t>())
{
    pozyx_sim_config_t config;
    if (scenario_.pozyx_realistic) {
        pozyx_sim_config_realistic(&config);
    } else {
        pozyx_sim_config_default(&config);
    }
    config.seed = scenario_.seed;
    config.who_am_i = scenario_.pozyx_who_am_i;
    config.firmware_version = scenario_.pozyx_firmware_version;
    config.range_noise_std_mm = scenario_.uwb.noise_std_m * 1000.0;
    config.range_bias_mm = scenario_.uwb.bias_m * 1000.0;
    config.max_range_m = scenario_.uwb.max_range_m;
    config.ranging_duration_us = scenario_.uwb.ranging_us;
    config.uwb_message_us = scenario_.uwb.message_us;
    config.remote_processing_us = scenario_.uwb.processing_us;
    config.accel_noise_std_mg = scenario_.accel.noise_std_mg;
    pozyx_sim_init(sim_.get(), &config);

    // The local device is the first node added: the one on the I2C bus.
    std::vector<const NodeSpec *> order;
    order.push_back(scenario_.node(scenario_.own_id));
    for (const NodeSpec &n : scenario_.nodes) {
        if (n.id != scenario_.own_id) {
            order.push_back(&n);
        }
    }
    for (const NodeSpec *n : order) {
        tracks_.push_back(std::make_unique<netgen::Track>(trackOf(*n, scenario_.motion, scenario_.accel)));
        pozyx_sim_node_config_t node;
        pozyx_sim_node_config_default(&node, n->id, n->accelerometer ? 1 : 0);
        node.position_m = {n->position.x_m, n->position.y_m, n->position.z_m};
        node.position_fn = &trackPosition;
        node.position_context = tracks_.back().get();
        node.accel_fn = &trackAccel;
        node.accel_context = tracks_.back().get();
        if (pozyx_sim_add_node(sim_.get(), &node) < 0) {
            throw ScenarioError(scenario_.source + ": node " + std::to_string(n->id) + " could not be added");
        }
    }
    shadow_.resize(sim_->node_count);

    for (const FaultSpec &f : scenario_.faults) {
        FaultState state;
        state.spec = f;
        faults_.push_back(state);
    }
}

World::~World() = default;

uint32_t *World::counterOf(FaultKind kind)
{
    pozyx_sim_faults_t &f = sim_->faults;
    switch (kind) {
    case FaultKind::NackAddress: return &f.nack_address;
    case FaultKind::NackWrite: return &f.nack_write;
    case FaultKind::NoCompletion: return &f.no_completion;
    case FaultKind::ErrorCompletion: return &f.error_completion;
    case FaultKind::GarbageRange: return &f.garbage_range;
    case FaultKind::StaleRange: return &f.stale_range;
    case FaultKind::DropRemoteReply: return &f.drop_remote_reply;
    case FaultKind::RefuseFunction: return &f.refuse_function;
    case FaultKind::LateReply: return &f.late_reply;
    case FaultKind::PowerOff: return nullptr;
    }
    return nullptr;
}

void World::applyFaultsDue(uint64_t now_us)
{
    const double t_s = static_cast<double>(now_us) / 1e6;
    while (next_fault_ < faults_.size() && toUs(faults_[next_fault_].spec.at_s) <= now_us) {
        FaultState &state = faults_[next_fault_];
        const FaultKind kind = state.spec.kind;
        state.armed = true;
        armed_[static_cast<size_t>(kind)] += state.spec.count;
        if (kind == FaultKind::PowerOff) {
            pozyx_sim_find(sim_.get(), state.spec.node)->config.powered = 0;
            state.injected = 1;
            state.first_s = state.last_s = t_s;
            ++injected_[static_cast<size_t>(kind)];
            power_on_due_.emplace_back(toUs(state.spec.at_s + state.spec.duration_s), next_fault_);
        } else {
            uint32_t *counter = counterOf(kind);
            *counter += state.spec.count;
            last_counter_[static_cast<size_t>(kind)] = *counter;
            if (kind == FaultKind::ErrorCompletion) {
                sim_->faults.error_code = state.spec.error_code;
            }
            pending_[static_cast<size_t>(kind)].push_back(next_fault_);
        }
        ++next_fault_;
    }
    for (auto it = power_on_due_.begin(); it != power_on_due_.end();) {
        if (it->first <= now_us) {
            FaultState &state = faults_[it->second];
            pozyx_sim_find(sim_.get(), state.spec.node)->config.powered = 1;
            state.ended = true;
            state.last_s = t_s;
            it = power_on_due_.erase(it);
        } else {
            ++it;
        }
    }
}

// The simulator decrements a fault counter each time it injects one: what went away since the
// last look was injected now, and is attributed to the armed faults of that kind in order.
void World::accountFaults(uint64_t now_us)
{
    const double t_s = static_cast<double>(now_us) / 1e6;
    for (int k = 0; k < kFaultKindCount; ++k) {
        const auto kind = static_cast<FaultKind>(k);
        if (kind == FaultKind::PowerOff) {
            continue;
        }
        const uint32_t counter = *counterOf(kind);
        uint32_t taken = last_counter_[static_cast<size_t>(k)] - counter;
        last_counter_[static_cast<size_t>(k)] = counter;
        injected_[static_cast<size_t>(k)] += taken;
        auto &queue = pending_[static_cast<size_t>(k)];
        while (taken > 0 && !queue.empty()) {
            FaultState &state = faults_[queue.front()];
            const uint32_t now_taken = std::min(taken, state.spec.count - state.injected);
            state.injected += now_taken;
            taken -= now_taken;
            if (state.first_s < 0.0) {
                state.first_s = t_s;
            }
            state.last_s = t_s;
            if (state.injected == state.spec.count) {
                queue.pop_front();
            }
        }
    }
}

// A ranging stores (or overwrites) one entry in the ranging node's list; the entries that
// differ from the shadow copy are the rangings that just completed. A ranging that changed
// nothing was a stale one (the fault leaves the entry as it was).
void World::accountRangings(uint64_t now_us, uint32_t rangings_before)
{
    uint32_t completed = sim_->stats.rangings - rangings_before;
    if (completed == 0) {
        return;
    }
    for (uint8_t i = 0; i < sim_->node_count; ++i) {
        const pozyx_sim_node_t &node = sim_->nodes[i];
        std::vector<pozyx_sim_range_entry_t> &shadow = shadow_[i];
        for (uint8_t e = 0; e < node.range_count; ++e) {
            const pozyx_sim_range_entry_t &entry = node.ranges[e];
            const pozyx_sim_range_entry_t *old = nullptr;
            for (const pozyx_sim_range_entry_t &s : shadow) {
                if (s.partner == entry.partner) {
                    old = &s;
                }
            }
            if (old != nullptr && old->timestamp_ms == entry.timestamp_ms && old->distance_mm == entry.distance_mm) {
                continue;
            }
            RangingRecord r;
            r.at_us = now_us;
            r.remote = i != 0;
            r.from_id = node.config.id;
            r.to_id = entry.partner;
            r.distance_mm = entry.distance_mm;
            r.true_distance_m = pozyx_sim_true_distance_m(sim_.get(), r.from_id, r.to_id);
            r.garbage = entry.distance_mm == POZYX_SIM_GARBAGE_DISTANCE_MM;
            if (r.garbage) {
                ++rangings_garbage_;
            } else {
                ++(r.remote ? rangings_remote_ : rangings_direct_);
                ++per_pair_[{r.from_id, r.to_id}];
                worst_range_error_m_ =
                    std::max(worst_range_error_m_,
                             std::fabs(static_cast<double>(r.distance_mm) * 1e-3 - r.true_distance_m));
            }
            if (ranges_csv_ != nullptr) {
                std::fprintf(ranges_csv_, "%.6f,%s,%u,%u,%" PRIu32 ",%.1f,%s\n", static_cast<double>(now_us) / 1e6,
                             r.remote ? "remote" : "direct", r.from_id, r.to_id, r.distance_mm,
                             r.true_distance_m * 1000.0, r.garbage ? "garbage" : "ok");
            }
            if (completed > 0) {
                --completed;
            }
        }
        shadow.assign(node.ranges, node.ranges + node.range_count);
    }
    rangings_stale_ += completed; // completed rangings that changed no entry
}

void World::writeTruth(uint64_t now_us)
{
    while (truth_ != nullptr && now_us >= next_truth_us_) {
        const double t_s = static_cast<double>(next_truth_us_) / 1e6;
        for (uint8_t i = 0; i < sim_->node_count; ++i) {
            const netgen::Vector3 p = tracks_[i]->positionM(t_s);
            std::fprintf(truth_, "%.3f,%u,%.4f,%.4f,%.4f\n", t_s, sim_->nodes[i].config.id, p.x(), p.y(), p.z());
        }
        next_truth_us_ += truth_period_us_;
    }
}

void World::advance(uint64_t now_us)
{
    now_us_ = std::max(now_us_, now_us);
    applyFaultsDue(now_us_);
    const uint32_t rangings_before = sim_->stats.rangings;
    pozyx_sim_advance(sim_.get(), now_us_);
    accountRangings(now_us_, rangings_before);
    accountFaults(now_us_);
    writeTruth(now_us_);
}

uint64_t World::nextDueUs() const
{
    uint64_t next = pozyx_sim_next_event_us(sim_.get());
    if (next_fault_ < faults_.size()) {
        next = std::min(next, toUs(faults_[next_fault_].spec.at_s));
    }
    for (const auto &due : power_on_due_) {
        next = std::min(next, due.first);
    }
    if (truth_ != nullptr) {
        next = std::min(next, next_truth_us_);
    }
    return next;
}

pozyx_sim_bus_t World::i2cStart(uint8_t address7, bool read, uint64_t now_us)
{
    advance(now_us);
    const pozyx_sim_bus_t result = pozyx_sim_i2c_start(sim_.get(), address7, read ? 1 : 0);
    accountFaults(now_us_);
    return result;
}

pozyx_sim_bus_t World::i2cWrite(uint8_t byte, uint64_t now_us)
{
    advance(now_us);
    const pozyx_sim_bus_t result = pozyx_sim_i2c_write(sim_.get(), byte);
    accountFaults(now_us_);
    return result;
}

uint8_t World::i2cRead(bool master_ack, uint64_t now_us)
{
    advance(now_us);
    const uint8_t value = pozyx_sim_i2c_read(sim_.get(), master_ack ? 1 : 0);
    accountFaults(now_us_);
    return value;
}

void World::i2cStop(uint64_t now_us)
{
    advance(now_us);
    pozyx_sim_i2c_stop(sim_.get());
    accountFaults(now_us_); // a function executed at STOP may take a fault
}

void World::setTruthCsv(std::FILE *file, uint64_t period_us)
{
    truth_ = file;
    truth_period_us_ = std::max<uint64_t>(period_us, 1000);
    next_truth_us_ = now_us_;
    if (truth_ != nullptr) {
        std::fprintf(truth_, "t,id,x,y,z\n");
    }
}

void World::setRangesCsv(std::FILE *file)
{
    ranges_csv_ = file;
    if (ranges_csv_ != nullptr) {
        std::fprintf(ranges_csv_, "t,kind,from,to,distance_mm,true_distance_mm,result\n");
    }
}

void World::report(nlohmann::ordered_json &out, double simulated_s) const
{
    using json = nlohmann::ordered_json;
    json per_pair = json::object();
    for (const auto &[pair, count] : per_pair_) {
        char key[32];
        std::snprintf(key, sizeof key, "0x%04X-0x%04X", pair.first, pair.second);
        per_pair[key] = count;
    }
    const uint64_t good = rangings_direct_ + rangings_remote_;
    out["rangings"] = {
        {"direct", rangings_direct_},
        {"remote", rangings_remote_},
        {"garbage", rangings_garbage_},
        {"stale", rangings_stale_},
        {"per_second", simulated_s > 0.0 ? static_cast<double>(good) / simulated_s : 0.0},
        {"worst_error_m", worst_range_error_m_},
        {"per_pair", per_pair},
    };
    json injected = json::object();
    json armed = json::object();
    for (int k = 0; k < kFaultKindCount; ++k) {
        injected[faultKindName(static_cast<FaultKind>(k))] = injected_[static_cast<size_t>(k)];
        armed[faultKindName(static_cast<FaultKind>(k))] = armed_[static_cast<size_t>(k)];
    }
    out["faults_injected"] = injected;
    out["faults_armed"] = armed;
    json events = json::array();
    for (const FaultState &state : faults_) {
        json e = {{"kind", faultKindName(state.spec.kind)},
                  {"at_s", state.spec.at_s},
                  {"count", state.spec.count},
                  {"injected", state.injected},
                  {"first_injected_s", state.first_s >= 0.0 ? json(state.first_s) : json(nullptr)},
                  {"last_injected_s", state.last_s >= 0.0 ? json(state.last_s) : json(nullptr)}};
        if (state.spec.kind == FaultKind::PowerOff) {
            e["node"] = state.spec.node;
            e["duration_s"] = state.spec.duration_s;
            e["powered_again"] = state.ended;
        }
        if (state.spec.kind == FaultKind::ErrorCompletion) {
            e["error_code"] = state.spec.error_code;
        }
        events.push_back(e);
    }
    out["fault_events"] = events;
    const pozyx_sim_stats_t &st = sim_->stats;
    out["i2c"] = {
        {"transactions", st.transactions},
        {"bytes_written", st.bytes_written},
        {"bytes_read", st.bytes_read},
        {"longest_write_bytes", st.longest_write},
        {"longest_read_bytes", st.longest_read},
        {"register_reads", st.register_reads},
        {"register_writes", st.register_writes},
        {"local_do_ranging_calls", st.function_calls[POZYX_FN_DO_RANGING - 0xB0]},
        {"remote_requests", st.remote_requests},
        {"messages_delivered", st.messages_delivered},
        {"protocol_violations", st.protocol_violations},
    };
    out["pozyx_model"] = {
        {"model", scenario_.pozyx_realistic ? "realistic" : "ideal"},
        {"collisions", st.collisions},
        {"busy_losses", st.busy_losses},
        {"boot_refusals", st.boot_refusals},
        {"list_full_errors", st.list_full_errors},
    };
    // When each node was carried: back-to-back legs make one span.
    json motion = json::array();
    for (size_t i = 0; i < tracks_.size(); ++i) {
        for (const netgen::Track::Span &span : tracks_[i]->spans()) {
            motion.push_back({{"node", sim_->nodes[i].config.id},
                              {"from_s", span.from_s},
                              {"to_s", span.to_s},
                              {"length_m", span.length_m}});
        }
    }
    out["motion"] = motion;
}

} // namespace cdro::fil
