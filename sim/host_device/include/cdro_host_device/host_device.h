/*
 * host_device.h: the CDRO firmware (firmware/core, the code the Uno runs) as a device on the
 * host, for cdro-sim. Built natively as a shared library (libcdro_host_device.so) that Python
 * loads with ctypes; it runs on the host, never on the Arduino.
 *
 * What it joins:
 *   - the firmware: cdro_fw_init / cdro_fw_step of firmware/core, unchanged, with host ops;
 *   - the Pozyx on its I2C bus: sim/pozyx_sim's register model (the one firmware in the
 *     loop uses, with its real-device behaviours on), each transaction costing simulated time
 *     at the I2C clock as on the Uno (9 bits a byte plus start and stop, Wire's overhead, clock
 *     stretching, Wire's timeout for a hung bus);
 *   - the serial port: the Uno's HardwareSerial, a 127-byte transmit buffer drained at the baud
 *     rate (frames that do not fit are dropped by the firmware) and a 63-byte receive buffer
 *     that host bytes reach one by one at the baud rate (those that find it full are lost:
 *     while the firmware boots and discovers, it does not read it);
 *   - the world, through callbacks of the caller: where each node is (so the model finds which
 *     links work), what each ranging reports (the caller's error model) and what each
 *     accelerometer reads; and where the bytes the firmware writes go.
 *
 * Time is simulated, in microseconds since the simulation started; it moves only when the
 * caller lets it pass (cdro_hd_idle_to) or the firmware spends it (I2C, waits). Device time
 * (millis) restarts at every power-on and reset. Deterministic given the calls.
 *
 *     cdro_hd_t *hd = cdro_hd_create(&config, &callbacks);
 *     cdro_hd_add_node(hd, own_id, is_tag);  ... the remote nodes
 *     cdro_hd_power_on(hd, 0, CDRO_RESET_POWER_ON);
 *     for (;;) { cdro_hd_idle_to(hd, cdro_hd_next_due_us(hd)); cdro_hd_step(hd); }
 */
#ifndef CDRO_HOST_DEVICE_H
#define CDRO_HOST_DEVICE_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Where a node is at t_s (simulation seconds): xyz_m[0..2], metres. */
typedef void (*cdro_hd_position_fn)(void *context, uint16_t id, double t_s, double *xyz_m);
/* The norm an accelerometer reads at t_s, mg (1000 at rest), noise included. */
typedef double (*cdro_hd_accel_fn)(void *context, uint16_t id, double t_s);
/* The ranging of `from` with `to` completing at t_s, on a link that works: 0 and the distance
 * (mm) and RSS (dBm), or the Pozyx ERRORCODE of a failure. */
typedef uint8_t (*cdro_hd_range_fn)(void *context, uint16_t from, uint16_t to, double t_s, uint32_t *distance_mm,
                                    int16_t *rss_dbm);
/* Bytes the receiving side takes now (beyond the UART), e.g. a live link's queue. */
typedef uint16_t (*cdro_hd_room_fn)(void *context);
/* Bytes the firmware wrote at t_us: one whole frame (ending in 0x00), or a lone 0x00. */
typedef void (*cdro_hd_write_fn)(void *context, const uint8_t *data, uint16_t length, uint64_t t_us);

typedef struct cdro_hd_callbacks {
    void *context;
    cdro_hd_position_fn position;
    cdro_hd_accel_fn accel;
    cdro_hd_range_fn range;
    cdro_hd_room_fn room; /* NULL: no limit beyond the UART */
    cdro_hd_write_fn write;
} cdro_hd_callbacks_t;

typedef struct cdro_hd_config {
    uint64_t seed;           /* the Pozyx model's own random draws */
    double max_range_m;      /* m, longer UWB links fail */
    uint8_t pozyx_firmware;  /* the Pozyx's FIRMWARE_VER, major << 4 | minor */
    uint8_t pozyx_present;   /* 0: the shield does not answer on I2C */
    uint16_t free_ram_bytes; /* STATUS.free_ram_bytes */
} cdro_hd_config_t;

typedef struct cdro_hd cdro_hd_t;

