/*
 * pozyx_sim.c: the simulated Pozyx device (see pozyx_sim.h).
 */
#include "pozyx_sim/pozyx_sim.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

#include "cdro_fw/pozyx_regs.h"

#define SIM_PI 3.14159265358979323846

/* Bus phases. */
enum {
    PHASE_IDLE = 0,
    PHASE_WRITE_FIRST, /* address+W seen: the next byte is a register or function address */
    PHASE_POINTER_SET, /* a register address was written; a repeated start may follow */
    PHASE_PARAMS,      /* a function address was written: parameters follow */
    PHASE_WRITE_DATA,  /* documented register write: data after the repeated start */
    PHASE_READ,        /* address+R */
    PHASE_REFUSED      /* the rest of this address phase is NACKed */
};

/* Event kinds. */
enum {
    EVENT_LOCAL_RANGING = 1, /* a = partner */
    EVENT_DISCOVERY,         /* a = type */
    EVENT_REPLY,             /* a = sender; data = reply bytes -> FUNC */
    EVENT_REMOTE_RANGING,    /* a = ranging node, b = partner: range, then the result message */
    EVENT_MESSAGE,           /* a = sender; data -> RX_DATA */
    EVENT_LOCAL_ERROR        /* ERR with data[0] as ERRORCODE */
};

/* ---- helpers ----------------------------------------------------------------------------- */

static void trace(pozyx_sim_t *sim, const char *format, unsigned a, unsigned b, unsigned c)
{
    char line[160];
    if (sim->config.trace == NULL) {
        return;
    }
    (void)snprintf(line, sizeof line, "%10.3f ms  ", (double)sim->now_us / 1000.0);
    {
        const size_t used = strlen(line);
        /* The format strings are literals of this file. */
#if defined(__GNUC__)
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wformat-nonliteral"
#endif
        (void)snprintf(line + used, sizeof line - used, format, a, b, c);
#if defined(__GNUC__)
#pragma GCC diagnostic pop
#endif
    }
    sim->config.trace(sim->config.trace_context, line);
}

static uint64_t rng_next(pozyx_sim_t *sim)
{
    /* xorshift64* */
    uint64_t x = sim->rng_state;
    x ^= x >> 12;
    x ^= x << 25;
    x ^= x >> 27;
    sim->rng_state = x;
    return x * 0x2545F4914F6CDD1DULL;
}

static double rng_uniform(pozyx_sim_t *sim)
{
    return ((double)(rng_next(sim) >> 11) + 0.5) / 9007199254740992.0; /* (0, 1) */
}

static double rng_normal(pozyx_sim_t *sim)
{
    double u;
    double v;
    if (sim->has_spare_normal) {
        sim->has_spare_normal = 0;
        return sim->spare_normal;
    }
    u = rng_uniform(sim);
    v = rng_uniform(sim);
    sim->spare_normal = sqrt(-2.0 * log(u)) * sin(2.0 * SIM_PI * v);
    sim->has_spare_normal = 1;
    return sqrt(-2.0 * log(u)) * cos(2.0 * SIM_PI * v);
}

static uint16_t get_u16(const uint8_t *p) { return (uint16_t)(p[0] | (p[1] << 8)); }

static void put_u16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)(v & 0xFFU);
    p[1] = (uint8_t)(v >> 8);
}

static void put_u32(uint8_t *p, uint32_t v)
{
    put_u16(p, (uint16_t)(v & 0xFFFFU));
    put_u16(p + 2, (uint16_t)(v >> 16));
}

static double seconds(const pozyx_sim_t *sim) { return (double)sim->now_us / 1e6; }

static uint32_t node_clock_ms(const pozyx_sim_t *sim, const pozyx_sim_node_t *node)
{
    return (uint32_t)(node->config.clock_offset_ms + (uint32_t)(sim->now_us / 1000U));
}

static pozyx_sim_node_t *local(pozyx_sim_t *sim) { return sim->node_count > 0 ? &sim->nodes[0] : NULL; }

/* Sees power-ups since the last look: a node powered again boots for config.boot_us. */
static void track_power(pozyx_sim_t *sim)
{
    uint8_t i;
    for (i = 0; i < sim->node_count; ++i) {
        pozyx_sim_node_t *node = &sim->nodes[i];
        if (node->config.powered && !node->was_powered) {
            node->ready_at_us = sim->now_us + sim->config.boot_us;
        }
        node->was_powered = node->config.powered;
    }
}

/* Powered and booted. */
static uint8_t node_up(const pozyx_sim_t *sim, const pozyx_sim_node_t *node)
{
    return (uint8_t)(node != NULL && node->config.powered && sim->now_us >= node->ready_at_us);
}

static uint8_t local_up(const pozyx_sim_t *sim)
{
    return (uint8_t)(sim->node_count > 0U && node_up(sim, &sim->nodes[0]));
}

/* Taking part in a ranging exchange at time t_us (config.busy_remotes). */
static uint8_t busy_at(const pozyx_sim_t *sim, const pozyx_sim_node_t *node, uint64_t t_us)
{
    return (uint8_t)(sim->config.busy_remotes && t_us >= node->busy_from_us && t_us < node->busy_until_us);
}

/* ---- configuration ---------------------------------------------------------------------- */

void pozyx_sim_config_default(pozyx_sim_config_t *config)
{
    memset(config, 0, sizeof(*config));
    config->i2c_address = POZYX_SIM_DEFAULT_I2C_ADDRESS;
    config->who_am_i = POZYX_WHO_AM_I_VALUE;
    config->firmware_version = 0x11;
    config->imu_flag = 1;
    config->seed = 1;
    config->range_noise_std_mm = 30.0;
    config->accel_noise_std_mg = 5.0;
    config->max_range_m = 50.0;
    config->ranging_duration_us = 15000;
    config->uwb_message_us = 3000;
    config->remote_processing_us = 1000;
    config->late_reply_us = 400000;
}

