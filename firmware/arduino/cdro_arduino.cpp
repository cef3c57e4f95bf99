/*
 * cdro_arduino.cpp: the only file of the firmware that touches Arduino APIs or AVR registers.
 *
 * It binds the hardware-independent core (firmware/core) to the board:
 *   Pozyx ops   Wire (TWI) with repeated starts, Wire's timeout, the bus clear after it,
 *               delay(), millis(), micros()
 *   serial ops  HardwareSerial: availableForWrite() for the free space, write(), read()
 *   platform    the reset cause from MCUSR (or from r2, where Optiboot leaves it), the watchdog,
 *               and the lowest free RAM, measured by painting the stack at reset
 * and runs cdro_fw_step() from loop(), resetting the watchdog once per step.
 */
/* Third-party headers: their warnings are not ours to fix (they cannot be -isystem on AVR,
 * where system headers are implicitly extern "C"). */
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wconversion"
#pragma GCC diagnostic ignored "-Wsign-conversion"
#pragma GCC diagnostic ignored "-Wshadow"
#pragma GCC diagnostic ignored "-Wpedantic"
#pragma GCC diagnostic ignored "-Wundef"
#pragma GCC diagnostic ignored "-Wnon-virtual-dtor"
#pragma GCC diagnostic ignored "-Woverloaded-virtual"
#pragma GCC diagnostic ignored "-Wdouble-promotion"
#pragma GCC diagnostic ignored "-Wcast-align"
#include <Arduino.h>
#include <Wire.h>
#include <avr/io.h>
#include <avr/wdt.h>
#pragma GCC diagnostic pop

#include "cdro_fw/firmware.h"

#if CDRO_FW_WATCHDOG_MS == 2000
#define CDRO_WDT_PERIOD WDTO_2S
#else
#error "CDRO_FW_WATCHDOG_MS has no WDTO_ constant here"
#endif

/* ---- before main(): reset cause, watchdog off, stack paint -------------------------------- */

#define CDRO_STACK_PAINT 0xC5 /* a byte value that free RAM keeps until touched */
#define CDRO_STR2(x) #x
#define CDRO_STR(x) CDRO_STR2(x)

extern uint8_t _end;    /* end of .data/.bss/.noinit: the heap would start here (none is used) */
extern uint8_t __stack; /* the top of RAM, where the stack starts */

/* The reset flags survive .bss clearing in .noinit. */
static uint8_t s_reset_flags __attribute__((section(".noinit")));

/* .init1 runs before .data and .bss are set up and before any call: fills the free RAM between
 * the end of the static data and the top of RAM with CDRO_STACK_PAINT. */
extern "C" void cdro_paint_ram(void) __attribute__((naked, used, section(".init1")));
void cdro_paint_ram(void)
{
    __asm__ __volatile__("ldi r30, lo8(_end)     \n\t"
                         "ldi r31, hi8(_end)     \n\t"
                         "ldi r24, " CDRO_STR(CDRO_STACK_PAINT) " \n\t"
                                                                "ldi r25, hi8(__stack)  \n\t"
                                                                "1: cpi r30, lo8(__stack) \n\t"
                                                                "cpc r31, r25           \n\t"
                                                                "brsh 2f                \n\t"
                                                                "st Z+, r24             \n\t"
                                                                "rjmp 1b                \n\t"
                                                                "2:                     \n\t" ::
                                                                    : "r24", "r25", "r30", "r31", "memory");
}

/* .init3 (stack pointer and r1 set up, .data/.bss not yet): keep MCUSR, clear it, and stop a
 * watchdog left running by a watchdog reset, which would otherwise reset again within 15 ms.
 * Optiboot clears MCUSR itself and hands the flags over in r2. */
extern "C" void cdro_save_reset_cause(void) __attribute__((naked, used, section(".init3")));
void cdro_save_reset_cause(void)
{
    uint8_t from_bootloader;
    __asm__ __volatile__("mov %0, r2" : "=r"(from_bootloader));
    uint8_t flags = MCUSR;
    MCUSR = 0;
    wdt_disable();
    s_reset_flags =
        static_cast<uint8_t>((flags != 0 ? flags : from_bootloader) &
                             (CDRO_RESET_POWER_ON | CDRO_RESET_EXTERNAL | CDRO_RESET_BROWN_OUT | CDRO_RESET_WATCHDOG));
}

/* Bytes of free RAM never touched since reset: the painted bytes above the static data that
 * neither the stack nor an interrupt has reached (the lowest stack-to-data gap ever). */
static uint16_t lowest_free_ram_bytes(void *)
{
    const uint8_t *p = &_end;
    const uint8_t *const top = &__stack;
    uint16_t free_bytes = 0;
    while (p < top && *p == CDRO_STACK_PAINT) {
        ++p;
        ++free_bytes;
    }
    return free_bytes;
}

/* ---- Pozyx ops: Wire ---------------------------------------------------------------------- */

