#include "cdro/netgen/random.hpp"

#include <cmath>

namespace cdro::netgen {

uint64_t mixSeed(uint64_t x)
{
    x += 0x9E3779B97F4A7C15ULL;
    x = (x ^ (x >> 30U)) * 0xBF58476D1CE4E5B9ULL;
    x = (x ^ (x >> 27U)) * 0x94D049BB133111EBULL;
    return x ^ (x >> 31U);
}

uint64_t Random::next()
{
    state_ += 0x9E3779B97F4A7C15ULL;
    uint64_t z = state_;
    z = (z ^ (z >> 30U)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27U)) * 0x94D049BB133111EBULL;
    return z ^ (z >> 31U);
}

double Random::uniform() { return static_cast<double>(next() >> 11U) * 0x1.0p-53; }

double Random::normal()
{
    if (has_spare_) {
        has_spare_ = false;
        return spare_;
    }
    const double radius = std::sqrt(-2.0 * std::log(1.0 - uniform()));
    const double angle = 6.283185307179586476925 * uniform();
    spare_ = radius * std::sin(angle);
    has_spare_ = true;
    return radius * std::cos(angle);
}

double Random::exponential(double mean) { return -mean * std::log(1.0 - uniform()); }

size_t Random::below(size_t count)
{
    const uint64_t n = count;
    const uint64_t limit = UINT64_MAX - UINT64_MAX % n; // rejection: no modulo bias
    uint64_t x = next();
    while (x >= limit) {
        x = next();
    }
    return static_cast<size_t>(x % n);
}

double MersenneRandom::uniform() { return static_cast<double>(engine_() >> 11U) * 0x1.0p-53; }

double MersenneRandom::normal()
{
    if (has_spare_) {
        has_spare_ = false;
        return spare_;
    }
    const double radius = std::sqrt(-2.0 * std::log(1.0 - uniform()));
    const double angle = 6.283185307179586476925 * uniform();
    spare_ = radius * std::sin(angle);
    has_spare_ = true;
    return radius * std::cos(angle);
}

size_t MersenneRandom::below(size_t count)
{
    const uint64_t n = count;
    const uint64_t limit = UINT64_MAX - UINT64_MAX % n; // rejection: no modulo bias
    uint64_t x = engine_();
    while (x >= limit) {
        x = engine_();
    }
    return static_cast<size_t>(x % n);
}

} // namespace cdro::netgen
