/*
 * pozyx_sim.h: a simulated Pozyx device on I2C, with a simulated UWB network around it.
 *
 * What it is. An I2C *slave* state machine driven by bus events (start with address and
 * direction, byte written -> ACK/NACK, byte read, stop), implementing the register protocol
 * of the Pozyx as far as the CDRO firmware uses it (firmware/core/include/cdro_fw/pozyx_regs.h):
 *   - register reads with auto-increment, clear-on-read ERRORCODE and INT_STATUS, the
 *     accelerometer (ACCEL_X..Z from each node's trace, 100 Hz samples with seeded noise),
 *     NETWORK_ID, DEVICE_LIST_SIZE, RX_NETWORK_ID / RX_DATA_LEN;
 *   - register writes in the documented form (START W reg, repeated START W data..., STOP);
 *     the plain form (data right after reg) is NACKed and counted as a protocol violation
 *     unless config.accept_plain_writes is set;
 *   - function calls (START W fn params..., repeated START R ret result..., STOP): TX_DATA,
 *     TX_SEND (remote read 0x02, remote write 0x04, data 0x06, remote function 0x08), RX_DATA,
 *     DO_RANGING, DEVICES_DISCOVER / GETIDS / CLEAR, DEVICE_GETINFO, DEVICE_GETRANGEINFO,
 *     LED_CTRL, RESET_SYS;
 *   - long operations that complete later in simulated time (pozyx_sim_advance): ranging,
 *     discovery, remote replies, and the remote DO_RANGING of the register facts, section 4.3
 *     (reply, two-way ranging between the two remote nodes, then an unsolicited 4-byte result
 *     message raising RX_DATA; the result is then read with a remote GETRANGEINFO);
 *   - a registry of nodes: ids, tag or anchor, positions as a function of time (so nodes can
 *     move), accelerometer traces, their own millisecond clocks; distances come from the
 *     geometry plus Gaussian noise from a seeded RNG; links longer than max_range_m fail;
 *   - fault injection (pozyx_sim_faults_t): NACK on the bus, a hung bus, operations that never
 *     complete (-> the driver's timeout), ERR with an error code, garbage distances
 *     (167772160 mm), stale GETRANGEINFO (the stored entry is left as it was), lost remote
 *     replies, late replies, refused functions, foreign UWB messages;
 *   - the real device's behaviours, each a switch of pozyx_sim_config_t that
 *     pozyx_sim_config_realistic turns on (and pozyx_sim_config_default, the ideal model, off):
 *     replies that raise RX_DATA with FUNC, nodes busy while they range, collisions of
 *     overlapping messages, boot time, clock stretching, the real timings, a full device list;
 *     nodes talk only on identical UWB settings (channel, rates, preamble).
 *
 * What it is not. It does not model I2C timing: the code driving it (a test adapter, or the
 * simavr TWI peripheral of the firmware-in-the-loop harness) advances time itself, and spends
 * the clock stretching the device asks for (stretch_us) if it can. It has no
 * dependency on the firmware core or on GoogleTest, and it never allocates: the caller owns
 * pozyx_sim_t (about 24 KB; allocate it statically or on the heap of the native program).
 *
 * Typical use:
 *     pozyx_sim_config_t config;
 *     pozyx_sim_config_default(&config);
 *     config.seed = 42;
 *     pozyx_sim_init(sim, &config);
 *     pozyx_sim_add_node(sim, &local);   // the first node added is the device on the bus
 *     pozyx_sim_add_node(sim, &anchor);  // ...remote nodes
 *     // per I2C transaction, in bus order:
 *     pozyx_sim_i2c_start(sim, 0x4B, 0); pozyx_sim_i2c_write(sim, reg);
 *     pozyx_sim_i2c_start(sim, 0x4B, 1); byte = pozyx_sim_i2c_read(sim, 0); pozyx_sim_i2c_stop(sim);
 *     // whenever simulated time moves:
 *     pozyx_sim_advance(sim, now_us);
 *
 * Time is in microseconds from the start of the simulation (uint64_t) and only moves forward.
 * Every function is deterministic given the seed and the sequence of calls.
 */
