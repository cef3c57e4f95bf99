#include "cdro/service/json_output.hpp"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>

#include <fcntl.h>
#include <poll.h>
#include <sys/stat.h>
#include <unistd.h>

#include <nlohmann/json.hpp>

#include "cdro/service/log.hpp"
#include "cdro/service/output_file.hpp"

namespace cdro::service {

JsonLinesWriter::JsonLinesWriter(const OutputConfig &config, ServiceCounters &counters)
    : config_(config), counters_(counters)
{
    if (config_.rate_hz > 0.0) {
        period_us_ = static_cast<int64_t>(std::llround(1e6 / config_.rate_hz));
    } else if (config_.limits.max_node_rate_hz > 0.0) {
        node_interval_us_ = static_cast<int64_t>(std::llround(1e6 / config_.limits.max_node_rate_hz));
    }
    rotate_bytes_ = static_cast<uint64_t>(std::llround(config_.limits.rotate_mib * 1024.0 * 1024.0));
}

JsonLinesWriter::~JsonLinesWriter() { close(); }

std::string JsonLinesWriter::line(const nlohmann::ordered_json &object)
{
    // Shortest round-trip formatting of doubles: the same value always prints the same way.
    return object.dump(-1, ' ', false, nlohmann::ordered_json::error_handler_t::replace);
}

void JsonLinesWriter::open()
{
    close();
    if (config_.jsonl.empty()) {
        return;
    }
    if (config_.jsonl == "-") {
        fd_ = STDOUT_FILENO;
        owns_fd_ = false;
        return;
    }
    // Appended to: what an earlier run (or the run before a restart) wrote stays.
    fd_ = openOutputFile(config_.jsonl, O_WRONLY | O_CREAT | O_APPEND, "output.jsonl");
    owns_fd_ = true;
    struct stat st {};
    // Only a regular file is rotated: /dev/null or a FIFO never fills.
    rotating_ = ::fstat(fd_, &st) == 0 && S_ISREG(st.st_mode);
    file_bytes_ = rotating_ ? static_cast<uint64_t>(st.st_size) : 0;
}

bool JsonLinesWriter::writable() { return fd_ >= 0 || reopen_pending_; }

void JsonLinesWriter::startNewFile()
{
    if (fd_ >= 0) {
        ::close(fd_);
        fd_ = -1;
        rotateFiles(config_.jsonl, config_.limits.keep);
        ++counters_.jsonl_rotations;
        log()->info("output: rotated {} (keeping {} older files)", config_.jsonl, config_.limits.keep);
    }
    try {
        // O_EXCL: whatever was at the path has just been rotated away.
        fd_ = openOutputFile(config_.jsonl, O_WRONLY | O_CREAT | O_EXCL | O_APPEND, "output.jsonl");
        file_bytes_ = 0;
        if (reopen_pending_) {
            log()->info("output: writing JSON lines to {} again", config_.jsonl);
        }
        reopen_pending_ = false;
    } catch (const ConfigError &error) {
        if (!reopen_pending_) {
            log()->error("{}; JSON lines are lost and counted in jsonl_write_errors until a new file can be started "
                         "(tried at every flush; it will be logged)",
                         error.what());
        }
        reopen_pending_ = true;
    }
}

void JsonLinesWriter::append(const std::string &text)
{
    pending_ += text;
    pending_ += '\n';
    ++counters_.jsonl_lines;
}

void JsonLinesWriter::writeAll(const MapState &map)
{
    for (const NodeEstimate &node : map.nodes) {
        append(line(nodeJson(node, outputTimeOf(map))));
        last_node_[node.id] = node;
    }
    if (map.robot) {
        append(line(robotJson(*map.robot, outputTimeOf(map))));
        last_robot_ = map.robot;
    }
}

void JsonLinesWriter::onUpdate(const MapState &map, const std::vector<size_t> &changed, int64_t event_us)
{
    if (!writable()) {
        return;
    }
    if (period_us_ > 0) {
        dirty_ = true;
        if (event_us < next_due_us_) {
            return;
        }
        // The next line is due one period after this one, on a grid of event time, so that
        // the pace of arrival does not matter.
        next_due_us_ = (event_us / period_us_ + 1) * period_us_;
        dirty_ = false;
        writeAll(map);
        return;
    }
    writeChanged(map, nodesToLookAt(map, changed, held_ids_), event_us);
}

void JsonLinesWriter::writeChanged(const MapState &map, const std::vector<size_t> &positions, int64_t event_us)
{
    std::vector<size_t> held;
    for (const size_t position : positions) {
        const NodeEstimate &node = map.nodes[position];
        auto it = last_node_.find(node.id);
        if (it != last_node_.end() && sameEstimate(it->second, node)) {
            continue;
        }
        if (node_interval_us_ > 0) {
            auto when = last_node_us_.find(node.id);
            if (when != last_node_us_.end() && event_us - when->second < node_interval_us_) {
                ++counters_.jsonl_lines_held;
                held.push_back(position);
                continue;
            }
        }
        append(line(nodeJson(node, outputTimeOf(map))));
        last_node_[node.id] = node;
        last_node_us_[node.id] = event_us;
    }
    held_robot_.reset();
    if (map.robot && !(last_robot_ && sameEstimate(*last_robot_, *map.robot))) {
        if (node_interval_us_ > 0 && last_robot_ && event_us - last_robot_us_ < node_interval_us_) {
            ++counters_.jsonl_lines_held;
            held_robot_ = map.robot;
        } else {
            append(line(robotJson(*map.robot, outputTimeOf(map))));
            last_robot_ = map.robot;
            last_robot_us_ = event_us;
        }
    }
    // What is held back goes out with the first update after its interval, or at the end as of
    // the last update, stamped with its event time, so that a replay ends with the same lines as
    // the live run it replays.
    held_nodes_.clear();
    held_ids_.clear();
    for (const size_t position : held) {
        held_nodes_.push_back(map.nodes[position]);
        held_ids_.push_back(map.nodes[position].id);
    }
    held_time_ = outputTimeOf(map);
}

void JsonLinesWriter::finish(const MapState &map)
{
    if (!writable()) {
        return;
    }
    if (period_us_ > 0 && dirty_) {
        dirty_ = false;
        writeAll(map);
    } else if (period_us_ == 0) {
        // What the rate limit held back: the last estimates must not be lost at the end.
        for (const NodeEstimate &node : held_nodes_) {
            append(line(nodeJson(node, held_time_)));
            last_node_[node.id] = node;
        }
        if (held_robot_) {
            append(line(robotJson(*held_robot_, held_time_)));
            last_robot_ = held_robot_;
        }
        held_nodes_.clear();
        held_ids_.clear();
        held_robot_.reset();
    }
}

void JsonLinesWriter::writeHealth(const Health &health, OutputTime time)
{
    if (!writable()) {
        return;
    }
    append(line(healthJson(health, time)));
}

void JsonLinesWriter::flush()
{
    size_t start = 0;
    while (start < pending_.size()) {
        size_t end = pending_.size();
        if (rotating_) {
            end = wholeLinesThatFit(start);
            if (end == start && (file_bytes_ > 0 || fd_ < 0)) {
                startNewFile(); // rotates the full file away, or retries after a failed rotation
                if (fd_ < 0) {
                    counters_.jsonl_write_errors += static_cast<uint64_t>(
                        std::count(pending_.begin() + static_cast<std::ptrdiff_t>(start), pending_.end(), '\n'));
                    break;
                }
                continue;
            }
            if (end == start) {
                end = pending_.find('\n', start) + 1; // a line longer than the limit gets a file of its own
            }
        }
        if (fd_ < 0 || !writeRange(start, end)) {
            break;
        }
        start = end;
    }
    pending_.clear();
}

size_t JsonLinesWriter::wholeLinesThatFit(size_t start) const
{
    const uint64_t room = file_bytes_ < rotate_bytes_ ? rotate_bytes_ - file_bytes_ : 0;
    if (fd_ < 0 || room == 0) {
        return start;
    }
    if (pending_.size() - start <= room) {
        return pending_.size();
    }
    const size_t last_newline = pending_.rfind('\n', start + static_cast<size_t>(room) - 1);
    return last_newline == std::string::npos || last_newline < start ? start : last_newline + 1;
}

bool JsonLinesWriter::writeRange(size_t start, size_t end)
{
    const char *data = pending_.data() + start;
    size_t left = end - start;
    while (left > 0) {
        const ssize_t n = ::write(fd_, data, left);
        if (n < 0 && errno == EINTR) {
            continue;
        }
        if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
            // A non-blocking stdout that is full: wait for it (as a blocking write would)
            // rather than lose lines or spin.
            pollfd p{fd_, POLLOUT, 0};
            ::poll(&p, 1, 1000);
            continue;
        }
        if (n <= 0) {
            ++counters_.jsonl_write_errors;
            if (!error_logged_) {
                error_logged_ = true;
                log()->error("output: cannot write JSON lines to {}: {} (counted in jsonl_write_errors)",
                             config_.jsonl == "-" ? "stdout" : config_.jsonl, std::strerror(errno));
            }
            return false;
        }
        data += n;
        left -= static_cast<size_t>(n);
        file_bytes_ += static_cast<uint64_t>(n);
    }
    return true;
}

void JsonLinesWriter::close()
{
    flush();
    if (owns_fd_ && fd_ >= 0) {
        ::close(fd_);
    }
    fd_ = -1;
    owns_fd_ = false;
    reopen_pending_ = false;
    rotating_ = false;
}

} // namespace cdro::service
