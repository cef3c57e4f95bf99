/*
 * firmware.c: the device behaviour of docs/protocol.md as a step function (see firmware.h).
 */
#include "cdro_fw/firmware.h"

#include <stddef.h>
#include <string.h>

#include "cdro/wire.h"
#include "cdro_fw/pozyx_regs.h"

#define NO_POLL_ROUND 0xFFU

/* Wire sizes used to decide whether a report fits now: payload + header, CRC, COBS, 0x00. */
#define WIRE_OVERHEAD (CDRO_HEADER_SIZE + CDRO_CRC_SIZE + 2U)
#define ERROR_WIRE_SIZE (CDRO_ERROR_MAX_SIZE + WIRE_OVERHEAD)

CDRO_FW_STATIC_ASSERT(CDRO_FW_MAX_REMOTE_NODES < NO_POLL_ROUND, poll_cursor_fits);

/* ---- time ------------------------------------------------------------------------------ */

/* 1 when device time `now` has reached `at` (wrap-safe for spans below 24 days). */
static uint8_t reached(uint32_t now_ms, uint32_t at_ms) { return (uint8_t)((uint32_t)(now_ms - at_ms) < 0x80000000UL); }

static uint32_t earlier(uint32_t now_ms, uint32_t a_ms, uint32_t b_ms)
{
    return (uint32_t)(a_ms - now_ms) <= (uint32_t)(b_ms - now_ms) ? a_ms : b_ms;
}

static uint32_t clock_ms(const cdro_fw_t *fw) { return fw->pozyx.ops->now_ms(fw->pozyx.user); }

static uint32_t clock_us(const cdro_fw_t *fw) { return fw->pozyx.ops->now_us(fw->pozyx.user); }

/* ---- frames out ------------------------------------------------------------------------ */

static void frame_init(cdro_frame_t *frame, uint8_t type)
{
    memset(frame, 0, sizeof(*frame));
    frame->type = type;
}

static void send_hello(cdro_fw_t *fw, uint32_t now_ms)
{
    cdro_frame_t frame;
    cdro_hello_t *hello = &frame.as.hello;
    frame_init(&frame, CDRO_FRAME_HELLO);
    hello->device_time_ms = now_ms;
    hello->firmware_version = CDRO_FW_VERSION;
    hello->protocol_version = CDRO_PROTOCOL_VERSION;
    hello->layout_hash = CDRO_LAYOUT_HASH;
    hello->node_id = fw->nodes[0].id;
    hello->capabilities = fw->capabilities;
    hello->pozyx_firmware = fw->pozyx_firmware;
    hello->max_nodes = CDRO_FW_MAX_REMOTE_NODES;
    hello->reset_cause = fw->reset_cause;
    hello->pozyx_tries = fw->pozyx_tries;
    (void)cdro_link_send(&fw->link, &frame);
}

static void send_error(cdro_fw_t *fw, uint8_t code, uint16_t detail, uint16_t node_id)
{
    cdro_frame_t frame;
    frame_init(&frame, CDRO_FRAME_ERROR);
    frame.as.error.device_time_ms = clock_ms(fw);
    frame.as.error.code = code;
    frame.as.error.detail = detail;
    frame.as.error.node_id = node_id;
    (void)cdro_link_send(&fw->link, &frame);
}

static void send_node_list(cdro_fw_t *fw, uint8_t source)
{
    fw->node_source = source;
    cdro_frame_t frame;
    uint8_t i;
    frame_init(&frame, CDRO_FRAME_NODE_LIST);
    frame.as.node_list.source = source;
    frame.as.node_list.node_ids_count = fw->node_count;
    for (i = 0; i < fw->node_count; ++i) {
        frame.as.node_list.node_ids[i] = fw->nodes[i + 1U].id;
    }
    (void)cdro_link_send(&fw->link, &frame);
}

static void send_ack(cdro_fw_t *fw, uint8_t type, uint16_t sequence, uint32_t value)
{
    cdro_frame_t frame;
    frame_init(&frame, CDRO_FRAME_ACK);
    frame.as.ack.acked_type = type;
    frame.as.ack.acked_sequence = sequence;
    frame.as.ack.value = value;
    (void)cdro_link_send(&fw->link, &frame);
}

static void send_nack(cdro_fw_t *fw, uint8_t type, uint16_t sequence, uint8_t reason)
{
    cdro_frame_t frame;
    ++fw->counters.commands_rejected;
    frame_init(&frame, CDRO_FRAME_NACK);
    frame.as.nack.nacked_type = type;
    frame.as.nack.nacked_sequence = sequence;
    frame.as.nack.reason = reason;
    (void)cdro_link_send(&fw->link, &frame);
}

static void send_status(cdro_fw_t *fw, uint32_t now_ms)
{
    cdro_frame_t frame;
    cdro_status_t *status = &frame.as.status;
    frame_init(&frame, CDRO_FRAME_STATUS);
    status->uptime_ms = now_ms;
    status->ranges_ok_direct = fw->counters.ranges_ok_direct;
    status->ranges_ok_remote = fw->counters.ranges_ok_remote;
    status->ranges_failed_direct = fw->counters.ranges_failed_direct;
    status->ranges_failed_remote = fw->counters.ranges_failed_remote;
    status->retries = fw->counters.retries;
    status->bus_errors = fw->pozyx.bus_errors;
    status->timeouts = fw->pozyx.timeouts;
    status->frames_sent = fw->link.frames_sent;
    status->frames_dropped = fw->link.frames_dropped;
    status->commands_rejected = fw->counters.commands_rejected;
    status->longest_loop_us = fw->longest_loop_us;
    status->free_ram_bytes = fw->free_ram_bytes != NULL ? fw->free_ram_bytes(fw->platform_user) : 0U;
    status->running = fw->running;
    status->node_count = fw->node_count;
    status->bus_recoveries = fw->pozyx.bus_recoveries;
    (void)cdro_link_send(&fw->link, &frame);
    fw->longest_loop_us = 0;
}

static void send_motion(cdro_fw_t *fw, const cdro_fw_node_t *node, uint8_t reason)
{
    cdro_frame_t frame;
    frame_init(&frame, CDRO_FRAME_MOTION);
    frame.as.motion.device_time_ms = clock_ms(fw);
    frame.as.motion.node_id = node->id;
    frame.as.motion.moving = node->motion.moving;
    /* The protocol bounds the norm at the sensor's 16 g; a sample beyond it is reported at it. */
    frame.as.motion.accel_norm_mg =
        node->motion.norm_mg > CDRO_MAX_ACCEL_MG ? (uint16_t)CDRO_MAX_ACCEL_MG : node->motion.norm_mg;
    frame.as.motion.deviation_mg = node->motion.window_deviation_mg;
    frame.as.motion.reason = reason;
    (void)cdro_link_send(&fw->link, &frame);
}

