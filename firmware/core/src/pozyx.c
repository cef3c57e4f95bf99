/*
 * pozyx.c: the Pozyx I2C driver (see pozyx.h for the transaction shapes and error model).
 * Written from the register facts; shares no code with the Pozyx libraries and avoids their
 * known bugs: every transaction's result is checked, ERR is checked in every wait, remote
 * replies and the result message of a remote ranging are matched by sender and length, and
 * flags read while polling are kept (and dropped where they cannot belong to what is awaited).
 */
#include "cdro_fw/pozyx.h"

#include <stddef.h>
#include <string.h>

#include "cdro/frame_layout.def"
#include "cdro/wire.h"
#include "cdro_fw/config.h"
#include "cdro_fw/pozyx_regs.h"

CDRO_FW_STATIC_ASSERT(CDRO_FW_I2C_MAX_TRANSFER == 32, wire_buffer_is_32_bytes);
CDRO_FW_STATIC_ASSERT(POZYX_GETIDS_MAX_PER_CALL * 2 + 1 < CDRO_FW_I2C_MAX_TRANSFER, getids_page_fits);

/* Largest params / result of one function call: the function or return byte takes one byte. */
#define MAX_CALL_BYTES (CDRO_FW_I2C_MAX_TRANSFER - 1)
/* Largest remote payload: TX_DATA carries the offset byte before it. */
#define MAX_REMOTE_PAYLOAD (MAX_CALL_BYTES - 1)

/* A failed transaction: counted, and after a timeout (a slave holding the bus) the bus is
 * cleared, so that the next transaction can work. */
static cdro_pozyx_status_t bus_failure(cdro_pozyx_t *dev, uint8_t target, cdro_i2c_result_t result)
{
    ++dev->bus_errors;
    dev->last_target = target;
    dev->bus_target = target;
    if (result == CDRO_I2C_TIMEOUT && dev->ops->bus_recover != NULL) {
        dev->ops->bus_recover(dev->user);
        ++dev->bus_recoveries;
    }
    return CDRO_POZYX_ERR_BUS;
}

/* Writes then reads (a repeated start between): the shape of a register read and a call. */
static cdro_i2c_result_t write_read(cdro_pozyx_t *dev, const uint8_t *out, uint8_t out_length, uint8_t *in,
                                    uint8_t in_length)
{
    cdro_i2c_result_t result = dev->ops->i2c_write(dev->user, dev->address, out, out_length, 0);
    if (result == CDRO_I2C_OK) {
        result = dev->ops->i2c_read(dev->user, dev->address, in, in_length);
    }
    return result;
}

void cdro_pozyx_init(cdro_pozyx_t *dev, const cdro_pozyx_ops_t *ops, void *user, uint8_t address)
{
    memset(dev, 0, sizeof(*dev));
    dev->ops = ops;
    dev->user = user;
    dev->address = address;
}

cdro_pozyx_status_t cdro_pozyx_read(cdro_pozyx_t *dev, uint8_t reg, uint8_t *data, uint8_t length)
{
    uint8_t offset = 0;
    if ((uint16_t)reg + length > 256U) {
        return CDRO_POZYX_ERR_ARGUMENT;
    }
    while (offset < length) {
        const uint8_t remaining = (uint8_t)(length - offset);
        const uint8_t chunk = remaining < CDRO_FW_I2C_MAX_TRANSFER ? remaining : CDRO_FW_I2C_MAX_TRANSFER;
        const uint8_t at = (uint8_t)(reg + offset);
        const cdro_i2c_result_t result = write_read(dev, &at, 1, data + offset, chunk);
        if (result != CDRO_I2C_OK) {
            return bus_failure(dev, at, result);
        }
        offset = (uint8_t)(offset + chunk);
    }
    return CDRO_POZYX_OK;
}

