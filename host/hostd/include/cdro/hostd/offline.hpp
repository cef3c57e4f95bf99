// offline.hpp: cdro-hostd's offline mode. Ranges from a CSV go through the engine in file
// order, exactly as they would arrive over the link, one at a time; the estimates are written
// as CSV. Used by the benchmarks, the tests and anyone with recorded data:
//
//   cdro-hostd --ranges-csv FILE [--heights-csv FILE] [--fixed-csv FILE] [--config FILE]
//              [--no-weight-transfer] [--no-cooperative] [--no-refinement] [--set K=V]...
//              [--trace-csv FILE [--trace-every N]] [--no-settle] --out-csv OUT
//
// OUT: one row per node, `id,x,y,var_x,cov_xy,var_y,converged` (m, m^2, 0/1; a node that could
// not be placed has empty position fields). Bad rows are reported on stderr with their line
// numbers, counted and skipped; so are ranges the engine refuses (a node ranging itself, a
// range that is not positive or beyond engine.range.max_range_m). At the end of the file the
// engine settles (engine.hpp) unless --no-settle: a live run keeps receiving ranges, a file
// ends. A file with no usable row (empty, only bad rows, or only ranges the engine refused)
// ends with status 2 and a message, and leaves no OUT (an empty map is not a result); what is
// not a CSV at all (a directory, /dev/zero, a binary file) is refused at once (csv_input.hpp).
//
// The ranges stream through the engine as they are read, in one pass with a fixed buffer:
// memory does not grow with the file, a progress line comes every second, and the summary
// gives the rate ("ranges.csv: 1000000 rows in 16.30 s (61338 rows/s)"). Measured (2-core
// development machine, RelWithDebInfo): reading and parsing alone 3.3 million rows/s; with the
// engine on a 4-node network about 61,000 rows/s (10 million rows in about 3 minutes, 8 MB
// resident). The movement stage merges its inputs by time, so it reads the ranges whole first.
//
// With --odometry-csv, --robot-id and --out-trajectory the movement stage runs (movement.hpp):
//   cdro-hostd --ranges-csv FILE --odometry-csv FILE --robot-id ID [--motion-csv FILE]
//              --out-csv NODES --out-trajectory TRAJ
// Ranges need their t column then. Every input is merged in time order (an odometry row at t
// ends its step at t, so it is applied before a range at the same t); rows out of time order
// in a file are reported, counted and sorted (stable). TRAJ has a row per odometry step once the
// robot has a position in the map's frame: its estimate right after that step (causal: nothing
// later is used).
//
// With --moving IDS and --out-trajectory the nodes listed (comma separated, decimal or 0x hex) move
// from the start and are tracked in 3D (Engine::trackMoving3D, motion_track_3d.hpp) against the
// fixed nodes of known height (--fixed-csv x, y with --heights-csv z) and against each other:
//   cdro-hostd --ranges-csv FILE --fixed-csv ANCHORS --heights-csv HEIGHTS --moving 10,11,20
//              --out-csv NODES --out-trajectory TRAJ
// Ranges need their t column (rows out of time order are reported, counted and sorted, stable).
// TRAJ has a row after each range of a moving node once it has heard four distinct anchors:
// t,id,x,y,z,var_x,cov_xy,var_y,var_z,cov_xz,cov_yz (s, m, m^2; causal; cdro-eval-motion
// --tag-trajectory reads it). Exit status 2 with a message for a moving node that is fixed, has a
// known height or has no range in FILE, for an id that is no node id, with the movement stage and
// with --trace-csv.
// --moving-body A:B:SEPARATION_M (repeatable): moving nodes A and B are carried by one rigid body,
// SEPARATION_M (m) apart (a drone's two tags: the distance between their lever arms).
// The calibration's parameters are the configuration's `calibration:` section (docs/engine.md).
#pragma once

#include <cstdio>
#include <optional>
#include <string>
#include <vector>

#include "cdro/engine/movement.hpp"
#include "cdro/engine/moving_calibration.hpp"
#include "cdro/engine/params.hpp"

namespace cdro::hostd {

struct OfflineOptions {
    std::string ranges_csv;
    // The movement stage (all three, or none): odometry t,distance_m,dheading_rad, the robot's
    // node id, and the robot's causal trajectory t,x,y,heading_rad,var_x,cov_xy,var_y,frame
    // (frame: odometry or map, RobotFrame in movement.hpp).
    std::string odometry_csv;
    int robot_id = -1; // -1 = none
    std::string out_trajectory;
    std::string motion_csv;                 // t,id,moving (optional)
    std::vector<std::string> moving;        // node ids moving from the start, tracked in 3D (--moving)
    std::vector<std::string> moving_bodies; // "A:B:SEPARATION_M": two of them on one rigid body (--moving-body)
    std::string out_anchors; // --moving without --fixed-csv: the calibrated anchors id,x,y,z,height_given
    // The calibration's parameters (the configuration's `calibration:` section); unset: the
    // defaults with range_sigma_m = engine.range.sigma_m.
    std::optional<engine::MovingCalibrationParams> calibration;
    std::string heights_csv;
    std::string fixed_csv;
    std::string out_csv;
    std::string trace_csv;     // "" = none
    uint32_t trace_every = 10; // ranges between trace snapshots
    bool settle = true;
    uint64_t settle_budget = 0;      // node updates at the end; 0 = 200 per node
    uint32_t max_reported_rows = 20; // bad rows printed one by one (all are counted)
    bool verbose = false;            // the engine's decisions on stderr (--verbose)
};

// Returns the process exit code: 0, or 2 with a message on stderr when an input cannot be
// used at all (missing file, header without the columns, unwritable output).
int runOffline(const OfflineOptions &options, const engine::EngineParams &params, std::FILE *log);
int runOffline(const OfflineOptions &options, const engine::EngineParams &params,
               const engine::MovementParams &movement, std::FILE *log);

} // namespace cdro::hostd
