/*
 * config.h: every compile-time limit, period and timeout of the firmware, in one place.
 *
 * Each value can be overridden with -D on the compiler command line (the CMake build does so
 * for the Mega: CDRO_FW_MAX_REMOTE_NODES=20). The checks at the end reject combinations that
 * would not fit the protocol, the Wire buffer or the watchdog period, at compile time.
 *
 * Units are in the names: _MS milliseconds, _US microseconds, _MG milli-g, _HZ hertz.
 */
#ifndef CDRO_FW_CONFIG_H
#define CDRO_FW_CONFIG_H

#include "cdro/frame_layout.def"

/* ---- identity ------------------------------------------------------------------------- */

#define CDRO_FW_VERSION_MAJOR 1
#define CDRO_FW_VERSION_MINOR 0
#define CDRO_FW_VERSION ((CDRO_FW_VERSION_MAJOR << 8) | CDRO_FW_VERSION_MINOR) /* HELLO */

/* HELLO.node_id when the Pozyx did not answer at boot: the UWB broadcast short address, which
 * no Pozyx uses as its own id. (HELLO.node_id must be non-zero on the wire.) */
#define CDRO_FW_NODE_ID_UNKNOWN 0xFFFFU

/* ---- sizes ---------------------------------------------------------------------------- */

/* Remote nodes this build can schedule (HELLO.max_nodes). The Uno's 2 KB of RAM holds 10
 * with the budgets of docs/firmware.md; the Mega takes the protocol's maximum (20). */
#ifndef CDRO_FW_MAX_REMOTE_NODES
#define CDRO_FW_MAX_REMOTE_NODES 10
#endif

/* Nodes with state on the device: the own node (index 0) and the remote nodes (1..n). */
#define CDRO_FW_MAX_NODES (CDRO_FW_MAX_REMOTE_NODES + 1)

/* Pairs in ALL_PAIRS mode: n direct pairs and n(n-1)/2 remote-to-remote pairs. */
#define CDRO_FW_MAX_PAIRS (CDRO_FW_MAX_REMOTE_NODES + (CDRO_FW_MAX_REMOTE_NODES * (CDRO_FW_MAX_REMOTE_NODES - 1)) / 2)

/* Host bytes decoded per main-loop step (bounds the step's command-handling time; the rest
 * stays in the serial receive buffer for the next step). */
#ifndef CDRO_FW_RX_BYTES_PER_STEP
#define CDRO_FW_RX_BYTES_PER_STEP 80
#endif

/* ---- serial link ---------------------------------------------------------------------- */

#ifndef CDRO_FW_SERIAL_BAUD
#define CDRO_FW_SERIAL_BAUD 115200UL /* bit/s, 8N1 */
#endif

/* ---- I2C and the Pozyx driver --------------------------------------------------------- */

#define CDRO_FW_POZYX_I2C_ADDRESS 0x4B /* 7-bit; 0x4A with the "I2C LSB" pads bridged */

/* Standard mode, as the reference library runs it (it never sets the clock: Wire's 100 kHz).
 * The Pozyx supports 400 kHz too (-DCDRO_FW_I2C_CLOCK_HZ=400000UL); 100 kHz is the one known
 * to work with the shield's pull-ups and the Pozyx's clock stretching. */
#ifndef CDRO_FW_I2C_CLOCK_HZ
#define CDRO_FW_I2C_CLOCK_HZ 100000UL
#endif

/* The AVR Wire library buffers 32 bytes per transaction and direction. */
#define CDRO_FW_I2C_MAX_TRANSFER 32

/* Wire's timeout: it covers a whole transfer (a 32-byte read at 100 kHz takes 3 ms) and the
 * Pozyx's clock stretching, so it must be generous; after it the driver clears the bus
 * (cdro_pozyx_ops_t.bus_recover) and counts it. At least 25 ms. */
#ifndef CDRO_FW_I2C_TIMEOUT_US
#define CDRO_FW_I2C_TIMEOUT_US 25000UL
#endif

/* Wait after power-up before the first access to the Pozyx. */
#define CDRO_FW_POZYX_BOOT_MS 250U

/* A Pozyx that did not answer (or answered with a wrong WHO_AM_I) is asked again after
 * 500 ms, then after twice as long each time, up to 8 s, for ever: a Pozyx that boots slower
 * (or is plugged in later) is found without a reset. Each try is reported. */
#define CDRO_FW_IDENTIFY_RETRY_MS 500U
#define CDRO_FW_IDENTIFY_RETRY_MAX_MS 8000U

/* Pozyx firmware versions (FIRMWARE_VER, major << 4 | minor) this driver can drive: from 1.0
 * (before it the function map differs: 0xC0 was GETRANGEINFO) to 1.2 (1.3 changed how remote
 * results are handled, register facts 2.2). Others are refused (ERROR POZYX_FIRMWARE). */
#define CDRO_FW_POZYX_FIRMWARE_MIN 0x10U
#define CDRO_FW_POZYX_FIRMWARE_MAX 0x12U

/* Interval between two INT_STATUS reads while waiting for a Pozyx operation. */
#define CDRO_FW_POLL_INTERVAL_MS 1U

/* Local DO_RANGING completion (FUNC or ERR). */
#ifndef CDRO_FW_RANGING_TIMEOUT_MS
#define CDRO_FW_RANGING_TIMEOUT_MS 100U
#endif

/* The reply to a remote register read or remote function call (FUNC or ERR). The reference
 * code allows 1000 ms; a reply is two UWB frames (~6 ms at 110 kbit/s), so 300 ms leaves a
 * wide margin while keeping a remote range well under the watchdog period. */
#ifndef CDRO_FW_REMOTE_REPLY_TIMEOUT_MS
#define CDRO_FW_REMOTE_REPLY_TIMEOUT_MS 300U
#endif