cdro_pozyx_status_t cdro_pozyx_write(cdro_pozyx_t *dev, uint8_t reg, const uint8_t *data, uint8_t length)
{
    if (length == 0U || length > CDRO_FW_I2C_MAX_TRANSFER || (uint16_t)reg + length > 256U) {
        return CDRO_POZYX_ERR_ARGUMENT;
    }
    /* The documented form: the register byte, a repeated start, then the data. */
    cdro_i2c_result_t result = dev->ops->i2c_write(dev->user, dev->address, &reg, 1, 0);
    if (result == CDRO_I2C_OK) {
        result = dev->ops->i2c_write(dev->user, dev->address, data, length, 1);
    }
    if (result != CDRO_I2C_OK) {
        return bus_failure(dev, reg, result);
    }
    return CDRO_POZYX_OK;
}

cdro_pozyx_status_t cdro_pozyx_call(cdro_pozyx_t *dev, uint8_t fn, const uint8_t *params, uint8_t params_length,
                                    uint8_t *result, uint8_t result_length, uint8_t *return_byte)
{
    uint8_t buffer[CDRO_FW_I2C_MAX_TRANSFER];
    if (params_length > MAX_CALL_BYTES || result_length > MAX_CALL_BYTES) {
        return CDRO_POZYX_ERR_ARGUMENT;
    }
    buffer[0] = fn;
    if (params_length > 0U) {
        memcpy(buffer + 1, params, params_length);
    }
    {
        const cdro_i2c_result_t bus =
            write_read(dev, buffer, (uint8_t)(params_length + 1U), buffer, (uint8_t)(result_length + 1U));
        if (bus != CDRO_I2C_OK) {
            return bus_failure(dev, fn, bus);
        }
    }
    if (return_byte != NULL) {
        *return_byte = buffer[0];
    }
    if (result_length > 0U) {
        memcpy(result, buffer + 1, result_length);
    }
    return CDRO_POZYX_OK;
}

/* A call whose return byte must be 1. */
static cdro_pozyx_status_t call_checked(cdro_pozyx_t *dev, uint8_t fn, const uint8_t *params, uint8_t params_length,
                                        uint8_t *result, uint8_t result_length)
{
    uint8_t ret = 0;
    const cdro_pozyx_status_t status = cdro_pozyx_call(dev, fn, params, params_length, result, result_length, &ret);
    if (status != CDRO_POZYX_OK) {
        return status;
    }
    if (ret != 1U) {
        dev->last_target = fn;
        return CDRO_POZYX_ERR_REFUSED;
    }
    return CDRO_POZYX_OK;
}

cdro_pozyx_status_t cdro_pozyx_clear_flags(cdro_pozyx_t *dev)
{
    uint8_t flags = 0;
    const cdro_pozyx_status_t status = cdro_pozyx_read(dev, POZYX_REG_INT_STATUS, &flags, 1);
    dev->sticky_flags = 0;
    dev->seen_flags = 0;
    return status;
}

cdro_pozyx_status_t cdro_pozyx_wait(cdro_pozyx_t *dev, uint8_t flags, uint16_t timeout_ms, uint8_t target)
{
    const uint8_t wanted = (uint8_t)(flags | POZYX_INT_ERR);
    const uint32_t start_ms = dev->ops->now_ms(dev->user);
    while ((dev->sticky_flags & wanted) == 0U) {
        uint8_t status_flags = 0;
        const cdro_pozyx_status_t status = cdro_pozyx_read(dev, POZYX_REG_INT_STATUS, &status_flags, 1);
        if (status != CDRO_POZYX_OK) {
            return status;
        }
        dev->sticky_flags = (uint8_t)(dev->sticky_flags | status_flags);
        dev->seen_flags = (uint8_t)(dev->seen_flags | status_flags);
        if ((dev->sticky_flags & wanted) != 0U) {
            break;
        }
        if ((uint32_t)(dev->ops->now_ms(dev->user) - start_ms) >= timeout_ms) {
            ++dev->timeouts;
            dev->last_target = target;
            dev->timeout_target = target;
            return CDRO_POZYX_ERR_TIMEOUT;
        }
        dev->ops->delay_ms(dev->user, CDRO_FW_POLL_INTERVAL_MS);
    }
    if ((dev->sticky_flags & POZYX_INT_ERR) != 0U) {
        uint8_t code = 0;
        dev->sticky_flags = (uint8_t)(dev->sticky_flags & (uint8_t)~wanted);
        dev->last_target = target;
        if (cdro_pozyx_read(dev, POZYX_REG_ERRORCODE, &code, 1) != CDRO_POZYX_OK) {
            code = 0;
            dev->last_target = target; /* the operation, not the ERRORCODE read, failed */
        }
        dev->last_error_code = code;
        return CDRO_POZYX_ERR_DEVICE;
    }
    dev->sticky_flags = (uint8_t)(dev->sticky_flags & (uint8_t)~flags);
    return CDRO_POZYX_OK;
}