#ifndef POZYX_SIM_H
#define POZYX_SIM_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define POZYX_SIM_MAX_NODES 32                    /* nodes in the registry, the local device included */
#define POZYX_SIM_MAX_RANGE_ENTRIES 20            /* stored range results per node (the device list) */
#define POZYX_SIM_MAX_EVENTS 16                   /* pending long operations and messages */
#define POZYX_SIM_BUFFER_SIZE 100                 /* UWB TX / RX buffers */
#define POZYX_SIM_MAX_PARAMS 128                  /* function parameter bytes accepted per call */
#define POZYX_SIM_GARBAGE_DISTANCE_MM 167772160UL /* what a failed ranging can return */
#define POZYX_SIM_DEFAULT_I2C_ADDRESS 0x4B

typedef enum pozyx_sim_bus {
    POZYX_SIM_ACK = 0,  /* the byte (or address) was acknowledged */
    POZYX_SIM_NACK = 1, /* refused */
    POZYX_SIM_HANG = 2  /* the device holds the clock low: the master must time out */
} pozyx_sim_bus_t;

typedef struct pozyx_sim_vec3 {
    double x, y, z;
} pozyx_sim_vec3_t;

/* A node's position in metres at simulated time t_s (seconds). */
typedef pozyx_sim_vec3_t (*pozyx_sim_position_fn)(void *context, double t_s);
/* A node's acceleration in mg (body frame, gravity included: 1000 mg on z at rest) at t_s. */
typedef pozyx_sim_vec3_t (*pozyx_sim_accel_fn)(void *context, double t_s);
/* Optional trace of what the device does, one line per call/event (no newline). */
typedef void (*pozyx_sim_trace_fn)(void *context, const char *line);

/* What one two-way ranging reports, when the caller decides it (config.range_fn). */
typedef struct pozyx_sim_range_outcome {
    uint8_t error_code;   /* 0: a result; else the ranging fails with this ERRORCODE */
    uint32_t distance_mm; /* mm, the stored distance (garbage and stale faults still apply) */
    int16_t rss_dbm;
} pozyx_sim_range_outcome_t;
/* Decides the ranging of `ranger` with `partner` completing at t_s, on a link the model found
 * working (both up, same UWB settings, within max_range_m, partner not busy). */
typedef void (*pozyx_sim_range_fn)(void *context, uint16_t ranger, uint16_t partner, double t_s,
                                   pozyx_sim_range_outcome_t *out);

typedef struct pozyx_sim_node_config {
    uint16_t id;                 /* network id, non-zero */
    uint8_t is_tag;              /* 1 = tag (has an accelerometer), 0 = anchor */
    uint8_t powered;             /* 0 = silent on UWB (and on I2C for the local device) */
    pozyx_sim_vec3_t position_m; /* m, used when position_fn is NULL */
    pozyx_sim_position_fn position_fn;
    void *position_context;
    pozyx_sim_accel_fn accel_fn; /* NULL: at rest, (0, 0, 1000) mg */
    void *accel_context;
    uint32_t clock_offset_ms; /* ms, the node's uptime at simulated time 0 */
    uint8_t self_test;        /* ST_RESULT; 0 = the healthy value (tag 0x3F, anchor 0x30) */
} pozyx_sim_node_config_t;