/* ---- state ------------------------------------------------------------------------------ */

static void node_reset(cdro_fw_node_t *node, uint16_t id)
{
    memset(node, 0, sizeof(*node));
    node->id = id;
    cdro_motion_detector_init(&node->motion);
}

static void set_nodes(cdro_fw_t *fw, const uint16_t *ids, uint8_t count)
{
    uint8_t i;
    fw->node_count = count;
    for (i = 0; i < count; ++i) {
        node_reset(&fw->nodes[i + 1U], ids[i]);
    }
    cdro_sched_set_nodes(&fw->sched, count);
    fw->poll_cursor = NO_POLL_ROUND;
}

static uint32_t moving_mask(const cdro_fw_t *fw)
{
    uint32_t mask = 0;
    uint8_t i;
    for (i = 0; i <= fw->node_count; ++i) {
        if (fw->nodes[i].motion.moving) {
            mask |= (uint32_t)1 << i;
        }
    }
    return mask;
}

void cdro_fw_init(cdro_fw_t *fw, const cdro_fw_config_t *config)
{
    memset(fw, 0, sizeof(*fw));
    cdro_pozyx_init(&fw->pozyx, config->pozyx_ops, config->pozyx_user, CDRO_FW_POZYX_I2C_ADDRESS);
    cdro_link_init(&fw->link, config->serial_ops, config->serial_user);
    cdro_sched_init(&fw->sched);
    fw->free_ram_bytes = config->free_ram_bytes;
    fw->platform_user = config->platform_user;
    fw->reset_cause = config->reset_cause;
    fw->slot_period_ms = 0;
    fw->motion_poll_ms = 200;
    fw->status_period_ms = 1000;
    fw->state = CDRO_FW_STATE_BOOT;
    fw->poll_cursor = NO_POLL_ROUND;
    node_reset(&fw->nodes[0], CDRO_FW_NODE_ID_UNKNOWN);
}

/* ---- boot ------------------------------------------------------------------------------ */

static uint8_t firmware_supported(uint8_t version)
{
    return (uint8_t)(version >= CDRO_FW_POZYX_FIRMWARE_MIN && version <= CDRO_FW_POZYX_FIRMWARE_MAX);
}

/* One try at identifying the own Pozyx. The first try sends 0x00 and HELLO whatever it finds
 * (the host learns at once that the device lives); a later try that finds it sends HELLO again,
 * now with the node id and capabilities. A silent Pozyx or a wrong WHO_AM_I is tried again,
 * CDRO_FW_IDENTIFY_RETRY_MS doubling up to CDRO_FW_IDENTIFY_RETRY_MAX_MS, each failed try
 * reported by ERROR POZYX_ABSENT. A failed self-test or an unsupported firmware is final. */
static void identify(cdro_fw_t *fw, uint32_t now_ms)
{
    cdro_pozyx_info_t info;
    const cdro_pozyx_status_t status = cdro_pozyx_identify(&fw->pozyx, &info);
    uint8_t error_code = 0;
    uint16_t error_detail = 0;
    if (fw->pozyx_tries < 0xFFU) {
        ++fw->pozyx_tries;
    }
    if (status == CDRO_POZYX_OK && info.network_id != 0U) {
        const uint8_t tag = (uint8_t)((info.hardware_version >> POZYX_HW_TYPE_SHIFT) == POZYX_HW_TYPE_TAG);
        const uint8_t expected = tag ? POZYX_ST_EXPECTED_TAG : POZYX_ST_EXPECTED_ANCHOR;
        fw->nodes[0].id = info.network_id;
        fw->nodes[0].flags = (uint8_t)(CDRO_FW_NODE_KIND_KNOWN | (tag ? CDRO_FW_NODE_TAG : 0U));
        fw->pozyx_firmware = info.firmware_version;
        fw->pozyx_state = CDRO_FW_POZYX_OK;
        if (!firmware_supported(info.firmware_version)) {
            fw->pozyx_state = CDRO_FW_POZYX_FIRMWARE;
            error_code = CDRO_DEVICE_ERROR_POZYX_FIRMWARE;
            error_detail = info.firmware_version;
        } else if ((info.self_test & expected) != expected) {
            fw->pozyx_state = CDRO_FW_POZYX_SELF_TEST;
            error_code = CDRO_DEVICE_ERROR_SELF_TEST;
            error_detail = info.self_test;
        }
        fw->capabilities =
            fw->pozyx_state != CDRO_FW_POZYX_FIRMWARE
                ? (uint8_t)(CDRO_CAP_DIRECT_RANGING | CDRO_CAP_REMOTE_RANGING | CDRO_CAP_REMOTE_ACCEL |
                            CDRO_CAP_DISCOVERY | CDRO_CAP_POZYX_SETUP | (tag ? CDRO_CAP_LOCAL_ACCEL : 0U))
                : 0U;
    } else {
        /* Silent, wrong WHO_AM_I, or no network id: HELLO says node 0xFFFF, Pozyx firmware 0. */
        const uint8_t shift = fw->pozyx_tries < 5U ? (uint8_t)(fw->pozyx_tries - 1U) : 4U;
        const uint32_t wait_ms = (uint32_t)CDRO_FW_IDENTIFY_RETRY_MS << shift;
        error_code = CDRO_DEVICE_ERROR_POZYX_ABSENT;
        error_detail = status == CDRO_POZYX_ERR_BUS ? 0U : info.who_am_i;
        fw->next_identify_ms =
            now_ms + (wait_ms < CDRO_FW_IDENTIFY_RETRY_MAX_MS ? wait_ms : CDRO_FW_IDENTIFY_RETRY_MAX_MS);
    }
    if (fw->pozyx_tries == 1U) {
        cdro_link_send_delimiter(&fw->link);
        send_hello(fw, now_ms);
        fw->next_status_ms = now_ms + fw->status_period_ms;
    } else if (fw->pozyx_state != CDRO_FW_POZYX_ABSENT) {
        send_hello(fw, now_ms); /* found at last: the host hears the node id and capabilities */
    }
    if (error_code != 0U) {
        send_error(fw, error_code, error_detail, 0);
    }
    fw->state = fw->pozyx_state == CDRO_FW_POZYX_OK ? CDRO_FW_STATE_DISCOVERY : CDRO_FW_STATE_READY;
}

