#include "cdro/engine/map_refine.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>

#include <Eigen/Dense>
#include <Eigen/SparseCholesky>
#include <Eigen/SparseCore>

namespace cdro::engine {

namespace {

// A square matrix made exactly symmetric, each pair of off-diagonal entries their mean, in place.
void symmetrizeInPlace(Eigen::MatrixXd &matrix)
{
    for (Eigen::Index j = 0; j < matrix.cols(); ++j) {
        for (Eigen::Index i = j + 1; i < matrix.rows(); ++i) {
            const double mean = 0.5 * (matrix(i, j) + matrix(j, i));
            matrix(i, j) = mean;
            matrix(j, i) = mean;
        }
    }
}

using SparseMatrix = Eigen::SparseMatrix<double>;
using Triplet = Eigen::Triplet<double>;
// The unit vector from b to a in D dimensions and their distance, on the stack (the normal
// equations need one per link per iteration); u stays 0 where the two coincide.
struct Direction {
    std::array<double, kMaxEmbeddingDimensions> u{};
    double distance = 0.0;
};
Direction directionBetween(const Eigen::MatrixXd &positions, uint32_t a, uint32_t b)
{
    Direction out;
    const Eigen::Index dims = positions.cols();
    double squared = 0.0;
    for (Eigen::Index d = 0; d < dims; ++d) {
        const double delta = positions(a, d) - positions(b, d);
        out.u[static_cast<size_t>(d)] = delta;
        squared += delta * delta;
    }
    out.distance = std::sqrt(squared);
    if (!(out.distance > 0.0)) {
        out.u.fill(0.0);
        return out;
    }
    for (Eigen::Index d = 0; d < dims; ++d) {
        out.u[static_cast<size_t>(d)] /= out.distance;
    }
    return out;
}

// The unknowns: placed, not fixed nodes with links (-1: not an unknown), numbered in order.
std::vector<int> freeNumbers(const MapProblem &problem, const std::vector<uint8_t> &placed, uint32_t *count)
{
    std::vector<int> number(problem.nodeCount(), -1);
    uint32_t next = 0;
    for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
        if (placed[node] != 0 && problem.fixed[node] == 0 && !problem.node_links[node].empty()) {
            number[node] = static_cast<int>(next++);
        }
    }
    *count = next;
    return number;
}

// One pair's terms in the normal equations (a link, or an unheard pair): the numbers of its two
// nodes (-1 for a node that does not move), u = d distance / d p_a, the information weight (u u^T
// in the blocks of a and b) and the push (-d cost / d distance: the descent moves along u at a
// and against it at b).
struct PairTerm {
    int na = -1;
    int nb = -1;
    std::array<double, kMaxEmbeddingDimensions> u{};
    double weight = 0.0;
    double push = 0.0;
};

// Each link's residual and its evaluation where the refinement last computed its cost (the
// positions its next normal equations start from): the terms reuse an evaluation when the
// residual they compute is the same to the bit, so each link's likelihood is evaluated once per
// accepted step instead of twice.
struct LinkEvaluations {
    std::vector<double> residual_m;
    std::vector<ResidualEvaluation> at;
    void clear(size_t links)
    {
        residual_m.assign(links, std::numeric_limits<double>::quiet_NaN());
        at.resize(links);
    }
};

// The pairs' terms at `positions` (one row per node, D columns), in the order the normal
// equations sum them: the links, then the close unheard pairs (not for the Fisher information:
// they are a soft prior, not information from ranges). IRLS weights, or the line-of-sight
// Fisher weights.
void pairTerms(const MapProblem &problem, const std::vector<uint8_t> &placed, const Eigen::MatrixXd &positions,
               const RangeLikelihood &likelihood, const std::vector<int> &number, double variance, bool fisher,
               std::vector<PairTerm> &terms, const LinkEvaluations *known = nullptr)
{
    const auto dims = positions.cols();
    terms.clear();
    for (size_t index = 0; index < problem.links.size(); ++index) {
        const MapLink &link = problem.links[index];
        const int na = number[link.a];
        const int nb = number[link.b];
        if (placed[link.a] == 0 || placed[link.b] == 0 || (na < 0 && nb < 0)) {
            continue;
        }
        const Direction direction = directionBetween(positions, link.a, link.b);
        const double distance = direction.distance;
        if (distance < 1e-9) {
            continue;
        }
        const double residual = link.range_m - distance;
        const ResidualEvaluation at = known != nullptr && known->residual_m[index] == residual
                                          ? known->at[index]
                                          : likelihood.evaluate(residual, variance);
        const double weight = fisher ? at.inlier_probability / variance : likelihood.irlsWeight(residual, variance, at);
        // cost = -log p(e), e = r - |p_a - p_b|: d cost / d p_a = slope * u, so push = -slope.
        terms.push_back(PairTerm{na, nb, direction.u, weight, -at.slope_per_m});
    }
    if (fisher || problem.unheard_radius_m <= 0.0) {
        return;
    }
    // cost k (1 - d/R)^2 = 1/2 w (R - d)^2 with w = 2 k / R^2, for d < R.
    const double radius = problem.unheard_radius_m;
    const double weight = 2.0 * problem.unheard_cost_nats / (radius * radius);
    forEachCloseUnheardPair(problem, placed, positions, [&](uint32_t a, uint32_t b, double distance) {
        const int na = number[a];
        const int nb = number[b];
        if (distance < 1e-9 || (na < 0 && nb < 0)) {
            return;
        }
        PairTerm term{na, nb, {}, weight, weight * (radius - distance)};
        for (Eigen::Index d = 0; d < dims; ++d) {
            term.u[static_cast<size_t>(d)] = (positions(a, d) - positions(b, d)) / distance;
        }
        terms.push_back(term);
    });
}

// The descent direction b = -d cost / dx of the terms, summed in their order.
void addDescent(const std::vector<PairTerm> &terms, Eigen::Index dims, Eigen::VectorXd &descent)
{
    for (const PairTerm &term : terms) {
        for (Eigen::Index d = 0; d < dims; ++d) {
            const double along = term.push * term.u[static_cast<size_t>(d)];
            if (term.na >= 0) {
                descent(term.na * dims + d) += along;
            }
            if (term.nb >= 0) {
                descent(term.nb * dims + d) -= along;
            }
        }
    }
}

// Normal equations of the links at `positions` as a triplet list (every entry of the symmetric
// matrix, the diagonal always present) and the descent direction: the Fisher information, for
// the covariance, which adds the range offsets' rows to the same list.
void normalEquations(const MapProblem &problem, const std::vector<uint8_t> &placed, const Eigen::MatrixXd &positions,
                     const RangeLikelihood &likelihood, const std::vector<int> &number, Eigen::Index unknowns,
                     double variance, bool fisher, std::vector<Triplet> &triplets, Eigen::VectorXd &descent)
{
    const auto dims = positions.cols();
    const Eigen::Index size = unknowns * dims;
    std::vector<PairTerm> terms;
    pairTerms(problem, placed, positions, likelihood, number, variance, fisher, terms);
    triplets.clear();
    descent.setZero(size);
    for (Eigen::Index i = 0; i < size; ++i) {
        triplets.emplace_back(static_cast<int>(i), static_cast<int>(i), 0.0);
    }
    for (const PairTerm &term : terms) {
        const int ca = term.na >= 0 ? static_cast<int>(term.na * dims) : -1;
        const int cb = term.nb >= 0 ? static_cast<int>(term.nb * dims) : -1;
        for (Eigen::Index i = 0; i < dims; ++i) {
            for (Eigen::Index j = 0; j < dims; ++j) {
                const double value = term.weight * term.u[static_cast<size_t>(i)] * term.u[static_cast<size_t>(j)];
                const int ii = static_cast<int>(i);
                const int jj = static_cast<int>(j);
                if (ca >= 0) {
                    triplets.emplace_back(ca + ii, ca + jj, value);
                }
                if (cb >= 0) {
                    triplets.emplace_back(cb + ii, cb + jj, value);
                }
                if (ca >= 0 && cb >= 0) {
                    triplets.emplace_back(ca + ii, cb + jj, -value);
                    triplets.emplace_back(cb + ii, ca + jj, -value);
                }
            }
        }
    }
    addDescent(terms, dims, descent);
}

// The refinement's normal equations, assembled straight into the compressed column storage of
// their lower triangle (all the solver reads): the nonzero pattern is the pairs' blocks, and each
// entry is summed in the pairs' order, which are the sums setFromTriplets makes of the triplet
// list above, so the steps are the same to the bit; what it saves is sorting a list of D^2 x 4
// triplets per link every iteration, the largest cost of a solve after the factorization.
class LowerNormalEquations {
public:
    // The pattern and the values of the terms, over `unknowns` nodes of `dims` coordinates.
    void assemble(const std::vector<PairTerm> &terms, Eigen::Index unknowns, Eigen::Index dims)
    {
        dims_ = dims;
        const auto nodes = static_cast<size_t>(unknowns);
        // Block column k holds the blocks of the numbered nodes above k that share a term with it.
        below_.assign(nodes, {});
        for (const PairTerm &term : terms) {
            if (term.na >= 0 && term.nb >= 0 && term.na != term.nb) {
                below_[static_cast<size_t>(std::min(term.na, term.nb))].push_back(std::max(term.na, term.nb));
            }
        }
        for (std::vector<int> &list : below_) {
            std::sort(list.begin(), list.end());
            list.erase(std::unique(list.begin(), list.end()), list.end());
        }
        const Eigen::Index size = unknowns * dims;
        column_start_.assign(static_cast<size_t>(size) + 1, 0);
        for (size_t k = 0; k < nodes; ++k) {
            for (Eigen::Index j = 0; j < dims; ++j) {
                const auto column = static_cast<size_t>(static_cast<Eigen::Index>(k) * dims + j);
                const auto entries = (dims - j) + static_cast<Eigen::Index>(below_[k].size()) * dims;
                column_start_[column + 1] = column_start_[column] + static_cast<int>(entries);
            }
        }
        const auto nonzeros = static_cast<Eigen::Index>(column_start_.back());
        rows_.resize(static_cast<size_t>(nonzeros));
        values_.resize(static_cast<size_t>(nonzeros));
        for (size_t k = 0; k < nodes; ++k) {
            for (Eigen::Index j = 0; j < dims; ++j) {
                const auto column = static_cast<Eigen::Index>(k) * dims + j;
                auto slot = static_cast<size_t>(column_start_[static_cast<size_t>(column)]);
                // An entry nothing adds to stays -0.0 + nothing; -0.0 + x is x to the bit, as the
                // first triplet's value is; the diagonal starts from the list's explicit 0.0.
                for (Eigen::Index i = j; i < dims; ++i, ++slot) {
                    rows_[slot] = static_cast<int>(static_cast<Eigen::Index>(k) * dims + i);
                    values_[slot] = i == j ? 0.0 : -0.0;
                }
                for (const int above : below_[k]) {
                    for (Eigen::Index i = 0; i < dims; ++i, ++slot) {
                        rows_[slot] = static_cast<int>(above * dims + i);
                        values_[slot] = -0.0;
                    }
                }
            }
        }
        for (const PairTerm &term : terms) {
            addDiagonalBlock(term.na, term);
            addDiagonalBlock(term.nb, term);
            if (term.na >= 0 && term.nb >= 0 && term.na != term.nb) {
                const int low = std::min(term.na, term.nb);
                const int high = std::max(term.na, term.nb);
                const std::vector<int> &list = below_[static_cast<size_t>(low)];
                const auto index = std::lower_bound(list.begin(), list.end(), high) - list.begin();
                for (Eigen::Index j = 0; j < dims; ++j) {
                    const auto first = static_cast<size_t>(column_start_[static_cast<size_t>(low * dims + j)] +
                                                           (dims - j) + index * dims);
                    for (Eigen::Index i = 0; i < dims; ++i) {
                        values_[first + static_cast<size_t>(i)] +=
                            -(term.weight * term.u[static_cast<size_t>(i)] * term.u[static_cast<size_t>(j)]);
                    }
                }
            }
        }
    }

