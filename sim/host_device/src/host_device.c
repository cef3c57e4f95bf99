/*
 * host_device.c: the firmware with host ops (see host_device.h).
 */
#include "cdro_host_device/host_device.h"

#include <stddef.h>
#include <stdlib.h>
#include <string.h>

#include "cdro_fw/firmware.h"
#include "pozyx_sim/pozyx_sim.h"

/* The Uno build's HardwareSerial buffers (platformio.ini, cmake/CdroAvrFirmware.cmake): 128 and
 * 64 bytes, of which a ring buffer holds one less. */
#define HD_TX_BUFFER 127U
#define HD_RX_BUFFER 63U
/* Host bytes on their way: they reach the receive buffer one every 10 bits at the baud rate. */
#define HD_WIRE_BUFFER 4096U
/* Wire's own cost per transaction beyond the bits on the wire, and the main loop's per step
 * (wdt_reset, millis, the call): the figures of the firmware's native tests (tests/firmware). */
#define HD_WIRE_OVERHEAD_NS 20000U
#define HD_LOOP_OVERHEAD_NS 50000U
#define HD_BUS_RECOVERY_US 100U /* 9 clocks and a STOP at 100 kHz */

typedef struct hd_node {
    cdro_hd_t *hd;
    uint16_t id;
} hd_node_t;

struct cdro_hd {
    pozyx_sim_t sim;
    cdro_fw_t fw;
    cdro_hd_config_t config;
    cdro_hd_callbacks_t callbacks;
    cdro_pozyx_ops_t pozyx_ops;
    cdro_serial_ops_t serial_ops;
    hd_node_t nodes[POZYX_SIM_MAX_NODES];
    uint64_t now_ns;      /* simulated time */
    uint64_t boot_ns;     /* simulated time of the last power-on or reset */
    uint64_t next_due_ns; /* what the last step asked for */
    uint8_t powered;
    /* UART transmit side: bytes still to go out, drained at the baud rate */
    uint32_t tx_pending;
    uint64_t tx_drained_ns;
    /* UART receive side: bytes on the wire, then the receive ring buffer */
    uint8_t wire[HD_WIRE_BUFFER];
    uint16_t wire_head;
    uint16_t wire_count;
    uint64_t wire_next_ns; /* when the wire's first byte reaches the receive buffer */
    uint8_t rx[HD_RX_BUFFER];
    uint16_t rx_head;
    uint16_t rx_count;
    uint32_t rx_lost;
    uint32_t boots;
};

/* ---- time ------------------------------------------------------------------------------- */

static void advance_ns(cdro_hd_t *hd, uint64_t ns)
{
    hd->now_ns += ns;
    pozyx_sim_advance(&hd->sim, hd->now_ns / 1000U);
}

static void advance_us(cdro_hd_t *hd, uint64_t us) { advance_ns(hd, us * 1000U); }

/* The address byte and `bytes` data bytes, 9 clocks each, start and stop, Wire's overhead. */
static void byte_time(cdro_hd_t *hd, uint32_t bytes)
{
    const uint64_t ns_per_bit = 1000000000ULL / CDRO_FW_I2C_CLOCK_HZ;
    advance_ns(hd, ns_per_bit * (9U * ((uint64_t)bytes + 1U) + 2U) + HD_WIRE_OVERHEAD_NS);
}

/* ---- Pozyx ops: Wire against the register model ------------------------------------------ */

static cdro_i2c_result_t i2c_write(void *user, uint8_t address, const uint8_t *data, uint8_t length, uint8_t stop)
{
    cdro_hd_t *hd = (cdro_hd_t *)user;
    cdro_i2c_result_t result = CDRO_I2C_OK;
    pozyx_sim_bus_t r;
    uint8_t i;
    if (length > CDRO_FW_I2C_MAX_TRANSFER) {
        return CDRO_I2C_ERROR; /* what Wire does with more than its buffer */
    }
    r = pozyx_sim_i2c_start(&hd->sim, address, 0);
    if (r == POZYX_SIM_NACK) {
        result = CDRO_I2C_NACK_ADDRESS;
    }
    for (i = 0; r == POZYX_SIM_ACK && i < length; ++i) {
        r = pozyx_sim_i2c_write(&hd->sim, data[i]);
        if (r == POZYX_SIM_NACK) {
            result = CDRO_I2C_NACK_DATA;
        }
    }
    if (r == POZYX_SIM_HANG) {
        advance_us(hd, CDRO_FW_I2C_TIMEOUT_US);
        pozyx_sim_i2c_stop(&hd->sim); /* Wire resets the TWI unit; the bus is released */
        return CDRO_I2C_TIMEOUT;
    }
    byte_time(hd, length);
    if (result != CDRO_I2C_OK || stop) {
        pozyx_sim_i2c_stop(&hd->sim); /* Wire sends STOP after a NACK */
    }
    return result;
}

