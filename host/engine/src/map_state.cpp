#include "cdro/engine/map_state.hpp"

#include <algorithm>

namespace cdro::engine {

const char *nodeRoleName(NodeRole role)
{
    switch (role) {
    case NodeRole::Free: return "free";
    case NodeRole::Fixed: return "fixed";
    case NodeRole::Pinned: return "pinned";
    }
    return "unknown";
}

const char *nodeLifecycleName(NodeLifecycle lifecycle)
{
    switch (lifecycle) {
    case NodeLifecycle::Unplaced: return "unplaced";
    case NodeLifecycle::Placed: return "placed";
    case NodeLifecycle::Converged: return "converged";
    case NodeLifecycle::Moving: return "moving";
    case NodeLifecycle::Settling: return "settling";
    }
    return "unknown";
}

const char *nodeDoubtName(NodeDoubt doubt)
{
    switch (doubt) {
    case NodeDoubt::None: return "";
    case NodeDoubt::TooFewLinks: return "too few links";
    case NodeDoubt::Ambiguous: return "ambiguous";
    case NodeDoubt::Foldable: return "foldable";
    case NodeDoubt::Flexible: return "flexible";
    case NodeDoubt::Unsettled: return "unsettled";
    }
    return "unknown";
}

uint32_t MapState::placedCount() const
{
    uint32_t count = 0;
    for (const NodeState &node : nodes) {
        count += node.placed() ? 1U : 0U;
    }
    return count;
}

void RangeWindow::push(double range_m)
{
    values_[next_] = range_m;
    next_ = (next_ + 1) % limit_;
    size_ = std::min(size_ + 1, limit_);
}

void RangeWindow::clear()
{
    size_ = 0;
    next_ = 0;
}

void RangeWindow::setCapacityLimit(uint32_t limit)
{
    limit_ = std::clamp<uint32_t>(limit, 1U, kCapacity);
    clear();
}

double RangeWindow::median() const
{
    if (size_ == 0) {
        return 0.0;
    }
    std::array<double, kCapacity> sorted{};
    std::copy(values_.begin(), values_.begin() + size_, sorted.begin());
    const auto middle = sorted.begin() + size_ / 2;
    std::nth_element(sorted.begin(), middle, sorted.begin() + size_);
    if (size_ % 2 == 1) {
        return *middle;
    }
    const double upper = *middle;
    const double lower = *std::max_element(sorted.begin(), middle);
    return 0.5 * (lower + upper);
}

double RangeWindow::newest() const
{
    if (size_ == 0) {
        return 0.0;
    }
    return values_[(next_ + limit_ - 1) % limit_];
}

std::vector<double> RangeWindow::values() const
{
    std::vector<double> out;
    out.reserve(size_);
    const uint32_t start = size_ < limit_ ? 0 : next_;
    for (uint32_t i = 0; i < size_; ++i) {
        out.push_back(values_[(start + i) % limit_]);
    }
    return out;
}

uint32_t MapState::findNode(NodeId id) const
{
    const auto found = node_index_.find(id);
    return found == node_index_.end() ? kNoIndex : found->second;
}

uint32_t MapState::addNode(NodeId id)
{
    const auto [position, inserted] = node_index_.emplace(id, static_cast<uint32_t>(nodes.size()));
    if (inserted) {
        NodeState state;
        state.id = id;
        nodes.push_back(state);
        const auto before = std::lower_bound(nodes_by_id_.begin(), nodes_by_id_.end(), id,
                                             [this](uint32_t node, NodeId key) { return nodes[node].id < key; });
        nodes_by_id_.insert(before, position->second);
    }
    return position->second;
}

uint32_t MapState::findLink(uint32_t node_a, uint32_t node_b) const
{
    NodeId a = nodes[node_a].id;
    NodeId b = nodes[node_b].id;
    if (a > b) {
        std::swap(a, b);
    }
    const auto found = link_index_.find(linkKey(a, b));
    return found == link_index_.end() ? kNoIndex : found->second;
}

uint32_t MapState::addLink(uint32_t node_x, uint32_t node_y, uint32_t window_limit)
{
    const uint32_t existing = findLink(node_x, node_y);
    if (existing != kNoIndex) {
        return existing;
    }
    if (nodes[node_x].id > nodes[node_y].id) {
        std::swap(node_x, node_y);
    }
    const uint32_t index = static_cast<uint32_t>(links.size());
    LinkState link;
    link.node_a = node_x;
    link.node_b = node_y;
    link.window.setCapacityLimit(window_limit);
    links.push_back(link);
    const uint32_t key = linkKey(nodes[node_x].id, nodes[node_y].id);
    link_index_.emplace(key, index);
    const auto before =
        std::lower_bound(links_by_id_.begin(), links_by_id_.end(), key, [this](uint32_t other, uint32_t k) {
            return linkKey(nodes[links[other].node_a].id, nodes[links[other].node_b].id) < k;
        });
    links_by_id_.insert(before, index);
    nodes[node_x].links.push_back(index);
    nodes[node_y].links.push_back(index);
    return index;
}

} // namespace cdro::engine
