#include "cdro/engine/moving_calibration.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <map>
#include <optional>
#include <stdexcept>
#include <string>

#include <Eigen/Eigenvalues>
#include <Eigen/SparseCholesky>
#include <Eigen/SparseCore>

#include "cdro/engine/range_model.hpp"

namespace cdro::engine {

namespace {

constexpr uint8_t kFree = 0;
constexpr uint8_t kHeightHeld = 1; // an anchor of known height: x, y free
constexpr uint8_t kHeld = 2;       // not moved at all

struct RangeTerm {
    uint32_t i = 0;
    uint32_t j = 0;
    double range_m = 0.0; // m
};

struct PriorTerm {
    uint32_t i = 0;       // earlier
    uint32_t j = 0;       // later
    double sigma_m = 0.0; // m, per axis
};

// Points in 3D (some with z held: an anchor of known height), ranges between them (Huber loss) and
// linear ties between pairs (Gaussian), solved by Levenberg-Marquardt.
struct Problem {
    std::vector<Vector3> points_m;
    std::vector<uint8_t> held; // per point: kFree, kHeightHeld, kHeld
    std::vector<RangeTerm> ranges;
    std::vector<PriorTerm> priors;
};

class LeastSquares {
public:
    LeastSquares(Problem &problem, double sigma_m, double huber_sigmas)
        : problem_(problem), sigma_m_(sigma_m), k_(huber_sigmas)
    {
        offset_.reserve(problem_.points_m.size());
        for (size_t i = 0; i < problem_.points_m.size(); ++i) {
            offset_.push_back(size_);
            size_ += problem_.held[i] == kFree ? 3 : problem_.held[i] == kHeightHeld ? 2 : 0;
        }
    }

    double cost(const std::vector<Vector3> &points_m) const
    {
        double total = 0.0;
        for (const RangeTerm &r : problem_.ranges) {
            const double z = std::abs(r.range_m - predictRange(points_m[r.i], points_m[r.j]).range_m) / sigma_m_;
            total += z <= k_ ? 0.5 * z * z : k_ * z - 0.5 * k_ * k_;
        }
        for (const PriorTerm &p : problem_.priors) {
            total += 0.5 * (points_m[p.j] - points_m[p.i]).squaredNorm() / (p.sigma_m * p.sigma_m);
        }
        return total;
    }

    // Returns the iterations taken.
    uint32_t solve(uint32_t max_iterations)
    {
        double lambda = 1e-3;
        double current = cost(problem_.points_m);
        uint32_t iteration = 0;
        for (; iteration < max_iterations; ++iteration) {
            Eigen::SparseMatrix<double> h;
            Eigen::VectorXd g;
            normalEquations(h, g);
            bool accepted = false;
            double step_m = 0.0;
            for (int attempt = 0; attempt < 12 && !accepted; ++attempt) {
                Eigen::SparseMatrix<double> a = h;
                for (Eigen::Index k = 0; k < size_; ++k) {
                    a.coeffRef(k, k) += lambda * (h.coeff(k, k) + 1e-6);
                }
                Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> solver(a);
                if (solver.info() != Eigen::Success) {
                    lambda *= 10.0;
                    continue;
                }
                const Eigen::VectorXd delta = solver.solve(-g);
                std::vector<Vector3> trial = problem_.points_m;
                apply(delta, trial);
                const double trial_cost = cost(trial);
                if (std::isfinite(trial_cost) && trial_cost < current) {
                    const double decrease = current - trial_cost;
                    problem_.points_m = std::move(trial);
                    current = trial_cost;
                    lambda = std::max(lambda / 3.0, 1e-9);
                    accepted = true;
                    step_m = delta.cwiseAbs().maxCoeff();
                    if (decrease < 1e-10 * (current + decrease)) {
                        step_m = 0.0; // converged: the cost no longer moves
                    }
                } else {
                    lambda *= 4.0;
                }
            }
            if (!accepted || step_m < 1e-7) {
                return iteration + (accepted ? 1U : 0U);
            }
        }
        return iteration;
    }

private:
    // The parameters of point i along axis (-1 when held).
    Eigen::Index parameter(uint32_t i, int axis) const
    {
        if (problem_.held[i] == kHeld || (axis == 2 && problem_.held[i] == kHeightHeld)) {
            return -1;
        }
        return offset_[i] + axis;
    }