static void start_round(cdro_fw_t *fw, uint8_t round)
{
    fw->round = round;
    fw->round_cursor = 0;
}

/* Keeps ids that are non-zero, not the own node and not repeated (NODE_LIST must validate). */
static uint8_t clean_ids(const cdro_fw_t *fw, uint16_t *ids, uint8_t count)
{
    uint8_t kept = 0;
    uint8_t i;
    for (i = 0; i < count; ++i) {
        uint8_t j;
        uint8_t keep = (uint8_t)(ids[i] != 0U && ids[i] != fw->nodes[0].id);
        for (j = 0; j < kept && keep; ++j) {
            keep = (uint8_t)(ids[j] != ids[i]);
        }
        if (keep) {
            ids[kept++] = ids[i];
        }
    }
    return kept;
}

static void discovery(cdro_fw_t *fw)
{
    uint16_t ids[CDRO_FW_MAX_REMOTE_NODES];
    uint8_t found = 0;
    uint8_t listed = 0;
    const cdro_pozyx_status_t status = cdro_pozyx_discover(&fw->pozyx, ids, CDRO_FW_MAX_REMOTE_NODES, &found, &listed);
    ++fw->discovery_attempts;
    if (status == CDRO_POZYX_OK) {
        const uint8_t wanted = listed < CDRO_FW_MAX_REMOTE_NODES ? listed : (uint8_t)CDRO_FW_MAX_REMOTE_NODES;
        if (found < wanted) { /* a page past the first did not verify: its ids are unknown */
            send_error(fw, CDRO_DEVICE_ERROR_DEVICE_LIST, listed, 0);
        }
        found = clean_ids(fw, ids, found);
        if (found > 0U) {
            set_nodes(fw, ids, found);
            send_node_list(fw, CDRO_NODE_SOURCE_DISCOVERY);
        }
        fw->state = CDRO_FW_STATE_READY;
        start_round(fw, CDRO_FW_ROUND_NODE_INFO);
    } else if (fw->discovery_attempts >= CDRO_FW_DISCOVERY_ATTEMPTS) {
        send_error(fw, CDRO_DEVICE_ERROR_DISCOVERY, status == CDRO_POZYX_ERR_DEVICE ? fw->pozyx.last_error_code : 0U,
                   0);
        fw->state = CDRO_FW_STATE_READY;
        start_round(fw, CDRO_FW_ROUND_NODE_INFO); /* at least the own node's settings */
    }
}

/* ---- commands ---------------------------------------------------------------------------- */

static void command_set_nodes(cdro_fw_t *fw, const cdro_frame_t *in)
{
    const cdro_set_nodes_t *cmd = &in->as.set_nodes;
    uint8_t i;
    if (cmd->node_ids_count > CDRO_FW_MAX_REMOTE_NODES) {
        send_nack(fw, in->type, in->sequence, CDRO_NACK_TOO_MANY_NODES);
        return;
    }
    for (i = 0; i < cmd->node_ids_count; ++i) {
        if (cmd->node_ids[i] == fw->nodes[0].id) { /* a node cannot range with itself */
            send_nack(fw, in->type, in->sequence, CDRO_NACK_BAD_VALUE);
            return;
        }
    }
    set_nodes(fw, cmd->node_ids, cmd->node_ids_count);
    send_ack(fw, in->type, in->sequence, 0);
    send_node_list(fw, CDRO_NODE_SOURCE_HOST);
    if (fw->pozyx_state == CDRO_FW_POZYX_OK && fw->round < CDRO_FW_ROUND_UWB_REMOTE) {
        start_round(fw, CDRO_FW_ROUND_NODE_INFO); /* the new nodes' settings */
    }
}

static void command_set_schedule(cdro_fw_t *fw, const cdro_frame_t *in, uint32_t now_ms)
{
    const cdro_set_schedule_t *cmd = &in->as.set_schedule;
    fw->slot_period_ms = cmd->slot_period_ms;
    fw->motion_poll_ms = cmd->motion_poll_ms;
    if (fw->status_period_ms != cmd->status_period_ms) {
        fw->status_period_ms = cmd->status_period_ms;
        fw->next_status_ms = now_ms + cmd->status_period_ms;
    }
    cdro_sched_configure(&fw->sched, cmd->mode, cmd->moving_boost, cmd->max_retries);
    if (fw->motion_poll_ms == 0U) {
        fw->poll_cursor = NO_POLL_ROUND;
    }
    /* The slot already due keeps its start time (set with the old period when the last slot
     * started); the new slot_period_ms applies from the slot after it. */
    send_ack(fw, in->type, in->sequence, 0);
}

