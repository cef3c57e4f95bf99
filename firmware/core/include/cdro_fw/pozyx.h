/*
 * pozyx.h: a small Pozyx driver over I2C, behind an operations table.
 *
 * The driver never touches hardware itself: every bus transaction, delay and clock reading
 * goes through cdro_pozyx_ops_t, bound to Wire/millis on the Arduino (firmware/arduino) and
 * to the simulated Pozyx in the native tests. Time is read, never assumed.
 *
 * Transaction shapes (7-bit address, default 0x4B):
 *   register read   START W reg, RS R n bytes, STOP          (chunks of <= 32 bytes)
 *   register write  START W reg, RS W data..., STOP          (data <= 32 bytes per call)
 *   function call   START W fn params..., RS R ret result..., STOP  (params, 1 + result <= 32)
 * Long functions (ranging, discovery) and remote operations complete later: the driver clears
 * INT_STATUS before the trigger, then polls it every CDRO_FW_POLL_INTERVAL_MS until the flag it
 * waits for or ERR, up to a timeout. INT_STATUS clears on read, so every value read is ORed
 * into a sticky copy, and flags are consumed from the copy.
 *
 * Error model: every call returns cdro_pozyx_status_t; CDRO_POZYX_OK is 0. A failed call
 * leaves the reason in the device struct (the register or function concerned, the Pozyx
 * ERRORCODE after an ERR) and counts bus errors and timeouts. No call allocates; no call blocks
 * longer than its documented timeout plus the I2C time of its polling (Wire's own timeout,
 * CDRO_FW_I2C_TIMEOUT_US, bounds a stuck bus; after one the driver has the bus cleared through
 * ops->bus_recover and counts it).
 */
#ifndef CDRO_FW_POZYX_H
#define CDRO_FW_POZYX_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Result of one I2C transaction, as the ops report it. */
typedef enum cdro_i2c_result {
    CDRO_I2C_OK = 0,
    CDRO_I2C_NACK_ADDRESS = 1, /* no device answered its address */
    CDRO_I2C_NACK_DATA = 2,    /* the device refused a byte */
    CDRO_I2C_TIMEOUT = 3,      /* the bus hung (clock stretched past the Wire timeout) */
    CDRO_I2C_ERROR = 4         /* anything else: arbitration lost, short read, too long */
} cdro_i2c_result_t;

/*
 * The hardware seam. All functions are required; `user` is passed back unchanged.
 *   i2c_write: START (or repeated START), address+W, the bytes; then STOP if send_stop,
 *              else the bus stays held for a repeated START. length <= 32.
 *   i2c_read:  START (or repeated START), address+R, length bytes (ACK all but the last),
 *              STOP. length <= 32.
 *   delay_ms:  waits (on the Arduino: delay(); in the simulation: advances simulated time).
 *   now_ms, now_us: free-running clocks, wrapping; only differences are used.
 *   bus_recover: after a transaction timed out (a slave holding SDA or SCL low): frees the bus
 *              (on the Arduino: clocks SCL until SDA is released, a STOP, the TWI restarted).
 *              May be NULL.
 */
typedef struct cdro_pozyx_ops {
    cdro_i2c_result_t (*i2c_write)(void *user, uint8_t address, const uint8_t *data, uint8_t length, uint8_t send_stop);
    cdro_i2c_result_t (*i2c_read)(void *user, uint8_t address, uint8_t *data, uint8_t length);
    void (*delay_ms)(void *user, uint16_t duration_ms);
    uint32_t (*now_ms)(void *user);
    uint32_t (*now_us)(void *user);
    void (*bus_recover)(void *user);
} cdro_pozyx_ops_t;

typedef enum cdro_pozyx_status {
    CDRO_POZYX_OK = 0,
    CDRO_POZYX_ERR_BUS = 1,      /* an I2C transaction failed (NACK, bus timeout, short read) */
    CDRO_POZYX_ERR_TIMEOUT = 2,  /* the operation did not complete within its timeout */
    CDRO_POZYX_ERR_DEVICE = 3,   /* the Pozyx raised ERR; last_error_code holds ERRORCODE */
    CDRO_POZYX_ERR_REFUSED = 4,  /* a function's return byte said failure */
    CDRO_POZYX_ERR_REPLY = 5,    /* a remote reply with the wrong length or content */
    CDRO_POZYX_ERR_RESULT = 6,   /* a range result outside physical bounds (garbage) */
    CDRO_POZYX_ERR_ARGUMENT = 7, /* the request does not fit the 32-byte Wire buffer, id 0, ... */
    CDRO_POZYX_ERR_IDENTITY = 8  /* WHO_AM_I is not 0x43 */
} cdro_pozyx_status_t;