    // Adds `value` to the diagonal entry of `row` (after the terms, as a triplet appended to the list).
    void addToDiagonal(Eigen::Index row, double value)
    {
        values_[static_cast<size_t>(column_start_[static_cast<size_t>(row)])] += value;
    }

    // The matrix, with `damping` x (its diagonal + floor) added to the diagonal, into `out` (the
    // same pattern is copied only when it changed).
    void write(SparseMatrix &out, const Eigen::VectorXd *damping_diagonal) const
    {
        const auto size = static_cast<Eigen::Index>(column_start_.size() - 1);
        const auto nonzeros = static_cast<Eigen::Index>(values_.size());
        if (out.rows() != size || out.cols() != size || out.nonZeros() != nonzeros || !out.isCompressed() ||
            !std::equal(column_start_.begin(), column_start_.end(), out.outerIndexPtr()) ||
            !std::equal(rows_.begin(), rows_.end(), out.innerIndexPtr())) {
            out.resize(size, size);
            out.resizeNonZeros(nonzeros);
            std::copy(column_start_.begin(), column_start_.end(), out.outerIndexPtr());
            std::copy(rows_.begin(), rows_.end(), out.innerIndexPtr());
        }
        std::copy(values_.begin(), values_.end(), out.valuePtr());
        if (damping_diagonal != nullptr) {
            for (Eigen::Index i = 0; i < size; ++i) {
                out.valuePtr()[column_start_[static_cast<size_t>(i)]] += (*damping_diagonal)(i);
            }
        }
    }

