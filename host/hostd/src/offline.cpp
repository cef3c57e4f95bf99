#include "cdro/hostd/offline.hpp"

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <fcntl.h>
#include <unistd.h>

#include "cdro/csv/reader.hpp"
#include "cdro/engine/engine.hpp"
#include "cdro/engine/movement.hpp"
#include "cdro/engine/moving_calibration.hpp"
#include "cdro/hostd/csv_input.hpp"
#include "cdro/hostd/known_geometry.hpp"
#include "cdro/hostd/estimates_csv.hpp"
#include "cdro/service/config.hpp"
#include "cdro/service/map_state.hpp"
#include "cdro/service/output_file.hpp"

namespace cdro::hostd {

namespace {

// Why a placed node is not converged, and what would help, on stderr (ids as in every log: 0x6001).
void reportDoubt(std::FILE *log, const engine::NodeOutput &node)
{
    const auto id = static_cast<unsigned>(node.id);
    switch (node.doubt) {
    case engine::NodeDoubt::None: return;
    case engine::NodeDoubt::TooFewLinks:
        std::fprintf(log,
                     "cdro-hostd: node 0x%04X has fewer than three links to placed nodes: its ranges cannot "
                     "fix it (not converged; add a link)\n",
                     id);
        return;
    case engine::NodeDoubt::Ambiguous:
        std::fprintf(log,
                     "cdro-hostd: node 0x%04X is ambiguous: another position, or another map of its part "
                     "(with the radios' range offsets or without), fits its %u links about as well (not "
                     "converged; add a link to a node off the line of its neighbours, or calibrate the "
                     "radios' antenna delays)\n",
                     id, node.link_count);
        return;
    case engine::NodeDoubt::Foldable:
        if (node.hinge_nodes == 0) {
            std::fprintf(log,
                         "cdro-hostd: node 0x%04X is not connected to the largest part of the network: its place "
                         "relative to it is unknown (not converged)\n",
                         id);
        } else {
            std::string hinge = service::nodeIdHex(node.hinge[0]);
            if (node.hinge_nodes == 2) {
                hinge += " and " + service::nodeIdHex(node.hinge[1]);
            }
            std::fprintf(log,
                         "cdro-hostd: node 0x%04X hangs on node%s %s: its part of the network can %s without "
                         "changing a range, so the ranges cannot tell its side (not converged; add a link "
                         "from it to another node)\n",
                         id, node.hinge_nodes == 2 ? "s" : "", hinge.c_str(),
                         node.hinge_nodes == 2 ? "fold over them" : "turn about it");
        }
        return;
    case engine::NodeDoubt::Flexible:
        std::fprintf(log,
                     "cdro-hostd: node 0x%04X is flexible: it hangs on links nothing else checks, so one "
                     "error in them (or the map's own uncertainty) could move it a metre or more (not "
                     "converged; add links across its part)\n",
                     id);
        return;
    case engine::NodeDoubt::Unsettled:
        std::fprintf(log, "cdro-hostd: node 0x%04X has not settled yet (not converged)\n", id);
        return;
    }
}

struct FileCloser {
    void operator()(std::FILE *file) const
    {
        if (file != nullptr) {
            std::fclose(file);
        }
    }
};
using File = std::unique_ptr<std::FILE, FileCloser>;

// Never through a symbolic link, never in a directory every user may write to (the service's
// rule for every file it writes: output_file.hpp).
File openForWriting(const std::string &path, std::FILE *log)
{
    int fd = -1;
    try {
        fd = service::openOutputFile(path, O_WRONLY | O_CREAT | O_TRUNC, "output file");
    } catch (const service::ConfigError &error) {
        std::fprintf(log, "cdro-hostd: %s\n", error.what());
        return File();
    }
    File file(::fdopen(fd, "w"));
    if (!file) {
        std::fprintf(log, "cdro-hostd: cannot write %s: %s\n", path.c_str(), std::strerror(errno));
        ::close(fd);
    }
    return file;
}

// Whether everything written to `file` reached it; says which file failed, and why, when not.
bool writtenOut(std::FILE *file, const std::string &path, std::FILE *log)
{
    if (std::fflush(file) != 0 || std::ferror(file)) {
        std::fprintf(log, "cdro-hostd: writing %s failed: %s\n", path.c_str(), std::strerror(errno));
        return false;
    }
    return true;
}

// The outputs of a run that ends with status 2 once they were opened (they are ours then; the
// trajectory is opened only after every input was read).
void removeOutputs(const OfflineOptions &options)
{
    for (const std::string *path : {&options.out_csv, &options.trace_csv}) {
        if (!path->empty()) {
            ::unlink(path->c_str());
        }
    }
}

// Wall time since construction, for the reading rate (never for anything that is output).
class RateClock {
public:
    double seconds() const
    {
        return std::max(1e-6, std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count());
    }

private:
    std::chrono::steady_clock::time_point start_ = std::chrono::steady_clock::now();
};

// True once a second (checked every 4096 calls, so that it costs nothing per row).
class ProgressTicker {
public:
    bool due()
    {
        if (++calls_ % 4096 != 0) {
            return false;
        }
        const auto now = std::chrono::steady_clock::now();
        if (now < next_) {
            return false;
        }
        next_ = now + std::chrono::seconds(1);
        return true;
    }

private:
    uint64_t calls_ = 0;
    std::chrono::steady_clock::time_point next_ = std::chrono::steady_clock::now() + std::chrono::seconds(1);
};

void reportRate(std::FILE *log, const std::string &path, size_t rows, const RateClock &clock)
{
    const double seconds = clock.seconds();
    std::fprintf(log, "cdro-hostd: %s: %zu rows in %.2f s (%.0f rows/s)\n", path.c_str(), rows, seconds,
                 static_cast<double>(rows) / seconds);
}

// Sorts rows by time (stable) and says how many were out of order.
template <typename Row> void sortByTime(std::vector<Row> &rows, const std::string &path, std::FILE *log)
{
    size_t out_of_order = 0;
    for (size_t i = 1; i < rows.size(); ++i) {
        out_of_order += rows[i].t_s < rows[i - 1].t_s ? 1U : 0U;
    }
    if (out_of_order > 0) {
        std::fprintf(log, "cdro-hostd: %s: %zu rows out of time order; sorted by t (stable)\n", path.c_str(),
                     out_of_order);
        std::stable_sort(rows.begin(), rows.end(), [](const Row &a, const Row &b) { return a.t_s < b.t_s; });
    }
}

void writeTrajectoryRow(std::FILE *out, double t_s, const engine::RobotOutput &robot)
{
    std::fprintf(out, "%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%s\n", t_s, robot.pose.x_m, robot.pose.y_m,
                 robot.pose.heading_rad, robot.covariance(0, 0), robot.covariance(0, 1), robot.covariance(1, 1),
                 engine::robotFrameName(robot.frame));
}

int runMovement(const OfflineOptions &options, const engine::EngineParams &params,
                const engine::MovementParams &movement_params, engine::Engine &engine,
                const CsvTable<RangeRow> &ranges_table, std::FILE *out, std::FILE *log)
{
    std::vector<RangeRow> ranges = ranges_table.rows;
    for (const RangeRow &row : ranges) {
        if (!row.has_time) {
            std::fprintf(log, "cdro-hostd: %s: the movement stage needs a t column in the ranges\n",
                         options.ranges_csv.c_str());
            return 2;
        }
    }
    CsvTable<OdometryRow> odometry = readOdometryCsv(options.odometry_csv, options.max_reported_rows);
    reportCsvProblems(options.odometry_csv, odometry.summary, options.max_reported_rows, log);
    CsvTable<MotionRow> motion;
    if (!options.motion_csv.empty()) {
        motion = readMotionCsv(options.motion_csv, options.max_reported_rows);
        reportCsvProblems(options.motion_csv, motion.summary, options.max_reported_rows, log);
    }
    sortByTime(ranges, options.ranges_csv, log);
    sortByTime(odometry.rows, options.odometry_csv, log);
    sortByTime(motion.rows, options.motion_csv, log);
    File trajectory = openForWriting(options.out_trajectory, log);
    if (!trajectory) {
        return 2;
    }
    std::fputs("t,x,y,heading_rad,var_x,cov_xy,var_y,frame\n", trajectory.get());

    engine::MovementStage stage(engine, movement_params);
    if (options.verbose) {
        stage.setTrace(
            [log](const std::string &message) { std::fprintf(log, "cdro-hostd: movement: %s\n", message.c_str()); });
    }
    // Merge the three streams by time; at equal times odometry first (it ends its step at t),
    // then motion reports, then ranges.
    size_t o = 0;
    size_t m = 0;
    size_t r = 0;
    uint64_t refused = 0;
    std::optional<engine::RobotFrame> last_frame; // of the last trajectory row
    double last_row_t_s = 0.0;                    // s
    while (o < odometry.rows.size() || m < motion.rows.size() || r < ranges.size()) {
        const double inf = std::numeric_limits<double>::infinity();
        const double to = o < odometry.rows.size() ? odometry.rows[o].t_s : inf;
        const double tm = m < motion.rows.size() ? motion.rows[m].t_s : inf;
        const double tr = r < ranges.size() ? ranges[r].t_s : inf;
        if (to <= tm && to <= tr) {
            const OdometryRow &row = odometry.rows[o++];
            stage.addOdometry(row.t_s, engine::OdometryStep{row.distance_m, row.dheading_rad});
            // Only when the robot has a position (RobotOutput::placed): dead reckoning while no map
            // exists, the map's once it does; none while its own stage-1 position is ambiguous.
            const std::optional<engine::RobotOutput> robot = stage.robot();
            if (robot && robot->placed) {
                if (last_frame && *last_frame != robot->frame) {
                    std::fprintf(log,
                                 "cdro-hostd: trajectory: the rows up to t = %.3f s are in the %s frame, from "
                                 "t = %.3f s in the %s frame (the map appeared while the robot stood): compare "
                                 "only rows of one frame\n",
                                 last_row_t_s, engine::robotFrameName(*last_frame), row.t_s,
                                 engine::robotFrameName(robot->frame));
                }
                last_frame = robot->frame;
                last_row_t_s = row.t_s;
                writeTrajectoryRow(trajectory.get(), row.t_s, *robot);
            }
        } else if (tm <= tr) {
            const MotionRow &row = motion.rows[m++];
            stage.setMoving(row.id, row.moving, row.t_s);
        } else {
            const RangeRow &row = ranges[r++];
            const engine::RangeVerdict verdict = stage.addRange(row.from, row.to, row.range_m, row.t_s);
            if (verdict == engine::RangeVerdict::RejectedSelf || verdict == engine::RangeVerdict::RejectedValue) {
                if (refused++ < options.max_reported_rows) {
                    std::fprintf(log, "cdro-hostd: %s:%zu: skipped: %s (%u -> %u, %.17g m)\n",
                                 options.ranges_csv.c_str(), row.line, engine::rangeVerdictName(verdict),
                                 static_cast<unsigned>(row.from), static_cast<unsigned>(row.to), row.range_m);
                }
            }
        }
    }
    writeNodesHeader(out);
    size_t placed = 0;
    for (const engine::NodeOutput &node : stage.estimates()) {
        if (node.link_count > 0 || node.fixed()) {
            writeNodeRow(out, node);
        }
        placed += node.placed() ? 1U : 0U;
    }
    if (!writtenOut(trajectory.get(), options.out_trajectory, log)) {
        return 2;
    }
    const engine::MovementCounters &c = stage.counters();
    const std::optional<engine::RobotOutput> robot = stage.robot();
    std::fprintf(
        log,
        "cdro-hostd: movement stage: %llu odometry steps, %llu ranges (%llu with the robot), %llu EKF updates, "
        "%llu gated, %llu nodes taken into the EKF (%llu via a SoG around the robot), %llu taken out moving; "
        "%zu nodes placed\n",
        static_cast<unsigned long long>(c.odometry_steps), static_cast<unsigned long long>(ranges.size()),
        static_cast<unsigned long long>(c.robot_ranges), static_cast<unsigned long long>(c.ekf_updates),
        static_cast<unsigned long long>(c.ekf_gated), static_cast<unsigned long long>(c.nodes_inserted),
        static_cast<unsigned long long>(c.beacon_sogs), static_cast<unsigned long long>(c.nodes_removed), placed);
    if (robot && robot->localized) {
        std::fprintf(log,
                     "cdro-hostd: range calibration: scale %.5f +- %.5f, offset %.3f +- %.3f m; range noise %.3f m; "
                     "%u heading hypotheses left\n",
                     robot->range_scale, robot->range_scale_sigma, robot->range_offset_m, robot->range_offset_sigma_m,
                     stage.rangeSigmaInUse(), robot->hypotheses);
    }
    (void)params;
    return 0;
}

// --moving without --fixed-csv: no anchor's position is given. The anchors (every static node a
// moving one ranges) are calibrated from the moving nodes' ranges (moving_calibration.hpp; the
// heights of --heights-csv held), then fixed in the engine at their estimates, in the solution's
// own frame, and the moving nodes tracked from them. Returns 2 with a message when the ranges do
// not allow it.
int calibrateAnchors(const OfflineOptions &options, engine::Engine &engine, const engine::EngineParams &params,
                     const std::vector<RangeRow> &ranges, const std::vector<engine::NodeId> &moving, std::FILE *log)
{
    std::vector<engine::CalibrationRange> input;
    input.reserve(ranges.size());
    for (const RangeRow &row : ranges) {
        input.push_back({row.t_s, row.from, row.to, row.range_m});
    }
    std::vector<std::pair<engine::NodeId, double>> heights;
    for (const engine::NodeState &node : engine.map().nodes) {
        if (node.height_m) {
            heights.emplace_back(node.id, *node.height_m);
        }
    }
    engine::MovingCalibrationParams calibration_params;
    calibration_params.range_sigma_m = params.range.sigma_m;
    if (options.calibration) {
        calibration_params = *options.calibration;
    }
    engine::MovingCalibration calibration(calibration_params, params.motion);
    std::vector<engine::CalibratedAnchor> anchors;
    try {
        anchors = calibration.solve(input, moving, heights);
    } catch (const std::invalid_argument &error) {
        std::fprintf(log, "cdro-hostd: --moving without --fixed-csv: %s\n", error.what());
        return 2;
    }
    for (const engine::CalibratedAnchor &anchor : anchors) {
        engine.setFixed(anchor.id, anchor.position_m.head<2>());
        if (!anchor.height_given) {
            engine.setHeight(anchor.id, anchor.position_m.z());
        }
        // scripts/miluv.py reads these lines.
        std::fprintf(log, "cdro-hostd: anchor %u self-calibrated at %.6f, %.6f, %.6f m (height %s)\n",
                     static_cast<unsigned>(anchor.id), anchor.position_m.x(), anchor.position_m.y(),
                     anchor.position_m.z(), anchor.height_given ? "given" : "estimated");
    }
    if (!options.out_anchors.empty()) {
        File file = openForWriting(options.out_anchors, log);
        if (!file) {
            return 2;
        }
        std::fputs("id,x,y,z,height_given\n", file.get());
        for (const engine::CalibratedAnchor &anchor : anchors) {
            std::fprintf(file.get(), "%u,%.17g,%.17g,%.17g,%d\n", static_cast<unsigned>(anchor.id),
                         anchor.position_m.x(), anchor.position_m.y(), anchor.position_m.z(),
                         anchor.height_given ? 1 : 0);
        }
        if (!writtenOut(file.get(), options.out_anchors, log)) {
            return 2;
        }
    }
    const engine::MovingCalibrationCounters &c = calibration.counters();
    std::fprintf(log,
                 "cdro-hostd: anchors calibrated from the moving nodes' ranges: %zu anchors, %llu ranges (%llu "
                 "ignored), %llu windows (%llu placed by the MDS), %llu epochs; %u + %u iterations; range residual "
                 "RMS %.3f m, %llu beyond the Huber bound\n",
                 anchors.size(), static_cast<unsigned long long>(c.ranges), static_cast<unsigned long long>(c.ignored),
                 static_cast<unsigned long long>(c.windows), static_cast<unsigned long long>(c.windows_placed),
                 static_cast<unsigned long long>(c.epochs), c.static_iterations, c.batch_iterations, c.rms_residual_m,
                 static_cast<unsigned long long>(c.outliers));
    return 0;
}

// --moving: the nodes tracked in 3D. Returns 2 with a message on `log` when the options or the
// ranges do not allow it (nothing written then but NODES, which the caller removes).
int runFlights(const OfflineOptions &options, const engine::EngineParams &params, engine::Engine &engine,
               const CsvTable<RangeRow> &ranges_table, std::FILE *out, std::FILE *log)
{
    if (!options.odometry_csv.empty() || options.robot_id >= 0 || !options.motion_csv.empty()) {
        std::fprintf(log, "cdro-hostd: --moving is not for the movement stage or motion reports (no --odometry-csv, "
                          "--robot-id or --motion-csv with it)\n");
        return 2;
    }
    if (options.out_trajectory.empty()) {
        std::fprintf(log, "cdro-hostd: --moving needs --out-trajectory (where the moving nodes' tracks go)\n");
        return 2;
    }
    if (!options.trace_csv.empty()) {
        std::fprintf(log, "cdro-hostd: --trace-csv is not written with --moving (the moving nodes' estimates are in "
                          "--out-trajectory)\n");
        return 2;
    }
    std::vector<engine::NodeId> moving;
    for (const std::string &text : options.moving) {
        uint16_t id = 0;
        if (!csv::parseNodeId(text, &id)) {
            std::fprintf(log, "cdro-hostd: --moving: '%s' is not a node id (1..65535, decimal or 0x hex)\n",
                         text.c_str());
            return 2;
        }
        if (std::find(moving.begin(), moving.end(), id) == moving.end()) {
            moving.push_back(id);
        }
    }
    std::vector<RangeRow> ranges = ranges_table.rows;
    for (const RangeRow &row : ranges) {
        if (!row.has_time) {
            std::fprintf(log, "cdro-hostd: %s: --moving needs a t column in the ranges\n", options.ranges_csv.c_str());
            return 2;
        }
    }
    for (const engine::NodeId id : moving) {
        const bool ranged = std::any_of(ranges.begin(), ranges.end(),
                                        [id](const RangeRow &row) { return row.from == id || row.to == id; });
        if (!ranged) {
            std::fprintf(log, "cdro-hostd: --moving: node %u (%s) has no range in %s\n", static_cast<unsigned>(id),
                         service::nodeIdHex(id).c_str(), options.ranges_csv.c_str());
            return 2;
        }
        try {
            engine.trackMoving3D(id);
        } catch (const std::logic_error &error) {
            std::fprintf(log, "cdro-hostd: --moving: %s\n", error.what());
            return 2;
        }
    }
    for (const std::string &text : options.moving_bodies) {
        // A:B:SEPARATION_M
        const size_t first = text.find(':');
        const size_t second = first == std::string::npos ? first : text.find(':', first + 1);
        uint16_t a = 0;
        uint16_t b = 0;
        double separation_m = 0.0;
        bool good = second != std::string::npos && csv::parseNodeId(text.substr(0, first), &a) &&
                    csv::parseNodeId(text.substr(first + 1, second - first - 1), &b);
        if (good) {
            const std::string number = text.substr(second + 1);
            char *end = nullptr;
            separation_m = std::strtod(number.c_str(), &end);
            good = !number.empty() && end == number.c_str() + number.size();
        }
        if (!good) {
            std::fprintf(log, "cdro-hostd: --moving-body: '%s' is not A:B:SEPARATION_M (two node ids, metres)\n",
                         text.c_str());
            return 2;
        }
        try {
            engine.trackOnOneBody(a, b, separation_m);
        } catch (const std::invalid_argument &error) {
            std::fprintf(log, "cdro-hostd: --moving-body %s: %s (both must be in --moving)\n", text.c_str(),
                         error.what());
            return 2;
        }
    }
    sortByTime(ranges, options.ranges_csv, log);
    if (options.fixed_csv.empty()) {
        if (const int code = calibrateAnchors(options, engine, params, ranges, moving, log); code != 0) {
            return code;
        }
    } else if (!options.out_anchors.empty()) {
        std::fprintf(log, "cdro-hostd: --out-anchors is written when the anchors are calibrated (--moving without "
                          "--fixed-csv); with --fixed-csv they are given\n");
        return 2;
    }
    File trajectory = openForWriting(options.out_trajectory, log);
    if (!trajectory) {
        return 2;
    }
    std::fputs("t,id,x,y,z,var_x,cov_xy,var_y,var_z,cov_xz,cov_yz\n", trajectory.get());
    uint64_t refused = 0;
    uint64_t rows_written = 0;
    for (const RangeRow &row : ranges) {
        const engine::RangeVerdict verdict = engine.addRange(row.from, row.to, row.range_m, row.t_s);
        if (verdict == engine::RangeVerdict::RejectedSelf || verdict == engine::RangeVerdict::RejectedValue) {
            if (refused++ < options.max_reported_rows) {
                std::fprintf(log, "cdro-hostd: %s:%zu: skipped: %s (%u -> %u, %.17g m)\n", options.ranges_csv.c_str(),
                             row.line, engine::rangeVerdictName(verdict), static_cast<unsigned>(row.from),
                             static_cast<unsigned>(row.to), row.range_m);
            }
            continue;
        }
        for (const engine::NodeId end : {row.from, row.to}) {
            const std::optional<engine::FlightEstimate> track = engine.flightEstimate(end);
            if (track && track->status == engine::FlightStatus::Tracking) {
                const engine::Vector3 &p = track->position_m;
                const engine::Matrix3 &c = track->covariance_m2;
                std::fprintf(trajectory.get(), "%.17g,%u,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g\n",
                             row.t_s, static_cast<unsigned>(end), p.x(), p.y(), p.z(), c(0, 0), c(0, 1), c(1, 1),
                             c(2, 2), c(0, 2), c(1, 2));
                ++rows_written;
            }
        }
    }
    if (options.settle) {
        engine.settle(200ULL * engine.map().nodes.size() + 1000ULL);
    }
    writeNodesHeader(out);
    for (const engine::NodeOutput &node : engine.estimates()) {
        if (node.link_count > 0 || node.fixed()) {
            writeNodeRow(out, node);
        }
    }
    if (!writtenOut(trajectory.get(), options.out_trajectory, log)) {
        return 2;
    }
    const engine::FlightCounters &c = engine.flightCounters();
    std::fprintf(log,
                 "cdro-hostd: moving nodes tracked in 3D: %zu nodes, %llu trajectory rows; %llu ranges to anchors and "
                 "%llu between moving nodes taken (%llu down-weighted as NLOS-looking), %llu refused, %llu resets, "
                 "%llu waiting for an end to start, %llu to nodes that are no anchor (not fixed with a known height), "
                 "%llu mirrored below the anchors, %llu truncated to the room, %llu one-body updates\n",
                 moving.size(), static_cast<unsigned long long>(rows_written),
                 static_cast<unsigned long long>(c.anchor_ranges), static_cast<unsigned long long>(c.tag_ranges),
                 static_cast<unsigned long long>(c.down_weighted), static_cast<unsigned long long>(c.refused),
                 static_cast<unsigned long long>(c.resets), static_cast<unsigned long long>(c.waiting),
                 static_cast<unsigned long long>(c.no_anchor), static_cast<unsigned long long>(c.mirrored),
                 static_cast<unsigned long long>(c.truncated), static_cast<unsigned long long>(c.body_updates));
    // The NLOS model's verdicts per anchor and for the tag-to-tag ranges (scripts/miluv.py reads
    // these lines: docs/engine.md, "Nodes that never stop").
    for (const engine::FlightNlosCount &count : engine.flightNlosCounts()) {
        const std::string link =
            count.anchor == 0 ? std::string("between moving nodes") : "to anchor " + std::to_string(count.anchor);
        const uint64_t decided = count.taken + count.refused;
        std::fprintf(log,
                     "cdro-hostd: NLOS ranges %s: %llu taken, %llu of them down-weighted, %llu refused; %.3f of "
                     "%llu down-weighted or refused\n",
                     link.c_str(), static_cast<unsigned long long>(count.taken),
                     static_cast<unsigned long long>(count.down_weighted),
                     static_cast<unsigned long long>(count.refused),
                     decided > 0
                         ? static_cast<double>(count.down_weighted + count.refused) / static_cast<double>(decided)
                         : 0.0,
                     static_cast<unsigned long long>(decided));
    }
    for (const engine::NodeId id : moving) {
        const std::optional<engine::FlightEstimate> track = engine.flightEstimate(id);
        if (track && track->status != engine::FlightStatus::Tracking) {
            std::fprintf(log,
                         "cdro-hostd: moving node %u heard %u distinct anchors: not enough for a 3D track (%u), "
                         "no rows\n",
                         static_cast<unsigned>(id), track->anchors_heard, engine::FlightTracks::kMinAnchors);
        }
    }
    return 0;
}

} // namespace

int runOffline(const OfflineOptions &options, const engine::EngineParams &params, std::FILE *log)
{
    return runOffline(options, params, engine::MovementParams{}, log);
}

int runOffline(const OfflineOptions &options, const engine::EngineParams &params,
               const engine::MovementParams &movement_params, std::FILE *log)
{
    bool outputs_opened = false; // only files this run opened are removed when it fails
    try {
        engine::Engine engine(params);
        if (options.verbose) {
            engine.setTrace(
                [log](const std::string &message) { std::fprintf(log, "cdro-hostd: engine: %s\n", message.c_str()); });
        }
        applyKnownGeometry(engine, KnownGeometry{options.heights_csv, options.fixed_csv, {}}, options.max_reported_rows,
                           log);
        if (options.moving.empty() && !options.moving_bodies.empty()) {
            std::fprintf(log, "cdro-hostd: --moving-body needs --moving (its nodes are moving ones)\n");
            return 2;
        }
        const bool flights = !options.moving.empty();
        if (!flights && !options.out_anchors.empty()) {
            std::fprintf(log, "cdro-hostd: --out-anchors needs --moving (the anchors are calibrated from moving "
                              "nodes' ranges)\n");
            return 2;
        }
        const bool movement =
            !flights && (!options.odometry_csv.empty() || options.robot_id >= 0 || !options.out_trajectory.empty());

        // Open the outputs before the work, so that an unwritable path fails at once.
        File out = openForWriting(options.out_csv, log);
        if (!out) {
            return 2;
        }
        outputs_opened = true;
        // An input with nothing to map ends the run with status 2, and no empty map is left
        // behind to be taken for a result.
        const auto nothing_to_map = [&](const std::string &why) {
            std::fprintf(log, "cdro-hostd: %s: %s; nothing to map (exit status 2)\n", options.ranges_csv.c_str(),
                         why.c_str());
            removeOutputs(options);
            return 2;
        };
        // The 3D tracks and the movement stage merge every input by time: the ranges are read
        // whole. Returns the exit status (2: nothing to map).
        const auto readWholeRanges = [&](CsvTable<RangeRow> &ranges) {
            const RateClock clock;
            ranges = readRangesCsv(options.ranges_csv, options.max_reported_rows);
            reportCsvProblems(options.ranges_csv, ranges.summary, options.max_reported_rows, log);
            reportRate(log, options.ranges_csv, ranges.summary.data_rows, clock);
            return ranges.rows.empty() ? nothing_to_map("no usable row (" + std::to_string(ranges.summary.bad_rows) +
                                                        " bad rows skipped)")
                                       : 0;
        };
        File trace;
        if (!options.trace_csv.empty()) {
            trace = openForWriting(options.trace_csv, log);
            if (!trace) {
                return 2;
            }
            writeTraceHeader(trace.get());
        }

        if (flights) {
            CsvTable<RangeRow> ranges;
            if (const int code = readWholeRanges(ranges); code != 0) {
                return code;
            }
            int code = runFlights(options, params, engine, ranges, out.get(), log);
            if (code == 0 && !writtenOut(out.get(), options.out_csv, log)) {
                code = 2;
            }
            if (code != 0) {
                removeOutputs(options);
            }
            return code;
        }
        if (movement) {
            if (options.odometry_csv.empty() || options.robot_id < 0 || options.out_trajectory.empty()) {
                std::fprintf(log,
                             "cdro-hostd: the movement stage needs --odometry-csv, --robot-id and --out-trajectory\n");
                return 2;
            }
            // The stage merges every input by time: the ranges are read whole and sorted.
            CsvTable<RangeRow> ranges;
            if (const int code = readWholeRanges(ranges); code != 0) {
                return code;
            }
            engine::MovementParams stage_params = movement_params;
            stage_params.robot_id = static_cast<engine::NodeId>(options.robot_id);
            const int code = runMovement(options, params, stage_params, engine, ranges, out.get(), log);
            if (code == 0 && !writtenOut(out.get(), options.out_csv, log)) {
                return 2;
            }
            return code;
        }
        uint64_t refused = 0;
        uint64_t processed = 0;
        const uint32_t every = std::max<uint32_t>(options.trace_every, 1U);
        // Motion reports (optional) are applied in time order between the ranges.
        CsvTable<MotionRow> motion;
        if (!options.motion_csv.empty()) {
            motion = readMotionCsv(options.motion_csv, options.max_reported_rows);
            reportCsvProblems(options.motion_csv, motion.summary, options.max_reported_rows, log);
            sortByTime(motion.rows, options.motion_csv, log);
        }
        size_t next_motion = 0;
        double last_t_s = 0.0;
        bool timed = false;
        bool untimed_with_motion = false;
        // The ranges stream through the engine as they are read (in file order, as over the
        // link): memory does not grow with the file, and a progress line comes every second.
        struct HeldTrace {
            uint64_t ranges = 0;
            std::vector<engine::NodeOutput> estimates;
            bool timed = false;
            double t_s = 0.0; // s
        };
        std::optional<HeldTrace> held_trace;
        const RateClock clock;
        ProgressTicker progress;
        csv::Reader reader(options.ranges_csv, rangesFormat(), csv::Policy::Lenient, options.max_reported_rows);
        reader.forEach([&](const csv::Row &fields) {
            RangeRow row;
            if (!rangeRow(fields, &row)) {
                return; // counted, and its reason kept, by the reader
            }
            if (untimed_with_motion) {
                return;
            }
            if (!motion.rows.empty() && !row.has_time) {
                untimed_with_motion = true;
                return;
            }
            while (next_motion < motion.rows.size() && motion.rows[next_motion].t_s <= row.t_s) {
                engine.setMoving(motion.rows[next_motion].id, motion.rows[next_motion].moving);
                ++next_motion;
            }
            const engine::RangeVerdict verdict =
                engine.addRange(row.from, row.to, row.range_m, row.has_time ? row.t_s : std::nan(""));
            ++processed;
            timed = row.has_time;
            last_t_s = row.t_s;
            if (verdict == engine::RangeVerdict::RejectedSelf || verdict == engine::RangeVerdict::RejectedValue) {
                if (refused++ < options.max_reported_rows) {
                    std::fprintf(log, "cdro-hostd: %s:%zu: skipped: %s (%u -> %u, %.17g m)\n",
                                 options.ranges_csv.c_str(), row.line, engine::rangeVerdictName(verdict),
                                 static_cast<unsigned>(row.from), static_cast<unsigned>(row.to), row.range_m);
                }
            }
            // A snapshot is written once the next range shows it was not the last: the last
            // range's snapshot is the final one, written after settling.
            if (held_trace) {
                writeTraceRows(trace.get(), held_trace->ranges, held_trace->estimates,
                               held_trace->timed ? &held_trace->t_s : nullptr);
                held_trace.reset();
            }
            if (trace && processed % every == 0) {
                held_trace = HeldTrace{processed, engine.estimates(), timed, last_t_s};
            }
            if (progress.due()) {
                const uint64_t so_far = processed + reader.summary().bad_rows;
                std::fprintf(log, "cdro-hostd: %s: %llu rows so far (%.0f rows/s)\n", options.ranges_csv.c_str(),
                             static_cast<unsigned long long>(so_far), static_cast<double>(so_far) / clock.seconds());
            }
        });
        if (untimed_with_motion) {
            std::fprintf(log, "cdro-hostd: %s: --motion-csv needs a t column in the ranges\n",
                         options.ranges_csv.c_str());
            return 2;
        }
        const size_t bad_rows = reader.summary().bad_rows;
        reportCsvProblems(options.ranges_csv, reader.summary(), options.max_reported_rows, log);
        reportRate(log, options.ranges_csv, reader.summary().data_rows, clock);
        if (refused > options.max_reported_rows) {
            std::fprintf(log, "cdro-hostd: %s: %llu more refused ranges (not shown)\n", options.ranges_csv.c_str(),
                         static_cast<unsigned long long>(refused - options.max_reported_rows));
        }
        if (processed == 0) {
            return nothing_to_map("no usable row (" + std::to_string(bad_rows) + " bad rows skipped)");
        }
        if (refused == processed) {
            return nothing_to_map("none of the " + std::to_string(processed) +
                                  " ranges read could be used (the engine refused every one, above)");
        }
        uint64_t settled = 0;
        if (options.settle) {
            const uint64_t budget =
                options.settle_budget != 0 ? options.settle_budget : 200ULL * engine.map().nodes.size() + 1000ULL;
            settled = engine.settle(budget);
        }
        const std::vector<engine::NodeOutput> estimates = engine.estimates();
        if (trace) {
            // The final state, after settling, as the last snapshot.
            writeTraceRows(trace.get(), processed, estimates, timed ? &last_t_s : nullptr);
        }
        writeNodesHeader(out.get());
        size_t placed = 0;
        size_t converged = 0;
        for (const engine::NodeOutput &node : estimates) {
            reportDoubt(log, node);
            if (node.link_count > 0 || node.fixed()) {
                writeNodeRow(out.get(), node);
            }
            placed += node.placed() ? 1U : 0U;
            converged += node.converged() ? 1U : 0U;
        }
        if (!writtenOut(out.get(), options.out_csv, log)) {
            return 2;
        }
        const engine::EngineCounters c = engine.counters();
        std::fprintf(log,
                     "cdro-hostd: %llu ranges read (%zu bad rows skipped), %llu used, %llu stored before placement, "
                     "%llu refused (%llu self, %llu value), %llu projections clamped\n",
                     static_cast<unsigned long long>(processed), bad_rows,
                     static_cast<unsigned long long>(c.ranges_used), static_cast<unsigned long long>(c.ranges_stored),
                     static_cast<unsigned long long>(refused), static_cast<unsigned long long>(c.intake.rejected_self),
                     static_cast<unsigned long long>(c.intake.rejected_value),
                     static_cast<unsigned long long>(c.intake.projection_clamped));
        std::fprintf(log,
                     "cdro-hostd: %zu nodes placed, %zu converged, %zu links; NLOS handling: %llu EKF updates gated, "
                     "%llu weight terms down-weighted, %llu refinement links down-weighted; %llu re-placements, "
                     "%llu global solves (%llu of them refreshes, %llu maps adopted), %llu settle updates; motion: "
                     "%llu starts (%llu inferred "
                     "from ranges), %llu stops\n",
                     placed, converged, engine.map().links.size(), static_cast<unsigned long long>(c.sogs.ekf_gated),
                     static_cast<unsigned long long>(c.sogs.weight_terms_downweighted),
                     static_cast<unsigned long long>(c.refinement.links_downweighted),
                     static_cast<unsigned long long>(c.placement.replacements),
                     static_cast<unsigned long long>(c.solve.solves),
                     static_cast<unsigned long long>(c.solve.solve_refreshes),
                     static_cast<unsigned long long>(c.solve.solves_adopted), static_cast<unsigned long long>(settled),
                     static_cast<unsigned long long>(c.motion.motion_starts),
                     static_cast<unsigned long long>(c.motion.motion_inferred),
                     static_cast<unsigned long long>(c.motion.motion_stops));
        return 0;
    } catch (const CsvError &error) {
        std::fprintf(log, "cdro-hostd: %s\n", error.what());
        // The outputs may have been opened already (the ranges are read as they are used):
        // nothing half-done is left behind.
        if (outputs_opened) {
            removeOutputs(options);
        }
        return 2;
    } catch (const std::logic_error &error) {
        std::fprintf(log, "cdro-hostd: %s\n", error.what());
        return 2;
    }
}

} // namespace cdro::hostd