/* What one remote-to-remote range saw, for the bench diagnostics (DIAGNOSE): filled by
 * cdro_pozyx_range_remote when cdro_pozyx_t.trace points at one. Times are the local clock. */
typedef struct cdro_pozyx_trace {
    uint8_t flags_to_ack;                         /* INT_STATUS bits read from TX_SEND up to the acknowledgement */
    uint8_t flags_to_result;                      /* bits read after it, up to the result message */
    uint8_t result_length;                        /* bytes, RX_DATA_LEN of the last message from the ranging node */
    uint32_t result_head;                         /* the first 4 bytes of the result message, little-endian */
    uint32_t send_ms, ack_ms, result_ms, done_ms; /* ms: TX_SEND, acknowledgement, result, GETRANGEINFO */
} cdro_pozyx_trace_t;

typedef struct cdro_pozyx {
    const cdro_pozyx_ops_t *ops;
    void *user;
    uint8_t address;           /* 7-bit I2C address */
    uint8_t sticky_flags;      /* INT_STATUS bits read but not consumed */
    uint8_t last_error_code;   /* ERRORCODE read after the last ERR, 0 if none */
    uint8_t last_target;       /* register or function of the last failure of any kind */
    uint8_t bus_target;        /* register or function of the last bus error (ERROR BUS detail) */
    uint8_t timeout_target;    /* function of the last timeout (ERROR TIMEOUT detail) */
    uint8_t seen_flags;        /* every INT_STATUS bit read since the last clear (diagnostics) */
    uint32_t bus_errors;       /* count of failed I2C transactions */
    uint32_t timeouts;         /* count of operations that timed out */
    uint32_t bus_recoveries;   /* count of bus clears after a transaction timed out */
    cdro_pozyx_trace_t *trace; /* NULL, or where cdro_pozyx_range_remote records what it saw */
} cdro_pozyx_t;

typedef struct cdro_pozyx_info {
    uint8_t who_am_i;
    uint8_t firmware_version; /* major << 4 | minor */
    uint8_t hardware_version; /* bits 7..5 type (POZYX_HW_TYPE_*), 4..0 revision */
    uint8_t self_test;        /* ST_RESULT bits */
    uint16_t network_id;
} cdro_pozyx_info_t;

typedef struct cdro_pozyx_range_result {
    uint32_t timestamp_ms; /* ms, the ranging node's own clock when it ranged */
    uint32_t distance_mm;  /* mm */
    int16_t rss_dbm;       /* dBm */
} cdro_pozyx_range_result_t;

typedef struct cdro_accel {
    int16_t x_mg, y_mg, z_mg; /* mg, body frame */
} cdro_accel_t;

void cdro_pozyx_init(cdro_pozyx_t *dev, const cdro_pozyx_ops_t *ops, void *user, uint8_t address);

/* ---- bus level ------------------------------------------------------------------------ */

/* Reads length bytes from reg on, in chunks of <= 32 bytes (each re-addressed). Never pass a
 * range that includes ERRORCODE/INT_STATUS by accident: they clear on read. */
cdro_pozyx_status_t cdro_pozyx_read(cdro_pozyx_t *dev, uint8_t reg, uint8_t *data, uint8_t length);

/* Writes length (<= 32) bytes at reg: START W reg, RS W data, STOP. */
cdro_pozyx_status_t cdro_pozyx_write(cdro_pozyx_t *dev, uint8_t reg, const uint8_t *data, uint8_t length);

/* Calls fn with params (<= 31 bytes) and reads result_length (<= 31) bytes after the return
 * byte. *return_byte gets the return byte (may be NULL). Does not interpret the return byte. */
cdro_pozyx_status_t cdro_pozyx_call(cdro_pozyx_t *dev, uint8_t fn, const uint8_t *params, uint8_t params_length,
                                    uint8_t *result, uint8_t result_length, uint8_t *return_byte);