/* Milliseconds left of timeout_ms since start_ms (0 when expired). */
static uint16_t remaining_ms(const cdro_pozyx_t *dev, uint32_t start_ms, uint16_t timeout_ms)
{
    const uint32_t elapsed_ms = (uint32_t)(dev->ops->now_ms(dev->user) - start_ms);
    return elapsed_ms >= timeout_ms ? 0U : (uint16_t)(timeout_ms - elapsed_ms);
}

cdro_pozyx_status_t cdro_pozyx_identify(cdro_pozyx_t *dev, cdro_pozyx_info_t *info)
{
    uint8_t status_regs[4]; /* WHO_AM_I, FIRMWARE_VER, HARDWARE_VER, ST_RESULT: not ERRORCODE */
    uint8_t id[2];
    cdro_pozyx_status_t status = cdro_pozyx_read(dev, POZYX_REG_WHO_AM_I, status_regs, sizeof status_regs);
    memset(info, 0, sizeof(*info));
    if (status != CDRO_POZYX_OK) {
        return status;
    }
    info->who_am_i = status_regs[0];
    info->firmware_version = status_regs[1];
    info->hardware_version = status_regs[2];
    info->self_test = status_regs[3];
    if (info->who_am_i != POZYX_WHO_AM_I_VALUE) {
        dev->last_target = POZYX_REG_WHO_AM_I;
        return CDRO_POZYX_ERR_IDENTITY;
    }
    status = cdro_pozyx_read(dev, POZYX_REG_NETWORK_ID, id, sizeof id);
    if (status == CDRO_POZYX_OK) {
        info->network_id = cdro_get_u16(id);
    }
    return status;
}

static void parse_accel(const uint8_t *raw, cdro_accel_t *accel)
{
    accel->x_mg = cdro_get_i16(raw);
    accel->y_mg = cdro_get_i16(raw + 2);
    accel->z_mg = cdro_get_i16(raw + 4);
}

cdro_pozyx_status_t cdro_pozyx_read_accel(cdro_pozyx_t *dev, cdro_accel_t *accel)
{
    uint8_t raw[6];
    const cdro_pozyx_status_t status = cdro_pozyx_read(dev, POZYX_REG_ACCEL_X, raw, sizeof raw);
    if (status == CDRO_POZYX_OK) {
        parse_accel(raw, accel);
    }
    return status;
}

/* Parses GETRANGEINFO's 10 bytes and rejects distances no UWB link can produce. */
static cdro_pozyx_status_t parse_range(cdro_pozyx_t *dev, const uint8_t *raw, cdro_pozyx_range_result_t *out)
{
    out->timestamp_ms = cdro_get_u32(raw);
    out->distance_mm = cdro_get_u32(raw + 4);
    out->rss_dbm = cdro_get_i16(raw + 8);
    if (out->distance_mm > CDRO_MAX_DISTANCE_MM) {
        dev->last_target = POZYX_FN_DEVICE_GETRANGEINFO;
        return CDRO_POZYX_ERR_RESULT;
    }
    return CDRO_POZYX_OK;
}