static cdro_i2c_result_t i2c_read(void *user, uint8_t address, uint8_t *data, uint8_t length)
{
    cdro_hd_t *hd = (cdro_hd_t *)user;
    pozyx_sim_bus_t r;
    uint64_t stretch_us;
    uint8_t i;
    if (length > CDRO_FW_I2C_MAX_TRANSFER) {
        return CDRO_I2C_ERROR;
    }
    r = pozyx_sim_i2c_start(&hd->sim, address, 1);
    /* Clock stretching: the device holds SCL before the first byte; Wire gives up at its timeout. */
    stretch_us = r == POZYX_SIM_ACK ? hd->sim.stretch_us : 0U;
    if (r == POZYX_SIM_HANG || stretch_us >= CDRO_FW_I2C_TIMEOUT_US) {
        advance_us(hd, CDRO_FW_I2C_TIMEOUT_US);
        pozyx_sim_i2c_stop(&hd->sim);
        return CDRO_I2C_TIMEOUT;
    }
    advance_us(hd, stretch_us);
    if (r == POZYX_SIM_NACK) {
        byte_time(hd, 0);
        pozyx_sim_i2c_stop(&hd->sim);
        return CDRO_I2C_NACK_ADDRESS;
    }
    for (i = 0; i < length; ++i) {
        data[i] = pozyx_sim_i2c_read(&hd->sim, (uint8_t)(i + 1U < length));
    }
    byte_time(hd, length);
    pozyx_sim_i2c_stop(&hd->sim);
    return CDRO_I2C_OK;
}

static void delay_ms(void *user, uint16_t duration_ms) { advance_us((cdro_hd_t *)user, (uint64_t)duration_ms * 1000U); }

static uint32_t now_ms(void *user)
{
    const cdro_hd_t *hd = (const cdro_hd_t *)user;
    return (uint32_t)((hd->now_ns - hd->boot_ns) / 1000000U);
}

static uint32_t now_us(void *user)
{
    const cdro_hd_t *hd = (const cdro_hd_t *)user;
    return (uint32_t)((hd->now_ns - hd->boot_ns) / 1000U);
}

static void bus_recover(void *user) { advance_us((cdro_hd_t *)user, HD_BUS_RECOVERY_US); }

/* ---- serial ops: HardwareSerial ---------------------------------------------------------- */

static uint64_t ns_per_serial_byte(void);

static void tx_drain(cdro_hd_t *hd)
{
    const uint64_t ns_per_byte = ns_per_serial_byte();
    uint64_t sent;
    if (hd->tx_pending == 0U) {
        hd->tx_drained_ns = hd->now_ns;
        return;
    }
    sent = (hd->now_ns - hd->tx_drained_ns) / ns_per_byte;
    if (sent >= hd->tx_pending) {
        hd->tx_pending = 0;
        hd->tx_drained_ns = hd->now_ns;
    } else {
        hd->tx_pending -= (uint32_t)sent;
        hd->tx_drained_ns += sent * ns_per_byte;
    }
}

uint16_t cdro_hd_tx_free(cdro_hd_t *hd)
{
    uint16_t free_bytes;
    tx_drain(hd);
    free_bytes = (uint16_t)(HD_TX_BUFFER - hd->tx_pending);
    if (hd->callbacks.room != NULL) {
        const uint16_t room = hd->callbacks.room(hd->callbacks.context);
        free_bytes = room < free_bytes ? room : free_bytes;
    }
    return free_bytes;
}

static uint16_t tx_free(void *user) { return cdro_hd_tx_free((cdro_hd_t *)user); }

