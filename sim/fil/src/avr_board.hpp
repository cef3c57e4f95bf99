// avr_board.hpp: the Uno as simavr runs it: an unmodified firmware .elf on the ATmega328P at
// 16 MHz, the simulated Pozyx (World) attached to the TWI as an I2C slave, UART0 as byte
// streams in both directions, and a watch on the PC that times every main-loop iteration
// (cycles between two entries of the loop function, found in the .elf's symbol table), so the
// firmware is measured without being changed.
#pragma once

#include <cstdint>
#include <deque>
#include <functional>
#include <stdexcept>
#include <string>

#include <nlohmann/json.hpp>

struct avr_t;
struct avr_irq_t;

namespace cdro::fil {

class World;

class BoardError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

struct BoardOptions {
    std::string elf_path;
    std::string mcu = "atmega328p";
    uint32_t frequency_hz = 16000000;
    std::string loop_symbol = "loop"; // Arduino's loop(): one call per firmware step
};

// The address of a function symbol in an AVR .elf (bytes, as simavr's PC); throws BoardError.
// With any_type, any symbol (e.g. the linker's `_end`), its value as the .elf has it.
uint32_t elfSymbolAddress(const std::string &elf_path, const std::string &symbol, bool any_type = false);

class AvrBoard {
public:
    AvrBoard(const BoardOptions &options, World &world);
    ~AvrBoard();
    AvrBoard(const AvrBoard &) = delete;
    AvrBoard &operator=(const AvrBoard &) = delete;

    enum class State { Running, Crashed, Done };

    // Runs instructions until the cycle count reaches `until_cycles` (or the CPU stops).
    State runUntil(uint64_t until_cycles);

    // Cycles since power-up, monotonic across resets (simavr restarts its count on reset).
    uint64_t cycles() const;
    uint64_t cyclesForUs(uint64_t us) const;
    uint64_t nowUs() const;
    uint32_t frequencyHz() const { return frequency_hz_; }

    // Bytes the firmware transmits on UART0, one call per byte, when it writes UDR0.
    void onTransmit(std::function<void(uint8_t)> sink) { tx_sink_ = std::move(sink); }
    // Host bytes for UART0's receiver: fed one per byte time at the UART's configured rate,
    // only while the receiver is enabled and its input FIFO has room, so none is lost here.
    void queueReceive(const uint8_t *data, size_t length);
    size_t receivePending() const { return rx_queue_.size(); }

    uint64_t txBytes() const { return tx_bytes_; }
    // True when the last byte sent was a frame delimiter (0x00), or nothing was sent yet.
    bool txAtFrameBoundary() const { return tx_bytes_ == 0 || last_tx_byte_ == 0; }
    uint64_t rxBytes() const { return rx_bytes_; }
    // bit/s the firmware configured on UART0 (from UBRR0 and U2X0), 0 before it did.
    uint32_t uartBaud() const;
    uint64_t resets() const { return resets_; }
    // Byte times a host byte waited because the receiver was off or its FIFO full.
    uint64_t rxWaits() const { return rx_waits_full_; }

    void report(nlohmann::ordered_json &out) const;

private:
    static void twiHook(avr_irq_t *irq, uint32_t value, void *param);
    static void uartOutHook(avr_irq_t *irq, uint32_t value, void *param);
    static void uartXonHook(avr_irq_t *irq, uint32_t value, void *param);
    static void uartXoffHook(avr_irq_t *irq, uint32_t value, void *param);
    static uint64_t feedTimer(avr_t *avr, uint64_t when, void *param);
    void armFeed();
    uint64_t cyclesPerRxByte() const;
    void onLoopEntry();
    uint16_t paintedFreeBytes() const;

    World &world_;
    avr_t *avr_ = nullptr;
    uint32_t frequency_hz_;
    avr_irq_t *twi_in_ = nullptr;
    avr_irq_t *uart_in_ = nullptr;

    // time
    uint64_t cycle_base_ = 0;   // cycles before the last reset
    uint64_t last_cycle_ = 0;   // avr->cycle seen last
    uint64_t next_advance_ = 0; // when the network is brought up to date next (cycles)

    // UART
    std::function<void(uint8_t)> tx_sink_;
    std::deque<uint8_t> rx_queue_;
    bool feeding_ = false;
    bool rx_fifo_full_ = false;
    uint64_t tx_bytes_ = 0, rx_bytes_ = 0, rx_waits_full_ = 0;
    uint8_t last_tx_byte_ = 0;

    // main-loop watch
    uint32_t loop_pc_ = 0;
    uint64_t loop_iterations_ = 0;
    bool loop_entered_ = false; // loop() was entered since the last reset
    uint64_t last_loop_entry_ = 0;
    uint64_t worst_loop_cycles_ = 0;
    uint64_t worst_loop_at_cycles_ = 0;
    uint64_t loop_cycles_total_ = 0;
    uint64_t loop_histogram_[24] = {}; // iterations by log2 of their length in us
    uint64_t resets_ = 0;
    std::string loop_symbol_;

    // stack: the lowest stack pointer after any instruction, against the end of the static data
    uint16_t static_end_ = 0; // first byte after .data/.bss/.noinit (the linker's _end)
    uint16_t lowest_sp_ = 0xFFFF;
};

} // namespace cdro::fil
