#include "avr_board.hpp"

#include <fcntl.h>
#include <gelf.h>
#include <libelf.h>
#include <unistd.h>

#include <cstdarg>
#include <cstdio>
#include <cstdlib>
#include <cstring>

extern "C" {
#include <simavr/avr_twi.h>
#include <simavr/avr_uart.h>
#include <simavr/sim_avr.h>
#include <simavr/sim_elf.h>
#include <simavr/sim_io.h>
}

#include "world.hpp"

namespace cdro::fil {

namespace {

// USART0 registers (data-space addresses; the same on the ATmega328P and the ATmega2560).
constexpr uint16_t kUcsr0a = 0xC0;
constexpr uint16_t kUcsr0b = 0xC1;
constexpr uint16_t kUbrr0l = 0xC4;
constexpr uint16_t kUbrr0h = 0xC5;
constexpr uint8_t kU2x0 = 1u << 1;
constexpr uint8_t kRxen0 = 1u << 4;
constexpr uint64_t kBitsPerByte = 10; // 8N1: start, 8 data, stop

// The network is brought up to date at least this often while no bus event does it, so that
// Pozyx operations complete within this much of their simulated time (the firmware polls the
// Pozyx every 1 ms).
constexpr uint64_t kAdvanceIntervalUs = 50;

// simavr logs through one global function: ours sends its errors and warnings to stderr
// (stdout carries the summary) and drops its chatter. Its format is simavr's printf format
// (the attribute lets the compiler check the forwarding).
__attribute__((format(printf, 3, 0))) void quietLogger(avr_t *, const int level, const char *format, va_list args)
{
    if (level <= LOG_WARNING) {
        std::fputs("simavr: ", stderr);
        std::vfprintf(stderr, format, args);
    }
}

} // namespace

uint32_t elfSymbolAddress(const std::string &elf_path, const std::string &symbol, bool any_type)
{
    if (elf_version(EV_CURRENT) == EV_NONE) {
        throw BoardError("libelf is too old");
    }
    const int fd = open(elf_path.c_str(), O_RDONLY);
    if (fd < 0) {
        throw BoardError(elf_path + ": cannot open (" + std::strerror(errno) + ")");
    }
    Elf *elf = elf_begin(fd, ELF_C_READ, nullptr);
    bool found = false;
    uint32_t address = 0;
    for (Elf_Scn *section = nullptr; elf != nullptr && !found && (section = elf_nextscn(elf, section)) != nullptr;) {
        GElf_Shdr header;
        if (gelf_getshdr(section, &header) == nullptr || header.sh_type != SHT_SYMTAB || header.sh_entsize == 0) {
            continue;
        }
        Elf_Data *data = elf_getdata(section, nullptr);
        const size_t count = header.sh_size / header.sh_entsize;
        for (size_t i = 0; data != nullptr && i < count; ++i) {
            GElf_Sym sym;
            if (gelf_getsym(data, static_cast<int>(i), &sym) == nullptr ||
                (!any_type && GELF_ST_TYPE(sym.st_info) != STT_FUNC)) {
                continue;
            }
            const char *name = elf_strptr(elf, header.sh_link, sym.st_name);
            if (name != nullptr && symbol == name) {
                address = static_cast<uint32_t>(sym.st_value);
                found = true;
                break;
            }
        }
    }
    if (elf != nullptr) {
        elf_end(elf);
    }
    close(fd);
    if (!found) {
        throw BoardError(elf_path + ": no function symbol '" + symbol +
                         "' (an .elf with its symbol table is needed to time the main loop; see --loop-symbol)");
    }
    return address;
}

AvrBoard::AvrBoard(const BoardOptions &options, World &world)
    : world_(world), frequency_hz_(options.frequency_hz), loop_symbol_(options.loop_symbol)
{
    if (access(options.elf_path.c_str(), R_OK) != 0) {
        throw BoardError(options.elf_path + ": cannot read the firmware (" + std::strerror(errno) +
                         "); build it with the AVR toolchain (docs/firmware.md, Building)");
    }
    loop_pc_ = elfSymbolAddress(options.elf_path, options.loop_symbol);
    // AVR .elf data addresses carry the 0x800000 data-space offset.
    static_end_ = static_cast<uint16_t>(elfSymbolAddress(options.elf_path, "_end", true) & 0xFFFFU);
    avr_global_logger_set(quietLogger);

    elf_firmware_t firmware;
    std::memset(&firmware, 0, sizeof firmware);
    if (elf_read_firmware(options.elf_path.c_str(), &firmware) != 0) {
        throw BoardError(options.elf_path + ": simavr cannot load this .elf");
    }
    // Our .elf carries no .mmcu section: the part and clock come from the options.
    if (firmware.mmcu[0] == '\0') {
        std::snprintf(firmware.mmcu, sizeof firmware.mmcu, "%s", options.mcu.c_str());
    }
    if (firmware.frequency == 0) {
        firmware.frequency = options.frequency_hz;
    }
    frequency_hz_ = firmware.frequency;
    avr_ = avr_make_mcu_by_name(firmware.mmcu);
    if (avr_ == nullptr) {
        throw BoardError("simavr does not know the part '" + std::string(firmware.mmcu) + "'");
    }
    avr_init(avr_);
    avr_->log = LOG_WARNING;
    avr_load_firmware(avr_, &firmware);
    avr_->frequency = frequency_hz_;
    // simavr copied the image into the core's flash and EEPROM; the .elf's copies are ours.
    std::free(firmware.flash);
    std::free(firmware.eeprom);

    // TWI: the Pozyx is a slave on the bus. simavr names the 328P's TWI 0 (some builds '0').
    avr_irq_t *twi_out = avr_io_getirq(avr_, AVR_IOCTL_TWI_GETIRQ(0), TWI_IRQ_OUTPUT);
    twi_in_ = avr_io_getirq(avr_, AVR_IOCTL_TWI_GETIRQ(0), TWI_IRQ_INPUT);
    if (twi_out == nullptr) {
        twi_out = avr_io_getirq(avr_, AVR_IOCTL_TWI_GETIRQ('0'), TWI_IRQ_OUTPUT);
        twi_in_ = avr_io_getirq(avr_, AVR_IOCTL_TWI_GETIRQ('0'), TWI_IRQ_INPUT);
    }
    if (twi_out == nullptr || twi_in_ == nullptr) {
        throw BoardError("simavr's " + std::string(firmware.mmcu) + " has no TWI to attach the Pozyx to");
    }
    avr_irq_register_notify(twi_out, &AvrBoard::twiHook, this);

    // UART0: no console echo (the bytes are binary frames) and no sleeping in polls.
    uint32_t flags = 0;
    avr_ioctl(avr_, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
    flags &= ~static_cast<uint32_t>(AVR_UART_FLAG_STDIO | AVR_UART_FLAG_POLL_SLEEP);
    avr_ioctl(avr_, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
    avr_irq_t *uart_out = avr_io_getirq(avr_, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT);
    uart_in_ = avr_io_getirq(avr_, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    avr_irq_t *xon = avr_io_getirq(avr_, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON);
    avr_irq_t *xoff = avr_io_getirq(avr_, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF);
    if (uart_out == nullptr || uart_in_ == nullptr || xon == nullptr || xoff == nullptr) {
        throw BoardError("simavr's " + std::string(firmware.mmcu) + " has no UART0");
    }
    avr_irq_register_notify(uart_out, &AvrBoard::uartOutHook, this);
    avr_irq_register_notify(xon, &AvrBoard::uartXonHook, this);
    avr_irq_register_notify(xoff, &AvrBoard::uartXoffHook, this);
}

AvrBoard::~AvrBoard()
{
    // simavr frees what it allocated for the core; the avr_t itself is never handed back by
    // its API (run_avr does not free it either), and this object lives as long as the process.
    if (avr_ != nullptr) {
        avr_terminate(avr_);
    }
}

uint64_t AvrBoard::cycles() const { return cycle_base_ + avr_->cycle; }

uint64_t AvrBoard::cyclesForUs(uint64_t us) const
{
    return us / 1000000u * frequency_hz_ + us % 1000000u * frequency_hz_ / 1000000u;
}

uint64_t AvrBoard::nowUs() const
{
    const uint64_t c = cycles();
    return c / frequency_hz_ * 1000000u + c % frequency_hz_ * 1000000u / frequency_hz_;
}

// ---- TWI: the Pozyx -------------------------------------------------------------------------

// The master's events arrive here synchronously; an ACK (or a read byte) must be raised back on
// the TWI input before returning, or the master sees a NACK.
void AvrBoard::twiHook(avr_irq_t *, uint32_t value, void *param)
{
    auto *board = static_cast<AvrBoard *>(param);
    avr_twi_msg_irq_t msg;
    msg.u.v = value;
    const uint8_t kind = static_cast<uint8_t>(msg.u.twi.msg);
    const uint8_t addr = static_cast<uint8_t>(msg.u.twi.addr);
    const uint64_t now_us = board->nowUs();
    World &world = board->world_;
    if (kind & TWI_COND_STOP) {
        world.i2cStop(now_us);
    }
    if (kind & TWI_COND_START) {
        // A hang cannot be shown on simavr's TWI (see scenario.cpp): it reads as a NACK.
        if (world.i2cStart(static_cast<uint8_t>(addr >> 1), (addr & 1u) != 0, now_us) == POZYX_SIM_ACK) {
            avr_raise_irq(board->twi_in_, avr_twi_irq_msg(TWI_COND_ACK, addr, 1));
        }
    }
    if (kind & TWI_COND_WRITE) {
        if (world.i2cWrite(static_cast<uint8_t>(msg.u.twi.data), now_us) == POZYX_SIM_ACK) {
            avr_raise_irq(board->twi_in_, avr_twi_irq_msg(TWI_COND_ACK, addr, 1));
        }
    }
    if (kind & TWI_COND_READ) {
        const uint8_t byte = world.i2cRead((kind & TWI_COND_ACK) != 0, now_us);
        avr_raise_irq(board->twi_in_, avr_twi_irq_msg(TWI_COND_READ, addr, byte));
    }
}

// ---- UART0 ----------------------------------------------------------------------------------

void AvrBoard::uartOutHook(avr_irq_t *, uint32_t value, void *param)
{
    auto *board = static_cast<AvrBoard *>(param);
    ++board->tx_bytes_;
    board->last_tx_byte_ = static_cast<uint8_t>(value);
    if (board->tx_sink_) {
        board->tx_sink_(static_cast<uint8_t>(value));
    }
}

void AvrBoard::uartXonHook(avr_irq_t *, uint32_t, void *param)
{
    static_cast<AvrBoard *>(param)->rx_fifo_full_ = false;
}

void AvrBoard::uartXoffHook(avr_irq_t *, uint32_t value, void *param)
{
    static_cast<AvrBoard *>(param)->rx_fifo_full_ = value != 0;
}

uint32_t AvrBoard::uartBaud() const
{
    const uint32_t ubrr = static_cast<uint32_t>(avr_->data[kUbrr0l] | ((avr_->data[kUbrr0h] & 0x0Fu) << 8));
    const uint32_t divider = ((avr_->data[kUcsr0a] & kU2x0) != 0 ? 8u : 16u) * (ubrr + 1u);
    return (avr_->data[kUcsr0b] & kRxen0) != 0 ? frequency_hz_ / divider : 0u;
}

uint64_t AvrBoard::cyclesPerRxByte() const
{
    const uint32_t baud = uartBaud();
    return baud == 0 ? frequency_hz_ / 1000u : kBitsPerByte * frequency_hz_ / baud;
}

void AvrBoard::queueReceive(const uint8_t *data, size_t length)
{
    rx_queue_.insert(rx_queue_.end(), data, data + length);
    armFeed();
}

void AvrBoard::armFeed()
{
    if (!feeding_ && !rx_queue_.empty()) {
        feeding_ = true;
        avr_cycle_timer_register(avr_, cyclesPerRxByte(), &AvrBoard::feedTimer, this);
    }
}

// One host byte per byte time, as the wire delivers them. While the receiver is off (before
// Serial.begin) or its FIFO is full the byte waits here: the host's bytes are never dropped
// by the harness; only the firmware's own buffers can lose them, as on the board.
uint64_t AvrBoard::feedTimer(avr_t *, uint64_t when, void *param)
{
    auto *board = static_cast<AvrBoard *>(param);
    if (board->rx_queue_.empty()) {
        board->feeding_ = false;
        return 0;
    }
    if (board->uartBaud() == 0 || board->rx_fifo_full_) {
        ++board->rx_waits_full_;
        return when + board->cyclesPerRxByte();
    }
    const uint8_t byte = board->rx_queue_.front();
    board->rx_queue_.pop_front();
    ++board->rx_bytes_;
    avr_raise_irq(board->uart_in_, byte);
    return when + board->cyclesPerRxByte();
}

// ---- running --------------------------------------------------------------------------------

void AvrBoard::onLoopEntry()
{
    const uint64_t now = cycles();
    if (loop_entered_) {
        const uint64_t length = now - last_loop_entry_;
        loop_cycles_total_ += length;
        if (length > worst_loop_cycles_) {
            worst_loop_cycles_ = length;
            worst_loop_at_cycles_ = last_loop_entry_;
        }
        uint64_t us = length * 1000000u / frequency_hz_;
        size_t bucket = 0;
        while (us > 1 && bucket + 1 < sizeof loop_histogram_ / sizeof loop_histogram_[0]) {
            us >>= 1;
            ++bucket;
        }
        ++loop_histogram_[bucket];
    }
    last_loop_entry_ = now;
    loop_entered_ = true;
    ++loop_iterations_;
}

AvrBoard::State AvrBoard::runUntil(uint64_t until_cycles)
{
    const uint64_t advance_cycles = cyclesForUs(kAdvanceIntervalUs);
    while (cycles() < until_cycles) {
        const int state = avr_run(avr_);
        if (avr_->cycle < last_cycle_) {
            cycle_base_ += last_cycle_; // simavr restarted its count: a reset
        }
        last_cycle_ = avr_->cycle;
        const uint16_t sp = static_cast<uint16_t>(avr_->data[R_SPL] | (avr_->data[R_SPH] << 8));
        if (sp < lowest_sp_ && avr_->pc != 0) {
            lowest_sp_ = sp;
        }
        if (avr_->pc == loop_pc_) {
            onLoopEntry();
        } else if (avr_->pc == 0 && cycles() > 0) {
            ++resets_;
            feeding_ = false;      // a reset cancels every cycle timer, ours included
            loop_entered_ = false; // setup() runs again before the next iteration
            armFeed();
        }
        if (cycles() >= next_advance_) {
            world_.advance(nowUs());
            next_advance_ = cycles() + advance_cycles;
        }
        if (state == cpu_Crashed) {
            return State::Crashed;
        }
        if (state == cpu_Done) {
            return State::Done;
        }
    }
    return State::Running;
}

void AvrBoard::report(nlohmann::ordered_json &out) const
{
    using json = nlohmann::ordered_json;
    const double us_per_cycle = 1e6 / static_cast<double>(frequency_hz_);
    json histogram = json::object();
    for (size_t i = 0; i < sizeof loop_histogram_ / sizeof loop_histogram_[0]; ++i) {
        if (loop_histogram_[i] != 0) {
            histogram["<" + std::to_string(2ull << i) + "us"] = loop_histogram_[i];
        }
    }
    const uint64_t measured = loop_iterations_ > resets_ + 1 ? loop_iterations_ - resets_ - 1 : 0;
    out["loop"] = {
        {"symbol", loop_symbol_},
        {"address", loop_pc_},
        {"iterations", loop_iterations_},
        {"worst_cycles", worst_loop_cycles_},
        {"worst_us", static_cast<double>(worst_loop_cycles_) * us_per_cycle},
        {"worst_at_s", static_cast<double>(worst_loop_at_cycles_) / static_cast<double>(frequency_hz_)},
        {"mean_cycles", measured > 0 ? static_cast<double>(loop_cycles_total_) / static_cast<double>(measured) : 0.0},
        {"histogram", histogram},
    };
    out["avr_resets"] = resets_;
    // Static RAM and the stack's worst case over the run: bytes between the end of the static
    // data and the lowest stack pointer (interrupts included, every instruction watched), and
    // the firmware's own painted low-water mark (STATUS free_ram_bytes) read from outside.
    out["stack"] = {
        {"ram_end", avr_->ramend},
        {"static_end", static_end_},
        {"lowest_sp", lowest_sp_},
        {"deepest_bytes", avr_->ramend - lowest_sp_},
        {"headroom_bytes", lowest_sp_ >= static_end_ ? lowest_sp_ - static_end_ + 1 : 0},
        {"painted_free_bytes", paintedFreeBytes()},
    };
}

uint16_t AvrBoard::paintedFreeBytes() const
{
    constexpr uint8_t kPaint = 0xC5; // cdro_arduino.cpp's CDRO_STACK_PAINT
    uint16_t free_bytes = 0;
    for (uint32_t a = static_end_; a <= avr_->ramend && avr_->data[a] == kPaint; ++a) {
        ++free_bytes;
    }
    return free_bytes;
}

} // namespace cdro::fil