/* The unsolicited result message a remote node sends after a remote DO_RANGING (RX_DATA). */
#ifndef CDRO_FW_REMOTE_RESULT_TIMEOUT_MS
#define CDRO_FW_REMOTE_RESULT_TIMEOUT_MS 100U
#endif

/* Length of that result message. Inferred (register facts 4.3: pypozyx decodes a 4-byte message
 * from the ranging node as the distance); the bench checklist of docs/firmware.md checks it on
 * the first real boards. The driver takes only a message of this length from the ranging node
 * as its result. */
#ifndef CDRO_FW_REMOTE_RESULT_LENGTH
#define CDRO_FW_REMOTE_RESULT_LENGTH 4U
#endif

/* Discovery: DEVICES_DISCOVER(all, slots, slot duration); completion within
 * slot_ms * (slots + 20) as in the reference code. */
#define CDRO_FW_DISCOVERY_SLOTS 3U
#define CDRO_FW_DISCOVERY_SLOT_MS 10U
#define CDRO_FW_DISCOVERY_TIMEOUT_MS (CDRO_FW_DISCOVERY_SLOT_MS * (CDRO_FW_DISCOVERY_SLOTS + 20U))
#define CDRO_FW_DISCOVERY_ATTEMPTS 2U /* discovery fails now and then: one retry at boot */

/* ---- schedule ------------------------------------------------------------------------- */

/* ERROR RANGING after this many consecutive failed attempts of one pair (once per streak). */
#define CDRO_FW_RANGING_ERROR_STREAK 5U

/* A pair whose slot failed (every attempt) n times in a row sits out the rest of its round and
 * min(2^(n-1) - 1, CDRO_FW_BACKOFF_MAX_ROUNDS) whole rounds: 0, 1, 3, 4, 4, ... So no pair goes
 * more than CDRO_FW_BACKOFF_MAX_ROUNDS whole rounds without an attempt. The same rule spaces
 * the accelerometer polls of a node that does not answer (in motion rounds). */
#define CDRO_FW_BACKOFF_MAX_ROUNDS 4U

/* A remote node's timestamps going backwards this many results in a row means it was reset:
 * the freshness reference is rebased (see firmware.c). */
#define CDRO_FW_STALE_REBASE 3U

/* ---- motion detection (docs/protocol.md, "Motion") ------------------------------------ */

#define CDRO_FW_ONE_G_MG 1000U
#define CDRO_FW_MOTION_WINDOW 8U          /* samples over which the deviation is the maximum */
#define CDRO_FW_MOVING_ABOVE_MG 80U       /* still -> moving when the deviation exceeds this */
#define CDRO_FW_STILL_BELOW_MG 40U        /* moving -> still when below this ... */
#define CDRO_FW_STILL_SAMPLES 16U         /* ... for this many consecutive samples */
#define CDRO_FW_MOTION_PERIODIC_MS 5000UL /* MOTION PERIODIC per node */

/* ---- watchdog and the main-loop bound ------------------------------------------------- */

#define CDRO_FW_WATCHDOG_MS 2000U /* WDTO_2S in the Arduino binding */

/* Longest single Pozyx operation one step may perform (docs/firmware.md derives the whole
 * step bound from it): a remote-to-remote range, two remote replies and the result message,
 * plus an allowance for the I2C traffic of polling (one INT_STATUS read per poll interval). */
#define CDRO_FW_LONGEST_OPERATION_MS                                           \
    (2U * CDRO_FW_REMOTE_REPLY_TIMEOUT_MS + CDRO_FW_REMOTE_RESULT_TIMEOUT_MS + \
     (2U * CDRO_FW_REMOTE_REPLY_TIMEOUT_MS + CDRO_FW_REMOTE_RESULT_TIMEOUT_MS) / 4U)

/* ---- compile-time checks -------------------------------------------------------------- */

#define CDRO_FW_STATIC_ASSERT(cond, name) typedef char cdro_fw_static_assert_##name[(cond) ? 1 : -1]

CDRO_FW_STATIC_ASSERT(CDRO_FW_MAX_REMOTE_NODES >= 1, at_least_one_remote_node);
CDRO_FW_STATIC_ASSERT(CDRO_FW_I2C_TIMEOUT_US >= 25000UL, wire_timeout_covers_a_transfer_and_stretching);
CDRO_FW_STATIC_ASSERT(CDRO_FW_MAX_REMOTE_NODES <= CDRO_MAX_NODES, node_list_fits_the_protocol);
CDRO_FW_STATIC_ASSERT(CDRO_FW_MAX_NODES <= 32, moving_mask_fits_uint32);
CDRO_FW_STATIC_ASSERT(CDRO_FW_MAX_PAIRS <= 254, pair_index_fits_uint8);
CDRO_FW_STATIC_ASSERT(CDRO_FW_BACKOFF_MAX_ROUNDS + 1 <= 15, backoff_fits_a_nibble);
CDRO_FW_STATIC_ASSERT(CDRO_FW_STILL_SAMPLES <= 255, still_count_fits_uint8);
CDRO_FW_STATIC_ASSERT(CDRO_FW_STALE_REBASE <= 3, stale_count_fits_two_bits);
CDRO_FW_STATIC_ASSERT(CDRO_FW_LONGEST_OPERATION_MS * 2U <= CDRO_FW_WATCHDOG_MS,
                      one_operation_fits_half_the_watchdog_period);
CDRO_FW_STATIC_ASSERT(CDRO_FW_DISCOVERY_TIMEOUT_MS *CDRO_FW_DISCOVERY_ATTEMPTS * 2U <= CDRO_FW_WATCHDOG_MS,
                      discovery_fits_half_the_watchdog_period);

#endif /* CDRO_FW_CONFIG_H */