static void handle_command(cdro_fw_t *fw, const cdro_frame_t *in, uint32_t now_ms)
{
    switch (in->type) {
    case CDRO_FRAME_SET_NODES: command_set_nodes(fw, in); break;
    case CDRO_FRAME_SET_SCHEDULE: command_set_schedule(fw, in, now_ms); break;
    case CDRO_FRAME_START:
        if (fw->pozyx_state != CDRO_FW_POZYX_OK || fw->node_count == 0U) {
            send_nack(fw, in->type, in->sequence, CDRO_NACK_WRONG_STATE);
            break;
        }
        if (!fw->running) {
            fw->running = 1;
            fw->next_slot_ms = now_ms;
            fw->next_poll_round_ms = now_ms;
            fw->next_periodic_motion_ms = now_ms + CDRO_FW_MOTION_PERIODIC_MS;
            fw->periodic_motion_mask = 0xFFFFFFFFUL; /* every node reports its first sample */
        }
        send_ack(fw, in->type, in->sequence, 0);
        break;
    case CDRO_FRAME_STOP:
        fw->running = 0;
        fw->poll_cursor = NO_POLL_ROUND;
        send_ack(fw, in->type, in->sequence, 0);
        break;
    case CDRO_FRAME_PING: send_ack(fw, in->type, in->sequence, in->as.ping.nonce); break;
    case CDRO_FRAME_SET_UWB:
    case CDRO_FRAME_DIAGNOSE:
        /* Only while stopped, with a working Pozyx, and no other round under way: they take
         * over the Pozyx for seconds. */
        if (fw->running || fw->pozyx_state != CDRO_FW_POZYX_OK || fw->round != CDRO_FW_ROUND_NONE) {
            send_nack(fw, in->type, in->sequence, CDRO_NACK_WRONG_STATE);
            break;
        }
        send_ack(fw, in->type, in->sequence, 0);
        if (in->type == CDRO_FRAME_SET_UWB) {
            const cdro_set_uwb_t *u = &in->as.set_uwb;
            fw->target_uwb[0] = u->uwb_channel;
            fw->target_uwb[1] = u->uwb_rates;
            fw->target_uwb[2] = u->uwb_plen;
            fw->target_uwb[3] = u->uwb_gain;
            fw->target_uwb[4] = u->range_protocol;
            start_round(fw, CDRO_FW_ROUND_UWB_REMOTE);
        } else {
            start_round(fw, CDRO_FW_ROUND_DIAG);
        }
        break;
    case CDRO_FRAME_HELLO_REQUEST:
        /* A host that opens the link of a running device (it restarted; the device did not)
         * has seen neither the boot HELLO nor the node list: send both, so that it can keep
         * the discovered list instead of having to set one. */
        send_hello(fw, now_ms);
        if (fw->node_count > 0U) {
            send_node_list(fw, fw->node_source);
        }
        break;
    case CDRO_FRAME_HELLO:
    case CDRO_FRAME_RANGE:
    case CDRO_FRAME_MOTION:
    case CDRO_FRAME_STATUS:
    case CDRO_FRAME_NODE_LIST:
    case CDRO_FRAME_ACK:
    case CDRO_FRAME_NACK:
    case CDRO_FRAME_ERROR:
    case CDRO_FRAME_NODE_INFO:
    case CDRO_FRAME_DIAG:
    case CDRO_FRAME_TYPE_NONE:
    default: send_nack(fw, in->type, in->sequence, CDRO_NACK_UNKNOWN_TYPE); break;
    }
}

static void handle_chunk(cdro_fw_t *fw, const cdro_frame_t *in, cdro_result_t result, uint32_t now_ms)
{
    switch (result) {
    case CDRO_OK: handle_command(fw, in, now_ms); break;
    case CDRO_ERR_VERSION:
    case CDRO_ERR_LENGTH: send_nack(fw, in->type, in->sequence, CDRO_NACK_MALFORMED); break;
    case CDRO_ERR_TYPE: send_nack(fw, in->type, in->sequence, CDRO_NACK_UNKNOWN_TYPE); break;
    case CDRO_ERR_VALUE:
        /* A device-to-host type is refused for its type, whatever its values. */
        send_nack(fw, in->type, in->sequence,
                  in->type < (uint8_t)CDRO_FRAME_SET_NODES ? CDRO_NACK_UNKNOWN_TYPE : CDRO_NACK_BAD_VALUE);
        break;
    case CDRO_ERR_COBS:
    case CDRO_ERR_SHORT:
    case CDRO_ERR_CRC:
    case CDRO_ERR_TOO_LONG:
    case CDRO_ERR_ARGUMENT:
    case CDRO_PENDING:
    default:
        /* Not trustworthy enough to answer: counted, and reported by ERROR COMMAND (rate-limited). */
        ++fw->counters.commands_rejected;
        fw->command_error_pending = 1U;
        fw->last_command_error = (uint8_t)(-(int)result);
        break;
    }
}

static void handle_host_bytes(cdro_fw_t *fw, uint32_t now_ms)
{
    uint8_t budget = CDRO_FW_RX_BYTES_PER_STEP;
    for (;;) {
        cdro_frame_t in;
        const cdro_result_t result = cdro_link_receive(&fw->link, &in, &budget);
        if (result == CDRO_PENDING) {
            break;
        }
        handle_chunk(fw, &in, result, now_ms);
    }
}

/* ---- reports ------------------------------------------------------------------------------ */

/* ERROR frames for counters that moved, at most one per kind and status period, so that a
 * failing bus cannot flood the link; the counters in STATUS carry the totals. */
static void report_errors(cdro_fw_t *fw, uint32_t now_ms)
{
    if (fw->link.dropped_unreported > 0U && fw->link.ops->tx_free(fw->link.user) >= ERROR_WIRE_SIZE) {
        const uint16_t dropped = fw->link.dropped_unreported;
        fw->link.dropped_unreported = 0;
        send_error(fw, CDRO_DEVICE_ERROR_TX_OVERFLOW, dropped, 0);
    }
    if ((uint16_t)fw->pozyx.bus_errors != fw->bus_errors_reported && reached(now_ms, fw->next_bus_report_ms)) {
        fw->bus_errors_reported = (uint16_t)fw->pozyx.bus_errors;
        fw->next_bus_report_ms = now_ms + fw->status_period_ms;
        send_error(fw, CDRO_DEVICE_ERROR_BUS, fw->pozyx.bus_target, 0);
    }
    if ((uint16_t)fw->pozyx.timeouts != fw->timeouts_reported && reached(now_ms, fw->next_timeout_report_ms)) {
        fw->timeouts_reported = (uint16_t)fw->pozyx.timeouts;
        fw->next_timeout_report_ms = now_ms + fw->status_period_ms;
        send_error(fw, CDRO_DEVICE_ERROR_TIMEOUT, fw->pozyx.timeout_target, 0);
    }
    if (fw->command_error_pending && reached(now_ms, fw->next_command_report_ms)) {
        fw->command_error_pending = 0U;
        fw->next_command_report_ms = now_ms + fw->status_period_ms;
        /* detail: the cdro_result_t as a 16-bit two's complement (e.g. 0xFFFC = CRC). */
        send_error(fw, CDRO_DEVICE_ERROR_COMMAND, (uint16_t)(0U - (uint16_t)fw->last_command_error), 0);
    }
}

/* ---- ranging ------------------------------------------------------------------------------- */

/* A range is fresh when its timestamp (the ranging node's clock) is later than the last one
 * accepted from that node: GETRANGEINFO returns the stored entry even when a ranging failed
 * silently. CDRO_FW_STALE_REBASE results in a row that go backwards mean the node restarted:
 * the reference is rebased to the newest (still rejected) timestamp. */