typedef struct pozyx_sim_config {
    uint8_t i2c_address;           /* 7-bit, default 0x4B */
    uint8_t who_am_i;              /* default 0x43 */
    uint8_t firmware_version;      /* default 0x11 */
    uint8_t accept_plain_writes;   /* 0 (default): only the documented register-write form */
    uint8_t imu_flag;              /* 1 (default): INT_STATUS IMU set every 10 ms on a tag */
    uint64_t seed;                 /* RNG seed for range and accelerometer noise */
    double range_noise_std_mm;     /* mm, Gaussian noise of each distance (default 30) */
    double range_bias_mm;          /* mm, added to every distance (default 0) */
    double accel_noise_std_mg;     /* mg, Gaussian noise of each accelerometer axis (default 5) */
    double max_range_m;            /* m, longer UWB links fail (default 50) */
    uint32_t ranging_duration_us;  /* us, one two-way ranging exchange (default 15000) */
    uint32_t uwb_message_us;       /* us, one UWB message on air incl. turnaround (default 3000) */
    uint32_t remote_processing_us; /* us, a remote node's handling of a request (default 1000) */
    /* Behaviours of the real device (pozyx_sim_config_realistic sets them; docs/firmware.md,
     * "The simulated Pozyx", says where each figure comes from). All off / 0 in the ideal model
     * of pozyx_sim_config_default, which the unit tests of the model and the driver use. */
    uint8_t reply_raises_rx_data;   /* a reply to a remote request raises RX_DATA with FUNC (it is
                                       a received UWB data message too) */
    uint8_t busy_remotes;           /* a node taking part in a two-way ranging (and, for the ranging
                                       node, until its result message is sent) receives nothing:
                                       a request reaching it then is lost */
    uint8_t collisions;             /* UWB messages whose air times overlap at the local device are
                                       all lost, as is one arriving while it sends or ranges */
    uint8_t device_list_full_error; /* a ranging with a 21st partner fails with ERR 0x03 (the local
                                       device) or silently (a remote one) instead of evicting */
    uint32_t boot_us;               /* us after power-up during which a device neither answers on
                                       I2C (NACK) nor on UWB */
    uint32_t stretch_function_us;   /* us the device holds SCL before the return byte of a function */
    uint32_t stretch_register_us;   /* us the device holds SCL before the first byte of a register
                                       read (see pozyx_sim_t.stretch_us) */
    uint8_t getids_ignores_offset;  /* not known of the real device (neither reference library pages
                                       with an offset): DEVICES_GETIDS answers from index 0 whatever
                                       the offset; for the driver's guard (off in both profiles) */
    uint32_t late_reply_us;         /* us a reply or result message is late under faults.late_reply
                                       (default 400000: past the firmware's 300 ms reply timeout) */
    pozyx_sim_trace_fn trace;       /* NULL = no trace */
    void *trace_context;
    /* NULL (default): distances from the geometry with range_noise_std_mm and range_bias_mm.
     * Set: every ranging's outcome comes from it (cdro-sim's error model: NLOS, outliers,
     * dropouts); a failed one raises ERR with its code on the local device, for a local and for
     * a remote ranging alike. */
    pozyx_sim_range_fn range_fn;
    void *range_context;
} pozyx_sim_config_t;

/* Faults: each counter arms that many occurrences; the simulator decrements it as it injects.
 * Set them directly in sim->faults at any time. */
typedef struct pozyx_sim_faults {
    uint32_t nack_address;      /* NACK the next n address phases */
    uint32_t nack_write;        /* NACK the next n written bytes */
    uint32_t hang;              /* the next n bus events hang (clock stretched forever) */
    uint32_t no_completion;     /* the next n long operations (ranging, discovery, remote ranging)
                                   never complete */
    uint32_t error_completion;  /* the next n long operations complete with ERR ... */
    uint8_t error_code;         /* ... and this ERRORCODE (default POZYX_ERROR_RANGING 0x11) */
    uint32_t garbage_range;     /* the next n rangings store POZYX_SIM_GARBAGE_DISTANCE_MM */
    uint32_t stale_range;       /* the next n rangings report success but store nothing new */
    uint32_t drop_remote_reply; /* the next n replies to remote requests are lost */
    uint32_t refuse_function;   /* the next n function calls return 0 without effect */
    uint32_t late_reply;        /* the next n replies to remote requests and result messages of
                                   remote rangings arrive config.late_reply_us late (after the
                                   driver has given up on them, into whatever it does next) */
} pozyx_sim_faults_t;

