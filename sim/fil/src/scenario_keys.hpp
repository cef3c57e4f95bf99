// scenario_keys.hpp: the keys of the scenario format as cdro-fil reads them, expanded from
// sim/scenario_keys.def, the one definition cdro-sim's table and docs/tools.md are generated
// from: each key's type, unit, default, valid range, which tool acts on it and what it means.
#pragma once

#include <limits>
#include <stdexcept>
#include <string>
#include <string_view>

#include "scenario_keys.def"

namespace cdro::fil {

namespace scenario_keys {

// The .def's tokens, as the expansion below names them.
enum class Shape { N, O, T };
enum class Type { REAL, INT, PAIR, POINTS, LIST, TEXT, BOOL, ENUM, MAP };
enum class Bounds { CLOSED, OPEN_MIN, OPEN_MAX, OPEN };
enum class Tool { BOTH, SIM, FIL };
constexpr double INF = std::numeric_limits<double>::infinity();
constexpr double kNoNumber = std::numeric_limits<double>::quiet_NaN();

} // namespace scenario_keys

struct ScenarioKey {
    std::string_view path; // list entries written []
    scenario_keys::Shape shape;
    scenario_keys::Type type;
    std::string_view unit;
    double fallback;               // the default of an N key; NaN for the others
    std::string_view default_text; // the default as the .def writes it
    double minimum;                // -INF: no bound
    double maximum;                // INF: no bound
    std::string_view minimum_text;
    std::string_view maximum_text;
    scenario_keys::Bounds bounds;
    scenario_keys::Tool tool;
    std::string_view meaning;

    bool ranged() const { return shape != scenario_keys::Shape::T; }
    bool required() const { return default_text == "required"; }
    bool admits(double value) const;
    // What a value must be, in the words cdro-sim uses (tools/cdro_tools/scenario_codegen.py,
    // requirement()): "in [0, 10] m", "at least 0", "above 0 Hz".
    std::string requirement() const;
};

namespace scenario_keys {

#define CDRO_SK_N(TYPE, PATH, UNIT, DEFAULT, MIN, MAX, BOUNDS, TOOL, MEANING) \
    ScenarioKey{PATH,                                                         \
                Shape::N,                                                     \
                Type::TYPE,                                                   \
                UNIT,                                                         \
                static_cast<double>(DEFAULT),                                 \
                #DEFAULT,                                                     \
                static_cast<double>(MIN),                                     \
                static_cast<double>(MAX),                                     \
                #MIN,                                                         \
                #MAX,                                                         \
                Bounds::BOUNDS,                                               \
                Tool::TOOL,                                                   \
                MEANING},
#define CDRO_SK_O(TYPE, PATH, UNIT, DEFAULT_TEXT, MIN, MAX, BOUNDS, TOOL, MEANING) \
    ScenarioKey{PATH,                                                              \
                Shape::O,                                                          \
                Type::TYPE,                                                        \
                UNIT,                                                              \
                kNoNumber,                                                         \
                DEFAULT_TEXT,                                                      \
                static_cast<double>(MIN),                                          \
                static_cast<double>(MAX),                                          \
                #MIN,                                                              \
                #MAX,                                                              \
                Bounds::BOUNDS,                                                    \
                Tool::TOOL,                                                        \
                MEANING},
#define CDRO_SK_T(TYPE, PATH, DEFAULT_TEXT, TOOL, MEANING)                                \
    ScenarioKey{PATH, Shape::T, Type::TYPE, "",           kNoNumber,  DEFAULT_TEXT, -INF, \
                INF,  "-INF",   "INF",      Bounds::OPEN, Tool::TOOL, MEANING},

inline constexpr ScenarioKey kKeys[] = {CDRO_SCENARIO_KEYS(CDRO_SK_N, CDRO_SK_O, CDRO_SK_T)};

#undef CDRO_SK_N
#undef CDRO_SK_O
#undef CDRO_SK_T

} // namespace scenario_keys

// The key at `path` ("uwb.noise_std_m", "nodes[].x_m"); a path the .def does not define is a bug
// of the reader, not of the file.
inline const ScenarioKey &scenarioKey(std::string_view path)
{
    for (const ScenarioKey &key : scenario_keys::kKeys) {
        if (key.path == path) {
            return key;
        }
    }
    throw std::logic_error("scenario_keys.def defines no key " + std::string(path));
}

// The default of an N key, for the structs' initializers.
inline double scenarioDefault(std::string_view path) { return scenarioKey(path).fallback; }

} // namespace cdro::fil
