#include "cdro/hostd/progress.hpp"

#include <string>

#include <unistd.h>

#include "cdro/service/log.hpp"

namespace cdro::hostd {

namespace {
constexpr int64_t kPeriodUs = 1'000'000; // us
} // namespace

ProgressLine::ProgressLine(service::Service &service, const engine::Engine &engine, std::FILE *out)
    : service_(service), engine_(engine), out_(out), in_place_(out == stderr && isatty(STDERR_FILENO) == 1)
{
    service_.loop().addTimerAfter(kPeriodUs, [this] { tick(); });
}

ProgressLine::~ProgressLine()
{
    if (in_place_) {
        service::endStatusLine();
    }
}

void ProgressLine::tick()
{
    const service::ServiceCounters &c = service_.counters();
    size_t nodes = 0;
    size_t placed = 0;
    size_t converged = 0;
    for (const engine::NodeOutput &node : engine_.estimates()) {
        if (node.link_count == 0) {
            continue;
        }
        ++nodes;
        placed += node.placed() ? 1U : 0U;
        converged += node.converged() ? 1U : 0U;
    }
    // Numbers and names of bounded length; the address (of any length) is appended.
    char counts[384];
    std::snprintf(counts, sizeof counts,
                  "cdro-hostd: %s | frames %llu good, %llu rejected, %llu lost | ranges %llu used | "
                  "nodes %zu: %zu placed, %zu converged",
                  service::linkStateName(service_.linkState()), static_cast<unsigned long long>(c.frames_ok),
                  static_cast<unsigned long long>(c.chunks_rejected), static_cast<unsigned long long>(c.frames_lost),
                  static_cast<unsigned long long>(engine_.counters().ranges_used), nodes, placed, converged);
    std::string text = counts;
    // The live map's address on every line: the line that printed it at the start has long
    // scrolled away when someone looks.
    const std::string url = service_.liveMapUrl();
    if (!url.empty()) {
        text += " | map " + url;
    }
    if (in_place_) {
        service::showStatusLine(text);
    } else {
        std::fprintf(out_, "%s\n", text.c_str());
        std::fflush(out_);
    }
    service_.loop().addTimerAfter(kPeriodUs, [this] { tick(); });
}

} // namespace cdro::hostd