static uint8_t fresh_range(cdro_fw_t *fw, cdro_fw_node_t *node, uint32_t timestamp_ms)
{
    if ((node->flags & CDRO_FW_NODE_HAS_RANGE_TS) != 0U &&
        (int32_t)(timestamp_ms - node->last_range_timestamp_ms) <= 0) {
        uint8_t stale = (uint8_t)(((node->flags & CDRO_FW_NODE_STALE_MASK) >> CDRO_FW_NODE_STALE_SHIFT) + 1U);
        if (stale >= CDRO_FW_STALE_REBASE) {
            node->last_range_timestamp_ms = timestamp_ms;
            stale = 0;
        }
        node->flags =
            (uint8_t)((node->flags & (uint8_t)~CDRO_FW_NODE_STALE_MASK) | (uint8_t)(stale << CDRO_FW_NODE_STALE_SHIFT));
        ++fw->counters.stale_results;
        return 0;
    }
    node->last_range_timestamp_ms = timestamp_ms;
    node->flags = (uint8_t)((node->flags & (uint8_t)~CDRO_FW_NODE_STALE_MASK) | CDRO_FW_NODE_HAS_RANGE_TS);
    return 1;
}

/* One ranging attempt. Returns 0 if no pair is due (all backing off this round). */
static uint8_t range_attempt(cdro_fw_t *fw, uint32_t now_ms)
{
    cdro_sched_slot_t slot;
    cdro_pozyx_range_result_t range;
    cdro_pozyx_status_t status;
    cdro_fw_node_t *from;
    cdro_fw_node_t *to;
    uint8_t ok;
    uint8_t actions;
    const uint32_t mask = moving_mask(fw);
    if (!cdro_sched_next(&fw->sched, mask, &slot)) {
        return 0;
    }
    if (!slot.is_retry) {
        fw->next_slot_ms = now_ms + fw->slot_period_ms;
    }
    from = &fw->nodes[slot.from];
    to = &fw->nodes[slot.to];
    memset(&range, 0, sizeof range);
    if (slot.from == 0U) {
        status = cdro_pozyx_range(&fw->pozyx, to->id, &range);
    } else {
        status = cdro_pozyx_range_remote(&fw->pozyx, from->id, to->id, &range);
    }
    ok = (uint8_t)(status == CDRO_POZYX_OK && fresh_range(fw, from, range.timestamp_ms));
    if (slot.is_retry) {
        ++fw->counters.retries;
    }
    if (ok) {
        cdro_frame_t frame;
        frame_init(&frame, CDRO_FRAME_RANGE);
        frame.as.range.device_time_ms = clock_ms(fw);
        frame.as.range.from_id = from->id;
        frame.as.range.to_id = to->id;
        frame.as.range.distance_mm = range.distance_mm;
        frame.as.range.rss_dbm = range.rss_dbm;
        frame.as.range.flags =
            (uint8_t)((slot.from != 0U ? CDRO_RANGE_FLAG_REMOTE : 0U) | (slot.is_retry ? CDRO_RANGE_FLAG_RETRY : 0U) |
                      (((mask >> slot.from) | (mask >> slot.to)) & 1UL ? CDRO_RANGE_FLAG_MOVING : 0U));
        (void)cdro_link_send(&fw->link, &frame);
        if (slot.from == 0U) {
            ++fw->counters.ranges_ok_direct;
        } else {
            ++fw->counters.ranges_ok_remote;
        }
    } else if (slot.from == 0U) {
        ++fw->counters.ranges_failed_direct;
    } else {
        ++fw->counters.ranges_failed_remote;
    }
    actions = cdro_sched_report(&fw->sched, ok);
    if ((actions & CDRO_SCHED_STREAK_ERROR) != 0U) {
        send_error(fw, CDRO_DEVICE_ERROR_RANGING, status == CDRO_POZYX_ERR_DEVICE ? fw->pozyx.last_error_code : 0U,
                   to->id);
    }
    return 1;
}

/* ---- motion -------------------------------------------------------------------------------- */

static uint8_t node_pollable(const cdro_fw_node_t *node, uint8_t index)
{
    if (CDRO_BACKOFF_SITTING_OUT(node->poll_backoff)) {
        return 0;
    }
    if (index == 0U || (node->flags & CDRO_FW_NODE_KIND_KNOWN) != 0U) {
        return (uint8_t)((node->flags & CDRO_FW_NODE_TAG) != 0U);
    }
    return 1; /* kind unknown: the poll asks first */
}

/* Moves the poll cursor to the next node with an accelerometer; 0 when the round is over. */
static uint8_t next_pollable(cdro_fw_t *fw)
{
    while (fw->poll_cursor != NO_POLL_ROUND) {
        if (fw->poll_cursor > fw->node_count) {
            fw->poll_cursor = NO_POLL_ROUND;
            break;
        }
        if (node_pollable(&fw->nodes[fw->poll_cursor], fw->poll_cursor)) {
            return 1;
        }
        ++fw->poll_cursor;
    }
    return 0;
}

static void start_poll_round(cdro_fw_t *fw, uint32_t now_ms)
{
    uint8_t i;
    fw->poll_cursor = 0;
    fw->next_poll_round_ms = now_ms + fw->motion_poll_ms;
    /* Every CDRO_FW_MOTION_PERIODIC_MS, each node's next good sample is reported (PERIODIC)
     * unless it is a change anyway. */
    if (reached(now_ms, fw->next_periodic_motion_ms)) {
        fw->periodic_motion_mask = 0xFFFFFFFFUL;
        fw->next_periodic_motion_ms = now_ms + CDRO_FW_MOTION_PERIODIC_MS;
    }
    for (i = 0; i <= fw->node_count; ++i) {
        fw->nodes[i].poll_backoff = cdro_backoff_round_start(fw->nodes[i].poll_backoff);
    }
}

/* One accelerometer poll of the node under the cursor (a remote node of unknown kind is asked
 * for its HARDWARE_VER first: anchors have no accelerometer and are not polled again). */
