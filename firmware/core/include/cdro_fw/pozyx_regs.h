/*
 * pozyx_regs.h: the Pozyx register and function addresses this firmware uses, and the values
 * it interprets. Interface facts only (docs: pozyx-register-facts.md of the project's shared
 * notes); nothing here comes from the Pozyx libraries. Shared by the driver and the simulated
 * device, so that both speak the same register map.
 *
 * All multi-byte registers are little-endian. "clear-on-read": reading the register clears it.
 */
#ifndef CDRO_FW_POZYX_REGS_H
#define CDRO_FW_POZYX_REGS_H

/* ---- status registers (read-only) ----------------------------------------------------- */
#define POZYX_REG_WHO_AM_I 0x00     /* u8, always POZYX_WHO_AM_I_VALUE */
#define POZYX_REG_FIRMWARE_VER 0x01 /* u8, major << 4 | minor */
#define POZYX_REG_HARDWARE_VER 0x02 /* u8, bits 7..5 device type, 4..0 revision */
#define POZYX_REG_ST_RESULT 0x03    /* u8, self-test bits POZYX_ST_* */
#define POZYX_REG_ERRORCODE 0x04    /* u8, last error, clear-on-read */
#define POZYX_REG_INT_STATUS 0x05   /* u8, event flags POZYX_INT_*, clear-on-read */

/* ---- configuration -------------------------------------------------------------------- */
#define POZYX_REG_INT_MASK 0x10       /* u8, which events drive the interrupt pin */
#define POZYX_REG_NETWORK_ID 0x1A     /* u16, this device's UWB short address */
#define POZYX_REG_UWB_CHANNEL 0x1C    /* u8, 1..5 or 7 */
#define POZYX_REG_UWB_RATES 0x1D      /* u8, bits 5..0 bitrate (0 110k, 1 850k, 2 6.8M), 7..6 PRF (1 16, 2 64 MHz) */
#define POZYX_REG_UWB_PLEN 0x1E       /* u8, preamble length code (0x08 = 1024 symbols) */
#define POZYX_REG_UWB_GAIN 0x1F       /* u8, TX gain in 0.5 dB steps; reset by a channel write */
#define POZYX_REG_RANGE_PROTOCOL 0x21 /* u8, 0 precision, 1 fast */

/* ---- data ----------------------------------------------------------------------------- */
#define POZYX_REG_PRESSURE 0x50         /* u32 mPa; start of the 49-byte sensor block */
#define POZYX_REG_ACCEL_X 0x54          /* 3 x i16, mg (1 LSB = 1 mg), X Y Z */
#define POZYX_REG_DEVICE_LIST_SIZE 0x81 /* u8, entries in the device list (max 20) */
#define POZYX_REG_RX_NETWORK_ID 0x82    /* u16, sender of the last UWB message */
#define POZYX_REG_RX_DATA_LEN 0x84      /* u8, its payload length */

#define POZYX_SENSOR_BLOCK_SIZE 49 /* bytes from POZYX_REG_PRESSURE */

/* ---- functions (call: write F + params, repeated start, read return byte + result) ----- */
#define POZYX_FN_RESET_SYS 0xB0
#define POZYX_FN_LED_CTRL 0xB1
#define POZYX_FN_TX_DATA 0xB2          /* offset, data...: fill the UWB TX buffer */
#define POZYX_FN_TX_SEND 0xB3          /* dest u16, op: send the TX buffer */
#define POZYX_FN_RX_DATA 0xB4          /* offset, length -> bytes of the RX buffer */
#define POZYX_FN_DO_RANGING 0xB5       /* dest u16; completion FUNC or ERR */
#define POZYX_FN_DEVICES_GETIDS 0xC0   /* offset, count -> count x u16 */
#define POZYX_FN_DEVICES_DISCOVER 0xC1 /* type, slots, slot_ms; completion FUNC or ERR */
#define POZYX_FN_DEVICES_CLEAR 0xC3
#define POZYX_FN_DEVICE_GETINFO 0xC5      /* id u16 -> id u16, flag u8 */
#define POZYX_FN_DEVICE_GETRANGEINFO 0xC7 /* id u16 -> timestamp u32 ms, distance u32 mm, rss i16 dBm */

#define POZYX_RANGEINFO_SIZE 10 /* bytes of the DEVICE_GETRANGEINFO result */

/* TX_SEND op codes: what the remote node does with the TX buffer. */
#define POZYX_REMOTE_READ 0x02     /* buffer: register, count; reply: count bytes */
#define POZYX_REMOTE_WRITE 0x04    /* buffer: register, data...; reply: acknowledgement only */
#define POZYX_REMOTE_DATA 0x06     /* plain data for the receiver */
#define POZYX_REMOTE_FUNCTION 0x08 /* buffer: function, params...; reply: return byte + result */

#define POZYX_BUFFER_SIZE 100 /* bytes of the UWB TX and RX buffers inside the Pozyx */

/* ---- values --------------------------------------------------------------------------- */
#define POZYX_WHO_AM_I_VALUE 0x43

#define POZYX_INT_ERR 0x01
#define POZYX_INT_POS 0x02
#define POZYX_INT_IMU 0x04
#define POZYX_INT_RX_DATA 0x08
#define POZYX_INT_FUNC 0x10

#define POZYX_ST_ACCEL 0x01
#define POZYX_ST_MAGN 0x02
#define POZYX_ST_GYRO 0x04
#define POZYX_ST_MCU 0x08
#define POZYX_ST_PRESSURE 0x10
#define POZYX_ST_UWB 0x20
#define POZYX_ST_EXPECTED_TAG 0x3F    /* every sensor */
#define POZYX_ST_EXPECTED_ANCHOR 0x30 /* pressure and UWB */

#define POZYX_HW_TYPE_SHIFT 5
#define POZYX_HW_TYPE_ANCHOR 0
#define POZYX_HW_TYPE_TAG 1

#define POZYX_DISCOVER_ANCHORS 0
#define POZYX_DISCOVER_TAGS 1
#define POZYX_DISCOVER_ALL 2

#define POZYX_DEVICE_LIST_MAX 20
#define POZYX_GETIDS_MAX_PER_CALL 15 /* 1 + 2 x 15 bytes = 31, inside the 32-byte Wire buffer */

/* ERRORCODE values the firmware and the simulator name (the rest pass through as numbers). */
#define POZYX_ERROR_NONE 0x00
#define POZYX_ERROR_DEVICE_LIST_FULL 0x03
#define POZYX_ERROR_FUNC_PARAMS 0x0D
#define POZYX_ERROR_RANGING 0x11
#define POZYX_ERROR_RTIMEOUT1 0x12
#define POZYX_ERROR_RTIMEOUT2 0x13
#define POZYX_ERROR_UWB_BUSY 0x15
#define POZYX_ERROR_NO_ACK 0x17

#endif /* CDRO_FW_POZYX_REGS_H */