static void tx_write(void *user, const uint8_t *data, uint8_t length)
{
    cdro_hd_t *hd = (cdro_hd_t *)user;
    tx_drain(hd);
    hd->tx_pending += length;
    if (hd->callbacks.write != NULL) {
        hd->callbacks.write(hd->callbacks.context, data, length, hd->now_ns / 1000U);
    }
}

static uint64_t ns_per_serial_byte(void) { return 10ULL * 1000000000ULL / CDRO_FW_SERIAL_BAUD; /* 8N1 */ }

/* Bytes that have arrived by now into the receive buffer; those that find it full are lost
 * (nothing read the buffer since the last call: every read calls this first). */
static void rx_arrivals(cdro_hd_t *hd)
{
    while (hd->wire_count > 0U && hd->wire_next_ns <= hd->now_ns) {
        const uint8_t byte = hd->wire[hd->wire_head];
        hd->wire_head = (uint16_t)((hd->wire_head + 1U) % HD_WIRE_BUFFER);
        --hd->wire_count;
        hd->wire_next_ns += ns_per_serial_byte();
        if (hd->rx_count < HD_RX_BUFFER) {
            hd->rx[(hd->rx_head + hd->rx_count) % HD_RX_BUFFER] = byte;
            ++hd->rx_count;
        } else {
            ++hd->rx_lost;
        }
    }
}

static int16_t rx_read(void *user)
{
    cdro_hd_t *hd = (cdro_hd_t *)user;
    uint8_t byte;
    rx_arrivals(hd);
    if (hd->rx_count == 0U) {
        return -1;
    }
    byte = hd->rx[hd->rx_head];
    hd->rx_head = (uint16_t)((hd->rx_head + 1U) % HD_RX_BUFFER);
    --hd->rx_count;
    return byte;
}

static uint16_t free_ram_bytes(void *user) { return ((const cdro_hd_t *)user)->config.free_ram_bytes; }

/* ---- the world ----------------------------------------------------------------------------- */

static pozyx_sim_vec3_t node_position(void *context, double t_s)
{
    const hd_node_t *node = (const hd_node_t *)context;
    double xyz[3] = {0.0, 0.0, 0.0};
    pozyx_sim_vec3_t p;
    node->hd->callbacks.position(node->hd->callbacks.context, node->id, t_s, xyz);
    p.x = xyz[0];
    p.y = xyz[1];
    p.z = xyz[2];
    return p;
}

/* The world gives a norm; the firmware's detector only uses the norm. */
static pozyx_sim_vec3_t node_accel(void *context, double t_s)
{
    const hd_node_t *node = (const hd_node_t *)context;
    pozyx_sim_vec3_t a;
    a.x = 0.0;
    a.y = 0.0;
    a.z = node->hd->callbacks.accel(node->hd->callbacks.context, node->id, t_s);
    return a;
}

static void node_range(void *context, uint16_t ranger, uint16_t partner, double t_s, pozyx_sim_range_outcome_t *out)
{
    const cdro_hd_t *hd = (const cdro_hd_t *)context;
    out->error_code =
        hd->callbacks.range(hd->callbacks.context, ranger, partner, t_s, &out->distance_mm, &out->rss_dbm);
}

/* ---- the device ------------------------------------------------------------------------------ */

cdro_hd_t *cdro_hd_create(const cdro_hd_config_t *config, const cdro_hd_callbacks_t *callbacks)
{
    pozyx_sim_config_t model;
    cdro_hd_t *hd = (cdro_hd_t *)calloc(1, sizeof(cdro_hd_t));
    if (hd == NULL) {
        return NULL;
    }
    hd->config = *config;
    hd->callbacks = *callbacks;
    pozyx_sim_config_realistic(&model);
    model.seed = config->seed;
    model.firmware_version = config->pozyx_firmware;
    model.max_range_m = config->max_range_m;
    model.accel_noise_std_mg = 0.0; /* the world's accelerometer has its own noise */
    model.range_fn = node_range;
    model.range_context = hd;
    pozyx_sim_init(&hd->sim, &model);
    hd->pozyx_ops.i2c_write = i2c_write;
    hd->pozyx_ops.i2c_read = i2c_read;
    hd->pozyx_ops.delay_ms = delay_ms;
    hd->pozyx_ops.now_ms = now_ms;
    hd->pozyx_ops.now_us = now_us;
    hd->pozyx_ops.bus_recover = bus_recover;
    hd->serial_ops.tx_free = tx_free;
    hd->serial_ops.tx_write = tx_write;
    hd->serial_ops.rx_read = rx_read;
    return hd;
}