typedef struct pozyx_sim_stats {
    uint32_t transactions;  /* STARTs that were not repeated starts */
    uint32_t bytes_written; /* bytes the master wrote (address bytes excluded) */
    uint32_t bytes_read;
    uint32_t longest_write;       /* most bytes written in one address phase */
    uint32_t longest_read;        /* most bytes read in one address phase */
    uint32_t function_calls[64];  /* per function 0xB0..0xEF: [fn - 0xB0] */
    uint32_t register_reads;      /* read phases at a register pointer */
    uint32_t register_writes;     /* register writes in the documented form */
    uint32_t protocol_violations; /* plain-form writes, reads without a pointer, writes to
                                      read-only registers, bytes after a read phase, ... */
    uint32_t rangings;            /* two-way rangings performed (local and remote) */
    uint32_t remote_requests;     /* TX_SEND of read, write or function */
    uint32_t messages_delivered;  /* UWB messages that reached the local RX buffer */
    uint32_t faults_injected;
    uint32_t collisions;       /* messages lost to overlapping air time (config.collisions) */
    uint32_t busy_losses;      /* requests lost to a busy node (config.busy_remotes) */
    uint32_t boot_refusals;    /* I2C address phases NACKed while booting (config.boot_us) */
    uint32_t list_full_errors; /* rangings refused for a full device list */
    uint64_t stretched_us;     /* us of clock stretching in all */
} pozyx_sim_stats_t;

typedef struct pozyx_sim_range_entry {
    uint16_t partner;
    uint32_t timestamp_ms; /* ms, the ranging node's clock */
    uint32_t distance_mm;
    int16_t rss_dbm;
} pozyx_sim_range_entry_t;

typedef struct pozyx_sim_node {
    pozyx_sim_node_config_t config;
    uint8_t regs[256]; /* plain register storage (configuration, positions) */
    pozyx_sim_range_entry_t ranges[POZYX_SIM_MAX_RANGE_ENTRIES];
    uint8_t range_count;
    int64_t accel_sample_index; /* 10 ms IMU sample held in accel_mg, -1 = none */
    int16_t accel_mg[3];
    uint8_t was_powered;                  /* config.powered when last looked at (to see power-ups) */
    uint64_t ready_at_us;                 /* booted from then on (config.boot_us after power-up) */
    uint64_t busy_from_us, busy_until_us; /* in a ranging exchange (config.busy_remotes) */
} pozyx_sim_node_t;

typedef struct pozyx_sim_event {
    uint64_t at_us;
    uint8_t kind;  /* internal */
    uint16_t a, b; /* node ids involved */
    uint8_t length;
    uint8_t collided; /* a message that overlapped another one on air: lost when due */
    uint8_t data[POZYX_SIM_BUFFER_SIZE];
} pozyx_sim_event_t;

typedef struct pozyx_sim {
    pozyx_sim_config_t config;
    pozyx_sim_faults_t faults;
    pozyx_sim_stats_t stats;
    pozyx_sim_node_t nodes[POZYX_SIM_MAX_NODES]; /* [0] is the local device on the bus */
    uint8_t node_count;
    uint64_t now_us;
    uint64_t rng_state;
    uint8_t has_spare_normal;
    double spare_normal;

    /* local device state */
    uint8_t int_status;
    uint8_t error_code;
    uint8_t tx_buffer[POZYX_SIM_BUFFER_SIZE];
    uint8_t tx_length;
    uint8_t rx_buffer[POZYX_SIM_BUFFER_SIZE];
    uint8_t rx_length;
    uint16_t rx_sender;
    uint16_t device_list[POZYX_SIM_MAX_RANGE_ENTRIES];
    uint8_t device_list_size;
    uint8_t busy; /* a local long operation (ranging, discovery) is pending */
    uint64_t last_imu_tick;
    uint64_t local_air_from_us, local_air_until_us; /* the local device sends or ranges then */
    uint64_t last_rx_until_us;                      /* end of the last message received */
    uint32_t stretch_us; /* us the device holds SCL after the last address phase of a read (clock
                            stretching): the harness lets that much time pass before the first
                            byte, or times out (the bytes are then not read) */

    /* bus state machine */
    uint8_t phase; /* internal */
    uint8_t in_transaction;
    uint8_t pointer; /* register or function addressed */
    uint8_t pointer_set;
    uint8_t params[POZYX_SIM_MAX_PARAMS];
    uint8_t params_length;
    uint8_t executed;
    uint8_t result[POZYX_SIM_BUFFER_SIZE + 2];
    uint8_t result_length;
    uint8_t result_position;
    uint8_t phase_bytes;

    pozyx_sim_event_t events[POZYX_SIM_MAX_EVENTS];
    uint8_t event_count;
} pozyx_sim_t;