cdro_pozyx_status_t cdro_pozyx_range(cdro_pozyx_t *dev, uint16_t to, cdro_pozyx_range_result_t *out)
{
    uint8_t id[2];
    uint8_t raw[POZYX_RANGEINFO_SIZE];
    cdro_pozyx_status_t status;
    if (to == 0U) {
        return CDRO_POZYX_ERR_ARGUMENT;
    }
    (void)cdro_put_u16(id, to);
    status = cdro_pozyx_clear_flags(dev);
    if (status == CDRO_POZYX_OK) {
        status = call_checked(dev, POZYX_FN_DO_RANGING, id, sizeof id, NULL, 0);
    }
    if (status == CDRO_POZYX_OK) {
        status = cdro_pozyx_wait(dev, POZYX_INT_FUNC, CDRO_FW_RANGING_TIMEOUT_MS, POZYX_FN_DO_RANGING);
    }
    if (status == CDRO_POZYX_OK) {
        status = call_checked(dev, POZYX_FN_DEVICE_GETRANGEINFO, id, sizeof id, raw, sizeof raw);
    }
    if (status == CDRO_POZYX_OK) {
        status = parse_range(dev, raw, out);
    }
    return status;
}

/* Loads payload into the TX buffer and sends it to node id with op; flags are cleared between
 * the two, so that only this request's reply can complete the wait that follows. */
static cdro_pozyx_status_t remote_send(cdro_pozyx_t *dev, uint16_t id, uint8_t op, const uint8_t *payload,
                                       uint8_t payload_length)
{
    uint8_t buffer[MAX_REMOTE_PAYLOAD + 1];
    uint8_t send[3];
    cdro_pozyx_status_t status;
    if (id == 0U || payload_length == 0U || payload_length > MAX_REMOTE_PAYLOAD) {
        return CDRO_POZYX_ERR_ARGUMENT;
    }
    buffer[0] = 0; /* offset in the TX buffer */
    memcpy(buffer + 1, payload, payload_length);
    status = call_checked(dev, POZYX_FN_TX_DATA, buffer, (uint8_t)(payload_length + 1U), NULL, 0);
    if (status == CDRO_POZYX_OK) {
        status = cdro_pozyx_clear_flags(dev);
    }
    if (status == CDRO_POZYX_OK) {
        (void)cdro_put_u8(cdro_put_u16(send, id), op);
        status = call_checked(dev, POZYX_FN_TX_SEND, send, sizeof send, NULL, 0);
    }
    return status;
}

/* Sender and length of the last UWB message (RX_NETWORK_ID, RX_DATA_LEN). */
static cdro_pozyx_status_t read_rx_header(cdro_pozyx_t *dev, uint16_t *sender, uint8_t *length)
{
    uint8_t raw[3];
    const cdro_pozyx_status_t status = cdro_pozyx_read(dev, POZYX_REG_RX_NETWORK_ID, raw, sizeof raw);
    *sender = cdro_get_u16(raw);
    *length = raw[2];
    return status;
}

/* Waits for the reply to a remote request (FUNC or ERR) and checks it came from id with
 * expected_length bytes: a message from any other node in between overwrote it. */
static cdro_pozyx_status_t remote_wait_reply(cdro_pozyx_t *dev, uint16_t id, uint8_t expected_length)
{
    uint16_t sender = 0;
    uint8_t length = 0;
    cdro_pozyx_status_t status =
        cdro_pozyx_wait(dev, POZYX_INT_FUNC, CDRO_FW_REMOTE_REPLY_TIMEOUT_MS, POZYX_FN_TX_SEND);
    if (status == CDRO_POZYX_OK) {
        status = read_rx_header(dev, &sender, &length);
    }
    if (status == CDRO_POZYX_OK && (sender != id || length != expected_length)) {
        dev->last_target = POZYX_REG_RX_NETWORK_ID;
        status = CDRO_POZYX_ERR_REPLY;
    }
    return status;
}

/* RX_DATA(0, length) into data; length <= 31. */
static cdro_pozyx_status_t read_rx_buffer(cdro_pozyx_t *dev, uint8_t *data, uint8_t length)
{
    uint8_t params[2];
    params[0] = 0;
    params[1] = length;
    return call_checked(dev, POZYX_FN_RX_DATA, params, sizeof params, data, length);
}