void pozyx_sim_config_realistic(pozyx_sim_config_t *config)
{
    pozyx_sim_config_default(config);
    /* Timings at the default UWB settings (channel 5, 110 kbit/s, PRF 64 MHz, preamble 1024),
     * sources in docs/firmware.md: one two-way ranging ~40 ms (pypozyx issue 64: ~18 Hz, 55 ms
     * a loop, for a local ranging plus two LED commands, one of them remote), one short message
     * ~3.5 ms (DW1000 frame: 1.05 ms preamble, 0.25 ms SFD and header, ~85 us a payload byte,
     * plus the turnaround). */
    config->ranging_duration_us = 40000;
    config->uwb_message_us = 3500;
    config->remote_processing_us = 1000;
    config->reply_raises_rx_data = 1;
    config->busy_remotes = 1;
    config->collisions = 1;
    config->device_list_full_error = 1;
    /* Both reference libraries wait 250 ms after power-up before the first access. */
    config->boot_us = 250000;
    /* Not documented (the bench checklist measures them): a function's return byte after
     * 100 us, a register's first byte after 10 us. */
    config->stretch_function_us = 100;
    config->stretch_register_us = 10;
}

void pozyx_sim_init(pozyx_sim_t *sim, const pozyx_sim_config_t *config)
{
    memset(sim, 0, sizeof(*sim));
    sim->config = *config;
    sim->rng_state = config->seed != 0U ? config->seed : 0x9E3779B97F4A7C15ULL;
    sim->faults.error_code = POZYX_ERROR_RANGING;
    (void)rng_next(sim);
}

void pozyx_sim_node_config_default(pozyx_sim_node_config_t *node, uint16_t id, uint8_t is_tag)
{
    memset(node, 0, sizeof(*node));
    node->id = id;
    node->is_tag = is_tag;
    node->powered = 1;
}

int pozyx_sim_add_node(pozyx_sim_t *sim, const pozyx_sim_node_config_t *node)
{
    pozyx_sim_node_t *slot;
    if (sim->node_count >= POZYX_SIM_MAX_NODES || node->id == 0U || pozyx_sim_find(sim, node->id) != NULL) {
        return -1;
    }
    slot = &sim->nodes[sim->node_count];
    memset(slot, 0, sizeof(*slot));
    slot->config = *node;
    slot->accel_sample_index = -1;
    put_u16(&slot->regs[POZYX_REG_NETWORK_ID], node->id);
    /* The settings the Pozyx performance tests used (register facts 7; [unverified] as factory
     * defaults): channel 5, 110 kbit/s with PRF 64 MHz, preamble 1024; gain 11.5 dB (assumed). */
    slot->regs[POZYX_REG_UWB_CHANNEL] = 5;
    slot->regs[POZYX_REG_UWB_RATES] = (2U << 6) | 0U;
    slot->regs[POZYX_REG_UWB_PLEN] = 0x08;
    slot->regs[POZYX_REG_UWB_GAIN] = 23;
    slot->was_powered = node->powered;
    slot->ready_at_us = sim->now_us + sim->config.boot_us;
    return sim->node_count++;
}

pozyx_sim_node_t *pozyx_sim_find(pozyx_sim_t *sim, uint16_t id)
{
    uint8_t i;
    for (i = 0; i < sim->node_count; ++i) {
        if (sim->nodes[i].config.id == id) {
            return &sim->nodes[i];
        }
    }
    return NULL;
}

pozyx_sim_vec3_t pozyx_sim_position(const pozyx_sim_t *sim, const pozyx_sim_node_t *node)
{
    if (node->config.position_fn != NULL) {
        return node->config.position_fn(node->config.position_context, seconds(sim));
    }
    return node->config.position_m;
}

static double distance_m(const pozyx_sim_t *sim, const pozyx_sim_node_t *a, const pozyx_sim_node_t *b)
{
    const pozyx_sim_vec3_t p = pozyx_sim_position(sim, a);
    const pozyx_sim_vec3_t q = pozyx_sim_position(sim, b);
    const double dx = p.x - q.x;
    const double dy = p.y - q.y;
    const double dz = p.z - q.z;
    return sqrt(dx * dx + dy * dy + dz * dz);
}

static const pozyx_sim_node_t *find_const(const pozyx_sim_t *sim, uint16_t id)
{
    uint8_t i;
    for (i = 0; i < sim->node_count; ++i) {
        if (sim->nodes[i].config.id == id) {
            return &sim->nodes[i];
        }
    }
    return NULL;
}

double pozyx_sim_true_distance_m(const pozyx_sim_t *sim, uint16_t a, uint16_t b)
{
    const pozyx_sim_node_t *na = find_const(sim, a);
    const pozyx_sim_node_t *nb = find_const(sim, b);
    if (na == NULL || nb == NULL) {
        return -1.0;
    }
    return distance_m(sim, na, nb);
}

/* A UWB link works when both ends exist, are up, use the same channel, rates and preamble
 * (register facts 7) and are within max_range_m. */
static uint8_t link_ok(pozyx_sim_t *sim, const pozyx_sim_node_t *a, const pozyx_sim_node_t *b)
{
    return (uint8_t)(a != NULL && b != NULL && a != b && node_up(sim, a) && node_up(sim, b) &&
                     memcmp(&a->regs[POZYX_REG_UWB_CHANNEL], &b->regs[POZYX_REG_UWB_CHANNEL], 3) == 0 &&
                     distance_m(sim, a, b) <= sim->config.max_range_m);
}

/* ---- events ------------------------------------------------------------------------------- */