void cdro_hd_destroy(cdro_hd_t *hd) { free(hd); }

int cdro_hd_add_node(cdro_hd_t *hd, uint16_t id, uint8_t is_tag)
{
    pozyx_sim_node_config_t node;
    hd_node_t *context;
    int index;
    if (hd->powered || hd->sim.node_count >= POZYX_SIM_MAX_NODES) {
        return -1;
    }
    context = &hd->nodes[hd->sim.node_count];
    context->hd = hd;
    context->id = id;
    pozyx_sim_node_config_default(&node, id, is_tag);
    node.position_fn = node_position;
    node.position_context = context;
    node.accel_fn = node_accel;
    node.accel_context = context;
    if (hd->sim.node_count == 0U) {
        node.powered = hd->config.pozyx_present;
    }
    index = pozyx_sim_add_node(&hd->sim, &node);
    return index < 0 ? -1 : 0;
}

void cdro_hd_power_on(cdro_hd_t *hd, uint8_t reset_cause)
{
    cdro_fw_config_t config;
    memset(&config, 0, sizeof config);
    config.pozyx_ops = &hd->pozyx_ops;
    config.pozyx_user = hd;
    config.serial_ops = &hd->serial_ops;
    config.serial_user = hd;
    config.free_ram_bytes = free_ram_bytes;
    config.platform_user = hd;
    config.reset_cause = reset_cause;
    hd->powered = 1;
    hd->boot_ns = hd->now_ns;
    hd->next_due_ns = hd->now_ns;
    rx_arrivals(hd);
    hd->rx_head = 0;
    hd->rx_count = 0;
    ++hd->boots;
    cdro_fw_init(&hd->fw, &config);
}

uint64_t cdro_hd_now_us(const cdro_hd_t *hd) { return hd->now_ns / 1000U; }

uint64_t cdro_hd_boot_us(const cdro_hd_t *hd) { return hd->boot_ns / 1000U; }

void cdro_hd_idle_to(cdro_hd_t *hd, uint64_t t_us)
{
    if (t_us * 1000U > hd->now_ns) {
        advance_ns(hd, t_us * 1000U - hd->now_ns);
    }
}

uint64_t cdro_hd_next_due_us(const cdro_hd_t *hd)
{
    if (hd->fw.state == CDRO_FW_STATE_READY && (hd->rx_count > 0U || hd->wire_count > 0U)) {
        /* the main loop reads host bytes at every step: as soon as they are there */
        const uint64_t arrival_ns = hd->rx_count > 0U ? hd->now_ns : hd->wire_next_ns;
        const uint64_t due_ns = arrival_ns < hd->next_due_ns ? arrival_ns : hd->next_due_ns;
        return (due_ns > hd->now_ns ? due_ns : hd->now_ns) / 1000U;
    }
    return hd->next_due_ns / 1000U;
}

void cdro_hd_step(cdro_hd_t *hd)
{
    const uint32_t device_ms = now_ms(hd);
    const uint32_t next_ms = cdro_fw_step(&hd->fw, device_ms);
    /* The step asks for device time next_ms (wrap-safe: a span from now). */
    const uint32_t wait_ms = (uint32_t)(next_ms - device_ms) < 0x80000000UL ? (uint32_t)(next_ms - device_ms) : 0U;
    const uint64_t asked_ns = hd->boot_ns + ((uint64_t)device_ms + wait_ms) * 1000000ULL;
    advance_ns(hd, HD_LOOP_OVERHEAD_NS);
    hd->next_due_ns = asked_ns > hd->now_ns ? asked_ns : hd->now_ns;
}

uint16_t cdro_hd_receive(cdro_hd_t *hd, const uint8_t *data, uint16_t length)
{
    uint16_t taken = 0;
    rx_arrivals(hd);
    if (hd->wire_count == 0U) {
        hd->wire_next_ns = hd->now_ns + ns_per_serial_byte();
    }
    while (taken < length && hd->wire_count < HD_WIRE_BUFFER) {
        hd->wire[(hd->wire_head + hd->wire_count) % HD_WIRE_BUFFER] = data[taken];
        ++hd->wire_count;
        ++taken;
    }
    hd->rx_lost += (uint32_t)(length - taken);
    return taken;
}

