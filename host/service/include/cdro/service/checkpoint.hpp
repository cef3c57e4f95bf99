// checkpoint.hpp: filter-state checkpoints in common/'s fixed-point SoG snapshot format
// (sog_layout.h), written atomically and loaded for --resume.
//
// What goes into a snapshot is the engine's business: the engine adapter
// (host/hostd/src/engine_adapter.cpp) implements
// CheckpointProvider (engine -> SogSnapshot with its own extension blocks, and back). This file
// only encodes through cdro_sog_writer_t, decodes through cdro_sog_reader_t, and does the file
// handling:
//   write: encode in memory, write to "<path>.tmp", fsync, rename over <path>, fsync the
//          directory. A crash at any point leaves either the old or the new checkpoint whole.
//   load:  read the whole file, check magic, CRC-32, layout and counts, decode every record;
//          only a snapshot that decoded completely is returned. Anything else throws
//          CheckpointError with a message that says what is wrong: never half-loaded.
//
// Extension tags 0xF000..0xFFFF are reserved for the service (kServiceExtensionTag); the
// engine uses tags below 0xF000. Every tag, and the service's block, is defined in
// common/include/cdro/checkpoint_layout.def.
#pragma once

#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

#include "cdro/checkpoint_layout.def"
#include "cdro/sog_layout.h"

namespace cdro::service {

class CheckpointError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

struct SogSnapshot {
    struct Pair {
        cdro_sog_pair_t pair{}; // component_count is set on encode
        std::vector<cdro_sog_component_t> components;
    };
    struct Extension {
        uint16_t tag = 0; // != 0
        std::vector<uint8_t> bytes;
    };
    cdro_sog_header_t header{}; // counts, layout version/hash set on encode
    std::vector<cdro_sog_node_t> nodes;
    std::vector<Pair> pairs;
    std::vector<Extension> extensions;

    const Extension *findExtension(uint16_t tag) const;
};

// The service's own extension (SERVICE_INFO of checkpoint_layout.def): what it needs to
// continue a run (informative on resume).
constexpr uint16_t kServiceExtensionTag = CDRO_CHECKPOINT_TAG_SERVICE;
struct ServiceCheckpointInfo {
    int64_t run_start_unix_us = 0;  // us, the run's t_s origin
    int64_t last_event_unix_us = 0; // us, event time of the last frame before the checkpoint
    uint64_t frames_delivered = 0;  // frames the consumer had seen
};
std::vector<uint8_t> encodeServiceInfo(const ServiceCheckpointInfo &info);
bool decodeServiceInfo(const std::vector<uint8_t> &bytes, ServiceCheckpointInfo *info);

// Implemented by the engine adapter (host/hostd/src/engine_adapter.cpp). Called on the loop thread.
class CheckpointProvider {
public:
    virtual ~CheckpointProvider() = default;
    virtual SogSnapshot snapshot() = 0;
    // Replaces the engine state; called before any frame is delivered.
    virtual void restore(const SogSnapshot &snapshot) = 0;
    // After restore(): the node ids the restored state holds beyond the snapshot's SOG_NODE
    // records (nodes tracked outside the static map), known to the intake as those are.
    virtual std::vector<uint16_t> restoredNodes() const { return {}; }
};

std::vector<uint8_t> encodeSnapshot(const SogSnapshot &snapshot);                        // throws CheckpointError
SogSnapshot decodeSnapshot(const uint8_t *bytes, size_t len, const std::string &origin); // throws

void writeCheckpointFile(const std::string &path, const SogSnapshot &snapshot); // atomic; throws
SogSnapshot loadCheckpointFile(const std::string &path);                        // throws

} // namespace cdro::service
