// output_changes.hpp: which nodes' outputs may have changed since the outputs last looked, so
// that they convert those alone (cdro-hostd's adapter, the service's outputs after each frame)
// and an update costs what it changed, not the size of the map.
//
// A range changes a handful of nodes: its two ends and the ones Engine::updateNode went through
// (the neighbours the relaxation updated). Everything else that changes outputs is rare and is
// reported as "all": a placement, a global solve adopted, the structure assessed, a motion
// report, a node unplaced, a new node or link, the output frame moved (a frame node updated,
// another triangle picked). Told apart by the engine's revision: every bump that did not come
// from a node update counted here makes the next answer "all". Nodes that move are listed on
// every answer: their output is their track predicted to the latest range's time.
#pragma once

#include <cstdint>
#include <vector>

#include "cdro/engine/alignment.hpp"
#include "cdro/engine/map_state.hpp"

namespace cdro::engine {

struct OutputChanges {
    bool all = true;                 // every node's output may have changed (also on the first look)
    std::vector<uint32_t> positions; // otherwise: their positions in Engine::estimates() (id order), ascending
};

class OutputChangeLog {
public:
    // Engine::updateNode went through `node` (map numbering); `bumped`: it bumped the revision.
    void nodeUpdated(uint32_t node, bool bumped);
    // A range taken on the link of nodes a and b, with its revision bump (the link's last range
    // and count; a new link also changes both ends' link counts).
    void rangeTaken(uint32_t a, uint32_t b);
    // What changed since the last call, the engine at `revision` with its output frame `transform`.
    OutputChanges take(const MapState &map, uint64_t revision, const RigidTransform &transform);

private:
    static constexpr size_t kMaxTouched = 1U << 16; // beyond it (nobody looking): "all"
    std::vector<uint32_t> touched_;                 // map numbering, repeats allowed
    bool overflowed_ = false;
    uint64_t bumps_from_updates_ = 0;
    bool taken_ = false;
    uint64_t revision_at_take_ = 0;
    RigidTransform transform_at_take_;
    std::vector<uint32_t> position_of_; // map numbering -> position in id order, for nodes_at_take_ nodes
};

} // namespace cdro::engine
