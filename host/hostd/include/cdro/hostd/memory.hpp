// memory.hpp: how the processes that run the engine ask the C library for memory.
//
// The global solve allocates large, short-lived buffers (the map covariance's dense inverse: 32 MB
// at 1000 nodes and 2,000 unknowns; the starts' sparse systems), on a worker thread. glibc's
// malloc serves a request above its mmap threshold (128 KiB) from mmap and gives it back on free,
// but raises that threshold to the size of every such block freed (up to 32 MiB): after the first
// solve the next solves' buffers came from the heap arenas, and their freed pages stayed resident.
// At 1000 nodes that was 138 MB of peak RSS for ~80 MB live (docs/bench.md, "Memory"); with the
// threshold fixed, 79 MB, the same CPU and the same outputs bit for bit.
#pragma once

namespace cdro::hostd {

// Fixes the C library's mmap threshold at its default (128 KiB), so that large buffers go back to
// the system when freed. Call once at the start of main, before any thread starts. A no-op where
// the C library is not glibc.
void returnLargeBuffersToTheSystem();

} // namespace cdro::hostd