void cdro_hd_read_counters(const cdro_hd_t *hd, cdro_hd_counters_t *out)
{
    const cdro_fw_t *fw = &hd->fw;
    memset(out, 0, sizeof(*out));
    out->ranges_ok_direct = fw->counters.ranges_ok_direct;
    out->ranges_ok_remote = fw->counters.ranges_ok_remote;
    out->ranges_failed_direct = fw->counters.ranges_failed_direct;
    out->ranges_failed_remote = fw->counters.ranges_failed_remote;
    out->retries = fw->counters.retries;
    out->bus_errors = fw->pozyx.bus_errors;
    out->timeouts = fw->pozyx.timeouts;
    out->frames_sent = fw->link.frames_sent;
    out->frames_dropped = fw->link.frames_dropped;
    out->commands_rejected = fw->counters.commands_rejected;
    out->stale_results = fw->counters.stale_results;
    out->accel_failures = fw->counters.accel_failures;
    out->host_bytes_lost = hd->rx_lost;
    out->boots = hd->boots;
}

uint8_t cdro_hd_running(const cdro_hd_t *hd) { return hd->fw.running; }

uint8_t cdro_hd_state(const cdro_hd_t *hd) { return hd->fw.state; }

uint8_t cdro_hd_moving(const cdro_hd_t *hd, uint16_t id)
{
    uint8_t i;
    for (i = 0; i <= hd->fw.node_count && i < CDRO_FW_MAX_NODES; ++i) {
        if (hd->fw.nodes[i].id == id) {
            return hd->fw.nodes[i].motion.moving;
        }
    }
    return 0;
}

uint16_t cdro_hd_next_sequence(const cdro_hd_t *hd) { return hd->fw.link.sequence; }

void cdro_hd_injected_frame(cdro_hd_t *hd, uint8_t sent)
{
    cdro_link_t *link = &hd->fw.link;
    ++link->sequence;
    if (sent) {
        ++link->frames_sent;
    } else {
        ++link->frames_dropped;
        if (link->dropped_unreported < 0xFFFFU) {
            ++link->dropped_unreported;
        }
    }
}

/* ---- constants ------------------------------------------------------------------------------- */

typedef struct hd_constant {
    const char *name;
    int64_t value;
} hd_constant_t;

static const hd_constant_t kConstants[] = {
    {"VERSION", CDRO_FW_VERSION},
    {"NODE_ID_UNKNOWN", CDRO_FW_NODE_ID_UNKNOWN},
    {"MAX_REMOTE_NODES", CDRO_FW_MAX_REMOTE_NODES},
    {"RX_BYTES_PER_STEP", CDRO_FW_RX_BYTES_PER_STEP},
    {"SERIAL_BAUD", (int64_t)CDRO_FW_SERIAL_BAUD},
    {"SERIAL_TX_BUFFER", HD_TX_BUFFER},
    {"SERIAL_RX_BUFFER", HD_RX_BUFFER},
    {"POZYX_BOOT_MS", CDRO_FW_POZYX_BOOT_MS},
    {"IDENTIFY_RETRY_MS", CDRO_FW_IDENTIFY_RETRY_MS},
    {"POZYX_FIRMWARE_MIN", CDRO_FW_POZYX_FIRMWARE_MIN},
    {"POZYX_FIRMWARE_MAX", CDRO_FW_POZYX_FIRMWARE_MAX},
    {"RANGING_TIMEOUT_MS", CDRO_FW_RANGING_TIMEOUT_MS},
    {"REMOTE_REPLY_TIMEOUT_MS", CDRO_FW_REMOTE_REPLY_TIMEOUT_MS},
    {"REMOTE_RESULT_TIMEOUT_MS", CDRO_FW_REMOTE_RESULT_TIMEOUT_MS},
    {"RANGING_ERROR_STREAK", CDRO_FW_RANGING_ERROR_STREAK},
    {"BACKOFF_MAX_ROUNDS", CDRO_FW_BACKOFF_MAX_ROUNDS},
    {"STALE_REBASE", CDRO_FW_STALE_REBASE},
    {"ONE_G_MG", CDRO_FW_ONE_G_MG},
    {"MOTION_WINDOW", CDRO_FW_MOTION_WINDOW},
    {"MOVING_ABOVE_MG", CDRO_FW_MOVING_ABOVE_MG},
    {"STILL_BELOW_MG", CDRO_FW_STILL_BELOW_MG},
    {"STILL_SAMPLES", CDRO_FW_STILL_SAMPLES},
    {"MOTION_PERIODIC_MS", (int64_t)CDRO_FW_MOTION_PERIODIC_MS},
    {"WATCHDOG_MS", CDRO_FW_WATCHDOG_MS},
    {"LONGEST_OPERATION_MS", CDRO_FW_LONGEST_OPERATION_MS},
    {"STATE_BOOT", CDRO_FW_STATE_BOOT},
};