static cdro_i2c_result_t i2c_write(void *, uint8_t address, const uint8_t *data, uint8_t length, uint8_t send_stop)
{
    Wire.beginTransmission(address);
    if (Wire.write(data, length) != length) {
        return CDRO_I2C_ERROR; /* over Wire's 32 bytes: the driver never asks for that */
    }
    switch (Wire.endTransmission(send_stop != 0)) {
    case 0: return CDRO_I2C_OK;
    case 2: return CDRO_I2C_NACK_ADDRESS;
    case 3: return CDRO_I2C_NACK_DATA;
    case 5: return CDRO_I2C_TIMEOUT;
    default: return CDRO_I2C_ERROR;
    }
}

static cdro_i2c_result_t i2c_read(void *, uint8_t address, uint8_t *data, uint8_t length)
{
    Wire.clearWireTimeoutFlag();
    const uint8_t got = Wire.requestFrom(address, length, static_cast<uint8_t>(true));
    if (got != length) {
        while (Wire.available() > 0) {
            (void)Wire.read();
        }
        if (Wire.getWireTimeoutFlag()) {
            return CDRO_I2C_TIMEOUT;
        }
        return got == 0 ? CDRO_I2C_NACK_ADDRESS : CDRO_I2C_ERROR;
    }
    for (uint8_t i = 0; i < length; ++i) {
        data[i] = static_cast<uint8_t>(Wire.read());
    }
    return CDRO_I2C_OK;
}

static void delay_ms(void *, uint16_t duration_ms) { delay(duration_ms); }

static uint32_t now_ms(void *) { return millis(); }

static uint32_t now_us(void *) { return micros(); }

/* SCL released: wait for it to go high, as a slave may stretch the clock (at most ~1 ms). */
static void wait_scl_released()
{
    for (uint16_t i = 0; i < 1000U && digitalRead(SCL) == LOW; ++i) {
        delayMicroseconds(1);
    }
}

/* After a transaction timed out, a slave may be holding SDA low in the middle of a byte that
 * the master abandoned. With the TWI off, SCL is clocked by hand (open drain: driven low, or
 * released to the shield's pull-ups) until the slave lets SDA go, at most 9 times (a byte and
 * its acknowledgement), then a STOP ends whatever it thought was going on, and the TWI starts
 * again. Not exercised by the tests (simavr's TWI has no pins to hold): the native tests check
 * when the driver asks for it and that it is counted. */
static void bus_recover(void *)
{
    Wire.end();
    digitalWrite(SDA, LOW); /* outputs drive low when enabled; inputs without pull-up */
    digitalWrite(SCL, LOW);
    pinMode(SDA, INPUT);
    pinMode(SCL, INPUT);
    for (uint8_t i = 0; i < 9U && digitalRead(SDA) == LOW; ++i) {
        pinMode(SCL, OUTPUT);
        delayMicroseconds(5); /* half a period at 100 kHz */
        pinMode(SCL, INPUT);
        wait_scl_released();
        delayMicroseconds(5);
    }
    /* STOP: SDA rises while SCL is high. */
    pinMode(SCL, OUTPUT);
    pinMode(SDA, OUTPUT);
    delayMicroseconds(5);
    pinMode(SCL, INPUT);
    wait_scl_released();
    delayMicroseconds(5);
    pinMode(SDA, INPUT);
    delayMicroseconds(5);
    Wire.begin();
    Wire.setClock(CDRO_FW_I2C_CLOCK_HZ);
    Wire.setWireTimeout(CDRO_FW_I2C_TIMEOUT_US, true);
}

static const cdro_pozyx_ops_t kPozyxOps = {i2c_write, i2c_read, delay_ms, now_ms, now_us, bus_recover};

/* ---- serial ops: HardwareSerial ----------------------------------------------------------- */

static uint16_t tx_free(void *)
{
    const int free_bytes = Serial.availableForWrite();
    return free_bytes > 0 ? static_cast<uint16_t>(free_bytes) : 0U;
}

static void tx_write(void *, const uint8_t *data, uint8_t length) { (void)Serial.write(data, length); }

static int16_t rx_read(void *) { return static_cast<int16_t>(Serial.read()); }

static const cdro_serial_ops_t kSerialOps = {tx_free, tx_write, rx_read};

/* ---- setup and loop ------------------------------------------------------------------------ */

static cdro_fw_t s_firmware;

void setup()
{
    wdt_enable(CDRO_WDT_PERIOD);
    Serial.begin(CDRO_FW_SERIAL_BAUD);
    Wire.begin();
    Wire.setClock(CDRO_FW_I2C_CLOCK_HZ);
    Wire.setWireTimeout(CDRO_FW_I2C_TIMEOUT_US, true); /* a stuck bus resets the TWI unit (then bus_recover) */

    cdro_fw_config_t config;
    config.pozyx_ops = &kPozyxOps;
    config.pozyx_user = nullptr;
    config.serial_ops = &kSerialOps;
    config.serial_user = nullptr;
    config.free_ram_bytes = lowest_free_ram_bytes;
    config.platform_user = nullptr;
    config.reset_cause = s_reset_flags;
    cdro_fw_init(&s_firmware, &config);
}

/* Not inlined into main() by the link-time optimiser: firmware in the loop (cdro-fil) times the
 * main loop by the entries of this symbol. */
void loop() __attribute__((noinline));
void loop()
{
    wdt_reset();
    (void)cdro_fw_step(&s_firmware, millis());
}
