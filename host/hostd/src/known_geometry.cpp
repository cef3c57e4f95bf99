// Known heights and fixed nodes, from the `map:` section or the command line (known_geometry.hpp).
#include "cdro/hostd/known_geometry.hpp"

#include <yaml-cpp/yaml.h>

#include "cdro/engine/engine.hpp"
#include "cdro/hostd/csv_input.hpp"
#include "cdro/service/config.hpp"
#include "cdro/service/yaml_section.hpp"

namespace cdro::hostd {

KnownGeometry parseKnownGeometry(const YAML::Node &root, const std::string &origin)
{
    KnownGeometry geometry;
    if (!root || !root.IsMap()) {
        return geometry;
    }
    const YAML::Node node = root["map"];
    if (!node) {
        return geometry;
    }
    service::Section section(node, "map", origin);
    section.readString("heights_csv", geometry.heights_csv);
    section.readString("fixed_csv", geometry.fixed_csv);
    section.rejectUnknownKeys();
    return geometry;
}

KnownGeometryCounts applyKnownGeometry(engine::Engine &engine, const KnownGeometry &geometry,
                                       uint32_t max_reported_rows, std::FILE *log)
{
    KnownGeometryCounts counts;
    if (!geometry.heights_csv.empty()) {
        const CsvTable<HeightRow> heights = readHeightsCsv(geometry.heights_csv);
        reportCsvProblems(geometry.heights_csv, heights.problems, max_reported_rows, log);
        for (const HeightRow &row : heights.rows) {
            engine.setHeight(row.id, row.z_m);
        }
        counts.heights = heights.rows.size();
        counts.skipped_rows += heights.problems.size();
    }
    if (!geometry.fixed_csv.empty()) {
        const CsvTable<FixedRow> fixed = readFixedCsv(geometry.fixed_csv);
        reportCsvProblems(geometry.fixed_csv, fixed.problems, max_reported_rows, log);
        for (const FixedRow &row : fixed.rows) {
            engine.setFixed(row.id, engine::Vector2(row.x_m, row.y_m));
        }
        counts.fixed = fixed.rows.size();
        counts.skipped_rows += fixed.problems.size();
    }
    return counts;
}

} // namespace cdro::hostd