/* Defaults as documented in pozyx_sim_config_t: the ideal model (every real behaviour off,
 * the historical faster timings). */
void pozyx_sim_config_default(pozyx_sim_config_t *config);

/* The default configuration with every real behaviour on and the timings of the real device
 * (docs/firmware.md, "The simulated Pozyx": the source of each figure). */
void pozyx_sim_config_realistic(pozyx_sim_config_t *config);

/* Resets everything: no nodes, time 0, no faults, zero statistics. */
void pozyx_sim_init(pozyx_sim_t *sim, const pozyx_sim_config_t *config);

/* Defaults for a node: powered, at the origin, at rest, healthy. */
void pozyx_sim_node_config_default(pozyx_sim_node_config_t *node, uint16_t id, uint8_t is_tag);

/* Adds a node; the first one added is the local device. Returns its index, or -1 if the
 * registry is full, the id is 0 or already present. */
int pozyx_sim_add_node(pozyx_sim_t *sim, const pozyx_sim_node_config_t *node);

/* The node with this id, or NULL. Its config may be changed at any time (move it, power it off). */
pozyx_sim_node_t *pozyx_sim_find(pozyx_sim_t *sim, uint16_t id);

/* Position (m) and true distance (m) at the current simulated time. */
pozyx_sim_vec3_t pozyx_sim_position(const pozyx_sim_t *sim, const pozyx_sim_node_t *node);
double pozyx_sim_true_distance_m(const pozyx_sim_t *sim, uint16_t a, uint16_t b);

/* ---- bus events (call them in bus order) ------------------------------------------------ */

/* START or repeated START with a 7-bit address and the direction (read = 1). */
pozyx_sim_bus_t pozyx_sim_i2c_start(pozyx_sim_t *sim, uint8_t address, uint8_t read);
/* A byte written by the master after an address+W. */
pozyx_sim_bus_t pozyx_sim_i2c_write(pozyx_sim_t *sim, uint8_t byte);
/* A byte read by the master after an address+R; master_ack = 1 if the master will read more. */
uint8_t pozyx_sim_i2c_read(pozyx_sim_t *sim, uint8_t master_ack);
/* STOP: ends the transaction. */
void pozyx_sim_i2c_stop(pozyx_sim_t *sim);

/* ---- time ------------------------------------------------------------------------------- */

/* Moves simulated time to now_us (never backwards) and completes what is due, in order. */
void pozyx_sim_advance(pozyx_sim_t *sim, uint64_t now_us);
/* When the next pending event completes, or UINT64_MAX if none (for event-driven harnesses). */
uint64_t pozyx_sim_next_event_us(const pozyx_sim_t *sim);

/* ---- injection ---------------------------------------------------------------------------- */

/* A UWB data message from node `from` reaching the local device at at_us (RX_DATA). */
int pozyx_sim_inject_message(pozyx_sim_t *sim, uint16_t from, const uint8_t *data, uint8_t length, uint64_t at_us);

#ifdef __cplusplus
}
#endif

#endif /* POZYX_SIM_H */