int64_t cdro_hd_constant(const char *name, uint8_t *found)
{
    size_t i;
    for (i = 0; i < sizeof kConstants / sizeof kConstants[0]; ++i) {
        if (strcmp(kConstants[i].name, name) == 0) {
            *found = 1;
            return kConstants[i].value;
        }
    }
    *found = 0;
    return 0;
}

/* ---- layouts --------------------------------------------------------------------------------- */

/* Every struct a ctypes binding declares by hand, with every field: the binding compares its own
 * sizes and offsets with these when it loads the library, so a field added, removed or retyped on
 * one side only fails there instead of corrupting memory. */
typedef struct hd_layout {
    const char *name;
    size_t bytes;
} hd_layout_t;

#define HD_FIELD(type, field)                   \
    {                                           \
#type "." #field, offsetof(type, field) \
    }

static const hd_layout_t kLayouts[] = {
    {"cdro_hd_config_t", sizeof(cdro_hd_config_t)},
    HD_FIELD(cdro_hd_config_t, seed),
    HD_FIELD(cdro_hd_config_t, max_range_m),
    HD_FIELD(cdro_hd_config_t, pozyx_firmware),
    HD_FIELD(cdro_hd_config_t, pozyx_present),
    HD_FIELD(cdro_hd_config_t, free_ram_bytes),
    {"cdro_hd_callbacks_t", sizeof(cdro_hd_callbacks_t)},
    HD_FIELD(cdro_hd_callbacks_t, context),
    HD_FIELD(cdro_hd_callbacks_t, position),
    HD_FIELD(cdro_hd_callbacks_t, accel),
    HD_FIELD(cdro_hd_callbacks_t, range),
    HD_FIELD(cdro_hd_callbacks_t, room),
    HD_FIELD(cdro_hd_callbacks_t, write),
    {"cdro_hd_counters_t", sizeof(cdro_hd_counters_t)},
    HD_FIELD(cdro_hd_counters_t, ranges_ok_direct),
    HD_FIELD(cdro_hd_counters_t, ranges_ok_remote),
    HD_FIELD(cdro_hd_counters_t, ranges_failed_direct),
    HD_FIELD(cdro_hd_counters_t, ranges_failed_remote),
    HD_FIELD(cdro_hd_counters_t, retries),
    HD_FIELD(cdro_hd_counters_t, bus_errors),
    HD_FIELD(cdro_hd_counters_t, timeouts),
    HD_FIELD(cdro_hd_counters_t, frames_sent),
    HD_FIELD(cdro_hd_counters_t, frames_dropped),
    HD_FIELD(cdro_hd_counters_t, commands_rejected),
    HD_FIELD(cdro_hd_counters_t, stale_results),
    HD_FIELD(cdro_hd_counters_t, accel_failures),
    HD_FIELD(cdro_hd_counters_t, host_bytes_lost),
    HD_FIELD(cdro_hd_counters_t, boots),
};

#undef HD_FIELD

uint32_t cdro_hd_layout(const char *name, uint8_t *found)
{
    size_t i;
    for (i = 0; i < sizeof kLayouts / sizeof kLayouts[0]; ++i) {
        if (strcmp(kLayouts[i].name, name) == 0) {
            *found = 1;
            return (uint32_t)kLayouts[i].bytes;
        }
    }
    *found = 0;
    return 0;
}