cdro_pozyx_status_t cdro_pozyx_remote_read(cdro_pozyx_t *dev, uint16_t id, uint8_t reg, uint8_t *data, uint8_t length)
{
    uint8_t request[2];
    cdro_pozyx_status_t status;
    if (length == 0U || length > MAX_CALL_BYTES) {
        return CDRO_POZYX_ERR_ARGUMENT;
    }
    request[0] = reg;
    request[1] = length;
    status = remote_send(dev, id, POZYX_REMOTE_READ, request, sizeof request);
    if (status == CDRO_POZYX_OK) {
        status = remote_wait_reply(dev, id, length);
    }
    if (status == CDRO_POZYX_OK) {
        status = read_rx_buffer(dev, data, length);
    }
    return status;
}

cdro_pozyx_status_t cdro_pozyx_remote_call(cdro_pozyx_t *dev, uint16_t id, uint8_t fn, const uint8_t *params,
                                           uint8_t params_length, uint8_t *result, uint8_t result_length)
{
    uint8_t buffer[MAX_CALL_BYTES];
    cdro_pozyx_status_t status;
    if (params_length > MAX_REMOTE_PAYLOAD - 1U || result_length > MAX_CALL_BYTES - 1U) {
        return CDRO_POZYX_ERR_ARGUMENT;
    }
    buffer[0] = fn;
    if (params_length > 0U) {
        memcpy(buffer + 1, params, params_length);
    }
    status = remote_send(dev, id, POZYX_REMOTE_FUNCTION, buffer, (uint8_t)(params_length + 1U));
    if (status == CDRO_POZYX_OK) {
        status = remote_wait_reply(dev, id, (uint8_t)(result_length + 1U));
    }
    if (status == CDRO_POZYX_OK) {
        status = read_rx_buffer(dev, buffer, (uint8_t)(result_length + 1U));
    }
    if (status == CDRO_POZYX_OK && buffer[0] != 1U) {
        dev->last_target = fn;
        status = CDRO_POZYX_ERR_REFUSED;
    }
    if (status == CDRO_POZYX_OK && result_length > 0U) {
        memcpy(result, buffer + 1, result_length);
    }
    return status;
}

cdro_pozyx_status_t cdro_pozyx_remote_write(cdro_pozyx_t *dev, uint16_t id, uint8_t reg, const uint8_t *data,
                                            uint8_t length)
{
    uint8_t request[MAX_REMOTE_PAYLOAD];
    uint16_t sender = 0;
    uint8_t ignored = 0;
    cdro_pozyx_status_t status;
    if (length == 0U || length > MAX_REMOTE_PAYLOAD - 1U) {
        return CDRO_POZYX_ERR_ARGUMENT;
    }
    request[0] = reg;
    memcpy(request + 1, data, length);
    status = remote_send(dev, id, POZYX_REMOTE_WRITE, request, (uint8_t)(length + 1U));
    /* The acknowledgement is the flag; its length is not documented, so only the sender is
     * checked. */
    if (status == CDRO_POZYX_OK) {
        status = cdro_pozyx_wait(dev, POZYX_INT_FUNC, CDRO_FW_REMOTE_REPLY_TIMEOUT_MS, POZYX_FN_TX_SEND);
    }
    if (status == CDRO_POZYX_OK) {
        status = read_rx_header(dev, &sender, &ignored);
    }
    if (status == CDRO_POZYX_OK && sender != id) {
        dev->last_target = POZYX_REG_RX_NETWORK_ID;
        status = CDRO_POZYX_ERR_REPLY;
    }
    return status;
}

cdro_pozyx_status_t cdro_pozyx_remote_read_accel(cdro_pozyx_t *dev, uint16_t id, cdro_accel_t *accel)
{
    uint8_t raw[6];
    const cdro_pozyx_status_t status = cdro_pozyx_remote_read(dev, id, POZYX_REG_ACCEL_X, raw, sizeof raw);
    if (status == CDRO_POZYX_OK) {
        parse_accel(raw, accel);
    }
    return status;
}

/* Waits for the result message a remote DO_RANGING makes `from` send (RX_DATA): the one from
 * `from` with CDRO_FW_REMOTE_RESULT_LENGTH bytes. Other nodes' messages and `from`'s
 * reply-shaped ones (a late reply to an earlier request) are skipped, up to timeout_ms in all. */
