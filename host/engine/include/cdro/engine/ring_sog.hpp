// ring_sog.hpp: SoG_ij, the sum of Gaussians that describes node j's position as seen from
// node i: a ring of N Gaussians of radius r_ij around i's estimate (paper eq. 5-7), updated
// by EKF with the ranges of the link (eq. 8's "standard EKF"), weighted by what the other
// nodes measured (eq. 8-11), and re-spread around its best component by weight transfer
// (eq. 15).
//
// Weight bookkeeping is explicit, as in PX4's EKF-GSF: weights are kept normalised (sum 1);
// after every change a floor is applied and the weights normalised again, so that a mode that
// has lost can come back when the evidence turns; if only floor-level weights support the new
// evidence (the ring sits on a wrong mode), the ring is reset to the evidence alone and the
// reset counted. Likelihoods are multiplied relative to their largest value, so that many
// agreeing neighbours cannot underflow a ring.
//
// Active set: once the weights have concentrated (after a weight transfer, all but a handful of
// components sit at the floor), updating the floor-level components changes nothing that
// matters until the evidence turns. An update can therefore be limited to the components
// whose weight is at least kActiveRatio of the heaviest; the caller asks for a full update
// (every component) regularly, which is when a better mode elsewhere on the ring is found and
// a collapse detected. Full updates on every range are the paper's filter exactly.
//
// The ring is relative to its centre: when the centre's estimate moves, the ring moves with
// it (translate(), O(1): the means are stored relative to an offset). Its weighted moments
// are cached, so that merging the rings that describe a node costs O(rings), not O(components).
//
// The movement stage's beacons are rings too (movement.hpp): a node ranged from the robot's
// path. Their ranges carry the radios' calibration (scale, offset and the height difference of
// range_model.hpp: RangeTerms), come from a centre that moves, so each range also weighs the
// components by how well they predicted it (RingUpdateRule::weigh_by), and what has lost is
// dropped (prune()) rather than kept at a floor. Their means are absolute
// (setAbsoluteComponents()), so that a checkpoint holds them exactly.
#pragma once

#include <cstdint>
#include <limits>
#include <vector>

#include "cdro/engine/range_likelihood.hpp"
#include "cdro/engine/types.hpp"

namespace cdro::engine {

struct RingSogParams {
    double arc_spacing_m = 1.0;      // m, largest distance between neighbouring means (MRPT d_max)
    uint32_t min_components = 30;    // N is at least this (small rings still cover the circle)
    uint32_t max_components = 720;   // and at most this (bounds memory and time on long links)
    double tangential_overlap = 2.5; // c: sigma_t = arc spacing / c, so neighbours overlap
    double radial_sigma_m = 0.10;    // m, sigma_s of a new component (the range noise)
    // m, sigma_t at least this: a ring of radius ~0 (a range shorter than the height difference)
    // still spreads along its circle (stage 1: sigma_s; the beacons: eq. 7 alone, 0)
    double min_tangential_sigma_m = 0.10;
    double weight_floor = 1e-6; // smallest weight a component keeps, 0..1/N
};

// One Gaussian of the ring.
struct SogComponentState {
    Vector2 mean_m = Vector2::Zero();        // m
    Matrix2 covariance_m2 = Matrix2::Zero(); // m^2
    double weight = 0.0;                     // normalised within the ring
};

// The terms of the range model besides the two points (range_model.hpp): stage 1's rings use
// none (h = |m - c|).
struct RangeTerms {
    double height_difference_m = 0.0; // m, dz
    double scale = 1.0;               // s
    double offset_m = 0.0;            // m, b
};

// What an update does besides the EKF step of each component.
struct RingUpdateRule {
    double gate_sigma = std::numeric_limits<double>::infinity(); // beyond this many sigma: left alone
    double process_noise_m2 = 0.0;                               // m^2, added to each covariance first
    bool full = true;                                            // every component, else the active set
    // When set (with full updates: a partial one would weigh only the active set), each
    // component's weight is also multiplied by the likelihood of the range it predicted
    // (normalised with the floor, never reset): a ring whose centre moves.
    const RangeLikelihood *weigh_by = nullptr;
};

struct RangeUpdateResult {
    uint32_t updated = 0; // components that took the range
    uint32_t gated = 0;   // components whose innovation was beyond the gate (not updated)
};

// Another node that ranged to the ring's target: where it is, how sure, and the range (m).
struct RangeWitness {
    Vector2 position_m = Vector2::Zero();
    Matrix2 covariance_m2 = Matrix2::Zero();
    double range_m = 0.0;
};

struct WeightUpdateResult {
    bool collapsed = false;    // reset to the evidence alone
    uint32_t downweighted = 0; // witnesses that read NLOS at the ring's best component
};

class RingSog {
public:
    RingSog() = default;

    // Eq. 5-7: N = max(min, min(max, floor(2 pi r / arc_spacing) + 1)) components on the circle
    // of radius range_m around center_m, radial std sigma_s, tangential std
    // sigma_t = (2 pi r / N) / c, equal weights 1/N.
    // The centre's own uncertainty (center_covariance_m2) is added to every component's.
    static RingSog generate(NodeId center, NodeId target, const Vector2 &center_m, double range_m,
                            const RingSogParams &params, const Matrix2 &center_covariance_m2 = Matrix2::Zero());

