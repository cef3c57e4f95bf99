/*
 * firmware.h: the whole device behaviour of docs/protocol.md ("Device behaviour") as a step
 * function that is handed the time and says when it next wants to run.
 *
 *   cdro_fw_init(&fw, &config);
 *   for (;;) { next_ms = cdro_fw_step(&fw, now_ms()); ... }
 *
 * One step handles, in this order: boot (once: Pozyx self-check, 0x00 + HELLO, discovery),
 * host commands (at most CDRO_FW_RX_BYTES_PER_STEP bytes), pending reports (TX_OVERFLOW,
 * rate-limited bus/timeout errors), STATUS when due, then at most ONE Pozyx operation: a ranging
 * attempt or a motion poll, alternating when both are due. A step therefore never blocks
 * longer than one operation's timeouts (CDRO_FW_LONGEST_OPERATION_MS) plus bounded
 * bookkeeping; docs/firmware.md gives the figures. Retries of a failed range run in the steps
 * that follow, without waiting for the slot period.
 *
 * Hardware access goes through the Pozyx ops (pozyx.h) and the serial ops (link.h); nothing
 * else in this library touches hardware. No heap, no globals: all state is in cdro_fw_t.
 */
#ifndef CDRO_FW_FIRMWARE_H
#define CDRO_FW_FIRMWARE_H

#include <stdint.h>

#include "cdro/frames.h"
#include "cdro_fw/config.h"
#include "cdro_fw/link.h"
#include "cdro_fw/motion.h"
#include "cdro_fw/pozyx.h"
#include "cdro_fw/scheduler.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct cdro_fw_config {
    const cdro_pozyx_ops_t *pozyx_ops;
    void *pozyx_user;
    const cdro_serial_ops_t *serial_ops;
    void *serial_user;
    /* Lowest free RAM seen so far, in bytes (STATUS.free_ram_bytes); NULL reports 0. */
    uint16_t (*free_ram_bytes)(void *user);
    void *platform_user;
    uint8_t reset_cause; /* CDRO_RESET_* bits of the last reset (HELLO) */
} cdro_fw_config_t;

/* cdro_fw_node_t.flags */
#define CDRO_FW_NODE_KIND_KNOWN 0x01U    /* tag or anchor is known */
#define CDRO_FW_NODE_TAG 0x02U           /* has an accelerometer */
#define CDRO_FW_NODE_ACCEL_FAILING 0x04U /* ERROR ACCEL sent; cleared by a good read */
#define CDRO_FW_NODE_HAS_SAMPLE 0x08U    /* at least one accelerometer sample */
#define CDRO_FW_NODE_HAS_RANGE_TS 0x10U  /* last_range_timestamp_ms is valid */
#define CDRO_FW_NODE_STALE_SHIFT 5U      /* bits 5..6: consecutive stale results */
#define CDRO_FW_NODE_STALE_MASK 0x60U

typedef struct cdro_fw_node {
    uint16_t id;                      /* Pozyx network id */
    uint8_t flags;                    /* CDRO_FW_NODE_* */
    uint8_t poll_backoff;             /* high nibble: failed polls in a row; low: poll rounds to skip */
    uint32_t last_range_timestamp_ms; /* ms, this node's clock, last accepted range it initiated */
    cdro_motion_detector_t motion;
} cdro_fw_node_t;

typedef enum cdro_fw_state {
    CDRO_FW_STATE_BOOT = 0,      /* waiting for the Pozyx to power up */
    CDRO_FW_STATE_DISCOVERY = 1, /* HELLO sent; discovering nodes */
    CDRO_FW_STATE_READY = 2      /* answering commands; ranging after START */
} cdro_fw_state_t;

/* What identifying the own Pozyx found (cdro_fw_t.pozyx_state). Only OK ranges. */
typedef enum cdro_fw_pozyx_state {
    CDRO_FW_POZYX_ABSENT = 0,    /* not tried yet, silent, or a wrong WHO_AM_I: tried again with backoff */
    CDRO_FW_POZYX_OK = 1,        /* identified, self-test passed, a firmware this build drives */
    CDRO_FW_POZYX_SELF_TEST = 2, /* its self-test failed (ERROR SELF_TEST) */
    CDRO_FW_POZYX_FIRMWARE = 3   /* a firmware this build cannot drive (ERROR POZYX_FIRMWARE) */
} cdro_fw_pozyx_state_t;

/* A round of Pozyx work outside ranging (cdro_fw_t.round), one node or item per step, before
 * any ranging or motion poll. */
