// json_output.hpp: the JSON Lines stream of docs/outputs.md, to stdout or a file.
//
// Policy (all decided on event time, so that a replay writes the same node and robot lines,
// byte for byte, whatever its speed):
//   rate_hz == 0  after every update, a line for each node (and the robot) whose estimate
//                 differs from the line last written for it, at most jsonl.max_node_rate_hz
//                 lines per node (and for the robot) per second: a change within 1/max_node_rate_hz
//                 of that node's last line is held back and goes out with the first update
//                 after the interval (the node's estimate then, which may have moved on), or at
//                 the end of the run (finish(): the last update's estimates with its event
//                 time, so a replay ends as the live run did); counted in jsonl_lines_held;
//   rate_hz > 0   every 1/rate_hz s of event time in which something was updated, a line for
//                 every node (and the robot).
// Health lines are written by the service's health timer (writeHealth); they describe the
// process (link state, counters) and are not part of the replay guarantee.
//
// A file is opened for appending, never truncated: a restart (systemd's Restart=, a resume)
// continues the file. Before a flush would take it past jsonl.rotate_mib, it is rotated as the
// capture is (path -> path.1 ... path.<keep>, output_file.hpp's rotateFiles) and a new file
// started; a flush is split at line ends, so that every file holds whole lines and stays under
// the limit (a single longer line gets a file of its own), and the disk use stays bounded.
//
// Lines are collected in memory and written with one write() per flush(); the service
// flushes after each batch of input and on exit. A failed write (e.g. a closed pipe) is
// logged once and counted in jsonl_write_errors; the service keeps running.
//
// Threading: loop thread only.
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "cdro/service/config.hpp"
#include "cdro/service/map_state.hpp"

namespace cdro::service {

class JsonLinesWriter {
public:
    JsonLinesWriter(const OutputConfig &config, ServiceCounters &counters);
    ~JsonLinesWriter();
    JsonLinesWriter(const JsonLinesWriter &) = delete;
    JsonLinesWriter &operator=(const JsonLinesWriter &) = delete;

    void open(); // "-" = stdout, "" = disabled; throws ConfigError if unwritable
    bool enabled() const { return fd_ >= 0; }

    // After an update at event time event_us (map.t_s is already set): changed, the positions
    // in map.nodes of the nodes it may have changed (MapSource::updateEstimates); the nodes held
    // back before are looked at again. Without `changed`, every node is looked at.
    void onUpdate(const MapState &map, const std::vector<size_t> &changed, int64_t event_us);
    void onUpdate(const MapState &map, int64_t event_us) { onUpdate(map, allNodes(map), event_us); }
    // At the end of a run: with rate_hz > 0, the estimates updated since the last period (map);
    // with the per-node limit, what the last update held back (as of that update).
    void finish(const MapState &map);
    void writeHealth(const Health &health, OutputTime time);
    void flush();
    void close();

    // The serialised line (no newline) exactly as written; exposed for MQTT and tests.
    static std::string line(const nlohmann::ordered_json &object);

private:
    void append(const std::string &text);
    void writeAll(const MapState &map);
    void writeChanged(const MapState &map, const std::vector<size_t> &positions, int64_t event_us);
    bool writable();                              // the file is open, or could be started again after a failed rotation
    void startNewFile();                          // rotates the current file away (if open), opens a new one
    size_t wholeLinesThatFit(size_t start) const; // end of the pending lines from start that fit the file
    bool writeRange(size_t start, size_t end);

    OutputConfig config_;
    ServiceCounters &counters_;
    int fd_ = -1;
    bool owns_fd_ = false;
    bool error_logged_ = false;
    std::string pending_;
    std::map<uint16_t, NodeEstimate> last_node_; // id -> the estimate last written
    std::optional<RobotPose> last_robot_;
    int64_t period_us_ = 0;
    int64_t next_due_us_ = INT64_MIN;
    bool dirty_ = false;
    int64_t node_interval_us_ = 0;             // 1/max_node_rate_hz; 0 = no limit
    std::map<uint16_t, int64_t> last_node_us_; // id -> event time of its last line
    int64_t last_robot_us_ = INT64_MIN;
    // What the last update held back (empty when it held nothing), sorted by id, as of that
    // update: finish() writes it.
    std::vector<NodeEstimate> held_nodes_;
    std::vector<uint16_t> held_ids_; // their ids: the next update looks at them again
    std::optional<RobotPose> held_robot_;
    OutputTime held_time_;
    uint64_t file_bytes_ = 0; // bytes in the current file
    uint64_t rotate_bytes_ = 0;
    bool reopen_pending_ = false; // a rotation could not start its new file
    bool rotating_ = false;       // a regular file of ours: rotated by size
};

} // namespace cdro::service
