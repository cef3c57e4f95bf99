#include "cdro/netgen/rigidity.hpp"

#include <Eigen/Eigenvalues>
#include <Eigen/SVD>

namespace cdro::netgen {

bool globallyRigid(const std::vector<Vector2> &position_m, const std::vector<std::pair<size_t, size_t>> &links,
                   RandomSource &random)
{
    // Rigidity matrix: one row per link, d|p_a - p_b| / d(p_a, p_b).
    const Eigen::Index n = static_cast<Eigen::Index>(position_m.size());
    const Eigen::Index m = static_cast<Eigen::Index>(links.size());
    if (n < 4) {
        return n == 3 && m == 3;
    }
    Eigen::MatrixXd rigidity = Eigen::MatrixXd::Zero(m, 2 * n);
    for (Eigen::Index l = 0; l < m; ++l) {
        const auto [a, b] = links[static_cast<size_t>(l)];
        const Vector2 d = position_m[a] - position_m[b];
        rigidity.block<1, 2>(l, 2 * static_cast<Eigen::Index>(a)) = d.transpose();
        rigidity.block<1, 2>(l, 2 * static_cast<Eigen::Index>(b)) = -d.transpose();
    }
    const Eigen::JacobiSVD<Eigen::MatrixXd> svd(rigidity, Eigen::ComputeFullU);
    const Eigen::VectorXd &singular = svd.singularValues();
    if (singular.size() == 0) {
        return false; // no link (and, for gcc's -Wnull-dereference, no empty vector read below)
    }
    const double tolerance = 1e-9 * singular(0);
    Eigen::Index rank = 0;
    for (Eigen::Index i = 0; i < singular.size(); ++i) {
        rank += singular(i) > tolerance ? 1 : 0;
    }
    if (rank != 2 * n - 3) {
        return false; // not even infinitesimally rigid
    }
    // Equilibrium stresses: the left null space of the rigidity matrix. A generic random
    // combination of them has the largest stress-matrix rank there is; n - 3 means globally rigid.
    const Eigen::MatrixXd stresses = svd.matrixU().rightCols(m - rank);
    if (stresses.cols() == 0) {
        return false;
    }
    Eigen::VectorXd mix(stresses.cols());
    for (Eigen::Index i = 0; i < mix.size(); ++i) {
        mix(i) = random.normal();
    }
    const Eigen::VectorXd omega = stresses * mix;
    Eigen::MatrixXd stress = Eigen::MatrixXd::Zero(n, n);
    for (Eigen::Index l = 0; l < m; ++l) {
        const auto [a, b] = links[static_cast<size_t>(l)];
        const Eigen::Index i = static_cast<Eigen::Index>(a);
        const Eigen::Index j = static_cast<Eigen::Index>(b);
        stress(i, j) -= omega(l);
        stress(j, i) -= omega(l);
        stress(i, i) += omega(l);
        stress(j, j) += omega(l);
    }
    const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eigen(stress);
    const Eigen::VectorXd values = eigen.eigenvalues().cwiseAbs();
    const double largest = values.maxCoeff();
    Eigen::Index stress_rank = 0;
    for (Eigen::Index i = 0; i < values.size(); ++i) {
        stress_rank += values(i) > 1e-9 * largest ? 1 : 0;
    }
    return stress_rank == n - 3;
}

} // namespace cdro::netgen