static int schedule(pozyx_sim_t *sim, uint64_t at_us, uint8_t kind, uint16_t a, uint16_t b, const uint8_t *data,
                    uint8_t length)
{
    pozyx_sim_event_t *event;
    if (sim->event_count >= POZYX_SIM_MAX_EVENTS || length > POZYX_SIM_BUFFER_SIZE) {
        return -1;
    }
    event = &sim->events[sim->event_count++];
    memset(event, 0, sizeof(*event));
    event->at_us = at_us;
    event->kind = kind;
    event->a = a;
    event->b = b;
    event->length = length;
    if (length > 0U && data != NULL) {
        memcpy(event->data, data, length);
    }
    return 0;
}

uint64_t pozyx_sim_next_event_us(const pozyx_sim_t *sim)
{
    uint64_t next = UINT64_MAX;
    uint8_t i;
    for (i = 0; i < sim->event_count; ++i) {
        if (sim->events[i].at_us < next) {
            next = sim->events[i].at_us;
        }
    }
    return next;
}

int pozyx_sim_inject_message(pozyx_sim_t *sim, uint16_t from, const uint8_t *data, uint8_t length, uint64_t at_us)
{
    return schedule(sim, at_us, EVENT_MESSAGE, from, 0, data, length);
}

/* config.collisions: a message on air at the local device over [at - uwb_message_us, at) is lost
 * when it overlaps another message arriving there (both are lost: the other is marked), the last
 * message received, or the local device's own sending or ranging (it is half-duplex). */
static uint8_t collides(pozyx_sim_t *sim, pozyx_sim_event_t *event)
{
    const uint64_t from_us = event->at_us > sim->config.uwb_message_us ? event->at_us - sim->config.uwb_message_us : 0U;
    uint8_t lost = event->collided;
    uint8_t i;
    if (!sim->config.collisions) {
        return 0;
    }
    if (from_us < sim->last_rx_until_us ||
        (from_us < sim->local_air_until_us && event->at_us > sim->local_air_from_us)) {
        lost = 1;
    }
    for (i = 0; i < sim->event_count; ++i) {
        pozyx_sim_event_t *other = &sim->events[i];
        if ((other->kind == EVENT_REPLY || other->kind == EVENT_MESSAGE) &&
            other->at_us < event->at_us + sim->config.uwb_message_us) {
            other->collided = 1;
            lost = 1;
        }
    }
    if (event->at_us > sim->last_rx_until_us) {
        sim->last_rx_until_us = event->at_us;
    }
    if (lost) {
        ++sim->stats.collisions;
        trace(sim, "message from 0x%04X lost in a collision", event->a, 0, 0);
    }
    return lost;
}

static void deliver(pozyx_sim_t *sim, uint16_t sender, const uint8_t *data, uint8_t length, uint8_t flag)
{
    sim->rx_sender = sender;
    sim->rx_length = length;
    memset(sim->rx_buffer, 0, sizeof sim->rx_buffer);
    if (length > 0U) {
        memcpy(sim->rx_buffer, data, length);
    }
    sim->int_status = (uint8_t)(sim->int_status | flag);
    ++sim->stats.messages_delivered;
    trace(sim, "message from 0x%04X, %u bytes, flag 0x%02X", sender, length, flag);
}

static void raise_error(pozyx_sim_t *sim, uint8_t code)
{
    sim->error_code = code;
    sim->int_status = (uint8_t)(sim->int_status | POZYX_INT_ERR);
    trace(sim, "ERR 0x%02X", code, 0, 0);
}

/* Consumes one armed fault. */
static uint8_t take(pozyx_sim_t *sim, uint32_t *counter)
{
    if (*counter == 0U) {
        return 0;
    }
    --*counter;
    ++sim->stats.faults_injected;
    return 1;
}

/* The caller's outcome of `node` ranging with `partner` now (config.range_fn); 0 without one. */
static uint8_t given_outcome(pozyx_sim_t *sim, const pozyx_sim_node_t *node, const pozyx_sim_node_t *partner,
                             pozyx_sim_range_outcome_t *out)
{
    memset(out, 0, sizeof(*out));
    if (sim->config.range_fn == NULL) {
        return 0;
    }
    sim->config.range_fn(sim->config.range_context, node->config.id, partner->config.id, seconds(sim), out);
    return 1;
}

/* Stores the result of `node` ranging with `partner`, as the real device does: the last entry
 * per partner; the distance is the caller's (`given`) or the model's. Applies the garbage and
 * stale faults. */
static uint8_t store_range(pozyx_sim_t *sim, pozyx_sim_node_t *node, const pozyx_sim_node_t *partner,
                           const pozyx_sim_range_outcome_t *given)
{
    pozyx_sim_range_entry_t *entry = NULL;
    double d_mm;
    uint8_t i;
    ++sim->stats.rangings;
    if (take(sim, &sim->faults.stale_range)) {
        trace(sim, "ranging 0x%04X-0x%04X: stale (entry kept)", node->config.id, partner->config.id, 0);
        return 1;
    }
    for (i = 0; i < node->range_count; ++i) {
        if (node->ranges[i].partner == partner->config.id) {
            entry = &node->ranges[i];
        }
    }
    if (entry == NULL) {
        if (node->range_count < POZYX_SIM_MAX_RANGE_ENTRIES) {
            entry = &node->ranges[node->range_count++];
        } else if (sim->config.device_list_full_error) {
            ++sim->stats.list_full_errors;
            trace(sim, "ranging 0x%04X-0x%04X: device list full", node->config.id, partner->config.id, 0);
            return 0;
        } else {
            memmove(&node->ranges[0], &node->ranges[1], sizeof(node->ranges[0]) * (POZYX_SIM_MAX_RANGE_ENTRIES - 1));
            entry = &node->ranges[POZYX_SIM_MAX_RANGE_ENTRIES - 1];
        }
    }
    entry->partner = partner->config.id;
    entry->timestamp_ms = node_clock_ms(sim, node);
    if (given != NULL) {
        entry->distance_mm = given->distance_mm;
        entry->rss_dbm = given->rss_dbm;
    } else {
        d_mm = distance_m(sim, node, partner) * 1000.0 + sim->config.range_bias_mm +
               sim->config.range_noise_std_mm * rng_normal(sim);
        if (d_mm < 0.0) {
            d_mm = 0.0;
        }
        entry->distance_mm = (uint32_t)lround(d_mm);
        {
            const double d_m = d_mm / 1000.0 > 0.1 ? d_mm / 1000.0 : 0.1;
            entry->rss_dbm = (int16_t)lround(-70.0 - 20.0 * log10(d_m));
        }
    }
    if (take(sim, &sim->faults.garbage_range)) {
        entry->distance_mm = POZYX_SIM_GARBAGE_DISTANCE_MM;
    }
    trace(sim, "ranging 0x%04X-0x%04X: %u mm", node->config.id, partner->config.id, entry->distance_mm);
    return 1;
}

