// foldable.hpp: the parts of a range network whose place the ranges cannot decide, from the
// link graph alone.
//
// A part that hangs on one node can turn about it, and a part that hangs on two nodes can be
// reflected across the line through them, without changing a single range: however well the
// map explains its links, such a part may be on the wrong side (a unique planar map needs a
// 3-connected graph; 3-connectivity is necessary, not sufficient). The per-node ambiguity check
// of the engine sees a single node with a mirror position, not a group of nodes that folds.
//
// A part joined to the rest by two links between four distinct nodes has one degree of freedom
// left (a four-bar linkage: the part swings with both links' lengths kept), and a part joined by
// two links at one of its nodes turns about that node: twoLinkCuts finds those joints.
#pragma once

#include <array>
#include <cstdint>
#include <utility>
#include <vector>

namespace cdro::engine {

constexpr uint32_t kNoHinge = 0xFFFFFFFFU;

struct Foldable {
    // Per node: true when it lies in a part that the removal of at most two other nodes (its
    // hinge) cuts off from the largest part, or outside the largest connected component.
    std::vector<uint8_t> foldable; // 0/1 (not vector<bool>: GCC 12 -O3 warns on it here)
    // Per foldable node: the hinge of the first cut found (node indices; kNoHinge where fewer
    // than two, both kNoHinge for a node outside the largest component).
    std::vector<std::array<uint32_t, 2>> hinge;
    uint32_t count = 0;
};

// node_count nodes; edges between active nodes (others are ignored, duplicates allowed);
// active (0/1): the nodes of the graph (e.g. the placed ones); anchored (0/1): nodes whose position is known
// (fixed): a cut-off part holding one is not marked. Deterministic; O(V (V + E)) for graphs
// with few cut nodes. The largest part (ties: the one with the smallest node index) stays.
Foldable findFoldable(uint32_t node_count, const std::vector<std::pair<uint32_t, uint32_t>> &edges,
                      const std::vector<uint8_t> &active, const std::vector<uint8_t> &anchored);

// The nodes whose removal cuts their part of the graph in two or more (articulation points),
// ascending; the same arguments. O(V + E).
std::vector<uint32_t> cutNodes(uint32_t node_count, const std::vector<std::pair<uint32_t, uint32_t>> &edges,
                               const std::vector<uint8_t> &active);

// The pairs of edges (indices into `edges`) whose removal cuts the graph of the active nodes in
// two, neither of them a bridge on its own: each pair once, its smaller index first, ascending.
// Only joints of exactly two edges: where three or more edges each cut the graph with any one of
// the others (parts joined in a ring by single links), none of their pairs is listed.
// Deterministic; O(V + E) and a sort of the edges (each non-tree edge gets a fixed pseudo-random
// 64-bit label, each tree edge the XOR of the labels of the cycles through it: two edges cut the
// graph together exactly when their labels are equal, up to a collision of 64-bit labels, which
// the caller can rule out by checking the cut).
std::vector<std::array<uint32_t, 2>> twoLinkCuts(uint32_t node_count,
                                                 const std::vector<std::pair<uint32_t, uint32_t>> &edges,
                                                 const std::vector<uint8_t> &active);

} // namespace cdro::engine
