// cdro-fil: firmware in the loop. Runs the unmodified Uno firmware (.elf) in simavr with the
// simulated Pozyx network of a scenario on its TWI pins, bridges its UART0 to a pseudo-terminal
// for the host (cdro-hostd, or any serial client), paces simulated time to the wall clock
// (never ahead of it: the host's timeouts are wall-clock), and at the end (--duration-s, or on
// SIGTERM/SIGINT) writes a JSON summary of what the run measured. docs/firmware.md, "Firmware
// in the loop", describes the options, the scenario format and the summary.
#include <poll.h>
#include <signal.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <exception>
#include <memory>
#include <string>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include "avr_board.hpp"
#include "pty_port.hpp"
#include "scenario.hpp"
#include "world.hpp"

using namespace cdro::fil;

namespace {

volatile sig_atomic_t g_stop_signal = 0;

void onSignal(int signal_number) { g_stop_signal = signal_number; }

struct Options {
    std::string elf;
    std::string scenario;
    int64_t seed = -1;        // -1: the scenario's
    double duration_s = -1.0; // s; -1: the scenario's; 0: until a signal
    std::string link;
    std::string summary; // "" = stdout
    std::string truth_csv;
    uint32_t truth_period_ms = 100;
    std::string ranges_csv;
    bool start_on_open = false;
    bool trace_pozyx = false;
    bool print_scenario = false;
    BoardOptions board;
};

class File {
public:
    File() = default;
    File(const std::string &path, const char *what)
    {
        if (!path.empty()) {
            file_ = std::fopen(path.c_str(), "w");
            if (file_ == nullptr) {
                throw std::runtime_error(path + ": cannot write the " + what + " (" + std::strerror(errno) + ")");
            }
        }
    }
    ~File()
    {
        if (file_ != nullptr) {
            std::fclose(file_);
        }
    }
    File(File &&other) noexcept : file_(other.file_) { other.file_ = nullptr; }
    File &operator=(File &&other) noexcept
    {
        std::swap(file_, other.file_);
        return *this;
    }
    std::FILE *get() const { return file_; }

private:
    std::FILE *file_ = nullptr;
};

void traceLine(void *, const char *line) { std::fprintf(stderr, "pozyx: %s\n", line); }

// Writes the summary whole: to a temporary file renamed over the path (a reader never sees
// half of it), or to the saved stdout.
void writeSummary(const nlohmann::ordered_json &summary, const std::string &path, int stdout_fd)
{
    const std::string text = summary.dump(2) + "\n";
    if (path.empty()) {
        size_t done = 0;
        while (done < text.size()) {
            const ssize_t n = write(stdout_fd, text.data() + done, text.size() - done);
            if (n <= 0) {
                std::fprintf(stderr, "cdro-fil: cannot write the summary to stdout: %s\n", std::strerror(errno));
                return;
            }
            done += static_cast<size_t>(n);
        }
        return;
    }
    const std::string temporary = path + ".tmp";
    std::FILE *out = std::fopen(temporary.c_str(), "w");
    if (out == nullptr || std::fputs(text.c_str(), out) < 0 || std::fclose(out) != 0 ||
        std::rename(temporary.c_str(), path.c_str()) != 0) {
        std::fprintf(stderr, "cdro-fil: cannot write the summary to %s: %s\n", path.c_str(), std::strerror(errno));
    }
}

uint64_t wallUs(std::chrono::steady_clock::time_point start)
{
    return static_cast<uint64_t>(
        std::chrono::duration_cast<std::chrono::microseconds>(std::chrono::steady_clock::now() - start).count());
}

int run(const Options &options, int stdout_fd)
{
    Scenario scenario = loadScenario(options.scenario);
    if (options.seed >= 0) {
        scenario.seed = static_cast<uint64_t>(options.seed);
    }
    if (options.duration_s >= 0.0) {
        scenario.duration_s = options.duration_s;
    }
    if (!options.summary.empty()) {
        // The summary is written at the end: find out now, not after the run, if it cannot be.
        const std::string probe = options.summary + ".tmp";
        std::FILE *out = std::fopen(probe.c_str(), "w");
        if (out == nullptr) {
            throw std::runtime_error(options.summary + ": cannot write the summary (" + std::strerror(errno) + ")");
        }
        std::fclose(out);
        std::remove(probe.c_str());
    }
    World world(scenario);
    if (options.trace_pozyx) {
        world.sim()->config.trace = &traceLine;
    }
    File truth(options.truth_csv, "truth CSV");
    File ranges(options.ranges_csv, "ranges CSV");
    world.setTruthCsv(truth.get(), static_cast<uint64_t>(options.truth_period_ms) * 1000u);
    world.setRangesCsv(ranges.get());
    AvrBoard board(options.board, world);
    PtyPort pty(options.link);
    board.onTransmit([&pty](uint8_t byte) { pty.send(byte); });

    std::fprintf(stderr, "cdro-fil: scenario '%s', seed %llu, %zu nodes; serial port %s%s%s\n", scenario.name.c_str(),
                 static_cast<unsigned long long>(scenario.seed), scenario.nodes.size(), pty.slavePath().c_str(),
                 pty.linkPath().empty() ? "" : " <- ", pty.linkPath().c_str());

    // Like the Uno's auto-reset on DTR, --start-on-open holds the AVR until the host opens the
    // port, so the host sees the boot from its first byte.
    while (options.start_on_open && !pty.hostConnected() && g_stop_signal == 0) {
        usleep(5000);
    }

    const uint64_t slice_us = 1000; // simulated time run between two looks at the wall clock
    // The run stops at its duration (or at a signal), then runs on until the UART has sent a
    // frame's last byte, so the host never gets a frame cut by the harness: at most one frame
    // time at the link's rate (73 bytes, 6.2 ms), bounded here.
    const uint64_t finish_limit_us = 100000;
    uint64_t stop_us = scenario.duration_s > 0.0 ? static_cast<uint64_t>(std::llround(scenario.duration_s * 1e6))
                                                 : UINT64_MAX - finish_limit_us;
    const auto start = std::chrono::steady_clock::now();
    uint64_t max_lag_us = 0;
    std::string exit_reason = "duration";
    AvrBoard::State state = AvrBoard::State::Running;
    uint8_t host_bytes[64];
    for (;;) {
        if (g_stop_signal != 0 && exit_reason != "signal") {
            exit_reason = "signal";
            stop_us = std::min(stop_us, board.nowUs());
        }
        if (board.nowUs() >= stop_us && (board.txAtFrameBoundary() || board.nowUs() >= stop_us + finish_limit_us)) {
            break;
        }
        const uint64_t limit_us = board.nowUs() < stop_us ? stop_us : stop_us + finish_limit_us;
        const uint64_t target_us = std::min(limit_us, board.nowUs() + slice_us);
        // Never ahead of the wall clock: the slice runs only once the wall clock has reached
        // its end. Meanwhile the host's bytes are taken in (a few at a time: the rest waits in
        // the terminal, as on the USB bridge, until the UART has taken these).
        for (;;) {
            if (board.receivePending() < sizeof host_bytes) {
                const size_t n = pty.readHost(host_bytes, sizeof host_bytes - board.receivePending());
                if (n > 0) {
                    board.queueReceive(host_bytes, n);
                }
            }
            const uint64_t wall_us = wallUs(start);
            if (wall_us >= target_us) {
                max_lag_us = std::max(max_lag_us, wall_us - target_us);
                break;
            }
            if (g_stop_signal != 0) {
                break; // ending: the last few milliseconds need not wait for the clock
            }
            const uint64_t wait_us = target_us - wall_us;
            pollfd p = {pty.masterFd(),
                        board.receivePending() < sizeof host_bytes ? static_cast<short>(POLLIN) : short{0}, 0};
            const timespec timeout = {static_cast<time_t>(wait_us / 1000000u),
                                      static_cast<long>(wait_us % 1000000u * 1000u)};
            if (ppoll(&p, 1, &timeout, nullptr) > 0 && (p.revents & POLLHUP) != 0) {
                // No host: nothing to read; sleep out the rest of the slice instead of spinning.
                const timespec rest = timeout;
                nanosleep(&rest, nullptr);
            }
        }
        state = board.runUntil(board.cyclesForUs(target_us));
        pty.flush();
        if (state != AvrBoard::State::Running) {
            exit_reason = state == AvrBoard::State::Crashed ? "cpu_crashed" : "cpu_done";
            break;
        }
    }
    world.advance(board.nowUs()); // the network (and the truth file) up to the last cycle run
    const double wall_s = static_cast<double>(wallUs(start)) / 1e6;
    const bool drained = pty.drain(2000);

    const double simulated_s = static_cast<double>(board.nowUs()) / 1e6;
    nlohmann::ordered_json summary;
    summary["scenario"] = scenario.name;
    summary["scenario_file"] = options.scenario;
    summary["seed"] = scenario.seed;
    summary["elf"] = options.elf;
    summary["mcu"] = options.board.mcu;
    summary["frequency_hz"] = board.frequencyHz();
    summary["exit_reason"] = exit_reason;
    summary["simulated_s"] = simulated_s;
    summary["cycles"] = board.cycles();
    summary["wall_s"] = wall_s;
    summary["max_lag_ms"] = static_cast<double>(max_lag_us) / 1000.0;
    summary["protocol_violations"] = world.sim()->stats.protocol_violations;
    board.report(summary);
    world.report(summary, simulated_s);
    const double link_bytes_per_s = board.uartBaud() > 0 ? board.uartBaud() / 10.0 : 0.0; // 8N1
    summary["uart"] = {
        {"baud", board.uartBaud()},
        {"tx_bytes", board.txBytes()},
        {"rx_bytes", board.rxBytes()},
        {"tx_bytes_per_s", simulated_s > 0.0 ? static_cast<double>(board.txBytes()) / simulated_s : 0.0},
        {"rx_bytes_per_s", simulated_s > 0.0 ? static_cast<double>(board.rxBytes()) / simulated_s : 0.0},
        {"tx_link_share", simulated_s > 0.0 && link_bytes_per_s > 0.0
                              ? static_cast<double>(board.txBytes()) / simulated_s / link_bytes_per_s
                              : 0.0},
        {"rx_pending_bytes", board.receivePending()},
        {"tx_dropped_bytes", pty.droppedBytes()},
        {"tx_unsent_bytes", pty.pendingBytes()},
        {"rx_waits", board.rxWaits()},
        {"host_read_everything", drained},
    };
    writeSummary(summary, options.summary, stdout_fd);
    std::fprintf(stderr,
                 "cdro-fil: %s after %.3f simulated s (%.3f s wall): %llu + %llu ranges, worst loop %llu cycles, "
                 "%.0f B/s to the host\n",
                 exit_reason.c_str(), simulated_s, wall_s, static_cast<unsigned long long>(world.rangingsDirect()),
                 static_cast<unsigned long long>(world.rangingsRemote()),
                 static_cast<unsigned long long>(summary["loop"]["worst_cycles"].get<uint64_t>()),
                 summary["uart"]["tx_bytes_per_s"].get<double>());
    return state == AvrBoard::State::Crashed ? 3 : 0;
}

} // namespace

