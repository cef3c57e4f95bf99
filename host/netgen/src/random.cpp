#include "cdro/netgen/random.hpp"

#include <cmath>

namespace cdro::netgen {

namespace {

// Box-Muller: two uniforms give two normals, the second kept for the next call.
template <typename Uniform> double pairedNormal(bool &has_spare, double &spare, Uniform uniform)
{
    if (has_spare) {
        has_spare = false;
        return spare;
    }
    const double radius = std::sqrt(-2.0 * std::log(1.0 - uniform()));
    const double angle = 6.283185307179586476925 * uniform();
    spare = radius * std::sin(angle);
    has_spare = true;
    return radius * std::cos(angle);
}

// [0, count) from 64 random bits, by rejection: no modulo bias.
template <typename Bits> size_t unbiasedBelow(size_t count, Bits bits)
{
    const uint64_t n = count;
    const uint64_t limit = UINT64_MAX - UINT64_MAX % n;
    uint64_t x = bits();
    while (x >= limit) {
        x = bits();
    }
    return static_cast<size_t>(x % n);
}

} // namespace

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
    return pairedNormal(has_spare_, spare_, [this] { return uniform(); });
}

double Random::exponential(double mean) { return -mean * std::log(1.0 - uniform()); }

size_t Random::below(size_t count)
{
    return unbiasedBelow(count, [this] { return next(); });
}

double MersenneRandom::uniform() { return static_cast<double>(engine_() >> 11U) * 0x1.0p-53; }

double MersenneRandom::normal()
{
    return pairedNormal(has_spare_, spare_, [this] { return uniform(); });
}

size_t MersenneRandom::below(size_t count)
{
    return unbiasedBelow(count, [this] { return engine_(); });
}

} // namespace cdro::netgen
