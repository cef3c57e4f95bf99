#include "support.hpp"

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <stdexcept>

namespace fwtest {

uint64_t testSeed(uint64_t fallback)
{
    uint64_t seed = fallback;
    if (const char *env = std::getenv("CDRO_TEST_SEED")) {
        seed = std::strtoull(env, nullptr, 0);
    }
    std::printf("seed %llu (set CDRO_TEST_SEED to replay)\n", static_cast<unsigned long long>(seed));
    return seed;
}

// ---- SimBus ------------------------------------------------------------------------------

SimBus::SimBus(pozyx_sim_t *sim, uint32_t i2c_clock_hz, uint32_t overhead_ns)
    : sim_(sim), ns_per_bit_(1000000000U / i2c_clock_hz), overhead_ns_(overhead_ns)
{
    ops_.i2c_write = &SimBus::write;
    ops_.i2c_read = &SimBus::read;
    ops_.delay_ms = &SimBus::delayMs;
    ops_.now_ms = &SimBus::msNow;
    ops_.now_us = &SimBus::usNow;
    ops_.bus_recover = &SimBus::busRecover;
}

void SimBus::advanceNs(uint64_t ns)
{
    now_ns_ += ns;
    pozyx_sim_advance(sim_, now_ns_ / 1000U);
}

void SimBus::advanceToUs(uint64_t us)
{
    if (us * 1000U > now_ns_) {
        advanceNs(us * 1000U - now_ns_);
    }
}

void SimBus::byteTime(uint32_t bytes)
{
    // address byte + data bytes, 9 clocks each, plus start and stop, plus the library overhead
    advanceNs(static_cast<uint64_t>(ns_per_bit_) * (9U * (bytes + 1U) + 2U) + overhead_ns_);
}

cdro_i2c_result_t SimBus::write(void *user, uint8_t address, const uint8_t *data, uint8_t length, uint8_t stop)
{
    auto *self = static_cast<SimBus *>(user);
    ++self->writes;
    if (length > self->longestWrite) {
        self->longestWrite = length;
    }
    if (length > 32U) {
        return CDRO_I2C_ERROR; // what Wire does with more than its buffer
    }
    pozyx_sim_bus_t r = pozyx_sim_i2c_start(self->sim_, address, 0);
    cdro_i2c_result_t result = CDRO_I2C_OK;
    if (r == POZYX_SIM_NACK) {
        result = CDRO_I2C_NACK_ADDRESS;
    }
    for (uint8_t i = 0; r == POZYX_SIM_ACK && i < length; ++i) {
        r = pozyx_sim_i2c_write(self->sim_, data[i]);
        if (r == POZYX_SIM_NACK) {
            result = CDRO_I2C_NACK_DATA;
        }
    }
    if (r == POZYX_SIM_HANG) {
        self->advanceUs(self->hangTimeoutUs);
        pozyx_sim_i2c_stop(self->sim_); // Wire resets the TWI unit; the bus is released
        return CDRO_I2C_TIMEOUT;
    }
    self->byteTime(length);
    if (result != CDRO_I2C_OK || stop) {
        pozyx_sim_i2c_stop(self->sim_); // Wire sends STOP after a NACK
    }
    return result;
}

cdro_i2c_result_t SimBus::read(void *user, uint8_t address, uint8_t *data, uint8_t length)
{
    auto *self = static_cast<SimBus *>(user);
    ++self->reads;
    if (length > self->longestRead) {
        self->longestRead = length;
    }
    if (length > 32U) {
        return CDRO_I2C_ERROR;
    }
    const pozyx_sim_bus_t r = pozyx_sim_i2c_start(self->sim_, address, 1);
    // Clock stretching: the device holds SCL before the first byte; Wire gives up at its timeout.
    const uint64_t stretch_us = r == POZYX_SIM_ACK ? self->sim_->stretch_us : 0U;
    if (r == POZYX_SIM_HANG || stretch_us >= self->hangTimeoutUs) {
        self->advanceUs(self->hangTimeoutUs);
        pozyx_sim_i2c_stop(self->sim_);
        return CDRO_I2C_TIMEOUT;
    }
    self->advanceUs(stretch_us);
    if (r == POZYX_SIM_NACK) {
        self->byteTime(0);
        pozyx_sim_i2c_stop(self->sim_);
        return CDRO_I2C_NACK_ADDRESS;
    }
    for (uint8_t i = 0; i < length; ++i) {
        data[i] = pozyx_sim_i2c_read(self->sim_, static_cast<uint8_t>(i + 1U < length));
    }
    self->byteTime(length);
    pozyx_sim_i2c_stop(self->sim_);
    return CDRO_I2C_OK;
}

void SimBus::delayMs(void *user, uint16_t ms)
{
    auto *self = static_cast<SimBus *>(user);
    ++self->delays;
    self->advanceUs(static_cast<uint64_t>(ms) * 1000U);
}

uint32_t SimBus::msNow(void *user) { return static_cast<SimBus *>(user)->nowMs(); }

void SimBus::busRecover(void *user)
{
    auto *self = static_cast<SimBus *>(user);
    ++self->recoveries;
    self->advanceUs(self->recoveryUs);
}

uint32_t SimBus::usNow(void *user) { return static_cast<uint32_t>(static_cast<SimBus *>(user)->nowUs()); }

// ---- FakeSerial ---------------------------------------------------------------------------

FakeSerial::FakeSerial(const SimBus *clock, uint16_t capacity, uint32_t baud)
    : clock_(clock), capacity_(capacity), ns_per_byte_(10ULL * 1000000000ULL / baud)
{
    cdro_decoder_init(&decoder);
    ops_.tx_free = &FakeSerial::txFree;
    ops_.tx_write = &FakeSerial::txWrite;
    ops_.rx_read = &FakeSerial::rxRead;
}

void FakeSerial::drain()
{
    const uint64_t now_ns = clock_->nowUs() * 1000U;
    if (!draining_) {
        drained_until_ns_ = now_ns;
        return;
    }
    if (pending_ == 0U) {
        drained_until_ns_ = now_ns;
        return;
    }
    const uint64_t sent = (now_ns - drained_until_ns_) / ns_per_byte_;
    if (sent >= pending_) {
        pending_ = 0;
        drained_until_ns_ = now_ns;
    } else {
        pending_ -= static_cast<uint32_t>(sent);
        drained_until_ns_ += sent * ns_per_byte_;
    }
}

uint16_t FakeSerial::txFree(void *user)
{
    auto *self = static_cast<FakeSerial *>(user);
    self->drain();
    return static_cast<uint16_t>(self->capacity_ - self->pending_);
}

void FakeSerial::txWrite(void *user, const uint8_t *data, uint8_t length)
{
    auto *self = static_cast<FakeSerial *>(user);
    self->drain();
    if (self->pending_ + length > self->capacity_) {
        throw std::logic_error("firmware wrote more than tx_free allowed");
    }
    self->pending_ += length;
    for (uint8_t i = 0; i < length; ++i) {
        self->wire.push_back(data[i]);
        cdro_frame_t frame;
        const cdro_result_t r = cdro_decoder_push(&self->decoder, data[i], &frame);
        if (r == CDRO_OK) {
            self->frames.push_back({frame, self->clock_->nowUs()});
        }
    }
}

int16_t FakeSerial::rxRead(void *user)
{
    auto *self = static_cast<FakeSerial *>(user);
    if (self->rx_.empty()) {
        return -1;
    }
    const uint8_t byte = self->rx_.front();
    self->rx_.pop_front();
    return byte;
}

void FakeSerial::hostSend(cdro_frame_t frame)
{
    frame.sequence = hostSequence++;
    uint8_t out[CDRO_MAX_ENCODED_FRAME];
    const size_t n = cdro_frame_encode(&frame, out, sizeof out);
    if (n == 0U) {
        throw std::logic_error("test frame does not encode");
    }
    rx_.insert(rx_.end(), out, out + n);
}

void FakeSerial::hostSendBytes(const std::vector<uint8_t> &bytes) { rx_.insert(rx_.end(), bytes.begin(), bytes.end()); }

std::vector<cdro_frame_t> FakeSerial::ofType(uint8_t type, size_t from) const
{
    std::vector<cdro_frame_t> out;
    for (size_t i = from; i < frames.size(); ++i) {
        if (frames[i].frame.type == type) {
            out.push_back(frames[i].frame);
        }
    }
    return out;
}

// ---- Bench ----------------------------------------------------------------------------------

static std::unique_ptr<pozyx_sim_t> makeSim(uint64_t seed, const std::vector<NodeSpec> &nodes, bool local_tag,
                                            uint16_t local_id, Model model)
{
    auto owner = std::make_unique<pozyx_sim_t>();
    pozyx_sim_config_t config;
    if (model == Model::Realistic) {
        pozyx_sim_config_realistic(&config);
    } else {
        pozyx_sim_config_default(&config);
    }
    config.seed = seed;
    pozyx_sim_init(owner.get(), &config);
    pozyx_sim_node_config_t node;
    pozyx_sim_node_config_default(&node, local_id, local_tag ? 1 : 0);
    pozyx_sim_add_node(owner.get(), &node);
    for (const NodeSpec &spec : nodes) {
        pozyx_sim_node_config_default(&node, spec.id, spec.tag ? 1 : 0);
        node.position_m = {spec.x, spec.y, spec.z};
        node.clock_offset_ms = 1000U * spec.id % 7919U; // every node has its own uptime
        if (pozyx_sim_add_node(owner.get(), &node) < 0) {
            throw std::logic_error("bad node spec");
        }
    }
    return owner;
}

Bench::Bench(uint64_t seed, const std::vector<NodeSpec> &nodes, bool local_tag, uint16_t local_id, Model model)
    : sim_(makeSim(seed, nodes, local_tag, local_id, model)), bus(sim_.get()), serial(&bus)
{
    cdro_fw_config_t config{};
    config.pozyx_ops = bus.ops();
    config.pozyx_user = bus.user();
    config.serial_ops = serial.ops();
    config.serial_user = serial.user();
    config.free_ram_bytes = [](void *) -> uint16_t { return 777; };
    config.reset_cause = CDRO_RESET_POWER_ON;
    cdro_fw_init(&fw, &config);
}

uint64_t Bench::step()
{
    const uint64_t start = bus.nowUs();
    (void)cdro_fw_step(&fw, bus.nowMs());
    const uint64_t took = bus.nowUs() - start;
    if (took > longestStepUs) {
        longestStepUs = took;
    }
    ++steps;
    bus.advanceUs(50); // the rest of loop(): the watchdog reset, the call itself
    return took;
}

void Bench::runUntilUs(uint64_t end_us)
{
    while (bus.nowUs() < end_us) {
        const uint64_t start = bus.nowUs();
        const uint32_t next_ms = cdro_fw_step(&fw, bus.nowMs());
        const uint64_t took = bus.nowUs() - start;
        if (took > longestStepUs) {
            longestStepUs = took;
        }
        ++steps;
        bus.advanceUs(50);
        // Sleep until the firmware's next time, but wake for host bytes at once.
        const uint64_t next_us = static_cast<uint64_t>(next_ms) * 1000U;
        if (serial.rxPending() == 0U && next_us > bus.nowUs()) {
            bus.advanceToUs(next_us < end_us ? next_us : end_us);
        }
    }
}

void Bench::boot()
{
    runUntilUs(bus.nowUs() + 1000000U); // 250 ms power-up wait, self-check, discovery
    if (fw.state != CDRO_FW_STATE_READY) {
        throw std::logic_error("firmware did not finish booting within 1 s");
    }
}

void Bench::command(cdro_frame_t frame)
{
    const uint16_t sequence = serial.hostSequence;
    const uint8_t type = frame.type;
    const size_t before = serial.frames.size();
    serial.hostSend(frame);
    const uint64_t deadline = bus.nowUs() + 2000000U;
    while (bus.nowUs() < deadline) {
        (void)step();
        for (size_t i = before; i < serial.frames.size(); ++i) {
            const cdro_frame_t &f = serial.frames[i].frame;
            if ((f.type == CDRO_FRAME_ACK && f.as.ack.acked_sequence == sequence) ||
                (f.type == CDRO_FRAME_NACK && f.as.nack.nacked_sequence == sequence) ||
                (type == CDRO_FRAME_HELLO_REQUEST && f.type == CDRO_FRAME_HELLO)) {
                // Let the frames that follow an answer (NODE_LIST after SET_NODES) out too.
                if (serial.rxPending() == 0U) {
                    return;
                }
            }
        }
    }
}

cdro_frame_t makeFrame(uint8_t type)
{
    cdro_frame_t frame;
    std::memset(&frame, 0, sizeof frame);
    frame.type = type;
    return frame;
}

cdro_frame_t setNodes(const std::vector<uint16_t> &ids)
{
    cdro_frame_t frame = makeFrame(CDRO_FRAME_SET_NODES);
    frame.as.set_nodes.node_ids_count = static_cast<uint8_t>(ids.size());
    for (size_t i = 0; i < ids.size(); ++i) {
        frame.as.set_nodes.node_ids[i] = ids[i];
    }
    return frame;
}

cdro_frame_t setSchedule(uint16_t slot_period_ms, uint8_t mode, uint16_t motion_poll_ms, uint8_t boost,
                         uint16_t status_period_ms, uint8_t max_retries)
{
    cdro_frame_t frame = makeFrame(CDRO_FRAME_SET_SCHEDULE);
    frame.as.set_schedule.slot_period_ms = slot_period_ms;
    frame.as.set_schedule.mode = mode;
    frame.as.set_schedule.motion_poll_ms = motion_poll_ms;
    frame.as.set_schedule.moving_boost = boost;
    frame.as.set_schedule.status_period_ms = status_period_ms;
    frame.as.set_schedule.max_retries = max_retries;
    return frame;
}

} // namespace fwtest
