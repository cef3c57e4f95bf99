// The simulated Pozyx on its own: the I2C slave state machine, driven by raw bus events.
#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <vector>

#include "cdro_fw/pozyx_regs.h"
#include "pozyx_sim/pozyx_sim.h"

namespace {

constexpr uint8_t kAddress = 0x4B;

struct Sim {
    std::unique_ptr<pozyx_sim_t> sim = std::make_unique<pozyx_sim_t>();
    pozyx_sim_t *operator->() { return sim.get(); }
    pozyx_sim_t *get() { return sim.get(); }

    explicit Sim(uint64_t seed = 7, double noise_mm = 30.0, bool realistic = false)
    {
        pozyx_sim_config_t config;
        if (realistic) {
            pozyx_sim_config_realistic(&config);
        } else {
            pozyx_sim_config_default(&config);
        }
        config.seed = seed;
        config.range_noise_std_mm = noise_mm;
        pozyx_sim_init(sim.get(), &config);
        add(0x6000, true, 0, 0, 0);
    }
    void add(uint16_t id, bool tag, double x, double y, double z)
    {
        pozyx_sim_node_config_t node;
        pozyx_sim_node_config_default(&node, id, tag ? 1 : 0);
        node.position_m = {x, y, z};
        ASSERT_GE(pozyx_sim_add_node(sim.get(), &node), 0);
    }