    void apply(const Eigen::VectorXd &delta, std::vector<Vector3> &points_m) const
    {
        for (uint32_t i = 0; i < points_m.size(); ++i) {
            for (int axis = 0; axis < 3; ++axis) {
                const Eigen::Index p = parameter(i, axis);
                if (p >= 0) {
                    points_m[i](axis) += delta(p);
                }
            }
        }
    }

    // Gauss-Newton's H = J^T W J and g = J^T W e, the Huber loss as iteratively reweighted squares.
    void normalEquations(Eigen::SparseMatrix<double> &h, Eigen::VectorXd &g) const
    {
        std::vector<Eigen::Triplet<double>> triplets;
        triplets.reserve(problem_.ranges.size() * 36 + problem_.priors.size() * 12 + static_cast<size_t>(size_));
        g = Eigen::VectorXd::Zero(size_);
        for (Eigen::Index k = 0; k < size_; ++k) {
            triplets.emplace_back(k, k, 0.0); // the diagonal is in the pattern
        }
        const std::vector<Vector3> &p = problem_.points_m;
        for (const RangeTerm &r : problem_.ranges) {
            const RangePrediction3 prediction = predictRange(p[r.i], p[r.j]);
            const Eigen::RowVector3d unit = prediction.jacobian_point;
            const double e = (r.range_m - prediction.range_m) / sigma_m_;
            const double weight = std::abs(e) <= k_ ? 1.0 : k_ / std::abs(e);
            // de/dp_i = -unit / sigma, de/dp_j = +unit / sigma
            std::array<std::pair<Eigen::Index, double>, 6> jacobian{};
            size_t count = 0;
            for (int axis = 0; axis < 3; ++axis) {
                const Eigen::Index pi = parameter(r.i, axis);
                const Eigen::Index pj = parameter(r.j, axis);
                if (pi >= 0) {
                    jacobian[count++] = {pi, -unit(axis) / sigma_m_};
                }
                if (pj >= 0) {
                    jacobian[count++] = {pj, unit(axis) / sigma_m_};
                }
            }
            for (size_t x = 0; x < count; ++x) {
                g(jacobian[x].first) += weight * jacobian[x].second * e;
                for (size_t y = 0; y < count; ++y) {
                    triplets.emplace_back(jacobian[x].first, jacobian[y].first,
                                          weight * jacobian[x].second * jacobian[y].second);
                }
            }
        }
        for (const PriorTerm &prior : problem_.priors) {
            const double w = 1.0 / (prior.sigma_m * prior.sigma_m);
            for (int axis = 0; axis < 3; ++axis) {
                const Eigen::Index pi = parameter(prior.i, axis);
                const Eigen::Index pj = parameter(prior.j, axis);
                const double e = p[prior.j](axis) - p[prior.i](axis); // times 1 / sigma, in w
                if (pi >= 0) {
                    g(pi) -= w * e;
                    triplets.emplace_back(pi, pi, w);
                }
                if (pj >= 0) {
                    g(pj) += w * e;
                    triplets.emplace_back(pj, pj, w);
                }
                if (pi >= 0 && pj >= 0) {
                    triplets.emplace_back(pi, pj, -w);
                    triplets.emplace_back(pj, pi, -w);
                }
            }
        }
        h.resize(size_, size_);
        h.setFromTriplets(triplets.begin(), triplets.end());
    }