    Eigen::VectorXd diagonal() const
    {
        const auto size = static_cast<Eigen::Index>(column_start_.size() - 1);
        Eigen::VectorXd out(size);
        for (Eigen::Index i = 0; i < size; ++i) {
            out(i) = values_[static_cast<size_t>(column_start_[static_cast<size_t>(i)])];
        }
        return out;
    }

private:
    void addDiagonalBlock(int n, const PairTerm &term)
    {
        if (n < 0) {
            return;
        }
        for (Eigen::Index j = 0; j < dims_; ++j) {
            const auto first = static_cast<size_t>(column_start_[static_cast<size_t>(n * dims_ + j)]);
            for (Eigen::Index i = j; i < dims_; ++i) {
                values_[first + static_cast<size_t>(i - j)] +=
                    term.weight * term.u[static_cast<size_t>(i)] * term.u[static_cast<size_t>(j)];
            }
        }
    }

    Eigen::Index dims_ = 2;
    std::vector<std::vector<int>> below_;
    std::vector<int> column_start_;
    std::vector<int> rows_;
    std::vector<double> values_;
};

// A link whose standardised residual (Baarda's w) is beyond kBiasSigmas reads off by more than
// its noise (mapCovariance); a redundancy below kMinShownRedundancy counts as that much (a link
// hardly checked shows almost nothing of its error, and what it shows is not magnified without
// bound).
constexpr double kBiasSigmas = 2.0;
constexpr double kMinShownRedundancy = 0.1;

// How much of the configured common excess (MapModelError) a map is given. Walls make links read
// long by what each crosses, so the excess the NLOS model cannot tell from noise differs from
// link to link, and the residuals spread beyond the noise: the variance factor rises. A map whose
// links fit their noise (a factor near 1) has little room for it: it gets kUnseenExcessFloor of
// it; one whose factor reaches 1 + kUnseenExcessFullFactor, all of it (between, in proportion).
// Measured on the scorecard's networks (docs/engine.md, "Confidence"): walled floors, corridors and PLANT
// 1.47-1.89, open random networks, wings and radios with offsets 1.00-1.07. Nodes of unknown
// height read long by what their heights differ, which the map absorbs node by node where the
// residuals do not show it: a map with such nodes gets at least kUnseenExcessFloorHeightsUnknown.
constexpr double kUnseenExcessFloor = 1.0 / 6.0;
constexpr double kUnseenExcessFloorHeightsUnknown = 0.5;
constexpr double kUnseenExcessFullFactor = 0.4;

double unseenExcessShare(double variance_factor, bool heights_unknown)
{
    const double floor = heights_unknown ? kUnseenExcessFloorHeightsUnknown : kUnseenExcessFloor;
    return std::clamp((variance_factor - 1.0) / kUnseenExcessFullFactor, floor, 1.0);
}

// Whether two compressed matrices have the same nonzero pattern.
bool samePattern(const SparseMatrix &x, const SparseMatrix &y)
{
    if (x.rows() != y.rows() || x.cols() != y.cols() || x.nonZeros() != y.nonZeros()) {
        return false;
    }
    const auto outer = static_cast<size_t>(x.outerSize()) + 1;
    const auto inner = static_cast<size_t>(x.nonZeros());
    return std::equal(x.outerIndexPtr(), x.outerIndexPtr() + outer, y.outerIndexPtr()) &&
           std::equal(x.innerIndexPtr(), x.innerIndexPtr() + inner, y.innerIndexPtr());
}

double embeddingCost(const MapProblem &problem, const std::vector<uint8_t> &placed, const Eigen::MatrixXd &positions,
                     const RangeLikelihood &likelihood, double variance, double squeeze_per_m2,
                     LinkEvaluations *evaluations = nullptr)
{
    double cost = 0.0;
    for (size_t index = 0; index < problem.links.size(); ++index) {
        const MapLink &link = problem.links[index];
        if (placed[link.a] != 0 && placed[link.b] != 0) {
            const double distance = (positions.row(link.a) - positions.row(link.b)).norm();
            const double residual = link.range_m - distance;
            const ResidualEvaluation at = likelihood.evaluate(residual, variance);
            cost -= at.log_density;
            if (evaluations != nullptr) {
                evaluations->residual_m[index] = residual;
                evaluations->at[index] = at;
            }
        }
    }
    forEachCloseUnheardPair(problem, placed, positions,
                            [&](uint32_t, uint32_t, double distance) { cost += problem.unheardCost(distance); });
    if (squeeze_per_m2 > 0.0 && positions.cols() > 2) {
        for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
            if (placed[node] != 0) {
                cost += squeeze_per_m2 * positions.row(node).tail(positions.cols() - 2).squaredNorm();
            }
        }
    }
    return cost;
}

} // namespace

