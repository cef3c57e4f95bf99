#include "cdro/service/json_output.hpp"

#include <cerrno>
#include <cmath>
#include <cstring>

#include <fcntl.h>
#include <poll.h>
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
    }
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
    fd_ = openOutputFile(config_.jsonl, O_WRONLY | O_CREAT | O_TRUNC | O_APPEND, "output.jsonl");
    owns_fd_ = true;
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

void JsonLinesWriter::onUpdate(const MapState &map, int64_t event_us)
{
    if (fd_ < 0) {
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
    for (const NodeEstimate &node : map.nodes) {
        auto it = last_node_.find(node.id);
        if (it != last_node_.end() && sameEstimate(it->second, node)) {
            continue;
        }
        append(line(nodeJson(node, outputTimeOf(map))));
        last_node_[node.id] = node;
    }
    if (map.robot && !(last_robot_ && sameEstimate(*last_robot_, *map.robot))) {
        append(line(robotJson(*map.robot, outputTimeOf(map))));
        last_robot_ = map.robot;
    }
}

void JsonLinesWriter::finish(const MapState &map)
{
    if (fd_ >= 0 && period_us_ > 0 && dirty_) {
        dirty_ = false;
        writeAll(map);
    }
}

void JsonLinesWriter::writeHealth(const Health &health, OutputTime time)
{
    if (fd_ < 0) {
        return;
    }
    append(line(healthJson(health, time)));
}

void JsonLinesWriter::flush()
{
    if (fd_ < 0 || pending_.empty()) {
        pending_.clear();
        return;
    }
    const char *data = pending_.data();
    size_t left = pending_.size();
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
            break;
        }
        data += n;
        left -= static_cast<size_t>(n);
    }
    pending_.clear();
}

void JsonLinesWriter::close()
{
    flush();
    if (owns_fd_ && fd_ >= 0) {
        ::close(fd_);
    }
    fd_ = -1;
    owns_fd_ = false;
}

} // namespace cdro::service
