// plant_data.hpp: PLANT (the real 28-node Pozyx network of ../shared/data/plant) for the
// benchmarks: where it is (--data-dir, $CDRO_DATA_DIR, ../shared/data from the repository
// root), its ranges in file order, the heights and the surveyed positions of the nodes that
// range. Header-only; used by bench/engine and bench/service. Read by the one CSV reader
// (cdro/csv/reader.hpp), Strict: a bad row or a file without the columns throws csv::Error (a
// std::runtime_error) naming the file and line; figures computed without a row of PLANT would be
// quietly wrong.
#pragma once

#include <cstdlib>
#include <fstream>
#include <map>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "cdro/csv/reader.hpp"
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

// dir holds ranges.csv (from,to,range_m) and nodes.csv (id,x,y,z).
inline Plant loadPlant(const std::string &dir)
{
    Plant plant;
    plant.dir = dir;
    csv::Reader ranges(dir + "/ranges.csv", csv::Format{{"from", "to", "range_m"}, {}, {}}, csv::Policy::Strict);
    ranges.forEach([&](const csv::Row &row) {
        Range range;
        if (row.nodeId("from", &range.from) && row.nodeId("to", &range.to) && row.number("range_m", &range.range_m)) {
            plant.ranges.push_back(range);
        }
    });
    std::map<engine::NodeId, bool> ranging;
    for (const Range &range : plant.ranges) {
        ranging[range.from] = true;
        ranging[range.to] = true;
    }
    // Only the nodes in the ranges: the other ten of nodes.csv would join the engine's node list
    // with no link and no part in the figures.
    csv::Reader nodes(dir + "/nodes.csv", csv::Format{{"id", "x", "y", "z"}, {}, {}}, csv::Policy::Strict);
    nodes.forEach([&](const csv::Row &row) {
        engine::NodeId id = 0;
        double x_m = 0.0;
        double y_m = 0.0;
        double z_m = 0.0;
        if (!row.nodeId("id", &id) || ranging.count(id) == 0) {
            return;
        }
        if (row.number("x", &x_m) && row.number("y", &y_m) && row.number("z", &z_m)) {
            plant.heights_m.emplace_back(id, z_m);
            plant.truth_m[id] = engine::Vector2(x_m, y_m);
        }
    });
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
