// plant_data.hpp: PLANT (the real 28-node Pozyx network of ../shared/data/plant) for the
// benchmarks: where it is (--data-dir, $CDRO_DATA_DIR, ../shared/data from the repository
// root), its ranges in file order, the heights and the surveyed positions of the nodes that
// range. Header-only; used by bench/engine and bench/service. Throws std::runtime_error with
// the file and line on a malformed file.
#pragma once

#include <cmath>
#include <cstdlib>
#include <fstream>
#include <map>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "cdro/engine/types.hpp"

namespace cdro::bench {

struct Range {
    engine::NodeId from = 0;
    engine::NodeId to = 0;
    double range_m = 0.0; // m, as measured (3D for PLANT)
};

struct Plant {
    std::string dir;
    std::vector<Range> ranges;                                // file order
    std::vector<std::pair<engine::NodeId, double>> heights_m; // m; nodes.csv order, nodes that range only
    std::map<engine::NodeId, engine::Vector2> truth_m;        // m; nodes that range only
};

// The rows of a CSV file with exactly this header (no quoting: PLANT has none).
inline std::vector<std::vector<std::string>> readCsv(const std::string &path, const std::vector<std::string> &header)
{
    std::ifstream in(path);
    if (!in) {
        throw std::runtime_error(path + ": cannot read");
    }
    std::string line;
    std::vector<std::vector<std::string>> rows;
    size_t number = 0;
    while (std::getline(in, line)) {
        ++number;
        if (!line.empty() && line.back() == '\r') {
            line.pop_back();
        }
        if (line.empty()) {
            continue;
        }
        std::vector<std::string> fields;
        std::stringstream split(line);
        std::string field;
        while (std::getline(split, field, ',')) {
            fields.push_back(field);
        }
        if (number == 1) {
            if (fields != header) {
                throw std::runtime_error(path + ": header is not " + line);
            }
            continue;
        }
        if (fields.size() != header.size()) {
            throw std::runtime_error(path + ":" + std::to_string(number) + ": expected " +
                                     std::to_string(header.size()) + " fields");
        }
        rows.push_back(fields);
    }
    return rows;
}

inline double parseNumber(const std::string &text, const std::string &where)
{
    char *end = nullptr;
    const double value = std::strtod(text.c_str(), &end);
    if (end == text.c_str() || *end != '\0' || !std::isfinite(value)) {
        throw std::runtime_error(where + ": not a number: " + text);
    }
    return value;
}

inline engine::NodeId parseNodeId(const std::string &text, const std::string &where)
{
    const double value = parseNumber(text, where);
    if (value < 1.0 || value > 65535.0 || value != std::floor(value)) {
        throw std::runtime_error(where + ": not a node id: " + text);
    }
    return static_cast<engine::NodeId>(value);
}

// dir holds ranges.csv (from,to,range_m) and nodes.csv (id,x,y,z).
inline Plant loadPlant(const std::string &dir)
{
    Plant plant;
    plant.dir = dir;
    for (const auto &row : readCsv(dir + "/ranges.csv", {"from", "to", "range_m"})) {
        plant.ranges.push_back(Range{parseNodeId(row[0], "ranges.csv"), parseNodeId(row[1], "ranges.csv"),
                                     parseNumber(row[2], "ranges.csv")});
    }
    std::map<engine::NodeId, bool> ranging;
    for (const Range &range : plant.ranges) {
        ranging[range.from] = true;
        ranging[range.to] = true;
    }
    // Only the nodes in the ranges: the other ten of nodes.csv would join the engine's node list
    // with no link and no part in the figures.
    for (const auto &row : readCsv(dir + "/nodes.csv", {"id", "x", "y", "z"})) {
        const engine::NodeId id = parseNodeId(row[0], "nodes.csv");
        if (ranging.count(id) != 0) {
            plant.heights_m.emplace_back(id, parseNumber(row[3], "nodes.csv"));
            plant.truth_m[id] = engine::Vector2(parseNumber(row[1], "nodes.csv"), parseNumber(row[2], "nodes.csv"));
        }
    }
    if (plant.truth_m.size() != ranging.size()) {
        throw std::runtime_error(dir + "/nodes.csv: some ranging nodes have no surveyed position");
    }
    return plant;
}

// The folder of PLANT's files. option: --data-dir (may be empty); source_dir: the repository
// root. --data-dir and CDRO_DATA_DIR name the folder that holds plant/, as for the tests
// (tests/tools/test_eval_plant.py); a folder with ranges.csv itself is taken too.
inline std::string findPlant(const std::string &option, const std::string &source_dir)
{
    std::string dir = option;
    if (dir.empty()) {
        const char *env = std::getenv("CDRO_DATA_DIR");
        dir = env != nullptr && *env != '\0' ? env : source_dir + "/../shared/data";
    }
    if (std::ifstream(dir + "/ranges.csv").good()) {
        return dir;
    }
    return dir + "/plant";
}

} // namespace cdro::bench