static int runMain(int argc, char **argv)
{
    CLI::App app{"cdro-fil: the Uno firmware in simavr against a simulated Pozyx network, its UART on a "
                 "pseudo-terminal (docs/firmware.md, \"Firmware in the loop\")"};
    Options options;
    CLI::Option *elf = app.add_option("--elf", options.elf, "the firmware image (build-avr/bin/cdro-firmware-uno.elf)")
                           ->check(CLI::ExistingFile);
    app.add_option("--scenario", options.scenario, "scenario YAML: nodes, motion, faults, models, seed")
        ->required()
        ->check(CLI::ExistingFile);
    app.add_option("--seed", options.seed, "override the scenario's seed")->check(CLI::NonNegativeNumber);
    app.add_option("--duration-s", options.duration_s,
                   "simulated seconds to run, then exit cleanly (0 = until SIGTERM/SIGINT; default: the scenario's)")
        ->check(CLI::NonNegativeNumber);
    app.add_option("--link", options.link, "also make this symlink to the pseudo-terminal (removed at exit)");
    app.add_option("--summary", options.summary, "write the JSON summary here instead of stdout");
    app.add_option("--truth-csv", options.truth_csv, "true positions over time: t,id,x,y,z (s, m)");
    app.add_option("--truth-period-ms", options.truth_period_ms, "ms between truth samples (default 100)")
        ->check(CLI::Range(1, 60000));
    app.add_option("--ranges-csv", options.ranges_csv,
                   "every ranging the simulated network performed: t,kind,from,to,distance_mm,true_distance_mm,result");
    app.add_flag("--start-on-open", options.start_on_open,
                 "hold the AVR in reset until a host opens the serial port (the Uno resets on DTR)");
    app.add_option("--mcu", options.board.mcu, "simavr part (default atmega328p)");
    app.add_option("--frequency-hz", options.board.frequency_hz, "CPU clock (default 16000000)")
        ->check(CLI::Range(1000000, 32000000));
    app.add_option("--loop-symbol", options.board.loop_symbol,
                   "function whose entries delimit main-loop iterations (default loop)");
    app.add_flag("--trace-pozyx", options.trace_pozyx, "log every simulated Pozyx call and event to stderr");
    app.add_flag("--print-scenario", options.print_scenario,
                 "print what cdro-fil and cdro-sim both read from the scenario as JSON and exit (no --elf needed)");
    try {
        app.parse(argc, argv);
        if (!options.print_scenario && elf->count() == 0) {
            throw CLI::RequiredError("--elf");
        }
    } catch (const CLI::ParseError &error) {
        // --help is a "parse error" with code 0; every real one is bad input: exit 2.
        return app.exit(error) == 0 ? 0 : 2;
    }
    if (options.print_scenario) {
        try {
            Scenario scenario = loadScenario(options.scenario);
            if (options.seed >= 0) {
                scenario.seed = static_cast<uint64_t>(options.seed);
            }
            if (options.duration_s >= 0.0) {
                scenario.duration_s = options.duration_s;
            }
            std::printf("%s\n", sharedViewJson(scenario).c_str());
            return 0;
        } catch (const std::exception &error) {
            std::fprintf(stderr, "cdro-fil: %s\n", error.what());
            return 2;
        }
    }
    options.board.elf_path = options.elf;

    // Anything a library prints on stdout would corrupt the summary: stdout is kept aside for
    // it and fd 1 points to stderr while the simulation runs.
    std::fflush(stdout);
    const int stdout_fd = dup(STDOUT_FILENO);
    if (stdout_fd < 0 || dup2(STDERR_FILENO, STDOUT_FILENO) < 0) {
        std::fprintf(stderr, "cdro-fil: cannot set up stdout: %s\n", std::strerror(errno));
        return 2;
    }
    struct sigaction action;
    std::memset(&action, 0, sizeof action);
    action.sa_handler = onSignal;
    sigemptyset(&action.sa_mask);
    sigaction(SIGTERM, &action, nullptr);
    sigaction(SIGINT, &action, nullptr);
    signal(SIGPIPE, SIG_IGN);
    try {
        return run(options, stdout_fd);
    } catch (const std::exception &error) {
        std::fprintf(stderr, "cdro-fil: %s\n", error.what());
        return 2;
    }
}

// An exception that escapes (from setting up the options, or a library's) ends the run with its
// message and status 2, not with std::terminate's abort.
int main(int argc, char **argv)
{
    try {
        return runMain(argc, argv);
    } catch (const std::exception &error) {
        std::fprintf(stderr, "cdro-fil: %s\n", error.what());
        return 2;
    }
}