MapRefineResult refineEmbedding(const MapProblem &problem, const std::vector<uint8_t> &placed,
                                Eigen::MatrixXd &positions, const RangeLikelihood &base_likelihood,
                                const std::vector<RefineStage> &stages, uint32_t iterations_per_stage,
                                double squeeze_per_m2, const MapRefineParams &params)
{
    MapRefineResult result;
    uint32_t free_count = 0;
    const std::vector<int> number = freeNumbers(problem, placed, &free_count);
    const Eigen::Index dims = positions.cols();
    if (free_count == 0 || dims < 2 || dims > static_cast<Eigen::Index>(kMaxEmbeddingDimensions)) {
        return result;
    }
    const auto unknowns = static_cast<Eigen::Index>(free_count);
    const Eigen::Index size = unknowns * dims;
    std::vector<uint32_t> free_nodes;
    for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
        if (number[node] >= 0) {
            free_nodes.push_back(node);
        }
    }
    Eigen::SimplicialLDLT<SparseMatrix> solver;
    bool analysed = false;
    SparseMatrix analysed_pattern;
    std::vector<PairTerm> terms;
    LowerNormalEquations equations;
    SparseMatrix normal;
    SparseMatrix damped;
    Eigen::VectorXd descent;
    Eigen::VectorXd damping_diagonal;
    Eigen::MatrixXd saved;
    LinkEvaluations evaluations;
    LinkEvaluations trial_evaluations;
    for (const RefineStage &stage : stages) {
        RangeLikelihoodParams stage_params = base_likelihood.params();
        if (stage.nlos_fraction >= 0.0) {
            stage_params.nlos_fraction = stage.nlos_fraction;
        }
        if (stage.nlos_mean_excess_m > 0.0) {
            stage_params.nlos_mean_excess_m = stage.nlos_mean_excess_m;
        }
        const RangeLikelihood likelihood(stage_params);
        const double sigma = problem.sigma_m * stage.sigma_scale;
        const double variance = sigma * sigma;
        double damping = params.initial_damping;
        evaluations.clear(problem.links.size());
        double cost = embeddingCost(problem, placed, positions, likelihood, variance, squeeze_per_m2, &evaluations);
        for (uint32_t iteration = 0; iteration < iterations_per_stage; ++iteration) {
            pairTerms(problem, placed, positions, likelihood, number, variance, false, terms, &evaluations);
            equations.assemble(terms, unknowns, dims);
            descent.setZero(size);
            addDescent(terms, dims, descent);
            if (squeeze_per_m2 > 0.0 && dims > 2) {
                for (Eigen::Index i = 0; i < unknowns; ++i) {
                    const uint32_t node = free_nodes[static_cast<size_t>(i)];
                    for (Eigen::Index d = 2; d < dims; ++d) {
                        const Eigen::Index row = i * dims + d;
                        equations.addToDiagonal(row, 2.0 * squeeze_per_m2);
                        descent(row) -= 2.0 * squeeze_per_m2 * positions(node, d);
                    }
                }
            }
            equations.write(normal, nullptr);
            const Eigen::VectorXd diagonal = equations.diagonal();
            const double mean_diagonal = std::max(diagonal.sum() / static_cast<double>(size), 1e-12);
            // The unheard pairs that are close can change the pattern between iterations; the
            // ordering depends on the pattern alone, so it is computed again only when that changed.
            if (!analysed || !samePattern(normal, analysed_pattern)) {
                solver.analyzePattern(normal);
                analysed_pattern = normal;
                analysed = true;
            }
            bool accepted = false;
            for (int attempt = 0; attempt < 10 && !accepted; ++attempt) {
                damping_diagonal = damping * (diagonal.array() + 1e-3 * mean_diagonal);
                equations.write(damped, &damping_diagonal);
                solver.factorize(damped);
                if (solver.info() != Eigen::Success) {
                    damping *= 10.0;
                    continue;
                }
                const Eigen::VectorXd step = solver.solve(descent);
                if (!step.allFinite()) {
                    damping *= 10.0;
                    continue;
                }
                saved = positions;
                double longest = 0.0;
                for (Eigen::Index i = 0; i < unknowns; ++i) {
                    const auto node = static_cast<Eigen::Index>(free_nodes[static_cast<size_t>(i)]);
                    positions.row(node) += step.segment(i * dims, dims).transpose();
                    longest = std::max(longest, step.segment(i * dims, dims).norm());
                }
                trial_evaluations.clear(problem.links.size());
                const double trial =
                    embeddingCost(problem, placed, positions, likelihood, variance, squeeze_per_m2, &trial_evaluations);
                if (trial <= cost) {
                    std::swap(evaluations, trial_evaluations);
                    accepted = true;
                    ++result.iterations;
                    damping = std::max(damping / 3.0, 1e-9);
                    const bool settled =
                        longest < params.step_tolerance_m || cost - trial < 1e-9 * (1.0 + std::abs(cost));
                    cost = trial;
                    if (settled) {
                        iteration = iterations_per_stage; // this stage has converged
                    }
                } else {
                    positions = saved;
                    damping *= 10.0;
                    ++result.refused;
                }
            }
            if (!accepted) {
                break;
            }
        }
    }
    result.cost = embeddingCost(problem, placed, positions, base_likelihood, problem.sigma_m * problem.sigma_m, 0.0);
    return result;
}

MapRefineResult refineMap(const MapProblem &problem, MapEstimate &estimate, const RangeLikelihood &likelihood,
                          const MapRefineParams &params)
{
    Eigen::MatrixXd positions(problem.nodeCount(), 2);
    for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
        positions.row(node) = estimate.position_m[node].transpose();
    }
    MapRefineResult result;
    for (size_t stage = 0; stage < params.stages.size(); ++stage) {
        const bool last = stage + 1 == params.stages.size();
        const MapRefineResult part =
            refineEmbedding(problem, estimate.placed, positions, likelihood, {params.stages[stage]},
                            params.iterations_per_stage * (last ? 3U : 1U), 0.0, params);
        result.iterations += part.iterations;
        result.refused += part.refused;
    }
    for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
        estimate.position_m[node] = positions.row(node).transpose();
    }
    result.cost = mapCost(problem, estimate, likelihood);
    return result;
}

