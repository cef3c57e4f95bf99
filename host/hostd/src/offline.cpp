#include "cdro/hostd/offline.hpp"

#include <cerrno>
#include <cstring>
#include <memory>

#include "cdro/engine/engine.hpp"
#include "cdro/hostd/csv_input.hpp"
#include "cdro/hostd/estimates_csv.hpp"

namespace cdro::hostd {

namespace {

struct FileCloser {
    void operator()(std::FILE *file) const
    {
        if (file != nullptr) {
            std::fclose(file);
        }
    }
};
using File = std::unique_ptr<std::FILE, FileCloser>;

File openForWriting(const std::string &path, std::FILE *log)
{
    File file(std::fopen(path.c_str(), "w"));
    if (!file) {
        std::fprintf(log, "cdro-hostd: cannot write %s: %s\n", path.c_str(), std::strerror(errno));
    }
    return file;
}

template <typename Table>
void reportProblems(const std::string &path, const Table &table, uint32_t limit, std::FILE *log)
{
    size_t shown = 0;
    for (const CsvProblem &problem : table.problems) {
        if (shown++ < limit) {
            std::fprintf(log, "cdro-hostd: %s:%zu: skipped: %s\n", path.c_str(), problem.line, problem.message.c_str());
        }
    }
    if (table.problems.size() > limit) {
        std::fprintf(log, "cdro-hostd: %s: %zu more bad rows skipped (not shown)\n", path.c_str(),
                     table.problems.size() - limit);
    }
}

} // namespace

int runOffline(const OfflineOptions &options, const engine::EngineParams &params, std::FILE *log)
{
    try {
        engine::Engine engine(params);
        if (!options.heights_csv.empty()) {
            const CsvTable<HeightRow> heights = readHeightsCsv(options.heights_csv);
            reportProblems(options.heights_csv, heights, options.max_reported_rows, log);
            for (const HeightRow &row : heights.rows) {
                engine.setHeight(row.id, row.z_m);
            }
        }
        if (!options.fixed_csv.empty()) {
            const CsvTable<FixedRow> fixed = readFixedCsv(options.fixed_csv);
            reportProblems(options.fixed_csv, fixed, options.max_reported_rows, log);
            for (const FixedRow &row : fixed.rows) {
                engine.setFixed(row.id, engine::Vector2(row.x_m, row.y_m));
            }
        }
        const CsvTable<RangeRow> ranges = readRangesCsv(options.ranges_csv);
        reportProblems(options.ranges_csv, ranges, options.max_reported_rows, log);

        // Open the outputs before the work, so that an unwritable path fails at once.
        File out = openForWriting(options.out_csv, log);
        if (!out) {
            return 2;
        }
        File trace;
        if (!options.trace_csv.empty()) {
            trace = openForWriting(options.trace_csv, log);
            if (!trace) {
                return 2;
            }
            writeTraceHeader(trace.get());
        }

        uint64_t refused = 0;
        uint64_t processed = 0;
        const uint32_t every = std::max<uint32_t>(options.trace_every, 1U);
        for (const RangeRow &row : ranges.rows) {
            const engine::RangeVerdict verdict = engine.addRange(row.from, row.to, row.range_m);
            ++processed;
            if (verdict == engine::RangeVerdict::RejectedSelf || verdict == engine::RangeVerdict::RejectedValue) {
                if (refused++ < options.max_reported_rows) {
                    std::fprintf(log, "cdro-hostd: %s:%zu: skipped: %s (%u -> %u, %.17g m)\n",
                                 options.ranges_csv.c_str(), row.line, engine::rangeVerdictName(verdict),
                                 static_cast<unsigned>(row.from), static_cast<unsigned>(row.to), row.range_m);
                }
            }
            if (trace && processed % every == 0) {
                writeTraceRows(trace.get(), processed, engine.estimates());
            }
        }
        if (refused > options.max_reported_rows) {
            std::fprintf(log, "cdro-hostd: %s: %llu more refused ranges (not shown)\n", options.ranges_csv.c_str(),
                         static_cast<unsigned long long>(refused - options.max_reported_rows));
        }
        uint64_t settled = 0;
        if (options.settle) {
            const uint64_t budget =
                options.settle_budget != 0 ? options.settle_budget : 200ULL * engine.network().nodes.size() + 1000ULL;
            settled = engine.settle(budget);
        }
        const std::vector<engine::NodeOutput> estimates = engine.estimates();
        if (trace) {
            // The final state, after settling, as the last snapshot.
            writeTraceRows(trace.get(), processed, estimates);
        }
        writeNodesHeader(out.get());
        size_t placed = 0;
        size_t converged = 0;
        for (const engine::NodeOutput &node : estimates) {
            if (node.link_count > 0 || node.fixed) {
                writeNodeRow(out.get(), node);
            }
            placed += node.placed ? 1U : 0U;
            converged += node.converged ? 1U : 0U;
        }
        if (std::fflush(out.get()) != 0 || std::ferror(out.get())) {
            std::fprintf(log, "cdro-hostd: writing %s failed: %s\n", options.out_csv.c_str(), std::strerror(errno));
            return 2;
        }
        const engine::EngineCounters &c = engine.counters();
        std::fprintf(log,
                     "cdro-hostd: %llu ranges read (%zu bad rows skipped), %llu used, %llu stored before placement, "
                     "%llu refused (%llu self, %llu value), %llu projections clamped\n",
                     static_cast<unsigned long long>(processed), ranges.problems.size(),
                     static_cast<unsigned long long>(c.ranges_used), static_cast<unsigned long long>(c.ranges_stored),
                     static_cast<unsigned long long>(refused), static_cast<unsigned long long>(c.rejected_self),
                     static_cast<unsigned long long>(c.rejected_value),
                     static_cast<unsigned long long>(c.projection_clamped));
        std::fprintf(log,
                     "cdro-hostd: %zu nodes placed, %zu converged, %zu links; NLOS handling: %llu EKF updates gated, "
                     "%llu weight terms down-weighted, %llu refinement links down-weighted; %llu re-placements, "
                     "%llu initializations (%llu adopted), %llu settle updates; motion: %llu starts (%llu inferred from "
                     "ranges), %llu stops\n",
                     placed, converged, engine.network().links.size(), static_cast<unsigned long long>(c.ekf_gated),
                     static_cast<unsigned long long>(c.weight_terms_downweighted),
                     static_cast<unsigned long long>(c.refinement_links_downweighted),
                     static_cast<unsigned long long>(c.replacements),
                     static_cast<unsigned long long>(c.reinitializations),
                     static_cast<unsigned long long>(c.reinitializations_adopted),
                     static_cast<unsigned long long>(settled), static_cast<unsigned long long>(c.motion_starts),
                     static_cast<unsigned long long>(c.motion_inferred), static_cast<unsigned long long>(c.motion_stops));
        return 0;
    } catch (const CsvError &error) {
        std::fprintf(log, "cdro-hostd: %s\n", error.what());
        return 2;
    } catch (const std::logic_error &error) {
        std::fprintf(log, "cdro-hostd: %s\n", error.what());
        return 2;
    }
}

} // namespace cdro::hostd
