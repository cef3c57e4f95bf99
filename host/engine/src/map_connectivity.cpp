#include "cdro/engine/map_connectivity.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <map>
#include <vector>

namespace cdro::engine {
namespace {

constexpr double kCeiling = 0.98; // P(heard) of a close pair: some miss each other all the same
constexpr double kFloor = 0.001;  // P(heard) of a far pair: a rare reflection carries far
// Pair distances are counted in bins this share of the median link wide: the fit sees the
// distances to a fraction of a per cent of a link, and its price does not grow with the pairs.
constexpr double kBinShare = 0.005;
// The widths tried, as shares of the median link: from a sharp edge to a gradual fall.
constexpr std::array<double, 7> kWidthShares = {0.02, 0.035, 0.06, 0.1, 0.17, 0.3, 0.5};
constexpr uint32_t kHalfDistanceSteps = 60;
constexpr uint32_t kGoldenSteps = 30;

struct Bin {
    double distance_m = 0.0; // m
    double heard = 0.0;
    double unheard = 0.0;
};

double heardAt(double distance_m, double half_distance_m, double width_m)
{
    const double fall = 1.0 / (1.0 + std::exp((distance_m - half_distance_m) / width_m));
    return kFloor + (kCeiling - kFloor) * fall;
}

double costOf(const std::vector<Bin> &bins, double half_distance_m, double width_m)
{
    double cost = 0.0;
    for (const Bin &bin : bins) {
        const double heard = heardAt(bin.distance_m, half_distance_m, width_m);
        if (bin.heard > 0.0) {
            cost -= bin.heard * std::log(heard);
        }
        if (bin.unheard > 0.0) {
            cost -= bin.unheard * std::log(1.0 - heard);
        }
    }
    return cost;
}

// The minimum of f over [low, high] by golden section (f unimodal there, as the cost is near a
// grid point that was best).
template <typename F> double goldenMinimum(F f, double low, double high)
{
    const double ratio = (std::sqrt(5.0) - 1.0) / 2.0;
    double x1 = high - ratio * (high - low);
    double x2 = low + ratio * (high - low);
    double f1 = f(x1);
    double f2 = f(x2);
    for (uint32_t step = 0; step < kGoldenSteps; ++step) {
        if (f1 <= f2) {
            high = x2;
            x2 = x1;
            f2 = f1;
            x1 = high - ratio * (high - low);
            f1 = f(x1);
        } else {
            low = x1;
            x1 = x2;
            f1 = f2;
            x2 = low + ratio * (high - low);
            f2 = f(x2);
        }
    }
    return f1 <= f2 ? x1 : x2;
}

} // namespace

double heardProbability(const ConnectivityFit &fit, double distance_m)
{
    return fit.width_m > 0.0 ? heardAt(distance_m, fit.half_distance_m, fit.width_m) : 0.0;
}

ConnectivityFit connectivityCost(const MapProblem &problem, const MapEstimate &estimate)
{
    ConnectivityFit fit;
    std::vector<uint32_t> placed;
    for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
        if (estimate.placed[node] != 0) {
            placed.push_back(node);
        }
    }
    if (placed.size() < 3) {
        return fit;
    }
    std::vector<double> heard_m;
    for (const MapLink &link : problem.links) {
        if (estimate.placed[link.a] != 0 && estimate.placed[link.b] != 0) {
            heard_m.push_back((estimate.position_m[link.a] - estimate.position_m[link.b]).norm());
        }
    }
    if (heard_m.empty()) {
        return fit;
    }
    std::vector<double> sorted = heard_m;
    std::sort(sorted.begin(), sorted.end());
    const double median_m = sorted[sorted.size() / 2];
    const double longest_m = sorted.back();
    if (!(median_m > 0.0) || !std::isfinite(longest_m)) {
        return fit;
    }
    const double widest_m = kWidthShares.back() * median_m;
    // Beyond this the fitted P(heard) is the floor whatever the parameters tried: one bin.
    const double far_m = 1.2 * longest_m + 10.0 * widest_m;
    const double bin_m = kBinShare * median_m;
    std::map<int64_t, Bin> bins; // by bin number: the sums come out in distance order every run
    auto add = [&](double distance_m, bool heard) {
        const double at_m = std::isfinite(distance_m) ? std::min(distance_m, far_m) : far_m;
        const auto number = static_cast<int64_t>(std::floor(at_m / bin_m));
        Bin &bin = bins[number];
        bin.distance_m = (static_cast<double>(number) + 0.5) * bin_m;
        (heard ? bin.heard : bin.unheard) += 1.0;
    };
    for (double distance_m : heard_m) {
        add(distance_m, true);
    }
    fit.heard_pairs = static_cast<uint32_t>(heard_m.size());
    for (size_t i = 0; i < placed.size(); ++i) {
        for (size_t j = i + 1; j < placed.size(); ++j) {
            if (problem.unheardPair(placed[i], placed[j])) {
                add((estimate.position_m[placed[i]] - estimate.position_m[placed[j]]).norm(), false);
                ++fit.unheard_pairs;
            }
        }
    }
    std::vector<Bin> counted;
    counted.reserve(bins.size());
    for (const auto &[number, bin] : bins) {
        counted.push_back(bin);
    }
    // A grid over both parameters (the half distance geometric from half the median link to past
    // the longest), then golden section between the best point's neighbours, one parameter at a time.
    const double first_half_m = 0.5 * median_m;
    const double last_half_m = 1.2 * longest_m;
    const double half_step = std::pow(std::max(last_half_m / first_half_m, 1.0 + 1e-9), 1.0 / (kHalfDistanceSteps - 1));
    double best = std::numeric_limits<double>::infinity();
    uint32_t best_h = 0;
    size_t best_w = 0;
    for (uint32_t h = 0; h < kHalfDistanceSteps; ++h) {
        const double half_m = first_half_m * std::pow(half_step, h);
        for (size_t w = 0; w < kWidthShares.size(); ++w) {
            const double cost = costOf(counted, half_m, kWidthShares[w] * median_m);
            if (cost < best) {
                best = cost;
                best_h = h;
                best_w = w;
            }
        }
    }
    double half_m = first_half_m * std::pow(half_step, best_h);
    double width_m = kWidthShares[best_w] * median_m;
    const double half_low_m = first_half_m * std::pow(half_step, best_h == 0 ? 0.0 : best_h - 1.0);
    const double half_high_m = first_half_m * std::pow(half_step, std::min(best_h + 1, kHalfDistanceSteps - 1));
    const double width_low_m = kWidthShares[best_w == 0 ? 0 : best_w - 1] * median_m;
    const double width_high_m = kWidthShares[std::min(best_w + 1, kWidthShares.size() - 1)] * median_m;
    for (int round = 0; round < 2; ++round) {
        half_m = goldenMinimum([&](double h) { return costOf(counted, h, width_m); }, half_low_m, half_high_m);
        width_m = goldenMinimum([&](double w) { return costOf(counted, half_m, w); }, width_low_m, width_high_m);
    }
    const double refined = costOf(counted, half_m, width_m);
    if (refined < best) {
        best = refined;
    } else {
        half_m = first_half_m * std::pow(half_step, best_h);
        width_m = kWidthShares[best_w] * median_m;
    }
    fit.cost_nats = best;
    fit.half_distance_m = half_m;
    fit.width_m = width_m;
    return fit;
}

} // namespace cdro::engine
