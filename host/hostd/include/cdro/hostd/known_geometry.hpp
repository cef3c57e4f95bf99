// known_geometry.hpp: what the user knows about the nodes before any range: their heights (a
// tape measure from the floor; ranges between two nodes of known height are projected to the
// plane) and nodes with surveyed coordinates that stay fixed (they also name the frame).
//
// The same CSV files in every mode (csv_input.hpp): `id,z` (m) and `id,x,y` (m, output frame).
// Live and replay runs take them from the configuration's `map:` section or the command line
// (--heights-csv, --fixed-csv, which win); the offline mode from the command line.
//
//   map:
//     heights_csv: site/heights.csv
//     fixed_csv: site/fixed.csv
//     moving: [0x6A70, 0x6A71]
//
// `moving` (or --moving, which wins): nodes that move from the start, their height unknown (tags
// on drones, people), tracked in 3D (Engine::trackMoving3D, motion_track_3d.hpp) against the
// fixed nodes of known height, in the live service as offline (offline.hpp).
#pragma once

#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include "cdro/hostd/csv_input.hpp"

namespace YAML {
class Node;
}

namespace cdro::engine {
class Engine;
}

namespace cdro::hostd {

struct KnownGeometry {
    std::string heights_csv;      // "" = none
    std::string fixed_csv;        // "" = none
    std::vector<uint16_t> moving; // node ids tracked in 3D; empty = none
};

// The `map:` section of a YAML document (root: the whole document); unknown keys are errors
// naming file and line. Throws cdro::service::ConfigError.
KnownGeometry parseKnownGeometry(const YAML::Node &root, const std::string &origin);

// The rows of the two files (bad rows reported on `log` and skipped, as below).
struct KnownRows {
    std::vector<HeightRow> heights;
    std::vector<FixedRow> fixed;
    size_t skipped_rows = 0;
    bool operator==(const KnownRows &other) const;
};
KnownRows readKnownGeometry(const KnownGeometry &geometry, uint32_t max_reported_rows, std::FILE *log);

// Reads the files and gives every good row to the engine (setHeight, setFixed); bad rows are
// reported on `log` with their line numbers (the first `max_reported_rows` of each file one by
// one) and skipped. Returns the rows used. Throws CsvError when a file cannot be used at all.
struct KnownGeometryCounts {
    size_t heights = 0;
    size_t fixed = 0;
    size_t skipped_rows = 0;
};
KnownGeometryCounts applyKnownGeometry(engine::Engine &engine, const KnownGeometry &geometry,
                                       uint32_t max_reported_rows, std::FILE *log);
KnownGeometryCounts applyKnownRows(engine::Engine &engine, const KnownRows &rows);

// The nodes of `moving` tracked in 3D (after applyKnownRows, before any range). Throws
// cdro::service::ConfigError naming map.moving when fewer than FlightTracks::kMinAnchors fixed nodes
// have a known height (the anchors a 3D track needs), or for a node that is fixed or has a known
// height.
void trackMovingNodes(engine::Engine &engine, const KnownRows &rows, const std::vector<uint16_t> &moving);

// A capture's record of what the map depends on (the service writes it into the capture
// header, capture.h): the known heights and fixed nodes, the nodes tracked in 3D, and the engine's and movement stage's
// settings as --print-config prints them. JSON:
//   {"heights": [[id, z_m], ...], "fixed": [[id, x_m, y_m], ...], "settings": "engine:\n  ...",
//    "moving": [id, ...], "solve_adoption": "recorded"}
// A replay takes from it whatever its own command line does not give (docs/service.md).
struct RunContext {
    KnownRows rows;
    std::string settings;         // YAML
    std::vector<uint16_t> moving; // map.moving; "moving": [id, ...] (absent in older captures: none)
    // The live run adopted its global solves between frames when done and recorded where (host
    // events, Engine::SolveAdoption::ByCaller); absent (captures of cdro-sim, older cdro-hostd):
    // adopted at the fixed lag, which a replay then keeps.
    bool solve_adoption_recorded = false;
};
std::string encodeRunContext(const RunContext &context);
// Throws cdro::service::ConfigError naming `origin` when the text is not a run context.
RunContext decodeRunContext(const std::string &text, const std::string &origin);

} // namespace cdro::hostd