static void poll_attempt(cdro_fw_t *fw)
{
    const uint8_t index = fw->poll_cursor;
    cdro_fw_node_t *node = &fw->nodes[index];
    cdro_accel_t accel;
    cdro_pozyx_status_t status;
    ++fw->poll_cursor;
    memset(&accel, 0, sizeof accel);
    if (index == 0U) {
        status = cdro_pozyx_read_accel(&fw->pozyx, &accel);
    } else {
        status = CDRO_POZYX_OK;
        if ((node->flags & CDRO_FW_NODE_KIND_KNOWN) == 0U) {
            uint8_t hardware = 0;
            status = cdro_pozyx_remote_read(&fw->pozyx, node->id, POZYX_REG_HARDWARE_VER, &hardware, 1);
            if (status == CDRO_POZYX_OK) {
                const uint8_t tag = (uint8_t)((hardware >> POZYX_HW_TYPE_SHIFT) == POZYX_HW_TYPE_TAG);
                node->flags = (uint8_t)(node->flags | CDRO_FW_NODE_KIND_KNOWN | (tag ? CDRO_FW_NODE_TAG : 0U));
                if (!tag) {
                    return;
                }
            }
        }
        if (status == CDRO_POZYX_OK) {
            status = cdro_pozyx_remote_read_accel(&fw->pozyx, node->id, &accel);
        }
    }
    if (status != CDRO_POZYX_OK) {
        ++fw->counters.accel_failures;
        node->poll_backoff = cdro_backoff_failed(node->poll_backoff);
        if ((node->flags & CDRO_FW_NODE_ACCEL_FAILING) == 0U) {
            node->flags = (uint8_t)(node->flags | CDRO_FW_NODE_ACCEL_FAILING);
            send_error(fw, CDRO_DEVICE_ERROR_ACCEL, status == CDRO_POZYX_ERR_DEVICE ? fw->pozyx.last_error_code : 0U,
                       node->id);
        }
        return;
    }
    node->poll_backoff = 0;
    node->flags = (uint8_t)(node->flags & (uint8_t)~CDRO_FW_NODE_ACCEL_FAILING);
    {
        const uint8_t changed = cdro_motion_detector_update(&node->motion, &accel);
        const uint32_t bit = (uint32_t)1 << index;
        if (changed) {
            send_motion(fw, node, CDRO_MOTION_REASON_CHANGE);
        } else if ((node->flags & CDRO_FW_NODE_HAS_SAMPLE) == 0U || (fw->periodic_motion_mask & bit) != 0U) {
            send_motion(fw, node, CDRO_MOTION_REASON_PERIODIC);
        }
        fw->periodic_motion_mask &= ~bit;
        node->flags = (uint8_t)(node->flags | CDRO_FW_NODE_HAS_SAMPLE);
    }
}

/* At most one Pozyx operation: a ranging attempt or a motion poll, alternating when both are due. */
static void operate(cdro_fw_t *fw, uint32_t now_ms)
{
    uint8_t slot_due;
    uint8_t poll_due;
    if (!fw->running) {
        return;
    }
    slot_due = (uint8_t)(fw->node_count > 0U &&
                         (fw->sched.current != CDRO_SCHED_NO_PAIR || reached(now_ms, fw->next_slot_ms)));
    if (fw->motion_poll_ms != 0U && fw->poll_cursor == NO_POLL_ROUND && reached(now_ms, fw->next_poll_round_ms)) {
        start_poll_round(fw, now_ms);
    }
    poll_due = next_pollable(fw);
    if (slot_due && (!poll_due || fw->last_op_was_poll)) {
        if (range_attempt(fw, now_ms)) {
            fw->last_op_was_poll = 0;
            return;
        }
    }
    if (poll_due) {
        poll_attempt(fw);
        fw->last_op_was_poll = 1;
    }
}

/* ---- rounds: node settings, SET_UWB, DIAGNOSE ------------------------------------------------ */

/* Reads node `index`'s firmware version and UWB settings (the own node locally) and reports them
 * in NODE_INFO, with what differs from the own node. A remote node's HARDWARE_VER, read on the
 * way, also tells the motion polls whether it has an accelerometer. */
static void node_info_step(cdro_fw_t *fw, uint8_t index)
{
    cdro_fw_node_t *node = &fw->nodes[index];
    uint8_t versions[2] = {0, 0};        /* FIRMWARE_VER, HARDWARE_VER */
    uint8_t uwb[6] = {0, 0, 0, 0, 0, 0}; /* UWB_CHANNEL .. RANGE_PROTOCOL (XTALTRIM at [4] skipped) */
    cdro_pozyx_status_t status;
    cdro_frame_t frame;
    cdro_node_info_t *info = &frame.as.node_info;
    uint8_t i;
    if (index == 0U) {
        versions[0] = fw->pozyx_firmware;
        status = cdro_pozyx_read(&fw->pozyx, POZYX_REG_UWB_CHANNEL, uwb, sizeof uwb);
    } else {
        status = cdro_pozyx_remote_read(&fw->pozyx, node->id, POZYX_REG_FIRMWARE_VER, versions, sizeof versions);
        if (status == CDRO_POZYX_OK) {
            const uint8_t tag = (uint8_t)((versions[1] >> POZYX_HW_TYPE_SHIFT) == POZYX_HW_TYPE_TAG);
            node->flags = (uint8_t)(node->flags | CDRO_FW_NODE_KIND_KNOWN | (tag ? CDRO_FW_NODE_TAG : 0U));
            status = cdro_pozyx_remote_read(&fw->pozyx, node->id, POZYX_REG_UWB_CHANNEL, uwb, sizeof uwb);
        }
    }
    uwb[4] = uwb[5]; /* RANGE_PROTOCOL after the gain: the NODE_INFO order */
    frame_init(&frame, CDRO_FRAME_NODE_INFO);
    info->node_id = node->id;
    info->result = status == CDRO_POZYX_OK ? CDRO_NODE_INFO_READ : CDRO_NODE_INFO_NO_ANSWER;
    if (status == CDRO_POZYX_OK) {
        info->pozyx_firmware = versions[0];
        info->uwb_channel = uwb[0];
        info->uwb_rates = uwb[1];
        info->uwb_plen = uwb[2];
        info->uwb_gain = uwb[3];
        info->range_protocol = uwb[4];
        if (index == 0U) {
            memcpy(fw->own_uwb, uwb, CDRO_FW_UWB_SETTINGS);
        }
        for (i = 0; i < CDRO_FW_UWB_SETTINGS; ++i) {
            if (uwb[i] != fw->own_uwb[i]) {
                info->mismatch = (uint8_t)(info->mismatch | (1U << i)); /* CDRO_MISMATCH_* in this order */
            }
        }
        if (!firmware_supported(versions[0])) {
            info->mismatch = (uint8_t)(info->mismatch | CDRO_MISMATCH_FIRMWARE);
        }
    }
    (void)cdro_link_send(&fw->link, &frame);
}

/* SET_UWB on remote node `index`: channel, rates and preamble (one write: the node switches at
 * once and answers on the new settings, so no acknowledgement is heard unless they are its old
 * ones), or, once the own node has switched, gain and protocol (acknowledged). */
