#include "cdro/engine/map_mds.hpp"

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <queue>

#include <Eigen/Dense>

namespace cdro::engine {

std::optional<Eigen::MatrixXd> mdsEmbedding(const MapProblem &problem, const std::vector<uint32_t> &part, uint32_t dims)
{
    const auto count = static_cast<Eigen::Index>(part.size());
    if (count < 3) {
        return std::nullopt;
    }
    std::vector<int> index(problem.nodeCount(), -1);
    for (Eigen::Index i = 0; i < count; ++i) {
        index[part[static_cast<size_t>(i)]] = static_cast<int>(i);
    }
    const double infinity = std::numeric_limits<double>::infinity();
    Eigen::MatrixXd squared(count, count);
    using Entry = std::pair<double, uint32_t>;
    std::vector<double> distance(part.size());
    for (Eigen::Index source = 0; source < count; ++source) {
        std::fill(distance.begin(), distance.end(), infinity);
        std::priority_queue<Entry, std::vector<Entry>, std::greater<Entry>> frontier;
        distance[static_cast<size_t>(source)] = 0.0;
        frontier.emplace(0.0, part[static_cast<size_t>(source)]);
        while (!frontier.empty()) {
            const auto [so_far, node] = frontier.top();
            frontier.pop();
            if (so_far > distance[static_cast<size_t>(index[node])]) {
                continue;
            }
            for (uint32_t link : problem.node_links[node]) {
                const uint32_t other = problem.other(link, node);
                if (index[other] < 0) {
                    continue;
                }
                const double through = so_far + problem.links[link].range_m;
                if (through < distance[static_cast<size_t>(index[other])]) {
                    distance[static_cast<size_t>(index[other])] = through;
                    frontier.emplace(through, other);
                }
            }
        }
        for (Eigen::Index j = 0; j < count; ++j) {
            const double d = distance[static_cast<size_t>(j)];
            if (!std::isfinite(d)) {
                return std::nullopt;
            }
            squared(source, j) = d * d;
        }
    }
    // B = -1/2 J D^2 J (D^2 symmetrised).
    Eigen::MatrixXd gram = 0.5 * (squared + squared.transpose());
    const Eigen::VectorXd row_mean = gram.rowwise().mean();
    const double grand_mean = row_mean.mean();
    for (Eigen::Index i = 0; i < count; ++i) {
        for (Eigen::Index j = 0; j < count; ++j) {
            gram(i, j) = -0.5 * (gram(i, j) - row_mean(i) - row_mean(j) + grand_mean);
        }
    }
    // The leading eigenpairs: dense for small parts, subspace iteration beyond.
    const auto wanted = static_cast<Eigen::Index>(std::min<uint32_t>(dims, static_cast<uint32_t>(count)));
    Eigen::MatrixXd vectors(count, wanted);
    Eigen::VectorXd values(wanted);
    if (count <= 400) {
        const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eigen(gram);
        if (eigen.info() != Eigen::Success) {
            return std::nullopt;
        }
        for (Eigen::Index k = 0; k < wanted; ++k) {
            vectors.col(k) = eigen.eigenvectors().col(count - 1 - k);
            values(k) = eigen.eigenvalues()(count - 1 - k);
        }
    } else {
        // A deterministic start; B is shifted so that its most negative eigenvalues cannot lead.
        const Eigen::Index width = wanted + 2;
        Eigen::MatrixXd basis(count, width);
        for (Eigen::Index i = 0; i < count; ++i) {
            const double t = static_cast<double>(i) / static_cast<double>(count);
            for (Eigen::Index k = 0; k < width; ++k) {
                basis(i, k) =
                    std::cos(3.14159265358979 * static_cast<double>(k + 1) * t + 0.3 * static_cast<double>(k));
            }
        }
        const double shift = gram.cwiseAbs().rowwise().sum().maxCoeff() * 0.5;
        for (int iteration = 0; iteration < 200; ++iteration) {
            basis = gram * basis + shift * basis;
            Eigen::HouseholderQR<Eigen::MatrixXd> qr(basis);
            basis = qr.householderQ() * Eigen::MatrixXd::Identity(count, width);
        }
        const Eigen::MatrixXd small = basis.transpose() * gram * basis;
        const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eigen(small);
        for (Eigen::Index k = 0; k < wanted; ++k) {
            vectors.col(k) = basis * eigen.eigenvectors().col(width - 1 - k);
            values(k) = eigen.eigenvalues()(width - 1 - k);
        }
    }
    Eigen::MatrixXd embedding = Eigen::MatrixXd::Zero(problem.nodeCount(), static_cast<Eigen::Index>(dims));
    for (Eigen::Index i = 0; i < count; ++i) {
        const auto node = static_cast<Eigen::Index>(part[static_cast<size_t>(i)]);
        for (Eigen::Index k = 0; k < wanted; ++k) {
            embedding(node, k) = std::sqrt(std::max(values(k), 0.0)) * vectors(i, k);
        }
    }
    return embedding;
}

std::optional<MapEstimate> mdsMap(const MapProblem &problem, const std::vector<uint32_t> &part)
{
    const std::optional<Eigen::MatrixXd> embedding = mdsEmbedding(problem, part, 2);
    if (!embedding) {
        return std::nullopt;
    }
    MapEstimate estimate = MapEstimate::unplaced(problem.nodeCount());
    for (uint32_t node : part) {
        estimate.placed[node] = 1;
        estimate.position_m[node] = embedding->row(node).transpose();
    }
    return estimate;
}

} // namespace cdro::engine