static cdro_pozyx_status_t wait_result_message(cdro_pozyx_t *dev, uint16_t from, uint16_t timeout_ms)
{
    const uint32_t start_ms = dev->ops->now_ms(dev->user);
    for (;;) {
        uint16_t sender = 0;
        uint8_t length = 0;
        const uint16_t left_ms = remaining_ms(dev, start_ms, timeout_ms);
        cdro_pozyx_status_t status;
        if (left_ms == 0U) { /* a stream of other messages cannot extend the wait */
            ++dev->timeouts;
            dev->last_target = POZYX_FN_DO_RANGING;
            dev->timeout_target = POZYX_FN_DO_RANGING;
            return CDRO_POZYX_ERR_TIMEOUT;
        }
        status = cdro_pozyx_wait(dev, POZYX_INT_RX_DATA, left_ms, POZYX_FN_DO_RANGING);
        if (status == CDRO_POZYX_OK) {
            status = read_rx_header(dev, &sender, &length);
        }
        if (dev->trace != NULL && status == CDRO_POZYX_OK && sender == from) {
            dev->trace->result_length = length;
        }
        if (status != CDRO_POZYX_OK || (sender == from && length == CDRO_FW_REMOTE_RESULT_LENGTH)) {
            return status;
        }
        /* Not the result message: keep waiting for the rest of the time. */
    }
}

cdro_pozyx_status_t cdro_pozyx_range_remote(cdro_pozyx_t *dev, uint16_t from, uint16_t to,
                                            cdro_pozyx_range_result_t *out)
{
    cdro_pozyx_trace_t *const trace = dev->trace;
    uint8_t id[2];
    uint8_t raw[POZYX_RANGEINFO_SIZE];
    cdro_pozyx_status_t status;
    if (from == 0U || to == 0U || from == to) {
        return CDRO_POZYX_ERR_ARGUMENT;
    }
    (void)cdro_put_u16(id, to);
    if (trace != NULL) {
        memset(trace, 0, sizeof(*trace));
        trace->send_ms = dev->ops->now_ms(dev->user);
    }
    /* 1. `from` accepts DO_RANGING(to) (its 1-byte reply must be 1). */
    status = cdro_pozyx_remote_call(dev, from, POZYX_FN_DO_RANGING, id, sizeof id, NULL, 0);
    if (trace != NULL) {
        trace->ack_ms = dev->ops->now_ms(dev->user);
        trace->flags_to_ack = dev->seen_flags;
        dev->seen_flags = 0;
    }
    /* 2. `from` ranges with `to` only after it has acknowledged, then sends its result message.
     * An RX_DATA seen up to the acknowledgement cannot be that message: it is the
     * acknowledgement itself (the device may raise RX_DATA with FUNC for a reply) or a late
     * message of an earlier attempt. Dropped, or the wait below would end at once and step 3
     * would read the range `from` stored before, while it is still ranging. */
    dev->sticky_flags = (uint8_t)(dev->sticky_flags & (uint8_t)~POZYX_INT_RX_DATA);
    if (status == CDRO_POZYX_OK) {
        status = wait_result_message(dev, from, CDRO_FW_REMOTE_RESULT_TIMEOUT_MS);
    }
    if (trace != NULL) {
        uint8_t head[4] = {0, 0, 0, 0};
        trace->result_ms = dev->ops->now_ms(dev->user);
        trace->flags_to_result = dev->seen_flags;
        if (status == CDRO_POZYX_OK) {
            status = read_rx_buffer(dev, head, sizeof head);
            trace->result_head = cdro_get_u32(head);
        }
    }
    /* 3. The stored result, read with a remote GETRANGEINFO(to) on `from`: never before the
     * result message says that `from` has finished ranging. */
    if (status == CDRO_POZYX_OK) {
        status = cdro_pozyx_remote_call(dev, from, POZYX_FN_DEVICE_GETRANGEINFO, id, sizeof id, raw, sizeof raw);
    }
    if (trace != NULL) {
        trace->done_ms = dev->ops->now_ms(dev->user);
    }
    if (status == CDRO_POZYX_OK) {
        status = parse_range(dev, raw, out);
    }
    return status;
}

