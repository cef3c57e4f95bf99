#include "cdro/engine/mds.hpp"

#include <cmath>
#include <functional>
#include <limits>
#include <queue>
#include <unordered_map>

#include <Eigen/Dense>

namespace cdro::engine {

std::optional<std::vector<Vector2>> mdsLayout(const Network &network, const std::vector<uint32_t> &nodes)
{
    const size_t count = nodes.size();
    if (count < 3) {
        return std::nullopt;
    }
    std::unordered_map<uint32_t, size_t> position_of;
    for (size_t i = 0; i < count; ++i) {
        position_of.emplace(nodes[i], i);
    }
    // All-pairs shortest paths over the links among these nodes: Dijkstra from each node.
    const double infinity = std::numeric_limits<double>::infinity();
    Eigen::MatrixXd distance = Eigen::MatrixXd::Constant(static_cast<Eigen::Index>(count),
                                                         static_cast<Eigen::Index>(count), infinity);
    using Entry = std::pair<double, size_t>;
    for (size_t source = 0; source < count; ++source) {
        std::priority_queue<Entry, std::vector<Entry>, std::greater<Entry>> frontier;
        auto row = distance.row(static_cast<Eigen::Index>(source));
        row(static_cast<Eigen::Index>(source)) = 0.0;
        frontier.emplace(0.0, source);
        while (!frontier.empty()) {
            const auto [so_far, at] = frontier.top();
            frontier.pop();
            if (so_far > row(static_cast<Eigen::Index>(at))) {
                continue;
            }
            for (uint32_t link : network.nodes[nodes[at]].links) {
                const auto found = position_of.find(network.otherNode(link, nodes[at]));
                if (found == position_of.end()) {
                    continue;
                }
                const double through = so_far + network.links[link].representative_m;
                if (through < row(static_cast<Eigen::Index>(found->second))) {
                    row(static_cast<Eigen::Index>(found->second)) = through;
                    frontier.emplace(through, found->second);
                }
            }
        }
    }
    if (!distance.allFinite()) {
        return std::nullopt;
    }
    // Classical MDS: B = -1/2 J D^2 J, coordinates from the two largest eigenpairs.
    const Eigen::MatrixXd squared = distance.array().square().matrix();
    const Eigen::MatrixXd symmetric = 0.5 * (squared + squared.transpose());
    const Eigen::VectorXd row_mean = symmetric.rowwise().mean();
    const double grand_mean = row_mean.mean();
    Eigen::MatrixXd gram = symmetric;
    for (Eigen::Index i = 0; i < gram.rows(); ++i) {
        for (Eigen::Index j = 0; j < gram.cols(); ++j) {
            gram(i, j) = -0.5 * (symmetric(i, j) - row_mean(i) - row_mean(j) + grand_mean);
        }
    }
    const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eigen(gram);
    if (eigen.info() != Eigen::Success) {
        return std::nullopt;
    }
    const Eigen::Index last = gram.rows() - 1;
    const double first_value = std::max(eigen.eigenvalues()(last), 0.0);
    const double second_value = std::max(eigen.eigenvalues()(last - 1), 0.0);
    std::vector<Vector2> layout(count);
    for (size_t i = 0; i < count; ++i) {
        const auto index = static_cast<Eigen::Index>(i);
        layout[i] = Vector2(std::sqrt(first_value) * eigen.eigenvectors()(index, last),
                            std::sqrt(second_value) * eigen.eigenvectors()(index, last - 1));
    }
    return layout;
}

} // namespace cdro::engine