static const pozyx_sim_range_entry_t *find_range(const pozyx_sim_node_t *node, uint16_t partner)
{
    uint8_t i;
    for (i = 0; i < node->range_count; ++i) {
        if (node->ranges[i].partner == partner) {
            return &node->ranges[i];
        }
    }
    return NULL;
}

/* [1, timestamp u32, distance u32, rss i16] or [0] when no entry. Returns the length. */
static uint8_t rangeinfo_reply(const pozyx_sim_node_t *node, uint16_t partner, uint8_t *out)
{
    const pozyx_sim_range_entry_t *entry = find_range(node, partner);
    if (entry == NULL) {
        out[0] = 0;
        return 1;
    }
    out[0] = 1;
    put_u32(out + 1, entry->timestamp_ms);
    put_u32(out + 5, entry->distance_mm);
    put_u16(out + 9, (uint16_t)entry->rss_dbm);
    return 11;
}

static void run_event(pozyx_sim_t *sim, pozyx_sim_event_t *event)
{
    pozyx_sim_node_t *self = local(sim);
    switch (event->kind) {
    case EVENT_LOCAL_RANGING: {
        pozyx_sim_node_t *partner = pozyx_sim_find(sim, event->a);
        pozyx_sim_range_outcome_t outcome;
        sim->busy = 0;
        if (self == NULL || !self->config.powered) {
            break;
        }
        if (take(sim, &sim->faults.error_completion)) {
            raise_error(sim, sim->faults.error_code);
        } else if (!link_ok(sim, self, partner) || busy_at(sim, partner, sim->now_us)) {
            raise_error(sim, POZYX_ERROR_RTIMEOUT1);
        } else if (given_outcome(sim, self, partner, &outcome) && outcome.error_code != 0U) {
            raise_error(sim, outcome.error_code);
        } else if (!store_range(sim, self, partner, sim->config.range_fn != NULL ? &outcome : NULL)) {
            raise_error(sim, POZYX_ERROR_DEVICE_LIST_FULL);
        } else {
            sim->int_status = (uint8_t)(sim->int_status | POZYX_INT_FUNC);
        }
        break;
    }
    case EVENT_DISCOVERY: {
        uint8_t i;
        sim->busy = 0;
        if (self == NULL || !self->config.powered) {
            break;
        }
        if (take(sim, &sim->faults.error_completion)) {
            raise_error(sim, sim->faults.error_code);
            break;
        }
        for (i = 1; i < sim->node_count; ++i) {
            pozyx_sim_node_t *node = &sim->nodes[i];
            uint8_t j;
            uint8_t known = 0;
            const uint8_t wanted =
                (uint8_t)(event->a == POZYX_DISCOVER_ALL || (event->a == POZYX_DISCOVER_TAGS && node->config.is_tag) ||
                          (event->a == POZYX_DISCOVER_ANCHORS && !node->config.is_tag));
            if (!wanted || !link_ok(sim, self, node)) {
                continue;
            }
            for (j = 0; j < sim->device_list_size; ++j) {
                known = (uint8_t)(known || sim->device_list[j] == node->config.id);
            }
            if (known) {
                continue;
            }
            if (sim->device_list_size >= POZYX_SIM_MAX_RANGE_ENTRIES) {
                raise_error(sim, POZYX_ERROR_DEVICE_LIST_FULL);
                break;
            }
            sim->device_list[sim->device_list_size++] = node->config.id;
        }
        sim->int_status = (uint8_t)(sim->int_status | POZYX_INT_FUNC);
        trace(sim, "discovery: %u devices", sim->device_list_size, 0, 0);
        break;
    }
    case EVENT_REPLY:
        if (!collides(sim, event) && local_up(sim)) {
            deliver(sim, event->a, event->data, event->length,
                    (uint8_t)(POZYX_INT_FUNC | (sim->config.reply_raises_rx_data ? POZYX_INT_RX_DATA : 0U)));
        }
        break;
    case EVENT_MESSAGE:
        if (!collides(sim, event) && local_up(sim)) {
            deliver(sim, event->a, event->data, event->length, POZYX_INT_RX_DATA);
        }
        break;
    case EVENT_LOCAL_ERROR: raise_error(sim, event->data[0]); break;
    case EVENT_REMOTE_RANGING: {
        pozyx_sim_node_t *ranger = pozyx_sim_find(sim, event->a);
        pozyx_sim_node_t *partner = pozyx_sim_find(sim, event->b);
        pozyx_sim_range_outcome_t outcome;
        if (ranger == NULL || !ranger->config.powered) {
            break;
        }
        if (take(sim, &sim->faults.error_completion)) {
            /* The failure shows on the local device as an ERR (e.g. no acknowledge). */
            raise_error(sim, sim->faults.error_code);
            break;
        }
        if (!link_ok(sim, ranger, partner)) {
            trace(sim, "remote ranging 0x%04X-0x%04X failed: no link", event->a, event->b, 0);
            break; /* no result message: the local device times out */
        }
        if (given_outcome(sim, ranger, partner, &outcome) && outcome.error_code != 0U) {
            raise_error(sim, outcome.error_code); /* as error_completion: an ERR on the local device */
            break;
        }
        if (!store_range(sim, ranger, partner, sim->config.range_fn != NULL ? &outcome : NULL)) {
            break; /* the same for a full device list */
        }
        if (link_ok(sim, ranger, self)) {
            const pozyx_sim_range_entry_t *entry = find_range(ranger, event->b);
            uint8_t message[4] = {0, 0, 0, 0};
            if (entry != NULL) {
                put_u32(message, entry->distance_mm);
            }
            (void)schedule(sim,
                           sim->now_us + sim->config.uwb_message_us +
                               (take(sim, &sim->faults.late_reply) ? sim->config.late_reply_us : 0U),
                           EVENT_MESSAGE, event->a, 0, message, sizeof message);
        }
        break;
    }
    default: break;
    }
}

