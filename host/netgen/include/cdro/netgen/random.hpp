// random.hpp: seeded randomness that gives the same draws on every platform and standard
// library (std::uniform_real_distribution, std::normal_distribution and std::shuffle are
// implementation-defined). splitmix64 (or mt19937_64) for the stream, Box-Muller for the normal
// draws, rejection for the integers (no modulo bias).
#pragma once

#include <cstddef>
#include <cstdint>
#include <random>
#include <utility>
#include <vector>

namespace cdro::netgen {

// splitmix64's output function: independent seeds for sub-streams from one printed seed.
uint64_t mixSeed(uint64_t x);

// What a generator that takes its randomness from the caller draws from (geometric.hpp): the
// caller's stream decides the draws, so a test can keep its own seeded stream going across the
// network and the ranges it then draws.
class RandomSource {
public:
    RandomSource() = default;
    RandomSource(const RandomSource &) = default;
    RandomSource &operator=(const RandomSource &) = default;
    virtual ~RandomSource() = default;
    virtual double uniform() = 0;                                                      // [0, 1)
    virtual double normal() = 0;                                                       // standard normal
    virtual size_t below(size_t count) = 0;                                            // [0, count), count > 0
    double uniform(double low, double high) { return low + (high - low) * uniform(); } // [low, high)
    bool chance(double probability) { return uniform() < probability; }
    template <typename T> void shuffle(std::vector<T> &items) // Fisher-Yates
    {
        for (size_t i = items.size(); i > 1; --i) {
            std::swap(items[i - 1], items[below(i)]);
        }
    }
};

// splitmix64: the stream of the building families, their range streams, cdro-netgen, the robot
// world and the engine tests.
class Random final : public RandomSource {
public:
    explicit Random(uint64_t seed) : state_(seed) {}
    using RandomSource::uniform;
    uint64_t next();
    double uniform() override;           // [0, 1)
    double normal() override;            // standard normal
    double exponential(double mean);     // Exp with this mean (> 0)
    size_t below(size_t count) override; // [0, count), count > 0

private:
    uint64_t state_;
    bool has_spare_ = false;
    double spare_ = 0.0;
};

// std::mt19937_64 (its sequence is fixed by the standard) with the same uniform, below and
// normal as Random: the stream of cdro-bench-engine's geometric networks and their range noise,
// kept because docs/bench.md's figures were measured on those draws.
class MersenneRandom final : public RandomSource {
public:
    explicit MersenneRandom(uint64_t seed) : engine_(seed) {}
    using RandomSource::uniform;
    double uniform() override;           // [0, 1)
    double normal() override;            // standard normal
    size_t below(size_t count) override; // [0, count), count > 0

private:
    std::mt19937_64 engine_;
    bool has_spare_ = false;
    double spare_ = 0.0;
};

} // namespace cdro::netgen