static void set_uwb_remote(cdro_fw_t *fw, uint8_t index, uint8_t round)
{
    const uint16_t id = fw->nodes[index].id;
    if (round == CDRO_FW_ROUND_UWB_REMOTE) {
        (void)cdro_pozyx_remote_write(&fw->pozyx, id, POZYX_REG_UWB_CHANNEL, fw->target_uwb, 3);
    } else if (cdro_pozyx_remote_write(&fw->pozyx, id, POZYX_REG_UWB_GAIN, &fw->target_uwb[3], 1) == CDRO_POZYX_OK) {
        (void)cdro_pozyx_remote_write(&fw->pozyx, id, POZYX_REG_RANGE_PROTOCOL, &fw->target_uwb[4], 1);
    }
}

/* The own node: channel, rates, preamble, then the gain (a channel write resets it), then the
 * protocol. Not saved to the Pozyx's flash: a power cycle restores the saved settings, which
 * the next start reads and reports. */
static void set_uwb_local(cdro_fw_t *fw)
{
    if (cdro_pozyx_write(&fw->pozyx, POZYX_REG_UWB_CHANNEL, fw->target_uwb, 3) == CDRO_POZYX_OK &&
        cdro_pozyx_write(&fw->pozyx, POZYX_REG_UWB_GAIN, &fw->target_uwb[3], 1) == CDRO_POZYX_OK) {
        (void)cdro_pozyx_write(&fw->pozyx, POZYX_REG_RANGE_PROTOCOL, &fw->target_uwb[4], 1);
    }
}

static void send_diag(cdro_fw_t *fw, uint8_t item, cdro_pozyx_status_t status, uint16_t node_id, uint32_t a, uint32_t b,
                      uint32_t c)
{
    cdro_frame_t frame;
    frame_init(&frame, CDRO_FRAME_DIAG);
    frame.as.diag.item = item;
    frame.as.diag.status = (uint8_t)status;
    frame.as.diag.node_id = node_id;
    frame.as.diag.value_a = a;
    frame.as.diag.value_b = b;
    frame.as.diag.value_c = c;
    (void)cdro_link_send(&fw->link, &frame);
}

/* The bench checklist (docs/firmware.md), one group of items per step, each step within one
 * operation's bound: a remote-to-remote range R1 -> R2 traced (flags, result message, times), a
 * local range to R1 timed, GETIDS with an offset, I2C transaction times against their wire time
 * (clock stretching), then the accelerometer norm of each tag (group 4 + node index). Items that
 * need nodes the list does not have report ERR_ARGUMENT. */
static void diag_step(cdro_fw_t *fw, uint8_t group)
{
    cdro_pozyx_t *dev = &fw->pozyx;
    cdro_pozyx_range_result_t range;
    cdro_pozyx_status_t status = CDRO_POZYX_ERR_ARGUMENT;
    const uint16_t r1 = fw->node_count >= 1U ? fw->nodes[1].id : 0U;
    const uint16_t r2 = fw->node_count >= 2U ? fw->nodes[2].id : 0U;
    memset(&range, 0, sizeof range);
    if (group == 0U) {
        cdro_pozyx_trace_t trace;
        memset(&trace, 0, sizeof trace);
        if (r2 != 0U) {
            dev->trace = &trace;
            status = cdro_pozyx_range_remote(dev, r1, r2, &range);
            dev->trace = NULL;
        }
        send_diag(fw, CDRO_DIAG_REMOTE_FLAGS, status, r1, trace.flags_to_ack, trace.flags_to_result,
                  trace.result_ms - trace.ack_ms);
        send_diag(fw, CDRO_DIAG_RESULT_MESSAGE, status, r1, trace.result_length, trace.result_head, range.distance_mm);
        send_diag(fw, CDRO_DIAG_REMOTE_TIME, status, r2, trace.done_ms - trace.send_ms, trace.ack_ms - trace.send_ms,
                  trace.done_ms - trace.result_ms);
    } else if (group == 1U) {
        uint32_t start_ms = clock_ms(fw);
        uint32_t func_ms = 0;
        if (r1 != 0U) {
            /* DO_RANGING to its FUNC, then the whole range (another ranging, GETRANGEINFO included). */
            uint8_t id[2];
            (void)cdro_put_u16(id, r1);
            status = cdro_pozyx_clear_flags(dev);
            if (status == CDRO_POZYX_OK) {
                status = cdro_pozyx_call(dev, POZYX_FN_DO_RANGING, id, sizeof id, NULL, 0, NULL);
            }
            if (status == CDRO_POZYX_OK) {
                status = cdro_pozyx_wait(dev, POZYX_INT_FUNC, CDRO_FW_RANGING_TIMEOUT_MS, POZYX_FN_DO_RANGING);
            }
            func_ms = clock_ms(fw) - start_ms;
            start_ms = clock_ms(fw);
            if (status == CDRO_POZYX_OK) {
                status = cdro_pozyx_range(dev, r1, &range);
            }
        }
        send_diag(fw, CDRO_DIAG_LOCAL_TIME, status, r1, func_ms, range.distance_mm, clock_ms(fw) - start_ms);
    } else if (group == 2U) {
        uint8_t size = 0;
        uint8_t params[2] = {0, 2};
        uint8_t first[4] = {0, 0, 0, 0};
        uint8_t second[2] = {0, 0};
        status = cdro_pozyx_read(dev, POZYX_REG_DEVICE_LIST_SIZE, &size, 1);
        if (status == CDRO_POZYX_OK && size < 2U) {
            status = CDRO_POZYX_ERR_ARGUMENT;
        }
        if (status == CDRO_POZYX_OK) {
            status = cdro_pozyx_call(dev, POZYX_FN_DEVICES_GETIDS, params, 2, first, 4, NULL);
        }
        if (status == CDRO_POZYX_OK) {
            params[0] = 1;
            params[1] = 1;
            status = cdro_pozyx_call(dev, POZYX_FN_DEVICES_GETIDS, params, 2, second, 2, NULL);
        }
        send_diag(fw, CDRO_DIAG_GETIDS_OFFSET, status, 0, size, cdro_get_u16(first + 2), cdro_get_u16(second));
    } else if (group == 3U) {
        uint32_t longest_read_us = 0;
        uint32_t longest_call_us = 0;
        uint8_t i;
        status = CDRO_POZYX_OK;
        for (i = 0; i < 8U && status == CDRO_POZYX_OK; ++i) {
            uint8_t raw[POZYX_RANGEINFO_SIZE];
            uint8_t id[2];
            uint8_t flags = 0;
            uint32_t start_us = clock_us(fw);
            uint32_t took_us;
            status = cdro_pozyx_read(dev, POZYX_REG_INT_STATUS, &flags, 1);
            took_us = clock_us(fw) - start_us;
            longest_read_us = took_us > longest_read_us ? took_us : longest_read_us;
            (void)cdro_put_u16(id, r1 != 0U ? r1 : 1U);
            start_us = clock_us(fw);
            if (status == CDRO_POZYX_OK) {
                status = cdro_pozyx_call(dev, POZYX_FN_DEVICE_GETRANGEINFO, id, sizeof id, raw, sizeof raw, NULL);
            }
            took_us = clock_us(fw) - start_us;
            longest_call_us = took_us > longest_call_us ? took_us : longest_call_us;
        }
        /* The call on the wire: address, function, 2 parameter bytes; address, 11 bytes read;
         * 9 clocks each, plus START, repeated START and STOP. */
        send_diag(fw, CDRO_DIAG_I2C_TIMING, status, 0, longest_read_us, longest_call_us,
                  (uint32_t)((16UL * 9UL + 3UL) * 1000000UL / CDRO_FW_I2C_CLOCK_HZ));
    } else {
        /* One node a step (a remote read can take its 300 ms timeout): the tags only. */
        const uint8_t index = (uint8_t)(group - 4U);
        const cdro_fw_node_t *node = &fw->nodes[index];
        cdro_accel_t accel;
        if ((node->flags & CDRO_FW_NODE_TAG) == 0U) {
            return;
        }
        memset(&accel, 0, sizeof accel);
        status = index == 0U ? cdro_pozyx_read_accel(dev, &accel) : cdro_pozyx_remote_read_accel(dev, node->id, &accel);
        send_diag(fw, CDRO_DIAG_ACCEL, status, node->id, cdro_accel_norm_mg(&accel), (uint32_t)(int32_t)accel.z_mg, 0);
    }
}