void pozyx_sim_advance(pozyx_sim_t *sim, uint64_t now_us)
{
    track_power(sim);
    for (;;) {
        uint8_t best = 0xFF;
        uint8_t i;
        for (i = 0; i < sim->event_count; ++i) {
            if (sim->events[i].at_us <= now_us && (best == 0xFF || sim->events[i].at_us < sim->events[best].at_us)) {
                best = i;
            }
        }
        if (best == 0xFF) {
            break;
        }
        {
            pozyx_sim_event_t event = sim->events[best];
            sim->events[best] = sim->events[--sim->event_count];
            if (event.at_us > sim->now_us) {
                sim->now_us = event.at_us;
            }
            run_event(sim, &event);
        }
    }
    if (now_us > sim->now_us) {
        sim->now_us = now_us;
    }
    if (sim->config.imu_flag && local(sim) != NULL && local(sim)->config.is_tag) {
        const uint64_t tick = sim->now_us / 10000U;
        if (tick != sim->last_imu_tick) {
            sim->last_imu_tick = tick;
            sim->int_status = (uint8_t)(sim->int_status | POZYX_INT_IMU);
        }
    }
}

/* ---- registers ------------------------------------------------------------------------------ */

static void update_accel(pozyx_sim_t *sim, pozyx_sim_node_t *node)
{
    const int64_t index = (int64_t)(sim->now_us / 10000U); /* 100 Hz samples */
    pozyx_sim_vec3_t a = {0.0, 0.0, 1000.0};
    double axes[3];
    uint8_t i;
    if (index == node->accel_sample_index) {
        return;
    }
    node->accel_sample_index = index;
    if (node->config.accel_fn != NULL) {
        a = node->config.accel_fn(node->config.accel_context, (double)index * 0.01);
    }
    axes[0] = a.x;
    axes[1] = a.y;
    axes[2] = a.z;
    for (i = 0; i < 3; ++i) {
        double v = axes[i] + sim->config.accel_noise_std_mg * rng_normal(sim);
        if (v > 16000.0) {
            v = 16000.0; /* the sensor saturates at 16 g */
        } else if (v < -16000.0) {
            v = -16000.0;
        }
        node->accel_mg[i] = (int16_t)lround(v);
    }
}

static uint8_t healthy_self_test(const pozyx_sim_node_t *node)
{
    if (node->config.self_test != 0U) {
        return node->config.self_test;
    }
    return node->config.is_tag ? POZYX_ST_EXPECTED_TAG : POZYX_ST_EXPECTED_ANCHOR;
}

/* A register as seen by a read, local (is_local: side effects) or remote. */
static uint8_t read_register(pozyx_sim_t *sim, pozyx_sim_node_t *node, uint8_t reg, uint8_t is_local)
{
    uint8_t value;
    switch (reg) {
    case POZYX_REG_WHO_AM_I: return sim->config.who_am_i;
    case POZYX_REG_FIRMWARE_VER: return sim->config.firmware_version;
    case POZYX_REG_HARDWARE_VER:
        return (uint8_t)(((node->config.is_tag ? POZYX_HW_TYPE_TAG : POZYX_HW_TYPE_ANCHOR) << POZYX_HW_TYPE_SHIFT) |
                         0x03);
    case POZYX_REG_ST_RESULT: return healthy_self_test(node);
    case POZYX_REG_ERRORCODE:
        if (!is_local) {
            return 0;
        }
        value = sim->error_code;
        sim->error_code = 0; /* clear-on-read */
        return value;
    case POZYX_REG_INT_STATUS:
        if (!is_local) {
            return 0;
        }
        value = sim->int_status;
        sim->int_status = 0; /* clear-on-read */
        return value;
    case POZYX_REG_DEVICE_LIST_SIZE: return is_local ? sim->device_list_size : 0U;
    case POZYX_REG_RX_NETWORK_ID: return is_local ? (uint8_t)(sim->rx_sender & 0xFFU) : 0U;
    case POZYX_REG_RX_NETWORK_ID + 1: return is_local ? (uint8_t)(sim->rx_sender >> 8) : 0U;
    case POZYX_REG_RX_DATA_LEN: return is_local ? sim->rx_length : 0U;
    default: break;
    }
    if (reg >= POZYX_REG_ACCEL_X && reg < POZYX_REG_ACCEL_X + 6U) {
        const uint8_t offset = (uint8_t)(reg - POZYX_REG_ACCEL_X);
        uint16_t raw = 0; /* an anchor has no accelerometer: zeros */
        if (node->config.is_tag) {
            update_accel(sim, node);
            raw = (uint16_t)node->accel_mg[offset / 2U];
        }
        return (uint8_t)((offset % 2U) == 0U ? (raw & 0xFFU) : (raw >> 8));
    }
    return node->regs[reg];
}

