// Test support for the firmware: the simulated Pozyx behind the driver's ops table (SimBus), a
// serial port that decodes what the firmware sends with common/'s decoder (FakeSerial), and a
// bench that runs the whole firmware against a simulated network in simulated time (Bench).
#pragma once

#include <cstdint>
#include <deque>
#include <memory>
#include <string>
#include <vector>

#include "cdro/frames.h"
#include "cdro_fw/firmware.h"
#include "cdro_fw/pozyx.h"
#include "pozyx_sim/pozyx_sim.h"

namespace fwtest {

// Seed for randomised tests: CDRO_TEST_SEED from the environment, else `fallback`; printed.
uint64_t testSeed(uint64_t fallback);

// The simulated Pozyx as the driver's I2C: each transaction's bytes go through the slave state
// machine and cost simulated time at the I2C clock (9 bits per byte plus start/stop and a fixed
// per-transaction overhead of the Wire library) plus the device's clock stretching (a stretch
// reaching Wire's timeout is a timeout); delay_ms advances simulated time.
class SimBus {
public:
    explicit SimBus(pozyx_sim_t *sim, uint32_t i2c_clock_hz = CDRO_FW_I2C_CLOCK_HZ, uint32_t overhead_ns = 20000);

    const cdro_pozyx_ops_t *ops() const { return &ops_; }
    void *user() { return this; }

    uint64_t nowUs() const { return now_ns_ / 1000U; }
    uint32_t nowMs() const { return static_cast<uint32_t>(now_ns_ / 1000000U); }
    void advanceNs(uint64_t ns);
    void advanceUs(uint64_t us) { advanceNs(us * 1000U); }
    void advanceToUs(uint64_t us);

    uint32_t writes = 0;                             // i2c_write calls
    uint32_t reads = 0;                              // i2c_read calls
    uint32_t delays = 0;                             // delay_ms calls
    uint32_t longestWrite = 0;                       // bytes in one i2c_write
    uint32_t longestRead = 0;                        // bytes in one i2c_read
    uint32_t hangTimeoutUs = CDRO_FW_I2C_TIMEOUT_US; // what Wire's timeout costs when the device hangs
    uint32_t recoveries = 0;                         // bus_recover calls (the bus clear after a timeout)
    uint32_t recoveryUs = 100;                       // what a bus clear costs: 9 clocks and a STOP at 100 kHz

private:
    static cdro_i2c_result_t write(void *user, uint8_t address, const uint8_t *data, uint8_t length, uint8_t stop);
    static cdro_i2c_result_t read(void *user, uint8_t address, uint8_t *data, uint8_t length);
    static void delayMs(void *user, uint16_t ms);
    static uint32_t msNow(void *user);
    static uint32_t usNow(void *user);
    static void busRecover(void *user);
    void byteTime(uint32_t bytes);

    pozyx_sim_t *sim_;
    uint64_t now_ns_ = 0;
    uint32_t ns_per_bit_;
    uint32_t overhead_ns_;
    cdro_pozyx_ops_t ops_;
};

struct ReceivedFrame {
    cdro_frame_t frame;
    uint64_t atUs; // when its delimiter was written
};

// The serial port: a UART transmit buffer of `capacity` bytes drained at the baud rate in
// simulated time (or not at all, to force drops), whose bytes a host-side cdro_decoder_t
// turns into frames; and a receive queue the test fills with host frames.
class FakeSerial {
public:
    FakeSerial(const SimBus *clock, uint16_t capacity = 127, uint32_t baud = 115200);

    const cdro_serial_ops_t *ops() const { return &ops_; }
    void *user() { return this; }

    void setDraining(bool draining) { draining_ = draining; }
    // Host to device.
    void hostSend(cdro_frame_t frame);
    void hostSendBytes(const std::vector<uint8_t> &bytes);
    uint16_t hostSequence = 100;

    std::vector<uint8_t> wire;         // every byte the firmware wrote
    std::vector<ReceivedFrame> frames; // decoded by the host-side decoder
    cdro_decoder_t decoder;            // host side; counters checked by tests
    size_t rxPending() const { return rx_.size(); }

    std::vector<cdro_frame_t> ofType(uint8_t type, size_t from = 0) const;
    size_t count(uint8_t type, size_t from = 0) const { return ofType(type, from).size(); }

private:
    static uint16_t txFree(void *user);
    static void txWrite(void *user, const uint8_t *data, uint8_t length);
    static int16_t rxRead(void *user);
    void drain();

    const SimBus *clock_;
    uint16_t capacity_;
    uint64_t ns_per_byte_;
    bool draining_ = true;
    uint64_t drained_until_ns_ = 0;
    uint32_t pending_ = 0;
    std::deque<uint8_t> rx_;
    cdro_serial_ops_t ops_;
};

// A node of the simulated network, with an optional motion trace.
struct NodeSpec {
    uint16_t id;
    bool tag;
    double x, y, z; // m
};

// Which behaviour of the simulated Pozyx: the real device's (pozyx_sim_config_realistic, the
// default of the firmware's tests) or the ideal model (pozyx_sim_config_default).
enum class Model { Realistic, Ideal };

// The firmware against a simulated Pozyx network, in simulated time.
class Bench {
    std::unique_ptr<pozyx_sim_t> sim_; // first: the members below are built on it

public:
    explicit Bench(uint64_t seed, const std::vector<NodeSpec> &nodes, bool local_tag = true, uint16_t local_id = 0x6000,
                   Model model = Model::Realistic);

    pozyx_sim_t *sim() { return sim_.get(); }
    SimBus bus;
    FakeSerial serial;
    cdro_fw_t fw;

    // One firmware step at the current time; then the loop's own overhead (50 us) passes.
    // Returns the step's duration in simulated us (what longest_loop_us measures).
    uint64_t step();
    // Steps until simulated time reaches end_us, sleeping until the time each step asks for.
    void runUntilUs(uint64_t end_us);
    void runForMs(uint32_t ms) { runUntilUs(bus.nowUs() + static_cast<uint64_t>(ms) * 1000U); }
    // Boot (HELLO, discovery) and then run until the frames stop changing for a step.
    void boot();
    // Sends a command and runs until it has been answered (or 2 s passed).
    void command(cdro_frame_t frame);

    uint64_t longestStepUs = 0; // over all steps so far
    uint32_t steps = 0;
};

cdro_frame_t makeFrame(uint8_t type);
cdro_frame_t setNodes(const std::vector<uint16_t> &ids);
cdro_frame_t setSchedule(uint16_t slot_period_ms, uint8_t mode, uint16_t motion_poll_ms, uint8_t boost,
                         uint16_t status_period_ms, uint8_t max_retries);

} // namespace fwtest