    // EKF update of every component with a range measured from the centre: h(m) = |m - c|
    // (range_model.hpp). The innovation variance includes the centre's own uncertainty
    // (center_covariance_m2) and the range noise; a component whose innovation exceeds
    // gate_sigma standard deviations is left alone (counted), so one NLOS reading cannot drag
    // the ring. process_noise_m2 is added to each component's covariance first (isotropic),
    // so a ring never becomes certain enough to ignore new ranges.
    RangeUpdateResult updateWithRange(const Vector2 &center_m, const Matrix2 &center_covariance_m2, double range_m,
                                      double range_sigma_m, double gate_sigma, double process_noise_m2,
                                      bool full = true)
    {
        RingUpdateRule rule;
        rule.gate_sigma = gate_sigma;
        rule.process_noise_m2 = process_noise_m2;
        rule.full = full;
        return updateWithRange(center_m, center_covariance_m2, range_m, range_sigma_m * range_sigma_m, RangeTerms{},
                               rule);
    }
    // The same with the range model's other terms and a noise variance (m^2) of the caller's:
    // h(m) = s sqrt(|m - c|^2 + dz^2) + b.
    RangeUpdateResult updateWithRange(const Vector2 &center_m, const Matrix2 &center_covariance_m2, double range_m,
                                      double noise_variance_m2, const RangeTerms &terms, const RingUpdateRule &rule);

    // Eq. 8-11 for every witness at once: v_k <- v_k prod_m p(r_m - |m_k - p_m|), with the
    // predictive variance sigma_r^2 + u^T (C_k + C_m) u, then normalised with the floor.
    WeightUpdateResult updateWeights(const std::vector<RangeWitness> &witnesses, const RangeLikelihood &likelihood,
                                     double range_sigma_m, bool full = true, bool allow_reset = true);

    static constexpr double kActiveRatio = 1e-4; // active: weight >= this * heaviest weight

    // Multiplies the weights by likelihood[k] >= 0 (one entry per component; only ratios
    // matter) and normalises with the floor. Returns true if the weights collapsed and were
    // reset to the evidence (only when allow_reset).
    bool applyLikelihood(const std::vector<double> &likelihood, bool allow_reset = true);

    // Eq. 15: w_k = N(|m_kmax - m_k|; 0, sigma_w^2), normalised, around the heaviest component.
    void transferWeights(double sigma_w_m);

    // Drops the components whose weight is below ratio times the heaviest, and normalises the
    // rest; returns how many were dropped.
    uint32_t prune(double ratio);

    void translate(const Vector2 &delta_m) { offset_m_ += delta_m; }
    // x -> rotation x + translation for every mean (and rotation C rotation^T).
    void applyRigid(const Matrix2 &rotation, const Vector2 &translation_m);

    // The moments of the whole ring (its total weight is 1): sum_k w_k m_k, and
    // sum_k w_k (C_k + (m_k - mean)(m_k - mean)^T).
    Gaussian2 moments() const;
    // Raw moments for merging several rings: sum w m, sum w (C + m m^T), sum w.
    void accumulateMoments(Vector2 *first_m, Matrix2 *second_m2, double *total) const;

    // Index of the heaviest component (the first, on a tie).
    uint32_t heaviest() const;

    NodeId center() const { return center_; }
    NodeId target() const { return target_; }
    uint32_t size() const { return static_cast<uint32_t>(components_.size()); }
    bool empty() const { return components_.empty(); }
    // The components with absolute means (a copy).
    std::vector<SogComponentState> components() const;
    // Replaces the components (absolute means; restore, tests). Weights are normalised.
    void setComponents(const std::vector<SogComponentState> &components);
    // Replaces them as they are: means stored absolute (no offset), weights unchanged, so that
    // components() gives them back to the bit.
    void setAbsoluteComponents(std::vector<SogComponentState> components);
    SogComponentState component(uint32_t k) const;
    double weightFloor() const { return weight_floor_; }
    void setWeightFloor(double floor) { weight_floor_ = floor; }
    uint32_t updateCount() const { return update_count_; }
    void countUpdate() { ++update_count_; }
    void setUpdateCount(uint32_t count) { update_count_ = count; }
    void setIdentity(NodeId center, NodeId target)
    {
        center_ = center;
        target_ = target;
    }

    // Normalises the weights with the floor; returns false (and resets them to uniform) when
    // their sum is not positive and finite.
    bool normalise();

private:
    void refreshMoments(); // marks the cached moments stale
    void computeMoments() const;
    // The components an update touches (all, or the active set), into `active`.
    void collectActive(bool full, std::vector<uint32_t> &active) const;

    NodeId center_ = 0;
    NodeId target_ = 0;
    double weight_floor_ = 1e-6;
    Vector2 offset_m_ = Vector2::Zero();        // m, added to every stored mean
    std::vector<SogComponentState> components_; // means relative to offset_m_
    mutable bool moments_stale_ = true;
    mutable Vector2 first_moment_m_ = Vector2::Zero();   // sum w m (relative)
    mutable Matrix2 second_moment_m2_ = Matrix2::Zero(); // sum w (C + m m^T) (relative)
    uint32_t update_count_ = 0;                          // ranges taken (decides which updates are full)
};

} // namespace cdro::engine