static uint8_t writable(uint8_t reg)
{
    return (uint8_t)((reg >= 0x10U && reg <= 0x11U) || (reg >= 0x14U && reg <= 0x23U) ||
                     (reg >= 0x27U && reg <= 0x2AU) || (reg >= 0x30U && reg <= 0x3BU) ||
                     (reg >= 0x85U && reg <= 0x88U));
}

/* ---- functions ------------------------------------------------------------------------------- */

/* A remote node's answer to a request (TX buffer contents and op). Returns 1 if it replies. */
static uint8_t remote_handle(pozyx_sim_t *sim, pozyx_sim_node_t *node, uint8_t op, uint8_t *reply, uint8_t *length,
                             uint64_t reply_at_us)
{
    const uint8_t *request = sim->tx_buffer;
    *length = 0;
    switch (op) {
    case POZYX_REMOTE_READ: {
        uint8_t count = request[1];
        uint8_t i;
        if (sim->tx_length < 2U || count == 0U || count > POZYX_SIM_BUFFER_SIZE) {
            return 0;
        }
        for (i = 0; i < count; ++i) {
            reply[i] = read_register(sim, node, (uint8_t)(request[0] + i), 0);
        }
        *length = count;
        return 1;
    }
    case POZYX_REMOTE_WRITE: {
        uint8_t i;
        for (i = 1; i < sim->tx_length; ++i) {
            const uint8_t reg = (uint8_t)(request[0] + i - 1U);
            if (writable(reg)) {
                node->regs[reg] = request[i];
            }
        }
        return 1; /* the flag is the acknowledgement */
    }
    case POZYX_REMOTE_FUNCTION: {
        const uint8_t fn = request[0];
        const uint8_t nparams = (uint8_t)(sim->tx_length - 1U);
        const uint8_t *params = request + 1;
        if (sim->tx_length < 1U) {
            return 0;
        }
        if (fn == POZYX_FN_DO_RANGING) {
            const uint16_t partner = nparams >= 2U ? get_u16(params) : 0U;
            reply[0] = (uint8_t)(nparams == 2U && partner != 0U && partner != node->config.id);
            *length = 1;
            if (reply[0] && !take(sim, &sim->faults.no_completion)) {
                pozyx_sim_node_t *other = pozyx_sim_find(sim, partner);
                const uint64_t done_us = reply_at_us + sim->config.ranging_duration_us;
                (void)schedule(sim, done_us, EVENT_REMOTE_RANGING, node->config.id, partner, NULL, 0);
                /* It ranges once its acknowledgement is out, and is busy until its result
                 * message is; the partner for the exchange itself. */
                node->busy_from_us = reply_at_us;
                node->busy_until_us = done_us + sim->config.uwb_message_us;
                if (other != NULL) {
                    other->busy_from_us = reply_at_us;
                    other->busy_until_us = done_us;
                }
            }
            return 1;
        }
        if (fn == POZYX_FN_DEVICE_GETRANGEINFO && nparams == 2U) {
            *length = rangeinfo_reply(node, get_u16(params), reply);
            return 1;
        }
        if (fn == POZYX_FN_LED_CTRL && nparams == 1U) {
            reply[0] = 1;
            *length = 1;
            return 1;
        }
        reply[0] = 0; /* anything else: refused */
        *length = 1;
        return 1;
    }
    default: return 0;
    }
}

static void call_tx_send(pozyx_sim_t *sim)
{
    uint16_t dest;
    uint8_t op;
    pozyx_sim_node_t *self = local(sim);
    pozyx_sim_node_t *node;
    uint8_t reply[POZYX_SIM_BUFFER_SIZE];
    uint8_t reply_length = 0;
    uint64_t reply_at_us;
    sim->result[0] = 0;
    if (sim->params_length != 3U) {
        return;
    }
    dest = get_u16(sim->params);
    op = sim->params[2];
    if (op != POZYX_REMOTE_READ && op != POZYX_REMOTE_WRITE && op != POZYX_REMOTE_DATA && op != POZYX_REMOTE_FUNCTION) {
        return;
    }
    if (dest == 0U && op != POZYX_REMOTE_DATA) {
        return;
    }
    sim->result[0] = 1;
    if (op == POZYX_REMOTE_DATA) {
        return;
    }
    ++sim->stats.remote_requests;
    trace(sim, "TX_SEND to 0x%04X op 0x%02X (%u bytes)", dest, op, sim->tx_length);
    node = pozyx_sim_find(sim, dest);
    /* The request is on air for one message time (the local device can receive nothing then). */
    sim->local_air_from_us = sim->now_us;
    sim->local_air_until_us = sim->now_us + sim->config.uwb_message_us;
    /* The request and its reply each take one message; the remote node handles it in between. */
    reply_at_us = sim->now_us + 2U * (uint64_t)sim->config.uwb_message_us + sim->config.remote_processing_us;
    if (!link_ok(sim, self, node)) {
        return; /* nobody answers: the master times out */
    }
    if (busy_at(sim, node, sim->now_us + sim->config.uwb_message_us)) {
        ++sim->stats.busy_losses;
        trace(sim, "request to 0x%04X lost: it is ranging", dest, 0, 0);
        return;
    }
    if (!remote_handle(sim, node, op, reply, &reply_length, reply_at_us)) {
        return;
    }
    if (!link_ok(sim, self, node)) {
        return; /* a remote write of its UWB settings: it answers on the new ones */
    }
    if (take(sim, &sim->faults.drop_remote_reply)) {
        trace(sim, "reply from 0x%04X lost", dest, 0, 0);
        return;
    }
    if (take(sim, &sim->faults.late_reply)) {
        reply_at_us += sim->config.late_reply_us;
        trace(sim, "reply from 0x%04X late", dest, 0, 0);
    }
    (void)schedule(sim, reply_at_us, EVENT_REPLY, dest, 0, reply, reply_length);
}

