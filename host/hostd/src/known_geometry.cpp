// Known heights and fixed nodes, from the `map:` section or the command line (known_geometry.hpp).
#include "cdro/hostd/known_geometry.hpp"

#include <algorithm>
#include <stdexcept>

#include <nlohmann/json.hpp>
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
    section.readIds("moving", geometry.moving);
    section.rejectUnknownKeys();
    return geometry;
}

bool KnownRows::operator==(const KnownRows &other) const
{
    if (heights.size() != other.heights.size() || fixed.size() != other.fixed.size()) {
        return false;
    }
    for (size_t i = 0; i < heights.size(); ++i) {
        if (heights[i].id != other.heights[i].id || heights[i].z_m != other.heights[i].z_m) {
            return false;
        }
    }
    for (size_t i = 0; i < fixed.size(); ++i) {
        if (fixed[i].id != other.fixed[i].id || fixed[i].x_m != other.fixed[i].x_m ||
            fixed[i].y_m != other.fixed[i].y_m) {
            return false;
        }
    }
    return true;
}

KnownRows readKnownGeometry(const KnownGeometry &geometry, uint32_t max_reported_rows, std::FILE *log)
{
    KnownRows rows;
    if (!geometry.heights_csv.empty()) {
        CsvTable<HeightRow> heights = readHeightsCsv(geometry.heights_csv, max_reported_rows);
        reportCsvProblems(geometry.heights_csv, heights.summary, max_reported_rows, log);
        rows.heights = std::move(heights.rows);
        rows.skipped_rows += heights.summary.bad_rows;
    }
    if (!geometry.fixed_csv.empty()) {
        CsvTable<FixedRow> fixed = readFixedCsv(geometry.fixed_csv, max_reported_rows);
        reportCsvProblems(geometry.fixed_csv, fixed.summary, max_reported_rows, log);
        rows.fixed = std::move(fixed.rows);
        rows.skipped_rows += fixed.summary.bad_rows;
    }
    return rows;
}

KnownGeometryCounts applyKnownRows(engine::Engine &engine, const KnownRows &rows)
{
    KnownGeometryCounts counts;
    for (const HeightRow &row : rows.heights) {
        engine.setHeight(row.id, row.z_m);
    }
    for (const FixedRow &row : rows.fixed) {
        engine.setFixed(row.id, engine::Vector2(row.x_m, row.y_m));
    }
    counts.heights = rows.heights.size();
    counts.fixed = rows.fixed.size();
    counts.skipped_rows = rows.skipped_rows;
    return counts;
}

void trackMovingNodes(engine::Engine &engine, const KnownRows &rows, const std::vector<uint16_t> &moving)
{
    if (moving.empty()) {
        return;
    }
    size_t anchors = 0;
    for (const FixedRow &fixed : rows.fixed) {
        anchors += std::any_of(rows.heights.begin(), rows.heights.end(),
                               [&fixed](const HeightRow &height) { return height.id == fixed.id; })
                       ? 1U
                       : 0U;
    }
    if (anchors < engine::FlightTracks::kMinAnchors) {
        throw service::ConfigError("map.moving: the nodes tracked in 3D need at least " +
                                   std::to_string(engine::FlightTracks::kMinAnchors) +
                                   " fixed nodes of known height (map.fixed_csv and map.heights_csv, or --fixed-csv "
                                   "and --heights-csv); " +
                                   std::to_string(anchors) + " given");
    }
    for (const uint16_t id : moving) {
        try {
            engine.trackMoving3D(id);
        } catch (const std::logic_error &error) {
            throw service::ConfigError(std::string("map.moving: ") + error.what());
        }
    }
}

KnownGeometryCounts applyKnownGeometry(engine::Engine &engine, const KnownGeometry &geometry,
                                       uint32_t max_reported_rows, std::FILE *log)
{
    return applyKnownRows(engine, readKnownGeometry(geometry, max_reported_rows, log));
}

std::string encodeRunContext(const RunContext &context)
{
    nlohmann::ordered_json json;
    json["heights"] = nlohmann::ordered_json::array();
    for (const HeightRow &row : context.rows.heights) {
        json["heights"].push_back({row.id, row.z_m});
    }
    json["fixed"] = nlohmann::ordered_json::array();
    for (const FixedRow &row : context.rows.fixed) {
        json["fixed"].push_back({row.id, row.x_m, row.y_m});
    }
    json["settings"] = context.settings;
    if (!context.moving.empty()) {
        json["moving"] = context.moving; // absent otherwise: the header of a run without it is as before
    }
    if (context.solve_adoption_recorded) {
        json["solve_adoption"] = "recorded";
    }
    return json.dump(); // doubles in their shortest round-trip form: read back bit for bit
}

RunContext decodeRunContext(const std::string &text, const std::string &origin)
{
    RunContext context;
    try {
        const nlohmann::json json = nlohmann::json::parse(text);
        for (const auto &item : json.at("heights")) {
            HeightRow row;
            row.id = item.at(0).get<uint16_t>();
            row.z_m = item.at(1).get<double>();
            context.rows.heights.push_back(row);
        }
        for (const auto &item : json.at("fixed")) {
            FixedRow row;
            row.id = item.at(0).get<uint16_t>();
            row.x_m = item.at(1).get<double>();
            row.y_m = item.at(2).get<double>();
            context.rows.fixed.push_back(row);
        }
        context.settings = json.at("settings").get<std::string>();
        if (json.contains("moving")) {
            context.moving = json.at("moving").get<std::vector<uint16_t>>();
        }
        if (json.contains("solve_adoption")) {
            const std::string adoption = json.at("solve_adoption").get<std::string>();
            if (adoption != "recorded") {
                throw cdro::service::ConfigError(origin + ": the run context's solve_adoption is '" + adoption +
                                                 "', which this cdro-hostd does not know");
            }
            context.solve_adoption_recorded = true;
        }
    } catch (const nlohmann::json::exception &error) {
        throw service::ConfigError(origin + ": the run's context in the capture header is unreadable (" +
                                   std::string(error.what()) + ")");
    }
    return context;
}

} // namespace cdro::hostd