    Problem &problem_;
    double sigma_m_;
    double k_;
    std::vector<Eigen::Index> offset_;
    Eigen::Index size_ = 0;
};

double median(std::vector<double> values)
{
    std::sort(values.begin(), values.end());
    const size_t n = values.size();
    return n % 2 == 1 ? values[n / 2] : 0.5 * (values[n / 2 - 1] + values[n / 2]);
}

// The variance (m^2, per axis) of the position's increment over dt_s when each velocity component
// is a stationary Ornstein-Uhlenbeck process (sigma s_mps, correlation time tau_s).
double incrementVariance(double dt_s, double s_mps, double tau_s)
{
    const double x = dt_s / tau_s;
    // x - 1 + e^-x, by its series where its terms cancel
    const double shape = x > 1e-3 ? x - 1.0 + std::exp(-x) : x * x / 2.0 - x * x * x / 6.0;
    return 2.0 * s_mps * s_mps * tau_s * tau_s * shape;
}

constexpr uint32_t kNoPoint = 0xFFFFFFFFU;
constexpr double kStartBelowM = 1.0; // m, a tag starts this far below the anchors' plane (it flies under them)

// One initialisation's outcome.
struct Attempt {
    double cost = 0.0; // the batch's robust cost at its end (dimensionless)
    uint32_t static_iterations = 0;
    uint32_t batch_iterations = 0;
    uint64_t outliers = 0;
    double rms_residual_m = 0.0; // m
    std::vector<Vector3> anchors_m;
    std::vector<CalibratedEpoch> epochs;
};

// Classical MDS: points (rows, `dims` columns) whose distances best match d (symmetric, m), from
// the double-centred squared distances' largest eigenvalues.
Eigen::MatrixXd classicalMds(const Eigen::MatrixXd &d, int dims)
{
    const Eigen::Index m = d.rows();
    Eigen::MatrixXd b = d.array().square().matrix();
    const Eigen::VectorXd row_mean = b.rowwise().mean();
    const double all_mean = row_mean.mean();
    for (Eigen::Index i = 0; i < m; ++i) {
        for (Eigen::Index j = 0; j < m; ++j) {
            b(i, j) = -0.5 * (b(i, j) - row_mean(i) - row_mean(j) + all_mean);
        }
    }
    const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eigen(b);
    Eigen::MatrixXd x = Eigen::MatrixXd::Zero(m, dims);
    for (int axis = 0; axis < dims && axis < m; ++axis) {
        const Eigen::Index k = m - 1 - axis;
        x.col(axis) = eigen.eigenvectors().col(k) * std::sqrt(std::max(eigen.eigenvalues()(k), 0.0));
    }
    return x;
}

} // namespace

MovingCalibration::MovingCalibration(const MovingCalibrationParams &params, const MotionParams &motion)
    : params_(params), motion_(motion)
{
}

std::vector<CalibratedAnchor> MovingCalibration::solve(const std::vector<CalibrationRange> &ranges,
                                                       const std::vector<NodeId> &moving,
                                                       const std::vector<std::pair<NodeId, double>> &heights)
{
    counters_ = MovingCalibrationCounters{};
    epochs_.clear();
    const auto tagIndex = [&moving](NodeId id) {
        const auto it = std::find(moving.begin(), moving.end(), id);
        return it == moving.end() ? -1 : static_cast<int>(it - moving.begin());
    };
    // The usable ranges, the anchors (in id order) and the first time.
    std::vector<CalibrationRange> used;
    std::vector<NodeId> anchor_ids;
    double t0_s = std::numeric_limits<double>::infinity();
    for (const CalibrationRange &r : ranges) {
        const int ta = tagIndex(r.a);
        const int tb = tagIndex(r.b);
        if ((ta < 0 && tb < 0) || r.a == r.b || !std::isfinite(r.range_m) || !(r.range_m > 0.0) ||
            !std::isfinite(r.t_s)) {
            ++counters_.ignored;
            continue;
        }
        used.push_back(r);
        if (ta < 0) {
            std::swap(used.back().a, used.back().b); // a is a tag
        }
        if (ta < 0 || tb < 0) {
            anchor_ids.push_back(used.back().b);
        }
        t0_s = std::min(t0_s, r.t_s);
    }
    std::sort(anchor_ids.begin(), anchor_ids.end());
    anchor_ids.erase(std::unique(anchor_ids.begin(), anchor_ids.end()), anchor_ids.end());
    counters_.ranges = used.size();
    if (anchor_ids.size() < 4) {
        throw std::invalid_argument("calibrating anchors from moving nodes needs at least 4 static anchors ranged by "
                                    "them; the ranges have " +
                                    std::to_string(anchor_ids.size()));
    }
    for (const NodeId tag : moving) {
        if (std::none_of(used.begin(), used.end(),
                         [tag](const CalibrationRange &r) { return r.a == tag || r.b == tag; })) {
            throw std::invalid_argument("moving node " + std::to_string(tag) + " has no usable range");
        }
    }
    const uint32_t anchors = static_cast<uint32_t>(anchor_ids.size());
    const auto anchorIndex = [&anchor_ids](NodeId id) {
        return static_cast<uint32_t>(std::lower_bound(anchor_ids.begin(), anchor_ids.end(), id) - anchor_ids.begin());
    };
    std::vector<std::optional<double>> height(anchors);
    double height_sum_m = 0.0;
    size_t heights_known = 0;
    for (const auto &[id, z_m] : heights) {
        const uint32_t i = anchorIndex(id);
        if (i < anchors && anchor_ids[i] == id && std::isfinite(z_m)) {
            height[i] = z_m;
            height_sum_m += z_m;
            ++heights_known;
        }
    }
    const double plane_m =
        heights_known > 0 ? height_sum_m / static_cast<double>(heights_known) : params_.unknown_plane_height_m;

    // 1. Virtual static nodes: (tag, window) -> graph node (after the anchors).
    std::map<std::pair<int, int64_t>, uint32_t> windows;
    const auto windowOf = [&](NodeId tag, double t_s) {
        return std::make_pair(tagIndex(tag), static_cast<int64_t>(std::floor((t_s - t0_s) / params_.window_s)));
    };
    for (const CalibrationRange &r : used) {
        for (const NodeId end : {r.a, r.b}) {
            if (tagIndex(end) >= 0) {
                windows.emplace(windowOf(end, r.t_s), 0U);
            }
        }
    }
    uint32_t next = anchors;
    for (auto &entry : windows) {
        entry.second = next++;
    }
    const uint32_t nodes = next;
    counters_.windows = nodes - anchors;
    const auto graphNode = [&](NodeId id, double t_s) {
        return tagIndex(id) >= 0 ? windows.at(windowOf(id, t_s)) : anchorIndex(id);
    };
    std::map<std::pair<uint32_t, uint32_t>, std::vector<double>> edges;
    for (const CalibrationRange &r : used) {
        const uint32_t u = graphNode(r.a, r.t_s);
        const uint32_t v = graphNode(r.b, r.t_s);
        if (u != v) {
            edges[{std::min(u, v), std::max(u, v)}].push_back(r.range_m);
        }
    }

    // 2. Shortest paths (Floyd-Warshall), classical MDS of the nodes connected to the anchors.
    const double inf = std::numeric_limits<double>::infinity();
    Eigen::MatrixXd dist = Eigen::MatrixXd::Constant(nodes, nodes, inf);
    dist.diagonal().setZero();
    for (const auto &[pair, values] : edges) {
        const double d = median(values);
        dist(pair.first, pair.second) = std::min(dist(pair.first, pair.second), d);
        dist(pair.second, pair.first) = dist(pair.first, pair.second);
    }
    for (Eigen::Index k = 0; k < nodes; ++k) {
        for (Eigen::Index i = 0; i < nodes; ++i) {
            const double dik = dist(i, k);
            if (dik == inf) {
                continue;
            }
            for (Eigen::Index j = 0; j < nodes; ++j) {
                dist(i, j) = std::min(dist(i, j), dik + dist(k, j));
            }
        }
    }
    std::vector<uint32_t> connected;
    for (uint32_t i = 0; i < nodes; ++i) {
        if (dist(0, i) < inf) {
            connected.push_back(i);
        }
    }
    for (uint32_t i = 0; i < anchors; ++i) {
        if (!(dist(0, i) < inf)) {
            throw std::invalid_argument("anchors " + std::to_string(anchor_ids[0]) + " and " +
                                        std::to_string(anchor_ids[i]) +
                                        " are not connected by the moving nodes' ranges: no common frame");
        }
    }
    // Two initialisations, each refined and solved; the one whose batch ends at the lower robust
    // cost is kept (a shortest path through a window overstates a distance, and which of the two
    // suffers less depends on where the tags flew).
    using Placement = std::vector<std::optional<Vector3>>;
    // The static network (anchors and placed windows, every range a residual) refined; the
    // anchors held as `anchor_hold` says (kHeld, or kHeightHeld: only a known height). Returns
    // the iterations.
    const auto refineNetwork = [&](Placement &placed, uint8_t anchor_hold) {
        Problem network;
        std::vector<uint32_t> point_of(nodes, kNoPoint);
        for (uint32_t i = 0; i < nodes; ++i) {
            if (placed[i]) {
                point_of[i] = static_cast<uint32_t>(network.points_m.size());
                network.points_m.push_back(*placed[i]);
                // `height` is the anchors' only: a window's node is always free.
                const bool anchor = i < anchors;
                network.held.push_back(anchor && (anchor_hold == kHeld || height[i]) ? anchor_hold : kFree);
            }
        }
        for (const CalibrationRange &r : used) {
            const uint32_t u = point_of[graphNode(r.a, r.t_s)];
            const uint32_t v = point_of[graphNode(r.b, r.t_s)];
            if (u != kNoPoint && v != kNoPoint && u != v) {
                network.ranges.push_back({u, v, r.range_m});
            }
        }
        const uint32_t iterations =
            LeastSquares(network, params_.range_sigma_m, params_.huber_sigmas).solve(params_.max_iterations);
        for (uint32_t i = 0; i < nodes; ++i) {
            if (placed[i]) {
                placed[i] = network.points_m[point_of[i]];
            }
        }
        return iterations;
    };
    // The tags' range times, per tag, sorted and unique.
    std::vector<std::vector<double>> times(moving.size());
    for (const CalibrationRange &r : used) {
        for (const NodeId end : {r.a, r.b}) {
            const int t = tagIndex(end);
            if (t >= 0) {
                times[static_cast<size_t>(t)].push_back(r.t_s);
            }
        }
    }
    for (std::vector<double> &list : times) {
        std::sort(list.begin(), list.end());
        list.erase(std::unique(list.begin(), list.end()), list.end());
    }
    // 3. The batch from one placement: anchors and every epoch of every tag.
    const auto batchSolve = [&](const Placement &placed) {
        Problem batch;
        Vector3 fallback_m = Vector3::Zero();
        for (uint32_t i = 0; i < anchors; ++i) {
            batch.points_m.push_back(*placed[i]);
            batch.held.push_back(height[i] ? kHeightHeld : kFree);
            fallback_m += *placed[i] / static_cast<double>(anchors);
        }
        fallback_m.z() = plane_m - kStartBelowM;
        std::vector<uint32_t> first_point(moving.size(), 0);
        for (size_t t = 0; t < moving.size(); ++t) {
            const std::vector<double> &list = times[t];
            first_point[t] = static_cast<uint32_t>(batch.points_m.size());
            for (size_t k = 0; k < list.size(); ++k) {
                // From its window, or the nearest placed window of the same tag, or below the anchors.
                const auto own = windowOf(moving[t], list[k]);
                std::optional<Vector3> start;
                int64_t best_gap = std::numeric_limits<int64_t>::max();
                for (auto it = windows.lower_bound({own.first, std::numeric_limits<int64_t>::min()});
                     it != windows.end() && it->first.first == own.first; ++it) {
                    const int64_t gap = std::abs(it->first.second - own.second);
                    if (placed[it->second] && gap < best_gap) {
                        best_gap = gap;
                        start = placed[it->second];
                    }
                }
                batch.points_m.push_back(start ? *start : fallback_m);
                batch.held.push_back(kFree);
                if (k > 0) {
                    const double variance = incrementVariance(list[k] - list[k - 1], motion_.flight_speed_sigma_mps,
                                                              motion_.flight_speed_tau_s);
                    const uint32_t j = static_cast<uint32_t>(batch.points_m.size() - 1);
                    batch.priors.push_back({j - 1, j, std::max(std::sqrt(variance), params_.min_prior_sigma_m)});
                }
            }
        }
        const auto epochPoint = [&](NodeId id, double t_s) {
            const int t = tagIndex(id);
            if (t < 0) {
                return anchorIndex(id);
            }
            const std::vector<double> &list = times[static_cast<size_t>(t)];
            return first_point[static_cast<size_t>(t)] +
                   static_cast<uint32_t>(std::lower_bound(list.begin(), list.end(), t_s) - list.begin());
        };
        for (const CalibrationRange &r : used) {
            batch.ranges.push_back({epochPoint(r.a, r.t_s), epochPoint(r.b, r.t_s), r.range_m});
        }
        LeastSquares solver(batch, params_.range_sigma_m, params_.huber_sigmas);
        Attempt attempt;
        attempt.batch_iterations = solver.solve(params_.max_iterations);
        attempt.cost = solver.cost(batch.points_m);
        double sum_m2 = 0.0;
        for (const RangeTerm &r : batch.ranges) {
            const double e = r.range_m - predictRange(batch.points_m[r.i], batch.points_m[r.j]).range_m;
            sum_m2 += e * e;
            attempt.outliers += std::abs(e) > params_.huber_sigmas * params_.range_sigma_m ? 1U : 0U;
        }
        attempt.rms_residual_m =
            batch.ranges.empty() ? 0.0 : std::sqrt(sum_m2 / static_cast<double>(batch.ranges.size()));
        attempt.anchors_m.assign(batch.points_m.begin(), batch.points_m.begin() + anchors);
        for (size_t t = 0; t < moving.size(); ++t) {
            for (size_t k = 0; k < times[t].size(); ++k) {
                attempt.epochs.push_back({moving[t], times[t][k], batch.points_m[first_point[t] + k]});
            }
        }
        return attempt;
    };

    const auto fold = [&](Placement &placed) {
        // The windows below the anchors' plane: the mirror image fits the ranges as well.
        for (uint32_t i = anchors; i < nodes; ++i) {
            if (placed[i] && placed[i]->z() > plane_m) {
                placed[i]->z() = 2.0 * plane_m - placed[i]->z();
            }
        }
    };
    // (a) MDS-MAP: classical MDS of every node connected to the anchors, in 3D; the anchors'
    // best-fit plane made horizontal at plane_m, its normal turned so that the windows lie below.
    Placement all_nodes(nodes);
    {
        Eigen::MatrixXd d(connected.size(), connected.size());
        for (size_t i = 0; i < connected.size(); ++i) {
            for (size_t j = 0; j < connected.size(); ++j) {
                d(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(j)) = dist(connected[i], connected[j]);
            }
        }
        const Eigen::MatrixXd x = classicalMds(d, 3);
        for (size_t i = 0; i < connected.size(); ++i) {
            all_nodes[connected[i]] = x.row(static_cast<Eigen::Index>(i)).transpose();
        }
        Vector3 centre = Vector3::Zero();
        for (uint32_t i = 0; i < anchors; ++i) {
            centre += *all_nodes[i];
        }
        centre /= static_cast<double>(anchors);
        Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
        for (uint32_t i = 0; i < anchors; ++i) {
            scatter += (*all_nodes[i] - centre) * (*all_nodes[i] - centre).transpose();
        }
        const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> plane(scatter);
        Vector3 normal = plane.eigenvectors().col(0);
        double below = 0.0;
        for (uint32_t i = anchors; i < nodes; ++i) {
            if (all_nodes[i]) {
                below += (*all_nodes[i] - centre).dot(normal);
            }
        }
        if (below > 0.0) {
            normal = -normal;
        }
        const Vector3 e1 = plane.eigenvectors().col(2);
        const Vector3 e2 = plane.eigenvectors().col(1);
        for (uint32_t i = 0; i < nodes; ++i) {
            if (all_nodes[i]) {
                const Vector3 v = *all_nodes[i] - centre;
                all_nodes[i] = Vector3(v.dot(e1), v.dot(e2), plane_m + v.dot(normal));
            }
        }
        for (uint32_t i = 0; i < anchors; ++i) {
            if (height[i]) {
                all_nodes[i]->z() = *height[i];
            }
        }
        fold(all_nodes);
    }
    // (b) classical MDS of the anchors alone (their shortest-path distances, made horizontal when
    // both heights are known), the windows then placed from them by least squares (the anchors
    // held), started under the anchors they heard.
    Placement anchors_first(nodes);
    {
        Eigen::MatrixXd d(anchors, anchors);
        bool planar = true;
        for (uint32_t i = 0; i < anchors; ++i) {
            planar = planar && height[i].has_value();
        }
        for (uint32_t i = 0; i < anchors; ++i) {
            for (uint32_t j = 0; j < anchors; ++j) {
                bool clamped = false; // a range shorter than the height difference projects to 0
                d(i, j) = projectRange(dist(i, j), planar ? *height[i] - *height[j] : 0.0, &clamped);
            }
        }
        const Eigen::MatrixXd x = classicalMds(d, planar ? 2 : 3);
        for (uint32_t i = 0; i < anchors; ++i) {
            const double z = planar ? *height[i] : plane_m + x(i, 2);
            anchors_first[i] = Vector3(x(i, 0), x(i, 1), height[i] ? *height[i] : z);
        }
        std::vector<Vector3> sum(nodes, Vector3::Zero());
        std::vector<uint32_t> count(nodes, 0);
        Vector3 centre = Vector3::Zero();
        for (uint32_t i = 0; i < anchors; ++i) {
            centre += *anchors_first[i] / static_cast<double>(anchors);
        }
        for (const auto &[pair, values] : edges) {
            if (pair.first < anchors && pair.second >= anchors) {
                sum[pair.second] += *anchors_first[pair.first];
                ++count[pair.second];
            }
        }
        for (uint32_t i = anchors; i < nodes; ++i) {
            if (all_nodes[i]) {
                const Vector3 heard = count[i] > 0 ? Vector3(sum[i] / static_cast<double>(count[i])) : centre;
                anchors_first[i] = Vector3(heard.x(), heard.y(), plane_m - kStartBelowM);
            }
        }
        refineNetwork(anchors_first, kHeld);
        fold(anchors_first);
    }

    bool have_best = false;
    Attempt best;
    for (Placement *placed : {&all_nodes, &anchors_first}) {
        const uint32_t static_iterations = refineNetwork(*placed, kHeightHeld);
        fold(*placed);
        Attempt attempt = batchSolve(*placed);
        attempt.static_iterations = static_iterations;
        if (!have_best || attempt.cost < best.cost) {
            best = std::move(attempt);
            have_best = true;
        }
    }
    counters_.windows_placed = static_cast<uint64_t>(connected.size()) - anchors;
    counters_.static_iterations = best.static_iterations;
    counters_.batch_iterations = best.batch_iterations;
    counters_.epochs = best.epochs.size();
    counters_.outliers = best.outliers;
    counters_.rms_residual_m = best.rms_residual_m;
    epochs_ = best.epochs;
    std::vector<CalibratedAnchor> out;
    for (uint32_t i = 0; i < anchors; ++i) {
        out.push_back({anchor_ids[i], best.anchors_m[i], height[i].has_value()});
    }
    return out;
}

} // namespace cdro::engine