static void call_do_ranging(pozyx_sim_t *sim)
{
    uint16_t dest;
    sim->result[0] = 0;
    if (sim->params_length != 2U) {
        raise_error(sim, POZYX_ERROR_FUNC_PARAMS);
        return;
    }
    dest = get_u16(sim->params);
    if (dest == 0U || sim->node_count == 0U || dest == sim->nodes[0].config.id || sim->busy) {
        return;
    }
    sim->result[0] = 1;
    if (take(sim, &sim->faults.no_completion)) {
        return; /* accepted, never completes */
    }
    sim->busy = 1;
    sim->local_air_from_us = sim->now_us;
    sim->local_air_until_us = sim->now_us + sim->config.ranging_duration_us;
    (void)schedule(sim, sim->now_us + sim->config.ranging_duration_us, EVENT_LOCAL_RANGING, dest, 0, NULL, 0);
}

static void call_discover(pozyx_sim_t *sim)
{
    uint8_t type = POZYX_DISCOVER_ANCHORS;
    uint8_t slots = 3;
    uint8_t slot_ms = 10;
    sim->result[0] = 0;
    if (sim->params_length > 3U || sim->busy) {
        return;
    }
    if (sim->params_length >= 1U) {
        type = sim->params[0];
    }
    if (sim->params_length >= 2U) {
        slots = sim->params[1];
    }
    if (sim->params_length >= 3U) {
        slot_ms = sim->params[2];
    }
    if (type > POZYX_DISCOVER_ALL) {
        return;
    }
    sim->result[0] = 1;
    if (take(sim, &sim->faults.no_completion)) {
        return;
    }
    sim->busy = 1;
    (void)schedule(sim, sim->now_us + (uint64_t)slot_ms * 1000U * (uint64_t)(slots + 1U), EVENT_DISCOVERY, type, 0,
                   NULL, 0);
}

/* Runs the addressed function with the collected parameters; fills result/result_length. */
static void execute(pozyx_sim_t *sim)
{
    const uint8_t fn = sim->pointer;
    const uint8_t *params = sim->params;
    const uint8_t n = sim->params_length;
    pozyx_sim_node_t *self = local(sim);
    sim->executed = 1;
    sim->result_length = 1;
    sim->result_position = 0;
    memset(sim->result, 0, sizeof sim->result);
    if (fn >= 0xB0U && fn < 0xB0U + 64U) {
        ++sim->stats.function_calls[fn - 0xB0U];
    }
    trace(sim, "function 0x%02X, %u params", fn, n, 0);
    if (take(sim, &sim->faults.refuse_function)) {
        return; /* return byte 0 */
    }
    switch (fn) {
    case POZYX_FN_TX_DATA:
        if (n >= 1U && (unsigned)params[0] + (unsigned)(n - 1U) <= POZYX_SIM_BUFFER_SIZE) {
            memcpy(sim->tx_buffer + params[0], params + 1, (size_t)(n - 1U));
            sim->tx_length = (uint8_t)(params[0] + n - 1U);
            sim->result[0] = 1;
        }
        break;
    case POZYX_FN_TX_SEND: call_tx_send(sim); break;
    case POZYX_FN_RX_DATA:
        if (n == 2U && (unsigned)params[0] + params[1] <= POZYX_SIM_BUFFER_SIZE) {
            sim->result[0] = 1;
            memcpy(sim->result + 1, sim->rx_buffer + params[0], params[1]);
            sim->result_length = (uint8_t)(1U + params[1]);
        }
        break;
    case POZYX_FN_DO_RANGING: call_do_ranging(sim); break;
    case POZYX_FN_DEVICES_DISCOVER: call_discover(sim); break;
    case POZYX_FN_DEVICES_CLEAR:
        sim->device_list_size = 0;
        sim->result[0] = 1;
        break;
    case POZYX_FN_DEVICES_GETIDS: {
        uint8_t offset = 0;
        uint8_t count = sim->device_list_size;
        uint8_t i;
        if (n == 2U) {
            offset = sim->config.getids_ignores_offset ? 0U : params[0];
            count = params[1];
        } else if (n != 0U) {
            break;
        }
        if ((unsigned)offset + count > POZYX_SIM_MAX_RANGE_ENTRIES) {
            break;
        }
        sim->result[0] = 1;
        for (i = 0; i < count; ++i) {
            const uint16_t id = (uint8_t)(offset + i) < sim->device_list_size ? sim->device_list[offset + i] : 0U;
            put_u16(sim->result + 1 + (size_t)2U * i, id);
        }
        sim->result_length = (uint8_t)(1U + 2U * count);
        break;
    }
    case POZYX_FN_DEVICE_GETINFO:
        if (n == 2U) {
            const uint16_t id = get_u16(params);
            uint8_t i;
            for (i = 0; i < sim->device_list_size; ++i) {
                if (sim->device_list[i] == id) {
                    const pozyx_sim_node_t *node = pozyx_sim_find(sim, id);
                    sim->result[0] = 1;
                    put_u16(sim->result + 1, id);
                    sim->result[3] = (uint8_t)(node != NULL && node->config.is_tag ? 2 : 1);
                    sim->result_length = 4;
                }
            }
        }
        break;
    case POZYX_FN_DEVICE_GETRANGEINFO:
        if (n == 2U && self != NULL) {
            sim->result_length = rangeinfo_reply(self, get_u16(params), sim->result);
        }
        break;
    case POZYX_FN_LED_CTRL:
        if (n == 1U) {
            sim->result[0] = 1;
        } else {
            raise_error(sim, POZYX_ERROR_FUNC_PARAMS);
        }
        break;
    case POZYX_FN_RESET_SYS:
        sim->result[0] = 1;
        sim->int_status = 0;
        sim->error_code = 0;
        sim->device_list_size = 0;
        sim->busy = 0;
        sim->event_count = 0;
        break;
    default: break; /* unknown function: return byte 0 */
    }
}

/* ---- the bus state machine ------------------------------------------------------------------- */

