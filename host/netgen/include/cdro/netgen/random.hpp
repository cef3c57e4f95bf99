// random.hpp: seeded randomness that gives the same draws on every platform and standard
// library (std::uniform_real_distribution, std::normal_distribution and std::shuffle are
// implementation-defined). splitmix64 for the stream, Box-Muller for the normal draws.
#pragma once

#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

namespace cdro::netgen {

// splitmix64's output function: independent seeds for sub-streams from one printed seed.
uint64_t mixSeed(uint64_t x);

class Random {
public:
    explicit Random(uint64_t seed) : state_(seed) {}
    uint64_t next();
    double uniform();                        // [0, 1)
    double uniform(double low, double high); // [low, high)
    double normal();                         // standard normal
    double exponential(double mean);         // Exp with this mean (> 0)
    size_t below(size_t count);              // [0, count), count > 0
    bool chance(double probability) { return uniform() < probability; }
    template <typename T> void shuffle(std::vector<T> &items)
    {
        for (size_t i = items.size(); i > 1; --i) {
            std::swap(items[i - 1], items[below(i)]);
        }
    }

private:
    uint64_t state_;
    bool has_spare_ = false;
    double spare_ = 0.0;
};

} // namespace cdro::netgen