/* Reads INT_STATUS once and forgets every flag seen so far (before triggering an operation). */
cdro_pozyx_status_t cdro_pozyx_clear_flags(cdro_pozyx_t *dev);

/* Polls until one of `flags` or ERR is set, consumes it and returns OK (flag) or ERR_DEVICE
 * (ERR; ERRORCODE read into last_error_code); ERR_TIMEOUT after timeout_ms. `target` names the
 * operation for error reports. */
cdro_pozyx_status_t cdro_pozyx_wait(cdro_pozyx_t *dev, uint8_t flags, uint16_t timeout_ms, uint8_t target);

/* ---- device level --------------------------------------------------------------------- */

/* Reads WHO_AM_I .. ST_RESULT (4 bytes, stopping short of ERRORCODE) and NETWORK_ID.
 * ERR_IDENTITY if WHO_AM_I is wrong (info->who_am_i holds what was read). */
cdro_pozyx_status_t cdro_pozyx_identify(cdro_pozyx_t *dev, cdro_pozyx_info_t *info);

/* The own node's accelerometer. */
cdro_pozyx_status_t cdro_pozyx_read_accel(cdro_pozyx_t *dev, cdro_accel_t *accel);

/* Own node ranges with `to`: clear, DO_RANGING, wait FUNC/ERR, GETRANGEINFO. */
cdro_pozyx_status_t cdro_pozyx_range(cdro_pozyx_t *dev, uint16_t to, cdro_pozyx_range_result_t *out);

/* Remote register read of length (<= 31) bytes at reg of node `id` over UWB. */
cdro_pozyx_status_t cdro_pozyx_remote_read(cdro_pozyx_t *dev, uint16_t id, uint8_t reg, uint8_t *data, uint8_t length);

/* Remote function call on node `id`: params <= 28 bytes, result <= 30 bytes after the return
 * byte, which must be 1 (else ERR_REFUSED). */
cdro_pozyx_status_t cdro_pozyx_remote_call(cdro_pozyx_t *dev, uint16_t id, uint8_t fn, const uint8_t *params,
                                           uint8_t params_length, uint8_t *result, uint8_t result_length);

/* Remote register write of length (<= 29) bytes at reg of node `id`: waits for the
 * acknowledgement (FUNC from `id`). A node whose UWB channel, rates or preamble the write
 * changes answers on its new settings, so the local device does not hear it: ERR_TIMEOUT. */
cdro_pozyx_status_t cdro_pozyx_remote_write(cdro_pozyx_t *dev, uint16_t id, uint8_t reg, const uint8_t *data,
                                            uint8_t length);

/* A remote node's accelerometer (remote read of 6 bytes at ACCEL_X). */
cdro_pozyx_status_t cdro_pozyx_remote_read_accel(cdro_pozyx_t *dev, uint16_t id, cdro_accel_t *accel);

/* Remote-to-remote range: node `from` ranges with node `to` (section 4.3 of the register facts):
 * remote DO_RANGING on `from` (its acknowledgement: from `from`, 1 byte, 1); RX_DATA flags seen
 * up to the acknowledgement dropped; its result message (RX_DATA from `from` with
 * CDRO_FW_REMOTE_RESULT_LENGTH bytes; anything else skipped); only then a remote GETRANGEINFO
 * on `from`. out->timestamp_ms is `from`'s clock. */
cdro_pozyx_status_t cdro_pozyx_range_remote(cdro_pozyx_t *dev, uint16_t from, uint16_t to,
                                            cdro_pozyx_range_result_t *out);

/* Clears the device list, discovers every node (anchors and tags) and reads up to max_ids ids.
 * *found gets the number read (<= max_ids); *listed the size of the Pozyx list. Pages after the
 * first (GETIDS with an offset, which neither reference library uses) are checked: an id of 0 or
 * one already read means the device ignored the offset, and the ids from that page on are
 * dropped; then *found < min(*listed, max_ids) with status OK. */
cdro_pozyx_status_t cdro_pozyx_discover(cdro_pozyx_t *dev, uint16_t *ids, uint8_t max_ids, uint8_t *found,
                                        uint8_t *listed);

/* Short stable name of a status, for test output. */
const char *cdro_pozyx_status_name(cdro_pozyx_status_t status);

#ifdef __cplusplus
}
#endif

#endif /* CDRO_FW_POZYX_H */