MapCovariance mapCovariance(const MapProblem &problem, const MapEstimate &estimate, const RangeLikelihood &likelihood,
                            const MapModelError &model_error)
{
    MapCovariance out;
    // Filled element by element: GCC 12 at -O1 (the sanitizer build) takes a temporary
    // Matrix2::Zero() here for maybe-uninitialized.
    out.covariance_m2.resize(problem.nodeCount());
    for (Matrix2 &covariance_m2 : out.covariance_m2) {
        covariance_m2.setZero();
    }
    out.shared_excess_m2 = out.covariance_m2;
    uint32_t free_count = 0;
    const std::vector<int> number = freeNumbers(problem, estimate.placed, &free_count);
    if (free_count == 0) {
        // Nothing to estimate (every placed node fixed or pinned): the fixed nodes are exact.
        out.link_redundancy.assign(problem.links.size(), -1.0);
        out.reliability_m.assign(problem.nodeCount(), 0.0);
        out.main_part.assign(problem.nodeCount(), 1);
        out.gauge_free = false;
        return out;
    }
    const auto positions_size = 2 * static_cast<Eigen::Index>(free_count);
    const double variance = problem.sigma_m * problem.sigma_m;
    Eigen::MatrixXd positions(problem.nodeCount(), 2);
    for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
        positions.row(node) = estimate.position_m[node].transpose();
    }
    std::vector<Triplet> triplets;
    Eigen::VectorXd descent;
    normalEquations(problem, estimate.placed, positions, likelihood, number, static_cast<Eigen::Index>(free_count),
                    variance, true, triplets, descent);
    // Range offsets estimated with the map are unknowns too (after the positions, one per placed
    // node, fixed nodes included): a link reads d + b_a + b_b, so its Jacobian row has a 1 for each
    // end's offset. Their prior is the one they were estimated under: deviations of
    // range_offset_spread_sigma_m around a common part that nothing but the links decides (flat),
    // which is the precision (I - 1 1^T / M) / sigma^2 over the M offsets. Without them the map
    // would be as sure as if the radios had been calibrated.
    std::vector<int> offset_number(problem.nodeCount(), -1);
    Eigen::Index offset_count = 0;
    if (model_error.range_offset_spread_sigma_m > 0.0) {
        for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
            if (estimate.placed[node] != 0 && !problem.node_links[node].empty()) {
                offset_number[node] = static_cast<int>(positions_size + offset_count++);
            }
        }
    }
    const Eigen::Index size = positions_size + offset_count;
    if (offset_count > 0) {
        const double prior = 1.0 / (model_error.range_offset_spread_sigma_m * model_error.range_offset_spread_sigma_m);
        for (Eigen::Index i = positions_size; i < size; ++i) {
            for (Eigen::Index k = positions_size; k < size; ++k) {
                const double value = prior * ((i == k ? 1.0 : 0.0) - 1.0 / static_cast<double>(offset_count));
                triplets.emplace_back(static_cast<int>(i), static_cast<int>(k), value);
            }
        }
        for (const MapLink &link : problem.links) {
            if (estimate.placed[link.a] == 0 || estimate.placed[link.b] == 0) {
                continue;
            }
            const Vector2 delta = estimate.position_m[link.a] - estimate.position_m[link.b];
            const double distance = delta.norm();
            if (distance < 1e-9) {
                continue;
            }
            const Vector2 u = delta / distance;
            const double weight = likelihood.evaluate(link.range_m - distance, variance).inlier_probability / variance;
            const int oa = offset_number[link.a];
            const int ob = offset_number[link.b];
            // The row (u at a, -u at b, 1 at o_a, 1 at o_b), times its weight, outer product.
            for (const int o : {oa, ob}) {
                for (const int p : {oa, ob}) {
                    triplets.emplace_back(o, p, weight);
                }
                for (int d = 0; d < 2; ++d) {
                    if (number[link.a] >= 0) {
                        triplets.emplace_back(o, 2 * number[link.a] + d, weight * u[d]);
                        triplets.emplace_back(2 * number[link.a] + d, o, weight * u[d]);
                    }
                    if (number[link.b] >= 0) {
                        triplets.emplace_back(o, 2 * number[link.b] + d, -weight * u[d]);
                        triplets.emplace_back(2 * number[link.b] + d, o, -weight * u[d]);
                    }
                }
            }
        }
    }
    SparseMatrix information(size, size);
    information.setFromTriplets(triplets.begin(), triplets.end());
    // The variance factor: weighted squared residuals of the line-of-sight links over their
    // degrees of freedom.
    double weighted = 0.0;
    double inliers = 0.0;
    for (const MapLink &link : problem.links) {
        if (estimate.placed[link.a] == 0 || estimate.placed[link.b] == 0) {
            continue;
        }
        const double residual = link.range_m - (estimate.position_m[link.a] - estimate.position_m[link.b]).norm();
        const double p = likelihood.evaluate(residual, variance).inlier_probability;
        weighted += p * residual * residual / variance;
        inliers += p;
    }
    out.gauge_free = problem.fixedCount() < 2;
    const double unknowns = static_cast<double>(size) - (out.gauge_free ? 3.0 : 0.0);
    const double degrees_of_freedom = inliers - unknowns;
    out.variance_factor = degrees_of_freedom >= 1.0 ? std::max(weighted / degrees_of_freedom, 1.0) : 1.0;
    bool heights_unknown = false; // a placed node's height is not known
    for (uint32_t node = 0; node < model_error.height_unknown.size() && node < problem.nodeCount(); ++node) {
        heights_unknown = heights_unknown || (model_error.height_unknown[node] != 0 && estimate.placed[node] != 0);
    }
    out.common_excess_m = model_error.common_excess_m * unseenExcessShare(out.variance_factor, heights_unknown);
    out.room_excess_m = model_error.room_excess_m * unseenExcessShare(out.variance_factor, heights_unknown);
    // Inverse of the information: with a free gauge its null space (translations, rotation) is
    // lifted by a tiny regulariser and projected out again (the pseudo-inverse), so the result is
    // the shape's uncertainty, as a rigid fit to the truth measures it.
    const Eigen::VectorXd information_diagonal = information.diagonal();
    const double mean_diagonal = std::max(information_diagonal.sum() / static_cast<double>(size), 1e-12);
    const double regulariser = out.gauge_free ? 1e-7 * mean_diagonal : 1e-12 * mean_diagonal;
    SparseMatrix regular = information;
    for (Eigen::Index i = 0; i < size; ++i) {
        regular.coeffRef(i, i) += regulariser;
    }
    Eigen::SimplicialLDLT<SparseMatrix> solver(regular);
    if (solver.info() != Eigen::Success) {
        return out;
    }
    std::vector<uint32_t> free_nodes;
    for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
        if (number[node] >= 0) {
            free_nodes.push_back(node);
        }
    }
    // The whole inverse (the reliabilities need its off-diagonal blocks), then, with a free
    // gauge, P X P with P = I - G G^T: G spans x, y translation and the rotation about the
    // centroid (orthonormalised), the pseudo-inverse. Solved a block of columns at a time into
    // the one dense matrix (at 1000 nodes it is tens of megabytes: no identity beside it).
    Eigen::MatrixXd inverse(size, size);
    constexpr Eigen::Index kSolveColumns = 64;
    for (Eigen::Index column = 0; column < size; column += kSolveColumns) {
        const Eigen::Index count = std::min(kSolveColumns, size - column);
        inverse.middleCols(column, count) =
            solver.solve(Eigen::MatrixXd::Identity(size, size).middleCols(column, count));
    }
    Eigen::MatrixXd gauge = Eigen::MatrixXd::Zero(size, 3);
    {
        Vector2 centroid = Vector2::Zero();
        for (uint32_t node : free_nodes) {
            centroid += estimate.position_m[node];
        }
        centroid /= static_cast<double>(free_nodes.size());
        for (size_t i = 0; i < free_nodes.size(); ++i) {
            const Vector2 r = estimate.position_m[free_nodes[i]] - centroid;
            const auto row = static_cast<Eigen::Index>(2 * i);
            gauge(row, 0) = 1.0;
            gauge(row + 1, 1) = 1.0;
            gauge(row, 2) = -r.y();
            gauge(row + 1, 2) = r.x();
        }
    }
    if (out.gauge_free) {
        Eigen::HouseholderQR<Eigen::MatrixXd> qr(gauge);
        const Eigen::MatrixXd basis = qr.householderQ() * Eigen::MatrixXd::Identity(size, 3);
        const Eigen::MatrixXd xg = inverse * basis;         // X G
        const Eigen::Matrix3d gxg = basis.transpose() * xg; // G^T X G
        // P X P = X - G W^T - W G^T with W = X G - G (G^T X G) / 2: two rank-3 updates in place.
        const Eigen::MatrixXd w = xg - 0.5 * basis * gxg;
        inverse.noalias() -= basis * w.transpose();
        inverse.noalias() -= w * basis.transpose();
    }
    symmetrizeInPlace(inverse);
    // Redundancy of each link (Baarda): r = 1 - w j^T X j, the share of an error in the link that its
    // own residual shows (0: no other link checks it). Gauge-invariant.
    struct LinkJacobian {
        int na = -1;
        int nb = -1;
        int oa = -1; // offset unknowns (rows of the inverse), -1 without
        int ob = -1;
        Vector2 u = Vector2::Zero();
        double weight = 0.0;
    };
    std::vector<LinkJacobian> jacobians(problem.links.size());
    out.link_redundancy.assign(problem.links.size(), -1.0);
    // The map's response to every link reading one metre longer (X J^T W 1): what a common
    // excess does to it. Walls make links read long, and a map of links that nearly all cross a
    // wall or two reads larger by what no range can tell from a larger building. An additive
    // excess, not a relative scale: it is the short links of small rooms whose share it is largest.
    Eigen::VectorXd expansion = Eigen::VectorXd::Zero(size);
    // The map's response to every link of one node reading a metre longer (X J^T W b_n, a column
    // per placed node with links, fixed nodes included): the excess a node's links share. A node
    // in a room has the room's walls on every link that leaves it, so its links read long
    // together; where they all leave it one way (a room off a corridor, a building's edge) the map
    // absorbs that excess by moving the node outward, and the residuals show none of it.
    // One column per such node: C = X J^T W B, built a block of columns at a time where it is
    // used (excessBlocks below), never whole (size x nodes: at 1000 nodes 24 MB).
    std::vector<uint32_t> shared_nodes;
    if (out.room_excess_m > 0.0) {
        for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
            if (estimate.placed[node] != 0 && !problem.node_links[node].empty()) {
                shared_nodes.push_back(node);
            }
        }
    }
    auto effectOf = [&](const LinkJacobian &j) {
        Eigen::VectorXd effect = Eigen::VectorXd::Zero(size); // X j
        if (j.na >= 0) {
            effect += inverse.middleCols<2>(2 * j.na) * j.u;
        }
        if (j.nb >= 0) {
            effect -= inverse.middleCols<2>(2 * j.nb) * j.u;
        }
        for (const int o : {j.oa, j.ob}) {
            if (o >= 0) {
                effect += inverse.col(o);
            }
        }
        return effect;
    };
    for (uint32_t index = 0; index < problem.links.size(); ++index) {
        const MapLink &link = problem.links[index];
        if (estimate.placed[link.a] == 0 || estimate.placed[link.b] == 0) {
            continue;
        }
        LinkJacobian &j = jacobians[index];
        j.na = number[link.a];
        j.nb = number[link.b];
        j.oa = offset_number[link.a];
        j.ob = offset_number[link.b];
        const Vector2 delta = estimate.position_m[link.a] - estimate.position_m[link.b];
        const double distance = delta.norm();
        if ((j.na < 0 && j.nb < 0 && j.oa < 0 && j.ob < 0) || distance < 1e-9) {
            continue;
        }
        j.u = delta / distance;
        j.weight = likelihood.evaluate(link.range_m - distance, variance).inlier_probability / variance;
        const Eigen::VectorXd effect = effectOf(j);
        if (model_error.common_excess_m > 0.0 && j.weight > 0.0) {
            expansion.noalias() += j.weight * effect;
        }
        double leverage = 0.0;
        if (j.na >= 0) {
            leverage += j.u.dot(effect.segment<2>(2 * j.na));
        }
        if (j.nb >= 0) {
            leverage -= j.u.dot(effect.segment<2>(2 * j.nb));
        }
        for (const int o : {j.oa, j.ob}) {
            if (o >= 0) {
                leverage += effect[o];
            }
        }
        out.link_redundancy[index] = std::clamp(1.0 - j.weight * leverage, 0.0, 1.0);
    }
    // What the links' residuals say beyond the noise model. A link whose residual fails Baarda's
    // w-test (the residual over its own standard deviation, sigma sqrt(r), beyond kBiasSigmas)
    // reads off by more than its noise (a wall, an antenna delay), by about e / r (its residual
    // shows the share r of its error), and the map carries that error: the sandwich X B X with
    // B = sum w k j j^T, k = w (e / r)^2 for such a link and 1 for the others (HC3, the
    // leverage-corrected estimator of heteroskedastic least squares). The same as X where the
    // residuals fit the model, larger around the links that do not, and larger still where few
    // links check them, since there a bias hides in the position. On the scorecard's families it
    // took the converged nodes more than 1 m off from 2 to 0 (docs/results.md).
    // Kept as its terms, X plus one rank-1 term k e e^T per such link (e = X j), never as a second
    // dense matrix: only the diagonal blocks of its frame transform are needed (below).
    std::vector<std::pair<uint32_t, double>> biased_links; // link, w (k - 1)
    for (uint32_t index = 0; index < problem.links.size(); ++index) {
        const LinkJacobian &j = jacobians[index];
        if (j.weight <= 0.0 || out.link_redundancy[index] < 0.0) {
            continue;
        }
        const MapLink &link = problem.links[index];
        const double residual = link.range_m - (estimate.position_m[link.a] - estimate.position_m[link.b]).norm();
        const double redundancy = std::max(out.link_redundancy[index], kMinShownRedundancy);
        const double shown = residual / redundancy;
        const double excess = j.weight * shown * shown;
        if (j.weight * residual * residual / redundancy > kBiasSigmas * kBiasSigmas) {
            biased_links.emplace_back(index, j.weight * (excess - 1.0));
        }
    }
    // Unknown heights: link l of node i reads e_l = (z_i - z_j)^2 / 2 d_l long. With the heights
    // independent, of std s, Var e_l = 2 s^4 / d_l^2 when both heights are unknown, and two links of
    // a node share a covariance of s^4 / 2 d_l d_m. The map moves by f_l = X j_l w_l per metre of
    // e_l; per node of unknown height g_i = sum over its links of f_l / d_l, and s^4 g_i g_i^T
    // summed over the nodes is exact on each link's own variance and twice the shared part
    // (conservative), in one product: a term spread_weight G G^T of the sandwich, G one column g_i
    // per node (built a block of columns at a time, as the shared excess's).
    std::vector<uint32_t> unknown_nodes;
    double spread_weight = 0.0;
    if (model_error.height_spread_m > 0.0 && model_error.height_unknown.size() == problem.nodeCount()) {
        for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
            if (model_error.height_unknown[node] != 0 && estimate.placed[node] != 0) {
                unknown_nodes.push_back(node);
            }
        }
        if (!unknown_nodes.empty()) {
            const double spread_m2 = model_error.height_spread_m * model_error.height_spread_m;
            // A model error in m^2, not scaled by the variance factor the covariance gets below.
            spread_weight = spread_m2 * spread_m2 / std::max(out.variance_factor, 1.0);
        }
    }
    // The main part: the largest group of nodes joined by links that other links check (and
    // that are line of sight). Its placement defines the frame the covariances are given in
    // (an S-transformation): what hangs on it by weak links is uncertain relative to it, and the
    // main part is not made uncertain by what hangs on it.
    std::vector<uint32_t> group(problem.nodeCount(), UINT32_MAX);
    std::vector<uint32_t> group_size;
    for (uint32_t start : free_nodes) {
        if (group[start] != UINT32_MAX) {
            continue;
        }
        const auto id = static_cast<uint32_t>(group_size.size());
        group_size.push_back(0);
        std::vector<uint32_t> stack{start};
        group[start] = id;
        while (!stack.empty()) {
            const uint32_t node = stack.back();
            stack.pop_back();
            ++group_size[id];
            for (uint32_t link : problem.node_links[node]) {
                const uint32_t other = problem.other(link, node);
                if (group[other] == UINT32_MAX && number[other] >= 0 &&
                    out.link_redundancy[link] >= kCheckedRedundancy && jacobians[link].weight * variance > 0.5) {
                    group[other] = id;
                    stack.push_back(other);
                }
            }
        }
    }
    const auto main_group =
        static_cast<uint32_t>(std::max_element(group_size.begin(), group_size.end()) - group_size.begin());
    out.main_part.assign(problem.nodeCount(), 0);
    for (uint32_t node : free_nodes) {
        out.main_part[node] = group[node] == main_group ? 1 : 0;
    }
    const double scale = std::sqrt(out.variance_factor);
    // The frame is the main part's; then, if some of its nodes turn out to hang on weakly checked
    // links, the frame is that of its reliable core instead (twice at most), so that a wing joined
    // by a few links does not share its uncertainty with the part it hangs on.
    // The first frame: the main part's nodes none of whose links is weakly checked.
    std::vector<uint8_t> datum = out.main_part;
    {
        std::vector<uint8_t> interior = out.main_part;
        uint32_t interior_size = 0;
        for (uint32_t node : free_nodes) {
            for (uint32_t link : problem.node_links[node]) {
                if (out.link_redundancy[link] >= 0.0 && out.link_redundancy[link] < 0.1) {
                    interior[node] = 0;
                }
            }
            interior_size += interior[node];
        }
        if (interior_size >= 3) {
            datum = interior;
        }
    }
    for (int pass = 0; pass < 4; ++pass) {
        // S = I - G F with F = (G^T E G)^-1 G^T E, E selecting the datum's coordinates (S = I
        // with a fixed gauge). S is applied through its three rows F, never formed: a vector in
        // O(size), and of S X S^T only the diagonal blocks the outputs need, in O(size^2); the
        // sandwich's rank-1 terms, each through its vector.
        Eigen::MatrixXd frame_rows; // F, 3 x size
        if (out.gauge_free) {
            Eigen::MatrixXd selected = Eigen::MatrixXd::Zero(size, 3); // E G
            for (size_t i = 0; i < free_nodes.size(); ++i) {
                if (datum[free_nodes[i]] != 0) {
                    selected.middleRows<2>(static_cast<Eigen::Index>(2 * i)) =
                        gauge.middleRows<2>(static_cast<Eigen::Index>(2 * i));
                }
            }
            const Eigen::Matrix3d normal_main = gauge.transpose() * selected;
            frame_rows = normal_main.ldlt().solve(selected.transpose());
        }
        const auto inFrame = [&](const Eigen::VectorXd &v) -> Eigen::VectorXd {
            if (frame_rows.size() == 0) {
                return v;
            }
            const Eigen::Vector3d along = frame_rows * v;
            return v - gauge * along;
        };
        Eigen::MatrixXd inverse_rows;                           // F X, 3 x size
        Eigen::Matrix3d inverse_core = Eigen::Matrix3d::Zero(); // F X F^T
        if (frame_rows.size() > 0) {
            inverse_rows.noalias() = frame_rows * inverse;
            inverse_core.noalias() = inverse_rows * frame_rows.transpose();
        }
        // The diagonal blocks of S X_B S^T: (S X S^T)_ii = X_ii - G_i (F X)_i - (F X)_i^T G_i^T +
        // G_i (F X F^T) G_i^T, then each term of the sandwich through S.
        std::vector<Matrix2> blocks(free_nodes.size());
        for (size_t i = 0; i < free_nodes.size(); ++i) {
            const auto row = static_cast<Eigen::Index>(2 * i);
            blocks[i] = inverse.block<2, 2>(row, row);
            if (frame_rows.size() > 0) {
                const Eigen::Matrix<double, 2, 3> g = gauge.middleRows<2>(row);
                const Eigen::Matrix<double, 3, 2> rows = inverse_rows.middleCols<2>(row);
                const Matrix2 mixed = g * rows;
                blocks[i] += g * inverse_core * g.transpose() - mixed - mixed.transpose();
            }
        }
        for (const auto &[index, term] : biased_links) {
            const Eigen::VectorXd effect = inFrame(effectOf(jacobians[index]));
            for (size_t i = 0; i < free_nodes.size(); ++i) {
                const auto row = static_cast<Eigen::Index>(2 * i);
                blocks[i].noalias() += term * effect.segment<2>(row) * effect.segment<2>(row).transpose();
            }
        }
        // Of columns C, one per node n of `nodes` (column n: the sum over the node's links l of
        // coefficient(l) X j_l), in the frame's terms S C = C - G (F C), the diagonal block of
        // each free node of (S C)(S C)^T, summed a block of columns at a time: C is never whole.
        // Its columns are built again in each pass (two effects per link, O(links x size), small
        // beside the pass's O(size^2)): memory traded for work that does not show (docs/bench.md).
        const auto excessBlocks = [&](const std::vector<uint32_t> &nodes, const auto &coefficient) {
            std::vector<Matrix2> outer(free_nodes.size());
            for (Matrix2 &block : outer) {
                block.setZero(); // element by element: see out.covariance_m2 above (GCC 12 at -O1)
            }
            Eigen::MatrixXd columns;
            Eigen::MatrixXd along;
            const auto node_count = static_cast<Eigen::Index>(nodes.size());
            for (Eigen::Index first = 0; first < node_count; first += kSolveColumns) {
                const Eigen::Index count = std::min(kSolveColumns, node_count - first);
                columns.setZero(size, count);
                for (Eigen::Index k = 0; k < count; ++k) {
                    for (const uint32_t link : problem.node_links[nodes[static_cast<size_t>(first + k)]]) {
                        const double c = coefficient(link);
                        if (c != 0.0) {
                            columns.col(k).noalias() += c * effectOf(jacobians[link]);
                        }
                    }
                }
                if (frame_rows.size() > 0) {
                    along.noalias() = frame_rows * columns;
                }
                for (size_t i = 0; i < free_nodes.size(); ++i) {
                    const auto row = static_cast<Eigen::Index>(2 * i);
                    Eigen::Matrix<double, 2, Eigen::Dynamic> rows = columns.middleRows<2>(row);
                    if (frame_rows.size() > 0) {
                        const Eigen::Matrix<double, 2, 3> g = gauge.middleRows<2>(row);
                        rows.noalias() -= g * along;
                    }
                    outer[i].noalias() += rows * rows.transpose();
                }
            }
            return outer;
        };
        if (spread_weight > 0.0) {
            // Each link of a node of unknown height moves the map by its effect per metre over its length.
            const std::vector<Matrix2> spread = excessBlocks(unknown_nodes, [&](uint32_t link) {
                const LinkJacobian &j = jacobians[link];
                if (j.weight <= 0.0 || out.link_redundancy[link] < 0.0) {
                    return 0.0;
                }
                return j.weight /
                       (estimate.position_m[problem.links[link].a] - estimate.position_m[problem.links[link].b]).norm();
            });
            for (size_t i = 0; i < free_nodes.size(); ++i) {
                blocks[i] += spread_weight * spread[i];
            }
        }
        // Model errors in m: in the frame's terms (S), not scaled by the variance factor.
        const double unscaled = 1.0 / std::max(out.variance_factor, 1.0);
        Eigen::VectorXd expanded; // S X J^T W 1: the common excess in the frame's terms
        if (out.common_excess_m > 0.0) {
            expanded = inFrame(expansion);
        }
        // S X J^T W B: the nodes' shared excesses in the frame's terms, each node's excess
        // independent of the others': the sum over the nodes of their effects' outer products,
        // only the diagonal blocks kept.
        const std::vector<Matrix2> shared_blocks =
            excessBlocks(shared_nodes, [&](uint32_t link) { return std::max(jacobians[link].weight, 0.0); });
        const double room_m2 = out.room_excess_m * out.room_excess_m * unscaled;
        for (size_t i = 0; i < free_nodes.size(); ++i) {
            const auto row = static_cast<Eigen::Index>(2 * i);
            Matrix2 block = blocks[i];
            if (expanded.size() > 0) {
                block += out.common_excess_m * out.common_excess_m * unscaled * expanded.segment<2>(row) *
                         expanded.segment<2>(row).transpose();
            }
            Matrix2 shared = Matrix2::Zero();
            if (!shared_nodes.empty()) {
                shared = room_m2 * shared_blocks[i];
                block += shared;
            }
            out.shared_excess_m2[free_nodes[i]] = out.variance_factor * 0.5 * (shared + shared.transpose());
            out.covariance_m2[free_nodes[i]] = out.variance_factor * 0.5 * (block + block.transpose());
        }
        // Reliability: the largest error in one link that could go unnoticed, delta0 sigma / sqrt(r),
        // and what it would do to every node (S X j w error).
        out.reliability_m.assign(problem.nodeCount(), 0.0);
        for (uint32_t index = 0; index < problem.links.size(); ++index) {
            const LinkJacobian &j = jacobians[index];
            if (j.weight <= 0.0 || out.link_redundancy[index] < 0.0) {
                continue;
            }
            const Eigen::VectorXd effect = inFrame(effectOf(j));
            const double checked = out.link_redundancy[index];
            // A link nothing checks: its possible error is bounded by nothing but the floor.
            const double blunder_times_weight =
                kReliabilityDelta * scale * std::sqrt(j.weight) / std::sqrt(std::max(checked, 1e-6));
            for (size_t i = 0; i < free_nodes.size(); ++i) {
                const double moved = blunder_times_weight * effect.segment<2>(static_cast<Eigen::Index>(2 * i)).norm();
                out.reliability_m[free_nodes[i]] = std::max(out.reliability_m[free_nodes[i]], moved);
            }
        }
        if (!out.gauge_free) {
            break;
        }
        std::vector<uint8_t> core(problem.nodeCount(), 0);
        uint32_t core_size = 0;
        for (uint32_t node : free_nodes) {
            if (datum[node] != 0 && out.reliability_m[node] < kReliableCoreM) {
                core[node] = 1;
                ++core_size;
            }
        }
        if (core_size < 3 || core == datum || pass == 3) {
            break;
        }
        datum = core;
    }
    return out;
}

} // namespace cdro::engine