    // START W reg, RS R n, STOP
    std::vector<uint8_t> readRegs(uint8_t reg, uint8_t n)
    {
        std::vector<uint8_t> out;
        EXPECT_EQ(pozyx_sim_i2c_start(get(), kAddress, 0), POZYX_SIM_ACK);
        EXPECT_EQ(pozyx_sim_i2c_write(get(), reg), POZYX_SIM_ACK);
        EXPECT_EQ(pozyx_sim_i2c_start(get(), kAddress, 1), POZYX_SIM_ACK);
        for (uint8_t i = 0; i < n; ++i) {
            out.push_back(pozyx_sim_i2c_read(get(), i + 1U < n));
        }
        pozyx_sim_i2c_stop(get());
        return out;
    }
    // START W fn params, RS R 1+n, STOP
    std::vector<uint8_t> call(uint8_t fn, const std::vector<uint8_t> &params, uint8_t n)
    {
        std::vector<uint8_t> out;
        EXPECT_EQ(pozyx_sim_i2c_start(get(), kAddress, 0), POZYX_SIM_ACK);
        EXPECT_EQ(pozyx_sim_i2c_write(get(), fn), POZYX_SIM_ACK);
        for (uint8_t p : params) {
            EXPECT_EQ(pozyx_sim_i2c_write(get(), p), POZYX_SIM_ACK);
        }
        EXPECT_EQ(pozyx_sim_i2c_start(get(), kAddress, 1), POZYX_SIM_ACK);
        for (uint8_t i = 0; i < n + 1U; ++i) {
            out.push_back(pozyx_sim_i2c_read(get(), i < n));
        }
        pozyx_sim_i2c_stop(get());
        return out;
    }
    uint8_t intStatus() { return readRegs(POZYX_REG_INT_STATUS, 1)[0]; }
    // TX_DATA(0, payload...), clear INT_STATUS, TX_SEND(dest, op): a remote request.
    void request(uint16_t dest, uint8_t op, std::vector<uint8_t> payload)
    {
        payload.insert(payload.begin(), 0);
        EXPECT_EQ(call(POZYX_FN_TX_DATA, payload, 0)[0], 1);
        (void)intStatus();
        EXPECT_EQ(call(POZYX_FN_TX_SEND, {static_cast<uint8_t>(dest & 0xFF), static_cast<uint8_t>(dest >> 8), op},
                       0)[0],
                  1);
    }
    uint64_t replyDelayUs() { return 2U * sim->config.uwb_message_us + sim->config.remote_processing_us; }
};

uint32_t u32(const std::vector<uint8_t> &v, size_t at)
{
    return static_cast<uint32_t>(v[at]) | (static_cast<uint32_t>(v[at + 1]) << 8) |
           (static_cast<uint32_t>(v[at + 2]) << 16) | (static_cast<uint32_t>(v[at + 3]) << 24);
}

TEST(PozyxSim, StatusRegistersAutoIncrement)
{
    Sim sim;
    const auto regs = sim.readRegs(POZYX_REG_WHO_AM_I, 4);
    EXPECT_EQ(regs[0], 0x43);
    EXPECT_EQ(regs[1], 0x11);
    EXPECT_EQ(regs[2] >> 5, 1) << "the local node is a tag";
    EXPECT_EQ(regs[3], 0x3F);
    const auto id = sim.readRegs(POZYX_REG_NETWORK_ID, 2);
    EXPECT_EQ(id[0] | (id[1] << 8), 0x6000);
    EXPECT_EQ(sim->stats.protocol_violations, 0U);
}

TEST(PozyxSim, WrongAddressAndUnpoweredDeviceAreNacked)
{
    Sim sim;
    EXPECT_EQ(pozyx_sim_i2c_start(sim.get(), 0x4A, 0), POZYX_SIM_NACK);
    pozyx_sim_i2c_stop(sim.get());
    pozyx_sim_find(sim.get(), 0x6000)->config.powered = 0;
    EXPECT_EQ(pozyx_sim_i2c_start(sim.get(), kAddress, 0), POZYX_SIM_NACK);
    pozyx_sim_i2c_stop(sim.get());
}

TEST(PozyxSim, IntStatusAndErrorCodeClearOnRead)
{
    Sim sim;
    // LED_CTRL without its parameter raises ERR with "invalid function parameters".
    EXPECT_EQ(sim.call(POZYX_FN_LED_CTRL, {}, 0)[0], 0);
    EXPECT_EQ(sim.intStatus() & POZYX_INT_ERR, POZYX_INT_ERR);
    EXPECT_EQ(sim.intStatus() & POZYX_INT_ERR, 0);
    EXPECT_EQ(sim.readRegs(POZYX_REG_ERRORCODE, 1)[0], POZYX_ERROR_FUNC_PARAMS);
    EXPECT_EQ(sim.readRegs(POZYX_REG_ERRORCODE, 1)[0], 0);
}

TEST(PozyxSim, RegisterWriteOnlyInTheDocumentedForm)
{
    Sim sim;
    // Documented: START W reg, RS W data, STOP.
    ASSERT_EQ(pozyx_sim_i2c_start(sim.get(), kAddress, 0), POZYX_SIM_ACK);
    ASSERT_EQ(pozyx_sim_i2c_write(sim.get(), POZYX_REG_INT_MASK), POZYX_SIM_ACK);
    ASSERT_EQ(pozyx_sim_i2c_start(sim.get(), kAddress, 0), POZYX_SIM_ACK);
    ASSERT_EQ(pozyx_sim_i2c_write(sim.get(), 0x1F), POZYX_SIM_ACK);
    pozyx_sim_i2c_stop(sim.get());
    EXPECT_EQ(sim.readRegs(POZYX_REG_INT_MASK, 1)[0], 0x1F);
    EXPECT_EQ(sim->stats.register_writes, 1U);
    // Plain: data right after the register byte is refused and counted.
    ASSERT_EQ(pozyx_sim_i2c_start(sim.get(), kAddress, 0), POZYX_SIM_ACK);
    ASSERT_EQ(pozyx_sim_i2c_write(sim.get(), POZYX_REG_INT_MASK), POZYX_SIM_ACK);
    EXPECT_EQ(pozyx_sim_i2c_write(sim.get(), 0x01), POZYX_SIM_NACK);
    pozyx_sim_i2c_stop(sim.get());
    EXPECT_EQ(sim.readRegs(POZYX_REG_INT_MASK, 1)[0], 0x1F);
    EXPECT_EQ(sim->stats.protocol_violations, 1U);
    // Read-only registers refuse writes.
    ASSERT_EQ(pozyx_sim_i2c_start(sim.get(), kAddress, 0), POZYX_SIM_ACK);
    ASSERT_EQ(pozyx_sim_i2c_write(sim.get(), POZYX_REG_WHO_AM_I), POZYX_SIM_ACK);
    ASSERT_EQ(pozyx_sim_i2c_start(sim.get(), kAddress, 0), POZYX_SIM_ACK);
    EXPECT_EQ(pozyx_sim_i2c_write(sim.get(), 0x00), POZYX_SIM_NACK);
    pozyx_sim_i2c_stop(sim.get());
    EXPECT_EQ(sim.readRegs(POZYX_REG_WHO_AM_I, 1)[0], 0x43);
}

TEST(PozyxSim, ReadWithoutAPointerIsRefused)
{
    Sim sim;
    EXPECT_EQ(pozyx_sim_i2c_start(sim.get(), kAddress, 1), POZYX_SIM_NACK);
    pozyx_sim_i2c_stop(sim.get());
    EXPECT_EQ(sim->stats.protocol_violations, 1U);
}

TEST(PozyxSim, LocalRangingCompletesAfterItsDurationWithTheGeometricDistance)
{
    Sim sim(11, 0.0);
    sim.add(0x6001, false, 3.0, 4.0, 0.0); // 5 m
    (void)sim.intStatus();
    EXPECT_EQ(sim.call(POZYX_FN_DO_RANGING, {0x01, 0x60}, 0)[0], 1);
    pozyx_sim_advance(sim.get(), sim->config.ranging_duration_us - 1U);
    EXPECT_EQ(sim.intStatus() & POZYX_INT_FUNC, 0) << "not before the ranging took its time";
    pozyx_sim_advance(sim.get(), sim->config.ranging_duration_us);
    EXPECT_EQ(sim.intStatus() & (POZYX_INT_FUNC | POZYX_INT_ERR), POZYX_INT_FUNC);
    const auto info = sim.call(POZYX_FN_DEVICE_GETRANGEINFO, {0x01, 0x60}, 10);
    ASSERT_EQ(info[0], 1);
    EXPECT_EQ(u32(info, 1), sim->config.ranging_duration_us / 1000U) << "the local node's clock, in ms";
    EXPECT_EQ(u32(info, 5), 5000U);
    // The rss is plausible for 5 m.
    const int16_t rss = static_cast<int16_t>(info[9] | (info[10] << 8));
    EXPECT_LT(rss, -60);
    EXPECT_GT(rss, -110);
}

// config.range_fn: the caller decides each ranging (cdro-sim's world), on links the model finds working.
struct GivenRanges {
    std::vector<uint8_t> codes{0, POZYX_ERROR_RANGING};
    size_t calls = 0;
    static void outcome(void *context, uint16_t ranger, uint16_t partner, double, pozyx_sim_range_outcome_t *out)
    {
        auto *self = static_cast<GivenRanges *>(context);
        EXPECT_EQ(ranger, 0x6000);
        EXPECT_EQ(partner, 0x6001);
        out->error_code = self->codes[self->calls++ % self->codes.size()];
        out->distance_mm = 1234;
        out->rss_dbm = -77;
    }
};

TEST(PozyxSim, ARangeFunctionDecidesEachRangingsDistanceOrFailure)
{
    Sim sim(11, 0.0);
    GivenRanges given;
    sim->config.range_fn = &GivenRanges::outcome;
    sim->config.range_context = &given;
    sim.add(0x6001, false, 3.0, 4.0, 0.0);  // 5 m by the geometry
    sim.add(0x6002, false, 80.0, 0.0, 0.0); // beyond max_range_m: never asked
    (void)sim.intStatus();

    EXPECT_EQ(sim.call(POZYX_FN_DO_RANGING, {0x01, 0x60}, 0)[0], 1);
    pozyx_sim_advance(sim.get(), sim->now_us + sim->config.ranging_duration_us);
    EXPECT_EQ(sim.intStatus() & (POZYX_INT_FUNC | POZYX_INT_ERR), POZYX_INT_FUNC);
    const auto info = sim.call(POZYX_FN_DEVICE_GETRANGEINFO, {0x01, 0x60}, 10);
    EXPECT_EQ(u32(info, 5), 1234U);
    EXPECT_EQ(static_cast<int16_t>(info[9] | (info[10] << 8)), -77);

    EXPECT_EQ(sim.call(POZYX_FN_DO_RANGING, {0x01, 0x60}, 0)[0], 1);
    pozyx_sim_advance(sim.get(), sim->now_us + sim->config.ranging_duration_us);
    EXPECT_EQ(sim.intStatus() & POZYX_INT_ERR, POZYX_INT_ERR);
    EXPECT_EQ(sim.readRegs(POZYX_REG_ERRORCODE, 1)[0], POZYX_ERROR_RANGING);

    EXPECT_EQ(sim.call(POZYX_FN_DO_RANGING, {0x02, 0x60}, 0)[0], 1);
    pozyx_sim_advance(sim.get(), sim->now_us + sim->config.ranging_duration_us);
    EXPECT_EQ(sim.readRegs(POZYX_REG_ERRORCODE, 1)[0], POZYX_ERROR_RTIMEOUT1);
    EXPECT_EQ(given.calls, 2U);
}

TEST(PozyxSim, RangingToAnAbsentNodeRaisesErr)
{
    Sim sim;
    EXPECT_EQ(sim.call(POZYX_FN_DO_RANGING, {0x77, 0x77}, 0)[0], 1);
    pozyx_sim_advance(sim.get(), 100000);
    EXPECT_EQ(sim.intStatus() & POZYX_INT_ERR, POZYX_INT_ERR);
    EXPECT_EQ(sim.readRegs(POZYX_REG_ERRORCODE, 1)[0], POZYX_ERROR_RTIMEOUT1);
}

TEST(PozyxSim, RangeNoiseIsSeededAndGaussian)
{
    auto run = [](uint64_t seed) {
        Sim sim(seed, 30.0);
        sim.add(0x6001, false, 10.0, 0.0, 0.0);
        std::vector<uint32_t> d;
        for (int i = 0; i < 400; ++i) {
            EXPECT_EQ(sim.call(POZYX_FN_DO_RANGING, {0x01, 0x60}, 0)[0], 1);
            pozyx_sim_advance(sim.get(), sim->now_us + sim->config.ranging_duration_us);
            d.push_back(u32(sim.call(POZYX_FN_DEVICE_GETRANGEINFO, {0x01, 0x60}, 10), 5));
        }
        return d;
    };
    const auto a = run(5);
    EXPECT_EQ(a, run(5)) << "same seed, same noise";
    EXPECT_NE(a, run(6));
    double mean = 0;
    for (uint32_t v : a) {
        mean += v;
    }
    mean /= static_cast<double>(a.size());
    double var = 0;
    for (uint32_t v : a) {
        var += (v - mean) * (v - mean);
    }
    const double std_mm = std::sqrt(var / static_cast<double>(a.size() - 1));
    EXPECT_NEAR(mean, 10000.0, 6.0); // 4.2 sigma of the mean
    EXPECT_NEAR(std_mm, 30.0, 4.5);  // ~4 sigma of the sample std
}

TEST(PozyxSim, RemoteReadRepliesAfterTwoMessagesWithFuncAndRxRegisters)
{
    Sim sim;
    sim.add(0x6002, true, 1.0, 0.0, 0.0);
    EXPECT_EQ(sim.call(POZYX_FN_TX_DATA, {0, POZYX_REG_HARDWARE_VER, 1}, 0)[0], 1);
    (void)sim.intStatus();
    EXPECT_EQ(sim.call(POZYX_FN_TX_SEND, {0x02, 0x60, POZYX_REMOTE_READ}, 0)[0], 1);
    const uint64_t due = 2U * sim->config.uwb_message_us + sim->config.remote_processing_us;
    pozyx_sim_advance(sim.get(), due - 1U);
    EXPECT_EQ(sim.intStatus() & POZYX_INT_FUNC, 0);
    pozyx_sim_advance(sim.get(), due);
    EXPECT_EQ(sim.intStatus() & POZYX_INT_FUNC, POZYX_INT_FUNC);
    const auto rx = sim.readRegs(POZYX_REG_RX_NETWORK_ID, 3);
    EXPECT_EQ(rx[0] | (rx[1] << 8), 0x6002);
    EXPECT_EQ(rx[2], 1);
    const auto data = sim.call(POZYX_FN_RX_DATA, {0, 1}, 1);
    EXPECT_EQ(data[0], 1);
    EXPECT_EQ(data[1] >> 5, 1) << "a tag";
}

TEST(PozyxSim, RemoteRangingSendsAResultMessageThenAnswersGetRangeInfo)
{
    Sim sim(3, 0.0);
    sim.add(0x6002, false, 0.0, 0.0, 0.0);
    sim.add(0x6003, false, 6.0, 8.0, 0.0); // 10 m from 0x6002
    EXPECT_EQ(sim.call(POZYX_FN_TX_DATA, {0, POZYX_FN_DO_RANGING, 0x03, 0x60}, 0)[0], 1);
    (void)sim.intStatus();
    EXPECT_EQ(sim.call(POZYX_FN_TX_SEND, {0x02, 0x60, POZYX_REMOTE_FUNCTION}, 0)[0], 1);
    pozyx_sim_advance(sim.get(), 2U * sim->config.uwb_message_us + sim->config.remote_processing_us);
    EXPECT_EQ(sim.intStatus() & POZYX_INT_FUNC, POZYX_INT_FUNC) << "the 1-byte function reply";
    EXPECT_EQ(sim.readRegs(POZYX_REG_RX_DATA_LEN, 1)[0], 1);
    EXPECT_EQ(sim.call(POZYX_FN_RX_DATA, {0, 1}, 1)[1], 1);
    pozyx_sim_advance(sim.get(), 100000);
    EXPECT_EQ(sim.intStatus() & POZYX_INT_RX_DATA, POZYX_INT_RX_DATA) << "the unsolicited result message";
    const auto rx = sim.readRegs(POZYX_REG_RX_NETWORK_ID, 3);
    EXPECT_EQ(rx[0] | (rx[1] << 8), 0x6002);
    EXPECT_EQ(rx[2], 4);
    EXPECT_EQ(u32(sim.call(POZYX_FN_RX_DATA, {0, 4}, 4), 1), 10000U);
    // Remote GETRANGEINFO on 0x6002 about 0x6003: 11 bytes back.
    EXPECT_EQ(sim.call(POZYX_FN_TX_DATA, {0, POZYX_FN_DEVICE_GETRANGEINFO, 0x03, 0x60}, 0)[0], 1);
    (void)sim.intStatus();
    EXPECT_EQ(sim.call(POZYX_FN_TX_SEND, {0x02, 0x60, POZYX_REMOTE_FUNCTION}, 0)[0], 1);
    pozyx_sim_advance(sim.get(), sim->now_us + 100000);
    EXPECT_EQ(sim.readRegs(POZYX_REG_RX_DATA_LEN, 1)[0], 11);
    const auto info = sim.call(POZYX_FN_RX_DATA, {0, 11}, 11);
    EXPECT_EQ(info[1], 1);
    EXPECT_EQ(u32(info, 6), 10000U);
    EXPECT_EQ(sim->stats.rangings, 1U);
}

TEST(PozyxSim, DiscoveryFindsPoweredNodesInRangeOnly)
{
    Sim sim;
    sim.add(0x6001, false, 5, 0, 0);
    sim.add(0x6002, true, 0, 5, 0);
    sim.add(0x6003, false, 500, 0, 0); // out of range
    sim.add(0x6004, false, 1, 1, 0);
    pozyx_sim_find(sim.get(), 0x6004)->config.powered = 0;
    EXPECT_EQ(sim.call(POZYX_FN_DEVICES_DISCOVER, {POZYX_DISCOVER_ALL, 3, 10}, 0)[0], 1);
    pozyx_sim_advance(sim.get(), 40000);
    EXPECT_EQ(sim.intStatus() & POZYX_INT_FUNC, POZYX_INT_FUNC);
    EXPECT_EQ(sim.readRegs(POZYX_REG_DEVICE_LIST_SIZE, 1)[0], 2);
    const auto ids = sim.call(POZYX_FN_DEVICES_GETIDS, {0, 2}, 4);
    EXPECT_EQ(ids[1] | (ids[2] << 8), 0x6001);
    EXPECT_EQ(ids[3] | (ids[4] << 8), 0x6002);
}

TEST(PozyxSim, FaultsAreInjectedOnceEachAndCounted)
{
    Sim sim;
    sim->faults.nack_address = 1;
    EXPECT_EQ(pozyx_sim_i2c_start(sim.get(), kAddress, 0), POZYX_SIM_NACK);
    pozyx_sim_i2c_stop(sim.get());
    EXPECT_EQ(sim.readRegs(POZYX_REG_WHO_AM_I, 1)[0], 0x43);
    sim->faults.hang = 1;
    EXPECT_EQ(pozyx_sim_i2c_start(sim.get(), kAddress, 0), POZYX_SIM_HANG);
    pozyx_sim_i2c_stop(sim.get());
    sim->faults.refuse_function = 1;
    EXPECT_EQ(sim.call(POZYX_FN_DEVICES_CLEAR, {}, 0)[0], 0);
    EXPECT_EQ(sim.call(POZYX_FN_DEVICES_CLEAR, {}, 0)[0], 1);
    EXPECT_EQ(sim->stats.faults_injected, 3U);
}

TEST(PozyxSim, AccelerometerFollowsTheTraceAt100Hz)
{
    Sim sim(9);
    sim->config.accel_noise_std_mg = 0.0;
    pozyx_sim_node_t *self = pozyx_sim_find(sim.get(), 0x6000);
    self->config.accel_fn = [](void *, double t_s) -> pozyx_sim_vec3_t { return {100.0 * t_s, -200.0, 1000.0}; };
    pozyx_sim_advance(sim.get(), 1234567); // 1.23 s: the sample of 1.23 s
    const auto raw = sim.readRegs(POZYX_REG_ACCEL_X, 6);
    EXPECT_EQ(static_cast<int16_t>(raw[0] | (raw[1] << 8)), 123);
    EXPECT_EQ(static_cast<int16_t>(raw[2] | (raw[3] << 8)), -200);
    EXPECT_EQ(static_cast<int16_t>(raw[4] | (raw[5] << 8)), 1000);
}

// ---- the real device's behaviours (pozyx_sim_config_realistic), one switch each ------------------

TEST(PozyxSimRealistic, TheProfileSwitchesEveryBehaviourOnAndTheIdealOneOff)
{
    pozyx_sim_config_t ideal;
    pozyx_sim_config_t real;
    pozyx_sim_config_default(&ideal);
    pozyx_sim_config_realistic(&real);
    EXPECT_EQ(ideal.reply_raises_rx_data + ideal.busy_remotes + ideal.collisions + ideal.device_list_full_error, 0);
    EXPECT_EQ(ideal.boot_us + ideal.stretch_function_us + ideal.stretch_register_us, 0U);
    EXPECT_EQ(real.reply_raises_rx_data + real.busy_remotes + real.collisions + real.device_list_full_error, 4);
    EXPECT_EQ(real.boot_us, 250000U);
    EXPECT_GT(real.stretch_function_us, 0U);
    EXPECT_EQ(real.ranging_duration_us, 40000U);
    EXPECT_EQ(real.uwb_message_us, 3500U);
}

TEST(PozyxSimRealistic, RepliesRaiseRxDataWithFunc)
{
    for (int on = 0; on < 2; ++on) {
        Sim sim;
        sim->config.reply_raises_rx_data = static_cast<uint8_t>(on);
        sim.add(0x6002, true, 1.0, 0.0, 0.0);
        sim.request(0x6002, POZYX_REMOTE_READ, {POZYX_REG_HARDWARE_VER, 1});
        pozyx_sim_advance(sim.get(), sim.replyDelayUs());
        EXPECT_EQ(sim.intStatus() & (POZYX_INT_FUNC | POZYX_INT_RX_DATA),
                  on ? POZYX_INT_FUNC | POZYX_INT_RX_DATA : POZYX_INT_FUNC);
    }
}

TEST(PozyxSimRealistic, ANodeRangingReceivesNothingUntilItsResultMessageIsOut)
{
    Sim sim(3, 0.0);
    sim->config.busy_remotes = 1;
    sim.add(0x6002, false, 0.0, 0.0, 0.0);
    sim.add(0x6003, false, 6.0, 8.0, 0.0);
    sim.request(0x6002, POZYX_REMOTE_FUNCTION, {POZYX_FN_DO_RANGING, 0x03, 0x60});
    const uint64_t ack_us = sim.replyDelayUs();
    pozyx_sim_advance(sim.get(), ack_us + 1000U);
    // While 0x6002 ranges with 0x6003, requests to either are lost.
    sim.request(0x6002, POZYX_REMOTE_READ, {POZYX_REG_HARDWARE_VER, 1});
    sim.request(0x6003, POZYX_REMOTE_READ, {POZYX_REG_HARDWARE_VER, 1});
    EXPECT_EQ(sim->stats.busy_losses, 2U);
    const uint64_t result_us = ack_us + sim->config.ranging_duration_us + sim->config.uwb_message_us;
    pozyx_sim_advance(sim.get(), result_us);
    EXPECT_EQ(sim.intStatus() & POZYX_INT_RX_DATA, POZYX_INT_RX_DATA) << "the result message";
    EXPECT_EQ(sim.readRegs(POZYX_REG_RX_DATA_LEN, 1)[0], 4);
    // Once the result message is out it answers again.
    sim.request(0x6002, POZYX_REMOTE_READ, {POZYX_REG_HARDWARE_VER, 1});
    pozyx_sim_advance(sim.get(), sim->now_us + sim.replyDelayUs());
    EXPECT_EQ(sim.intStatus() & POZYX_INT_FUNC, POZYX_INT_FUNC);
    EXPECT_EQ(sim->stats.busy_losses, 2U);
    // The ideal model answers mid-ranging.
    sim->config.busy_remotes = 0;
    sim.request(0x6002, POZYX_REMOTE_FUNCTION, {POZYX_FN_DO_RANGING, 0x03, 0x60});
    pozyx_sim_advance(sim.get(), sim->now_us + sim.replyDelayUs() + 1000U);
    sim.request(0x6002, POZYX_REMOTE_READ, {POZYX_REG_HARDWARE_VER, 1});
    pozyx_sim_advance(sim.get(), sim->now_us + sim.replyDelayUs());
    EXPECT_EQ(sim.intStatus() & POZYX_INT_FUNC, POZYX_INT_FUNC);
}

TEST(PozyxSimRealistic, MessagesOverlappingOnAirAreAllLost)
{
    Sim sim;
    sim->config.collisions = 1;
    sim.add(0x6002, false, 1.0, 0.0, 0.0);
    const uint8_t data[4] = {1, 2, 3, 4};
    const uint64_t air = sim->config.uwb_message_us;
    // Two messages 1 ms apart overlap: both lost. A third one air time later is received.
    ASSERT_EQ(pozyx_sim_inject_message(sim.get(), 0x6002, data, 4, 10000), 0);
    ASSERT_EQ(pozyx_sim_inject_message(sim.get(), 0x6003, data, 4, 11000), 0);
    ASSERT_EQ(pozyx_sim_inject_message(sim.get(), 0x6004, data, 4, 11000 + air), 0);
    pozyx_sim_advance(sim.get(), 10500);
    EXPECT_EQ(sim.intStatus() & POZYX_INT_RX_DATA, 0);
    pozyx_sim_advance(sim.get(), 11500);
    EXPECT_EQ(sim.intStatus() & POZYX_INT_RX_DATA, 0);
    pozyx_sim_advance(sim.get(), 12000 + air);
    EXPECT_EQ(sim.intStatus() & POZYX_INT_RX_DATA, POZYX_INT_RX_DATA);
    EXPECT_EQ(sim.readRegs(POZYX_REG_RX_NETWORK_ID, 2)[0], 0x04);
    EXPECT_EQ(sim->stats.collisions, 2U);
    // A message arriving while the local device ranges is lost too (it is half-duplex).
    EXPECT_EQ(sim.call(POZYX_FN_DO_RANGING, {0x02, 0x60}, 0)[0], 1);
    ASSERT_EQ(pozyx_sim_inject_message(sim.get(), 0x6003, data, 4, sim->now_us + 5000), 0);
    pozyx_sim_advance(sim.get(), sim->now_us + sim->config.ranging_duration_us + 1000);
    EXPECT_EQ(sim.intStatus() & (POZYX_INT_RX_DATA | POZYX_INT_FUNC), POZYX_INT_FUNC);
    EXPECT_EQ(sim->stats.collisions, 3U);
}

TEST(PozyxSimRealistic, TheDeviceAnswersOnlyOnceBootedAgainAfterEachPowerUp)
{
    Sim sim;
    sim->config.boot_us = 250000;
    // Nodes added at time 0 are powered up then.
    sim->nodes[0].ready_at_us = sim->config.boot_us;
    pozyx_sim_advance(sim.get(), 249000);
    EXPECT_EQ(pozyx_sim_i2c_start(sim.get(), kAddress, 0), POZYX_SIM_NACK);
    pozyx_sim_i2c_stop(sim.get());
    pozyx_sim_advance(sim.get(), 250000);
    EXPECT_EQ(sim.readRegs(POZYX_REG_WHO_AM_I, 1)[0], 0x43);
    sim->nodes[0].config.powered = 0;
    pozyx_sim_advance(sim.get(), 300000);
    sim->nodes[0].config.powered = 1;
    pozyx_sim_advance(sim.get(), 400000);
    EXPECT_EQ(pozyx_sim_i2c_start(sim.get(), kAddress, 0), POZYX_SIM_NACK) << "booting again";
    pozyx_sim_i2c_stop(sim.get());
    pozyx_sim_advance(sim.get(), 650000);
    EXPECT_EQ(sim.readRegs(POZYX_REG_WHO_AM_I, 1)[0], 0x43);
    EXPECT_EQ(sim->stats.boot_refusals, 2U);
}

TEST(PozyxSimRealistic, ClockStretchingBeforeTheFirstByteOfARead)
{
    Sim sim;
    sim->config.stretch_function_us = 100;
    sim->config.stretch_register_us = 10;
    (void)sim.readRegs(POZYX_REG_WHO_AM_I, 1);
    EXPECT_EQ(sim->stretch_us, 10U);
    (void)sim.call(POZYX_FN_DEVICES_CLEAR, {}, 0);
    EXPECT_EQ(sim->stretch_us, 100U);
    EXPECT_EQ(sim->stats.stretched_us, 110U);
}

TEST(PozyxSimRealistic, ATwentyFirstRangingPartnerIsAnErrorNotAnEviction)
{
    for (int real = 0; real < 2; ++real) {
        Sim sim(5, 0.0);
        sim->config.device_list_full_error = static_cast<uint8_t>(real);
        for (uint16_t i = 0; i < 21; ++i) {
            sim.add(static_cast<uint16_t>(0x6100 + i), false, 1.0 + i, 0.0, 0.0);
        }
        for (uint16_t i = 0; i < 21; ++i) {
            const uint16_t id = static_cast<uint16_t>(0x6100 + i);
            EXPECT_EQ(sim.call(POZYX_FN_DO_RANGING, {static_cast<uint8_t>(id & 0xFF), static_cast<uint8_t>(id >> 8)},
                               0)[0],
                      1);
            pozyx_sim_advance(sim.get(), sim->now_us + sim->config.ranging_duration_us);
            const uint8_t flags = sim.intStatus();
            if (i < 20 || !real) {
                EXPECT_EQ(flags & POZYX_INT_FUNC, POZYX_INT_FUNC) << i;
            } else {
                EXPECT_EQ(flags & POZYX_INT_ERR, POZYX_INT_ERR);
                EXPECT_EQ(sim.readRegs(POZYX_REG_ERRORCODE, 1)[0], POZYX_ERROR_DEVICE_LIST_FULL);
            }
        }
        EXPECT_EQ(sim->stats.list_full_errors, real ? 1U : 0U);
    }
}

TEST(PozyxSimRealistic, ALateReplyArrivesLateIntoWhateverComesNext)
{
    Sim sim;
    sim.add(0x6002, true, 1.0, 0.0, 0.0);
    sim->faults.late_reply = 1;
    sim.request(0x6002, POZYX_REMOTE_READ, {POZYX_REG_HARDWARE_VER, 1});
    pozyx_sim_advance(sim.get(), sim.replyDelayUs() + sim->config.late_reply_us - 1U);
    EXPECT_EQ(sim.intStatus() & POZYX_INT_FUNC, 0);
    pozyx_sim_advance(sim.get(), sim.replyDelayUs() + sim->config.late_reply_us);
    EXPECT_EQ(sim.intStatus() & POZYX_INT_FUNC, POZYX_INT_FUNC);
    EXPECT_EQ(sim->faults.late_reply, 0U);
}

TEST(PozyxSimRealistic, NodesTalkOnlyOnTheSameUwbSettings)
{
    Sim sim;
    sim.add(0x6002, true, 1.0, 0.0, 0.0);
    sim.add(0x6003, false, 2.0, 0.0, 0.0);
    EXPECT_EQ(sim.readRegs(POZYX_REG_UWB_CHANNEL, 4), (std::vector<uint8_t>{5, 0x80, 0x08, 23}));
    // A remote write of another channel moves the node away: its acknowledgement is not heard.
    sim.request(0x6002, POZYX_REMOTE_WRITE, {POZYX_REG_UWB_CHANNEL, 2});
    pozyx_sim_advance(sim.get(), sim.replyDelayUs());
    EXPECT_EQ(sim.intStatus() & POZYX_INT_FUNC, 0);
    EXPECT_EQ(sim.call(POZYX_FN_DEVICES_DISCOVER, {POZYX_DISCOVER_ALL, 3, 10}, 0)[0], 1);
    pozyx_sim_advance(sim.get(), sim->now_us + 40000);
    EXPECT_EQ(sim.readRegs(POZYX_REG_DEVICE_LIST_SIZE, 1)[0], 1) << "only 0x6003 is on channel 5";
    // The local device follows it: now it hears 0x6002 (and not 0x6003).
    ASSERT_EQ(pozyx_sim_i2c_start(sim.get(), kAddress, 0), POZYX_SIM_ACK);
    ASSERT_EQ(pozyx_sim_i2c_write(sim.get(), POZYX_REG_UWB_CHANNEL), POZYX_SIM_ACK);
    ASSERT_EQ(pozyx_sim_i2c_start(sim.get(), kAddress, 0), POZYX_SIM_ACK);
    ASSERT_EQ(pozyx_sim_i2c_write(sim.get(), 2), POZYX_SIM_ACK);
    pozyx_sim_i2c_stop(sim.get());
    sim.request(0x6002, POZYX_REMOTE_READ, {POZYX_REG_UWB_CHANNEL, 1});
    pozyx_sim_advance(sim.get(), sim->now_us + sim.replyDelayUs());
    EXPECT_EQ(sim.intStatus() & POZYX_INT_FUNC, POZYX_INT_FUNC);
    EXPECT_EQ(sim.call(POZYX_FN_RX_DATA, {0, 1}, 1)[1], 2);
}

} // namespace