cdro_pozyx_status_t cdro_pozyx_discover(cdro_pozyx_t *dev, uint16_t *ids, uint8_t max_ids, uint8_t *found,
                                        uint8_t *listed)
{
    uint8_t params[3];
    uint8_t list_size = 0;
    uint8_t offset = 0;
    cdro_pozyx_status_t status = call_checked(dev, POZYX_FN_DEVICES_CLEAR, NULL, 0, NULL, 0);
    *found = 0;
    *listed = 0;
    if (status == CDRO_POZYX_OK) {
        status = cdro_pozyx_clear_flags(dev);
    }
    if (status == CDRO_POZYX_OK) {
        params[0] = POZYX_DISCOVER_ALL;
        params[1] = CDRO_FW_DISCOVERY_SLOTS;
        params[2] = CDRO_FW_DISCOVERY_SLOT_MS;
        status = call_checked(dev, POZYX_FN_DEVICES_DISCOVER, params, sizeof params, NULL, 0);
    }
    if (status == CDRO_POZYX_OK) {
        status = cdro_pozyx_wait(dev, POZYX_INT_FUNC, CDRO_FW_DISCOVERY_TIMEOUT_MS, POZYX_FN_DEVICES_DISCOVER);
    }
    if (status == CDRO_POZYX_OK) {
        status = cdro_pozyx_read(dev, POZYX_REG_DEVICE_LIST_SIZE, &list_size, 1);
    }
    if (status != CDRO_POZYX_OK) {
        return status;
    }
    if (list_size > POZYX_DEVICE_LIST_MAX) {
        list_size = POZYX_DEVICE_LIST_MAX; /* never trust a count beyond the documented list */
    }
    *listed = list_size;
    while (offset < list_size && offset < max_ids) {
        uint8_t raw[2 * POZYX_GETIDS_MAX_PER_CALL];
        uint8_t count = (uint8_t)(list_size - offset);
        uint8_t i;
        if (count > (uint8_t)(max_ids - offset)) {
            count = (uint8_t)(max_ids - offset);
        }
        if (count > POZYX_GETIDS_MAX_PER_CALL) {
            count = POZYX_GETIDS_MAX_PER_CALL;
        }
        params[0] = offset;
        params[1] = count;
        status = call_checked(dev, POZYX_FN_DEVICES_GETIDS, params, 2, raw, (uint8_t)(2U * count));
        if (status != CDRO_POZYX_OK) {
            return status;
        }
        for (i = 0; i < count; ++i) {
            const uint16_t id = cdro_get_u16(raw + (size_t)2U * i);
            uint8_t j;
            /* A page after the first must hold new, non-zero ids: a device that ignored the
             * offset repeats the first page. Its ids from here on are unknown: stop. */
            for (j = 0; j < offset + i && offset > 0U; ++j) {
                if (ids[j] == id) {
                    return CDRO_POZYX_OK;
                }
            }
            if (offset > 0U && id == 0U) {
                return CDRO_POZYX_OK;
            }
            ids[offset + i] = id;
        }
        offset = (uint8_t)(offset + count);
        *found = offset;
    }
    return CDRO_POZYX_OK;
}

const char *cdro_pozyx_status_name(cdro_pozyx_status_t status)
{
    switch (status) {
    case CDRO_POZYX_OK: return "ok";
    case CDRO_POZYX_ERR_BUS: return "bus";
    case CDRO_POZYX_ERR_TIMEOUT: return "timeout";
    case CDRO_POZYX_ERR_DEVICE: return "device";
    case CDRO_POZYX_ERR_REFUSED: return "refused";
    case CDRO_POZYX_ERR_REPLY: return "reply";
    case CDRO_POZYX_ERR_RESULT: return "result";
    case CDRO_POZYX_ERR_ARGUMENT: return "argument";
    case CDRO_POZYX_ERR_IDENTITY: return "identity";
    default: return "unknown";
    }
}