static void end_phase(pozyx_sim_t *sim)
{
    if (sim->phase == PHASE_READ || sim->phase == PHASE_REFUSED) {
        if (sim->phase_bytes > sim->stats.longest_read && sim->phase == PHASE_READ) {
            sim->stats.longest_read = sim->phase_bytes;
        }
    } else if (sim->phase != PHASE_IDLE) {
        if (sim->phase_bytes > sim->stats.longest_write) {
            sim->stats.longest_write = sim->phase_bytes;
        }
    }
    sim->phase_bytes = 0;
}

pozyx_sim_bus_t pozyx_sim_i2c_start(pozyx_sim_t *sim, uint8_t address, uint8_t read)
{
    const uint8_t previous = sim->phase;
    if (take(sim, &sim->faults.hang)) {
        return POZYX_SIM_HANG;
    }
    end_phase(sim);
    if (!sim->in_transaction) {
        ++sim->stats.transactions;
        sim->pointer_set = 0;
    }
    sim->in_transaction = 1;
    sim->stretch_us = 0;
    track_power(sim);
    if (address == sim->config.i2c_address && sim->node_count > 0U && sim->nodes[0].config.powered && !local_up(sim)) {
        ++sim->stats.boot_refusals; /* powered, still booting */
    }
    if (address != sim->config.i2c_address || !local_up(sim) || take(sim, &sim->faults.nack_address)) {
        sim->phase = PHASE_REFUSED;
        return POZYX_SIM_NACK;
    }
    if (read) {
        if (!sim->pointer_set) {
            ++sim->stats.protocol_violations; /* a read with no register or function addressed */
            sim->phase = PHASE_REFUSED;
            return POZYX_SIM_NACK;
        }
        if (sim->pointer >= 0xA0U) {
            if (!sim->executed) {
                execute(sim);
            }
            sim->result_position = 0;
            sim->stretch_us = sim->config.stretch_function_us;
        } else {
            ++sim->stats.register_reads;
            sim->stretch_us = sim->config.stretch_register_us;
        }
        sim->stats.stretched_us += sim->stretch_us;
        sim->phase = PHASE_READ;
        return POZYX_SIM_ACK;
    }
    /* Write: after a register address and a repeated start, the documented write form. */
    sim->phase = (previous == PHASE_POINTER_SET && sim->pointer_set && sim->pointer < 0xA0U) ? PHASE_WRITE_DATA
                                                                                             : PHASE_WRITE_FIRST;
    if (sim->phase == PHASE_WRITE_DATA) {
        ++sim->stats.register_writes;
    }
    return POZYX_SIM_ACK;
}

pozyx_sim_bus_t pozyx_sim_i2c_write(pozyx_sim_t *sim, uint8_t byte)
{
    if (take(sim, &sim->faults.hang)) {
        return POZYX_SIM_HANG;
    }
    ++sim->stats.bytes_written;
    ++sim->phase_bytes;
    if (take(sim, &sim->faults.nack_write)) {
        return POZYX_SIM_NACK;
    }
    switch (sim->phase) {
    case PHASE_WRITE_FIRST:
        sim->pointer = byte;
        sim->pointer_set = 1;
        sim->executed = 0;
        sim->params_length = 0;
        sim->phase = byte >= 0xA0U ? PHASE_PARAMS : PHASE_POINTER_SET;
        return POZYX_SIM_ACK;
    case PHASE_POINTER_SET:
        if (!sim->config.accept_plain_writes) {
            ++sim->stats.protocol_violations; /* data right after the register byte */
            sim->phase = PHASE_REFUSED;
            return POZYX_SIM_NACK;
        }
        sim->phase = PHASE_WRITE_DATA;
        ++sim->stats.register_writes;
        /* fall through: the byte is data */
        /* FALLTHROUGH */
    case PHASE_WRITE_DATA:
        if (!writable(sim->pointer)) {
            ++sim->stats.protocol_violations;
            sim->phase = PHASE_REFUSED;
            return POZYX_SIM_NACK;
        }
        sim->nodes[0].regs[sim->pointer] = byte;
        sim->pointer = (uint8_t)(sim->pointer + 1U);
        return POZYX_SIM_ACK;
    case PHASE_PARAMS:
        if (sim->params_length >= POZYX_SIM_MAX_PARAMS) {
            sim->phase = PHASE_REFUSED;
            return POZYX_SIM_NACK;
        }
        sim->params[sim->params_length++] = byte;
        return POZYX_SIM_ACK;
    case PHASE_IDLE:
    case PHASE_READ:
    case PHASE_REFUSED:
    default: ++sim->stats.protocol_violations; return POZYX_SIM_NACK;
    }
}

uint8_t pozyx_sim_i2c_read(pozyx_sim_t *sim, uint8_t master_ack)
{
    uint8_t value = 0xFF;
    (void)master_ack;
    if (sim->phase != PHASE_READ) {
        ++sim->stats.protocol_violations;
        return 0xFF; /* the bus floats high */
    }
    ++sim->stats.bytes_read;
    ++sim->phase_bytes;
    if (sim->pointer >= 0xA0U) {
        if (sim->result_position < sim->result_length) {
            value = sim->result[sim->result_position];
        } else {
            value = 0;
        }
        if (sim->result_position < 0xFFU) {
            ++sim->result_position;
        }
        return value;
    }
    value = read_register(sim, &sim->nodes[0], sim->pointer, 1);
    sim->pointer = (uint8_t)(sim->pointer + 1U); /* auto-increment */
    return value;
}

void pozyx_sim_i2c_stop(pozyx_sim_t *sim)
{
    if (sim->phase == PHASE_PARAMS && !sim->executed) {
        execute(sim); /* a function called without reading its return byte */
    }
    end_phase(sim);
    sim->phase = PHASE_IDLE;
    sim->in_transaction = 0;
}
