// foldable.cpp: cuts of one and two nodes in the link graph (see foldable.hpp).
//
// For every node u, the articulation points v of the graph without u give the cuts {u, v}
// (Hopcroft-Tarjan, iterative so that a long chain of nodes cannot overflow the stack); the
// parts that such a cut separates from the largest part can fold.
#include "cdro/engine/foldable.hpp"

#include <algorithm>
#include <cstddef>

namespace cdro::engine {
namespace {

using Adjacency = std::vector<std::vector<uint32_t>>;

// The connected components of the nodes with inside[i] != 0, each listed in increasing order
// of discovery from its smallest node (components come in order of their smallest node).
std::vector<std::vector<uint32_t>> components(const Adjacency &adjacency, const std::vector<char> &inside)
{
    const size_t count = adjacency.size();
    std::vector<char> seen(count, 0);
    std::vector<std::vector<uint32_t>> out;
    std::vector<uint32_t> stack;
    for (uint32_t root = 0; root < count; ++root) {
        if (!inside[root] || seen[root]) {
            continue;
        }
        out.emplace_back();
        seen[root] = 1;
        stack.push_back(root);
        while (!stack.empty()) {
            const uint32_t node = stack.back();
            stack.pop_back();
            out.back().push_back(node);
            for (uint32_t next : adjacency[node]) {
                if (inside[next] && !seen[next]) {
                    seen[next] = 1;
                    stack.push_back(next);
                }
            }
        }
    }
    return out;
}

// The articulation points of the graph on the nodes with inside[i] != 0.
std::vector<uint32_t> articulationPoints(const Adjacency &adjacency, const std::vector<char> &inside)
{
    const size_t count = adjacency.size();
    std::vector<uint32_t> discovered(count, 0); // 0: not yet; else the discovery time
    std::vector<uint32_t> low(count, 0);
    std::vector<uint32_t> parent(count, kNoHinge);
    std::vector<uint32_t> children(count, 0);
    std::vector<size_t> next_edge(count, 0);
    std::vector<char> is_cut(count, 0);
    std::vector<uint32_t> stack;
    uint32_t time = 0;
    for (uint32_t root = 0; root < count; ++root) {
        if (!inside[root] || discovered[root] != 0) {
            continue;
        }
        discovered[root] = low[root] = ++time;
        stack.push_back(root);
        while (!stack.empty()) {
            const uint32_t node = stack.back();
            if (next_edge[node] < adjacency[node].size()) {
                const uint32_t next = adjacency[node][next_edge[node]++];
                if (!inside[next]) {
                    continue;
                }
                if (discovered[next] == 0) {
                    parent[next] = node;
                    ++children[node];
                    discovered[next] = low[next] = ++time;
                    stack.push_back(next);
                } else if (next != parent[node]) {
                    low[node] = std::min(low[node], discovered[next]);
                }
                continue;
            }
            stack.pop_back();
            const uint32_t up = parent[node];
            if (up != kNoHinge) {
                low[up] = std::min(low[up], low[node]);
                if (parent[up] != kNoHinge && low[node] >= discovered[up]) {
                    is_cut[up] = 1;
                }
            }
        }
        if (children[root] > 1) {
            is_cut[root] = 1;
        }
    }
    std::vector<uint32_t> out;
    for (uint32_t node = 0; node < count; ++node) {
        if (is_cut[node]) {
            out.push_back(node);
        }
    }
    return out;
}

// The largest part; of equal ones the first, i.e. the one with the smallest node (components()
// lists them in that order). parts must not be empty.
size_t largestPart(const std::vector<std::vector<uint32_t>> &parts)
{
    size_t largest = 0;
    for (size_t i = 1; i < parts.size(); ++i) {
        if (parts[i].size() > parts[largest].size()) {
            largest = i;
        }
    }
    return largest;
}

// Every part but the largest is marked, unless it holds an anchored node.
void markAllButLargest(const std::vector<std::vector<uint32_t>> &parts, const std::vector<uint8_t> &anchored,
                       std::array<uint32_t, 2> hinge, Foldable &out)
{
    if (parts.size() < 2) {
        return;
    }
    const size_t largest = largestPart(parts);
    for (size_t i = 0; i < parts.size(); ++i) {
        if (i == largest ||
            std::any_of(parts[i].begin(), parts[i].end(), [&](uint32_t node) { return anchored[node] != 0; })) {
            continue;
        }
        for (uint32_t node : parts[i]) {
            if (out.foldable[node] == 0) {
                out.foldable[node] = 1;
                out.hinge[node] = hinge;
                ++out.count;
            }
        }
    }
}

std::vector<char> insideOf(uint32_t node_count, const std::vector<uint8_t> &active)
{
    std::vector<char> inside(node_count, 0);
    for (uint32_t node = 0; node < node_count && node < active.size(); ++node) {
        inside[node] = active[node] != 0 ? 1 : 0;
    }
    return inside;
}

// Each node's neighbours among the inside nodes, ascending, once each.
Adjacency adjacencyOf(uint32_t node_count, const std::vector<std::pair<uint32_t, uint32_t>> &edges,
                      const std::vector<char> &inside)
{
    Adjacency adjacency(node_count);
    for (const auto &[a, b] : edges) {
        if (a < node_count && b < node_count && a != b && inside[a] && inside[b]) {
            adjacency[a].push_back(b);
            adjacency[b].push_back(a);
        }
    }
    for (std::vector<uint32_t> &neighbours : adjacency) {
        std::sort(neighbours.begin(), neighbours.end());
        neighbours.erase(std::unique(neighbours.begin(), neighbours.end()), neighbours.end());
    }
    return adjacency;
}

} // namespace

std::vector<uint32_t> cutNodes(uint32_t node_count, const std::vector<std::pair<uint32_t, uint32_t>> &edges,
                               const std::vector<uint8_t> &active)
{
    const std::vector<char> inside = insideOf(node_count, active);
    return articulationPoints(adjacencyOf(node_count, edges, inside), inside);
}

Foldable findFoldable(uint32_t node_count, const std::vector<std::pair<uint32_t, uint32_t>> &edges,
                      const std::vector<uint8_t> &active, const std::vector<uint8_t> &anchored)
{
    Foldable out;
    out.foldable.assign(node_count, 0);
    out.hinge.assign(node_count, {kNoHinge, kNoHinge});
    std::vector<uint8_t> anchor(node_count, 0);
    for (uint32_t node = 0; node < node_count && node < anchored.size(); ++node) {
        anchor[node] = anchored[node] != 0 ? 1 : 0;
    }
    std::vector<char> inside = insideOf(node_count, active);
    const Adjacency adjacency = adjacencyOf(node_count, edges, inside);

    // Nodes outside the largest component cannot be placed relative to it at all.
    const std::vector<std::vector<uint32_t>> whole = components(adjacency, inside);
    markAllButLargest(whole, anchor, {kNoHinge, kNoHinge}, out);
    std::fill(inside.begin(), inside.end(), 0);
    if (whole.empty()) {
        return out;
    }
    const std::vector<uint32_t> *main_part = &whole[largestPart(whole)];
    for (uint32_t node : *main_part) {
        inside[node] = 1;
    }

    // Cuts of one node: a part turns about it.
    for (uint32_t cut : articulationPoints(adjacency, inside)) {
        inside[cut] = 0;
        markAllButLargest(components(adjacency, inside), anchor, {cut, kNoHinge}, out);
        inside[cut] = 1;
    }
    // Cuts of two nodes: a part is reflected across the line through them.
    std::vector<uint32_t> members = *main_part;
    std::sort(members.begin(), members.end());
    for (uint32_t first : members) {
        inside[first] = 0;
        for (uint32_t second : articulationPoints(adjacency, inside)) {
            inside[second] = 0;
            markAllButLargest(components(adjacency, inside), anchor, {std::min(first, second), std::max(first, second)},
                              out);
            inside[second] = 1;
        }
        inside[first] = 1;
    }
    return out;
}

std::vector<std::array<uint32_t, 2>> twoLinkCuts(uint32_t node_count,
                                                 const std::vector<std::pair<uint32_t, uint32_t>> &edges,
                                                 const std::vector<uint8_t> &active)
{
    const std::vector<char> inside = insideOf(node_count, active);
    // Each inside node's incident edges: (the other end, the edge's index), in the edges' order.
    std::vector<std::vector<std::pair<uint32_t, uint32_t>>> incident(node_count);
    for (size_t index = 0; index < edges.size(); ++index) {
        const auto [a, b] = edges[index];
        if (a < node_count && b < node_count && a != b && inside[a] && inside[b]) {
            incident[a].emplace_back(b, static_cast<uint32_t>(index));
            incident[b].emplace_back(a, static_cast<uint32_t>(index));
        }
    }
    // A spanning forest (depth first, from the smallest node of each component), its nodes in
    // the order they were reached.
    std::vector<uint32_t> parent_edge(node_count, kNoHinge);
    std::vector<uint32_t> parent(node_count, kNoHinge);
    std::vector<char> seen(node_count, 0);
    std::vector<uint32_t> order;
    std::vector<uint32_t> stack;
    for (uint32_t root = 0; root < node_count; ++root) {
        if (!inside[root] || seen[root]) {
            continue;
        }
        seen[root] = 1;
        stack.push_back(root);
        while (!stack.empty()) {
            const uint32_t node = stack.back();
            stack.pop_back();
            order.push_back(node);
            for (const auto &[next, index] : incident[node]) {
                if (!seen[next]) {
                    seen[next] = 1;
                    parent[next] = node;
                    parent_edge[next] = index;
                    stack.push_back(next);
                }
            }
        }
    }
    std::vector<char> in_tree(edges.size(), 0);
    for (uint32_t node : order) {
        if (parent_edge[node] != kNoHinge) {
            in_tree[parent_edge[node]] = 1;
        }
    }
    // Labels: splitmix64 of each non-tree edge's index; a node holds the XOR of its non-tree edges'.
    std::vector<uint64_t> label(edges.size(), 0);
    std::vector<uint64_t> below(node_count, 0);
    for (size_t index = 0; index < edges.size(); ++index) {
        const auto [a, b] = edges[index];
        if (in_tree[index] || a >= node_count || b >= node_count || a == b || !inside[a] || !inside[b]) {
            continue;
        }
        uint64_t z = static_cast<uint64_t>(index) + 0x9E3779B97F4A7C15ULL;
        z = (z ^ (z >> 30U)) * 0xBF58476D1CE4E5B9ULL;
        z = (z ^ (z >> 27U)) * 0x94D049BB133111EBULL;
        label[index] = (z ^ (z >> 31U)) | 1U; // never 0: 0 marks a bridge
        below[a] ^= label[index];
        below[b] ^= label[index];
    }
    // A tree edge's label: the XOR over the subtree under it (the cycles that leave the subtree).
    for (auto it = order.rbegin(); it != order.rend(); ++it) {
        const uint32_t node = *it;
        if (parent_edge[node] != kNoHinge) {
            label[parent_edge[node]] = below[node];
            below[parent[node]] ^= below[node];
        }
    }
    std::vector<std::pair<uint64_t, uint32_t>> labelled;
    for (size_t index = 0; index < edges.size(); ++index) {
        if (label[index] != 0) {
            labelled.emplace_back(label[index], static_cast<uint32_t>(index));
        }
    }
    std::sort(labelled.begin(), labelled.end());
    std::vector<std::array<uint32_t, 2>> out;
    for (size_t first = 0; first < labelled.size();) {
        size_t end = first + 1;
        while (end < labelled.size() && labelled[end].first == labelled[first].first) {
            ++end;
        }
        if (end - first == 2) {
            out.push_back({labelled[first].second, labelled[first + 1].second});
        }
        first = end;
    }
    std::sort(out.begin(), out.end());
    return out;
}

} // namespace cdro::engine
