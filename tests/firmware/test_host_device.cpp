// The firmware on the host (sim/host_device, cdro-sim's device) through its C interface,
// as cdro-sim drives it: boot, a command, ranging against the caller's world, a reset. Linked
// against the shared library only (its codec decodes what it wrote).
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <vector>

#include "cdro/frames.h"
#include "cdro_host_device/host_device.h"

namespace {

struct World {
    std::vector<cdro_frame_t> frames;
    std::vector<uint64_t> times;
    cdro_decoder_t decoder;
    uint32_t ranges_asked = 0;

    World() { cdro_decoder_init(&decoder); }

    static void position(void *, uint16_t id, double, double *xyz)
    {
        xyz[0] = id == 0x6001 ? 0.0 : 4.0;
        xyz[1] = id == 0x6003 ? 3.0 : 0.0;
        xyz[2] = 0.0;
    }
    static double accel(void *, uint16_t, double) { return 1000.0; }
    static uint8_t range(void *context, uint16_t from, uint16_t to, double, uint32_t *distance_mm, int16_t *rss_dbm)
    {
        auto *self = static_cast<World *>(context);
        ++self->ranges_asked;
        *distance_mm = 4000U + from % 16U + to % 16U;
        *rss_dbm = -80;
        return 0;
    }
    static void write(void *context, const uint8_t *data, uint16_t length, uint64_t t_us)
    {
        auto *self = static_cast<World *>(context);
        for (uint16_t i = 0; i < length; ++i) {
            cdro_frame_t frame;
            if (cdro_decoder_push(&self->decoder, data[i], &frame) == CDRO_OK) {
                self->frames.push_back(frame);
                self->times.push_back(t_us);
            }
        }
    }
    size_t count(uint8_t type) const
    {
        size_t n = 0;
        for (const auto &f : frames) {
            n += f.type == type;
        }
        return n;
    }
};

struct Device {
    World world;
    cdro_hd_t *hd = nullptr;

    Device()
    {
        cdro_hd_config_t config;
        std::memset(&config, 0, sizeof config);
        config.seed = 3;
        config.max_range_m = 30.0;
        config.pozyx_firmware = 0x12;
        config.pozyx_present = 1;
        config.free_ram_bytes = 600;
        cdro_hd_callbacks_t callbacks;
        std::memset(&callbacks, 0, sizeof callbacks);
        callbacks.context = &world;
        callbacks.position = &World::position;
        callbacks.accel = &World::accel;
        callbacks.range = &World::range;
        callbacks.write = &World::write;
        hd = cdro_hd_create(&config, &callbacks);
        EXPECT_EQ(cdro_hd_add_node(hd, 0x6001, 1), 0);
        EXPECT_EQ(cdro_hd_add_node(hd, 0x6002, 0), 0);
        EXPECT_EQ(cdro_hd_add_node(hd, 0x6003, 0), 0);
        EXPECT_EQ(cdro_hd_add_node(hd, 0x6003, 0), -1) << "an id twice";
        cdro_hd_power_on(hd, CDRO_RESET_POWER_ON);
    }
    ~Device() { cdro_hd_destroy(hd); }
    void runUntil(uint64_t end_us)
    {
        while (cdro_hd_next_due_us(hd) <= end_us) {
            cdro_hd_idle_to(hd, cdro_hd_next_due_us(hd));
            cdro_hd_step(hd);
        }
        cdro_hd_idle_to(hd, end_us);
    }
    void send(uint8_t type, uint16_t sequence)
    {
        cdro_frame_t frame;
        std::memset(&frame, 0, sizeof frame);
        frame.version = CDRO_PROTOCOL_VERSION;
        frame.type = type;
        frame.sequence = sequence;
        uint8_t encoded[CDRO_MAX_ENCODED_FRAME];
        const size_t length = cdro_frame_encode(&frame, encoded, sizeof encoded);
        ASSERT_GT(length, 0U);
        EXPECT_EQ(cdro_hd_receive(hd, encoded, static_cast<uint16_t>(length)), length);
    }
};

TEST(HostDevice, BootsDiscoversAndAnswersAsTheFirmware)
{
    Device device;
    device.runUntil(1000000);
    ASSERT_FALSE(device.world.frames.empty());
    const cdro_frame_t &hello = device.world.frames[0];
    EXPECT_EQ(hello.type, CDRO_FRAME_HELLO);
    EXPECT_EQ(hello.as.hello.node_id, 0x6001);
    uint8_t found = 0;
    EXPECT_EQ(hello.as.hello.device_time_ms, cdro_hd_constant("POZYX_BOOT_MS", &found));
    EXPECT_EQ(found, 1);
    EXPECT_GE(device.world.times[0], 250000U) << "after the firmware's boot wait";
    EXPECT_EQ(device.world.count(CDRO_FRAME_NODE_LIST), 1U);
    EXPECT_EQ(cdro_hd_state(device.hd), 2U);

    device.send(CDRO_FRAME_START, 9);
    device.runUntil(3000000);
    EXPECT_EQ(cdro_hd_running(device.hd), 1U);
    EXPECT_GT(device.world.count(CDRO_FRAME_RANGE), 10U);
    EXPECT_EQ(device.world.ranges_asked, device.world.count(CDRO_FRAME_RANGE)) << "every range asked the world";
    cdro_hd_counters_t counters;
    cdro_hd_read_counters(device.hd, &counters);
    EXPECT_EQ(counters.frames_sent, device.world.frames.size());
    EXPECT_EQ(counters.boots, 1U);
}

TEST(HostDevice, AResetRestartsTheFirmwareButNotTheNetwork)
{
    Device device;
    device.runUntil(2000000);
    const uint64_t reset_us = cdro_hd_now_us(device.hd);
    cdro_hd_power_on(device.hd, CDRO_RESET_WATCHDOG);
    device.world.frames.clear();
    device.world.times.clear();
    device.runUntil(reset_us + 1000000);
    ASSERT_FALSE(device.world.frames.empty());
    EXPECT_EQ(device.world.frames[0].type, CDRO_FRAME_HELLO);
    EXPECT_EQ(device.world.frames[0].sequence, 0U);
    EXPECT_EQ(device.world.frames[0].as.hello.reset_cause, CDRO_RESET_WATCHDOG);
    EXPECT_EQ(cdro_hd_boot_us(device.hd), reset_us);
}

TEST(HostDevice, UnknownConstantsAreNotFound)
{
    uint8_t found = 1;
    EXPECT_EQ(cdro_hd_constant("NO_SUCH", &found), 0);
    EXPECT_EQ(found, 0U);
    EXPECT_EQ(cdro_hd_constant("MOVING_ABOVE_MG", &found), 80);
    EXPECT_EQ(found, 1U);
    const Device device; // created, before its Pozyx is up
    EXPECT_EQ(cdro_hd_state(device.hd), cdro_hd_constant("STATE_BOOT", &found));
    EXPECT_EQ(found, 1U);
}

} // namespace