/* One step of the round under way: a node of NODE_INFO or SET_UWB, or a DIAGNOSE group. */
static void round_step(cdro_fw_t *fw)
{
    const uint8_t at = fw->round_cursor++;
    switch (fw->round) {
    case CDRO_FW_ROUND_NODE_INFO:
        if (at <= fw->node_count) {
            node_info_step(fw, at);
            return;
        }
        break;
    case CDRO_FW_ROUND_UWB_REMOTE:
    case CDRO_FW_ROUND_UWB_GAIN:
        if (at < fw->node_count) {
            set_uwb_remote(fw, (uint8_t)(at + 1U), fw->round);
            return;
        }
        if (fw->round == CDRO_FW_ROUND_UWB_REMOTE) {
            start_round(fw, CDRO_FW_ROUND_UWB_LOCAL);
            return;
        }
        start_round(fw, CDRO_FW_ROUND_NODE_INFO); /* and report what every node has now */
        return;
    case CDRO_FW_ROUND_UWB_LOCAL:
        set_uwb_local(fw);
        start_round(fw, CDRO_FW_ROUND_UWB_GAIN);
        return;
    case CDRO_FW_ROUND_DIAG:
        if (at < 4U + 1U + fw->node_count) { /* 4 groups, then each node (the tags' accelerometers) */
            diag_step(fw, at);
            return;
        }
        break;
    default: break;
    }
    fw->round = CDRO_FW_ROUND_NONE;
}

/* ---- the step -------------------------------------------------------------------------------- */

static uint32_t next_wake(const cdro_fw_t *fw, uint32_t now_ms)
{
    uint32_t next = fw->next_status_ms;
    if (fw->state != CDRO_FW_STATE_READY || fw->link.dropped_unreported > 0U || fw->round != CDRO_FW_ROUND_NONE) {
        return now_ms;
    }
    if (fw->pozyx_state == CDRO_FW_POZYX_ABSENT) {
        next = earlier(now_ms, next, reached(now_ms, fw->next_identify_ms) ? now_ms : fw->next_identify_ms);
    }
    if (fw->running) {
        if (fw->node_count > 0U) {
            if (fw->sched.current != CDRO_SCHED_NO_PAIR) {
                return now_ms;
            }
            next = earlier(now_ms, next, reached(now_ms, fw->next_slot_ms) ? now_ms : fw->next_slot_ms);
        }
        if (fw->motion_poll_ms != 0U) {
            if (fw->poll_cursor != NO_POLL_ROUND) {
                return now_ms;
            }
            next = earlier(now_ms, next, reached(now_ms, fw->next_poll_round_ms) ? now_ms : fw->next_poll_round_ms);
        }
    }
    return reached(now_ms, next) ? now_ms : next;
}

uint32_t cdro_fw_step(cdro_fw_t *fw, uint32_t now_ms)
{
    const uint32_t start_us = clock_us(fw);
    uint32_t elapsed_us;
    uint32_t next_ms;
    if (fw->state == CDRO_FW_STATE_BOOT) {
        if (!reached(now_ms, CDRO_FW_POZYX_BOOT_MS)) {
            return CDRO_FW_POZYX_BOOT_MS; /* the Pozyx needs this long after power-up */
        }
        identify(fw, now_ms);
    } else if (fw->state == CDRO_FW_STATE_DISCOVERY) {
        discovery(fw);
    } else {
        handle_host_bytes(fw, now_ms);
        report_errors(fw, now_ms);
        if (reached(now_ms, fw->next_status_ms)) {
            fw->next_status_ms = now_ms + fw->status_period_ms;
            send_status(fw, now_ms);
        }
        /* At most one Pozyx operation a step: another identification try, a round's step, or
         * ranging / motion. */
        if (fw->pozyx_state == CDRO_FW_POZYX_ABSENT) {
            if (reached(now_ms, fw->next_identify_ms)) {
                identify(fw, now_ms);
            }
        } else if (fw->round != CDRO_FW_ROUND_NONE) {
            round_step(fw);
        } else {
            operate(fw, now_ms);
        }
    }
    next_ms = next_wake(fw, now_ms);
    elapsed_us = clock_us(fw) - start_us;
    if (elapsed_us > fw->longest_loop_us) {
        fw->longest_loop_us = elapsed_us;
    }
    return next_ms;
}