/* The STATUS counters and a few more, as the firmware holds them now. */
typedef struct cdro_hd_counters {
    uint32_t ranges_ok_direct;
    uint32_t ranges_ok_remote;
    uint32_t ranges_failed_direct;
    uint32_t ranges_failed_remote;
    uint32_t retries;
    uint32_t bus_errors;
    uint32_t timeouts;
    uint32_t frames_sent;
    uint32_t frames_dropped;
    uint32_t commands_rejected;
    uint32_t stale_results;
    uint32_t accel_failures;
    uint32_t host_bytes_lost; /* host bytes that found the receive buffer full (since creation) */
    uint32_t boots;           /* power-ons and resets (since creation) */
} cdro_hd_counters_t;

/* NULL when out of memory. */
cdro_hd_t *cdro_hd_create(const cdro_hd_config_t *config, const cdro_hd_callbacks_t *callbacks);
void cdro_hd_destroy(cdro_hd_t *hd);

/* A node of the network; the first one added is the device's own Pozyx. 0, or -1 (registry
 * full, id 0 or repeated). Only before the first power-on. */
int cdro_hd_add_node(cdro_hd_t *hd, uint16_t id, uint8_t is_tag);

/* The Uno (re)starts now: cdro_fw_init with this reset cause, device time 0, receive buffer
 * cleared. The Pozyx and the network keep running. */
void cdro_hd_power_on(cdro_hd_t *hd, uint8_t reset_cause);

uint64_t cdro_hd_now_us(const cdro_hd_t *hd);
uint64_t cdro_hd_boot_us(const cdro_hd_t *hd);
/* Lets simulated time pass up to t_us (never backwards). */
void cdro_hd_idle_to(cdro_hd_t *hd, uint64_t t_us);
/* When the firmware next wants to run: what its last step asked, or earlier when host bytes
 * arrive (once it is ready; before, they wait in the receive buffer). */
uint64_t cdro_hd_next_due_us(const cdro_hd_t *hd);
/* One cdro_fw_step at the current time; simulated time moves by what it spends. */
void cdro_hd_step(cdro_hd_t *hd);

/* Host bytes sent now: they reach the receive buffer at the baud rate, after what is still on
 * its way. Returns how many were taken (the rest, beyond 4096 on their way, are lost). */
uint16_t cdro_hd_receive(cdro_hd_t *hd, const uint8_t *data, uint16_t length);

void cdro_hd_read_counters(const cdro_hd_t *hd, cdro_hd_counters_t *out);
uint8_t cdro_hd_running(const cdro_hd_t *hd);
/* cdro_fw_state_t: 0 boot (before HELLO), 1 discovery, 2 ready. */
uint8_t cdro_hd_state(const cdro_hd_t *hd);
/* 1 when the firmware's motion detector has node `id` moving. */
uint8_t cdro_hd_moving(const cdro_hd_t *hd, uint16_t id);

/* A frame that did not come from the firmware but is to look as if it did (fault injection):
 * the sequence number it must carry, then whether the link took it (counted as the
 * firmware's link counts its own). */
uint16_t cdro_hd_next_sequence(const cdro_hd_t *hd);
void cdro_hd_injected_frame(cdro_hd_t *hd, uint8_t sent);
/* Bytes the transmit path takes now (the UART's free space, and the room callback's). */
uint16_t cdro_hd_tx_free(cdro_hd_t *hd);

/* The firmware's compile-time constants (firmware/core/include/cdro_fw/config.h, and the states
 * of cdro_fw_state_t) by name without the CDRO_FW_ prefix, e.g. "MOVING_ABOVE_MG",
 * "STATE_BOOT"; *found = 0 for an unknown name. */
int64_t cdro_hd_constant(const char *name, uint8_t *found);

/* The layout of the structs above, in bytes, for a binding that declares them by hand (ctypes,
 * tools/cdro_tools/simulation/host_device.py, checks its own against it when it loads the
 * library): "cdro_hd_config_t" is its sizeof, "cdro_hd_config_t.seed" the offsetof of that field.
 * *found = 0 for an unknown name. */
uint32_t cdro_hd_layout(const char *name, uint8_t *found);

#ifdef __cplusplus
}
#endif

#endif /* CDRO_HOST_DEVICE_H */
