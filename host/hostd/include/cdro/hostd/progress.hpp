// progress.hpp: `cdro-hostd --progress`: one line on stderr every second of wall time (a
// timer on the service's loop, so it reads the engine on the loop thread): link state, good
// and rejected frames, ranges the map took, nodes placed and converged, the live map's address.
// On a terminal the line is redrawn in place under the log (service::showStatusLine); to
// anything else (journald, a file) it is an ordinary line each second.
#pragma once

#include <cstdio>

#include "cdro/engine/engine.hpp"
#include "cdro/service/service.hpp"

namespace cdro::hostd {

class ProgressLine {
public:
    ProgressLine(service::Service &service, const engine::Engine &engine, std::FILE *out);
    // Leaves the last line on the terminal, ended, so that what follows starts a line of its own.
    ~ProgressLine();
    ProgressLine(const ProgressLine &) = delete;
    ProgressLine &operator=(const ProgressLine &) = delete;

private:
    void tick();

    service::Service &service_;
    const engine::Engine &engine_;
    std::FILE *out_;
    bool in_place_; // out_ is stderr and a terminal
};

} // namespace cdro::hostd