typedef enum cdro_fw_round {
    CDRO_FW_ROUND_NONE = 0,
    CDRO_FW_ROUND_NODE_INFO = 1,  /* reading every node's firmware and UWB settings (NODE_INFO) */
    CDRO_FW_ROUND_UWB_REMOTE = 2, /* SET_UWB: writing channel, rates, preamble on each remote node */
    CDRO_FW_ROUND_UWB_LOCAL = 3,  /* ... then on the own node, with the gain and the protocol */
    CDRO_FW_ROUND_UWB_GAIN = 4,   /* ... then gain and protocol on each remote node (same settings now) */
    CDRO_FW_ROUND_DIAG = 5        /* DIAGNOSE: the bench checklist, one DIAG item group per step */
} cdro_fw_round_t;

/* The UWB settings registers in NODE_INFO order: channel, rates, preamble, gain, protocol. */
#define CDRO_FW_UWB_SETTINGS 5

typedef struct cdro_fw_counters {
    uint32_t ranges_ok_direct;
    uint32_t ranges_ok_remote;
    uint32_t ranges_failed_direct; /* failed attempts, retries included */
    uint32_t ranges_failed_remote;
    uint32_t retries;           /* attempts that were retries */
    uint32_t stale_results;     /* ranges rejected because the timestamp did not advance */
    uint32_t accel_failures;    /* failed accelerometer polls */
    uint32_t commands_rejected; /* host chunks rejected or NACKed */
} cdro_fw_counters_t;

typedef struct cdro_fw {
    cdro_pozyx_t pozyx;
    cdro_link_t link;
    cdro_sched_t sched;
    cdro_fw_node_t nodes[CDRO_FW_MAX_NODES]; /* [0] own node, [1..node_count] remote nodes */
    cdro_fw_counters_t counters;
    uint16_t (*free_ram_bytes)(void *user);
    void *platform_user;

    /* schedule (SET_SCHEDULE) */
    uint16_t slot_period_ms;
    uint16_t motion_poll_ms;
    uint16_t status_period_ms;

    uint8_t state;                            /* cdro_fw_state_t */
    uint8_t running;                          /* 1 after START */
    uint8_t pozyx_state;                      /* cdro_fw_pozyx_state_t */
    uint8_t pozyx_tries;                      /* identification tries so far (HELLO.pozyx_tries), saturating */
    uint8_t round;                            /* cdro_fw_round_t */
    uint8_t round_cursor;                     /* the node (0 = own) or item group the round does next */
    uint8_t own_uwb[CDRO_FW_UWB_SETTINGS];    /* the own node's settings, as NODE_INFO compares */
    uint8_t target_uwb[CDRO_FW_UWB_SETTINGS]; /* SET_UWB's settings while its rounds run */
    uint8_t node_count;                       /* remote nodes */
    uint8_t node_source;                      /* CDRO_NODE_SOURCE_* of the node list (sent again after HELLO_REQUEST) */
    uint8_t reset_cause;
    uint8_t pozyx_firmware; /* FIRMWARE_VER, 0 = not read */
    uint8_t capabilities;   /* CDRO_CAP_* */
    uint8_t discovery_attempts;
    uint8_t poll_cursor; /* next node of the motion round; > node_count: no round running */
    uint8_t last_op_was_poll;

    uint32_t next_identify_ms;        /* device time of the next identification try (ABSENT) */
    uint32_t next_slot_ms;            /* device time the next slot may start */
    uint32_t next_poll_round_ms;      /* device time the next motion round may start */
    uint32_t next_status_ms;          /* device time of the next STATUS */
    uint32_t periodic_motion_mask;    /* bit i: node i's next sample is reported PERIODIC */
    uint32_t next_periodic_motion_ms; /* device time the mask is next set for every node */
    /* Low 16 bits of pozyx.bus_errors / pozyx.timeouts when last reported. 16 bits cannot
     * alias: with the 10 ms bus timeout at most 6000 occur in the longest status period. */
    uint16_t bus_errors_reported;
    uint16_t timeouts_reported;
    uint8_t command_error_pending;   /* an undecodable host chunk came since the last ERROR COMMAND */
    uint32_t next_bus_report_ms;     /* device time from which the next ERROR BUS may go */
    uint32_t next_timeout_report_ms; /* ... ERROR TIMEOUT */
    uint32_t next_command_report_ms; /* ... ERROR COMMAND */
    uint8_t last_command_error;      /* cdro_result_t of the last undecodable chunk, negated */
    uint32_t longest_loop_us;        /* us, longest step since the last STATUS */
} cdro_fw_t;

void cdro_fw_init(cdro_fw_t *fw, const cdro_fw_config_t *config);

/* Runs one step at device time now_ms (ms since boot). Returns the device time at which it next
 * wants to run; calling earlier is harmless (host bytes are read at every call). */
uint32_t cdro_fw_step(cdro_fw_t *fw, uint32_t now_ms);

#ifdef __cplusplus
}
#endif

#endif /* CDRO_FW_FIRMWARE_H */
