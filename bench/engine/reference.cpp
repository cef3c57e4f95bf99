// cdro-reference: the reference no user has, for the scorecard (docs/results.md): the engine's
// robust map solve started at the truth. The links are the ones the engine's own intake keeps
// (range_intake.hpp: projected with the known heights, the median of each link's window) and
// the problem is the one its global step builds (global_step.hpp: unheard pairs included), so
// the reference differs from the engine's answer only by where the solve starts.
//
//   cdro-reference --truth truth.csv --ranges ranges.csv [--heights heights.csv] --out reference.csv
//   cdro-reference ... --local        refines in the basin of the given positions only (no annealing)
//   cdro-reference ... --hypotheses   also solves from scratch as the engine's settle does (no truth
//                                      used) and prints every start's map: origin, cost, aligned RMSE
//
// truth: id,x,y[,z] (m); the output has the estimates' columns (id,x,y,var_x,cov_xy,var_y,converged;
// covariances from the map's information, converged = 1 for every solved node) and the
// solve's cost is printed on stdout (nats).
#include <cstdio>
#include <limits>
#include <stdexcept>
#include <map>
#include <string>

#include <CLI/CLI.hpp>

#include "cdro/engine/map_connectivity.hpp"
#include "cdro/engine/alignment.hpp"
#include "cdro/engine/global_solve.hpp"
#include "cdro/engine/global_step.hpp"
#include "cdro/engine/map_refine.hpp"
#include "cdro/engine/range_intake.hpp"
#include "cdro/hostd/csv_input.hpp"

namespace {

using namespace cdro;

// Every bad row (the reader keeps all their reasons: kAll).
constexpr size_t kAll = std::numeric_limits<size_t>::max();
template <typename Row> void reportProblems(const std::string &path, const hostd::CsvTable<Row> &table)
{
    for (const csv::Problem &problem : table.summary.problems) {
        std::fprintf(stderr, "cdro-reference: %s:%zu: %s (row skipped)\n", path.c_str(), problem.line,
                     problem.message.c_str());
    }
}

} // namespace

static int runMain(int argc, char **argv)
{
    CLI::App app{"cdro-reference: the engine's robust map solve started at the truth"};
    std::string truth_path;
    std::string ranges_path;
    std::string heights_path;
    std::string out_path;
    app.add_option("--truth", truth_path, "id,x,y[,z] (m)")->required();
    app.add_option("--ranges", ranges_path, "[t,]from,to,range_m")->required();
    app.add_option("--heights", heights_path, "id,z (m): the heights the engine is told");
    app.add_option("--out", out_path, "the reference map, as the engine's estimates CSV")->required();
    bool local = false;
    app.add_flag("--local", local,
                 "refine from the given positions at the nominal noise only (no annealing from wide noise): "
                 "the cost of the basin the positions are in, e.g. of a map an engine run ended in");
    bool hypotheses = false;
    uint32_t growth_seeds = engine::GlobalSolveParams{}.growth_seeds;
    app.add_option("--growth-seeds", growth_seeds,
                   "with --hypotheses: maps grown from this many seed triangles (the engine's solve: 3)")
        ->check(CLI::Range(1U, 1000U));
    app.add_flag("--hypotheses", hypotheses,
                 "also solve from scratch (the settle's starts, no truth used) and print each start's map: "
                 "origin, cost (nats) and RMSE against the truth (m, rigid fit with reflection)");
    CLI11_PARSE(app, argc, argv);
    try {
        const engine::EngineParams params;
        engine::MapState map;
        engine::RangeIntake intake(params.range);
        if (!heights_path.empty()) {
            const auto heights = hostd::readHeightsCsv(heights_path, kAll);
            reportProblems(heights_path, heights);
            for (const hostd::HeightRow &row : heights.rows) {
                map.nodes[intake.node(map, row.id)].height_m = row.z_m;
            }
        }
        const auto ranges = hostd::readRangesCsv(ranges_path, kAll);
        reportProblems(ranges_path, ranges);
        for (const hostd::RangeRow &row : ranges.rows) {
            const engine::TakenRange taken =
                intake.take(map, row.from, row.to, row.range_m,
                            row.has_time ? row.t_s : std::numeric_limits<double>::quiet_NaN());
            if (taken.link != engine::kNoIndex) {
                intake.refreshLinkRange(map, taken.link, false);
            }
        }
        const auto truth = hostd::readFixedCsv(truth_path, kAll);
        reportProblems(truth_path, truth);
        std::map<engine::NodeId, engine::Vector2> true_position;
        for (const hostd::FixedRow &row : truth.rows) {
            true_position[row.id] = engine::Vector2(row.x_m, row.y_m);
        }
        for (engine::NodeState &node : map.nodes) {
            if (true_position.count(node.id) == 0) {
                throw std::runtime_error("node " + std::to_string(node.id) + " ranged but has no row in " + truth_path);
            }
            node.lifecycle = engine::NodeLifecycle::Placed;
        }
        const engine::StateProblem built = engine::mapProblemOf(map, params, intake.counters().taken());
        const engine::MapProblem &problem = built.problem;
        engine::MapEstimate estimate = engine::MapEstimate::unplaced(problem.nodeCount());
        for (uint32_t i = 0; i < problem.nodeCount(); ++i) {
            estimate.placed[i] = problem.node_links[i].empty() ? 0 : 1;
            estimate.position_m[i] = true_position[problem.ids[i]];
        }
        if (hypotheses) {
            engine::GlobalSolveParams solve;
            solve.range_offsets = params.solve.range_offsets;
            solve.growth_seeds = growth_seeds;
            const engine::GlobalSolveResult solved =
                engine::solveGlobally(problem, engine::mapLikelihood(params.likelihood), solve);
            for (const engine::MapHypothesis &h : solved.all) {
                std::vector<engine::MapPoint> placed;
                for (uint32_t i = 0; i < problem.nodeCount(); ++i) {
                    if (h.estimate.placed[i] != 0) {
                        placed.push_back({problem.ids[i], h.estimate.position_m[i]});
                    }
                }
                const engine::AlignedErrors aligned = engine::alignedErrors(placed, true_position, true);
                // connectivity_nats as the solve ranked it (a map placing fewer nodes than the
                // fullest gets their worst); own_nats over the map's own placed nodes.
                std::printf("hypothesis cost_nats %.3f connectivity_nats %.3f own_nats %.3f placed %u rmse_m %.3f "
                            "origin %s\n",
                            h.cost, h.connectivity_nats, engine::connectivityCost(problem, h.estimate).cost_nats,
                            h.estimate.placedCount(), aligned.compared() == 0 ? 0.0 : aligned.rmse_m, h.origin.c_str());
            }
        }
        // As the global solve treats each of its maps: refined, then judged under the NLOS model
        // learnt from its own residuals.
        engine::RangeLikelihood likelihood = engine::mapLikelihood(params.likelihood);
        engine::MapRefineParams first;
        if (local) {
            first.stages = {engine::RefineStage{}};
        }
        engine::refineMap(problem, estimate, likelihood, first);
        const engine::GlobalSolveParams solve;
        for (uint32_t round = 0; round < solve.learn_rounds; ++round) {
            likelihood = engine::RangeLikelihood(engine::learnNlosModel(problem, estimate, likelihood));
            engine::MapRefineParams again = solve.refine;
            again.stages = {engine::RefineStage{}};
            engine::refineMap(problem, estimate, likelihood, again);
        }
        const engine::MapCovariance confidence =
            engine::mapCovariance(problem, estimate, likelihood, engine::MapModelError{});
        std::FILE *out = std::fopen(out_path.c_str(), "w");
        if (out == nullptr) {
            throw std::runtime_error("cannot write " + out_path);
        }
        std::fputs("id,x,y,var_x,cov_xy,var_y,converged\n", out);
        for (uint32_t i = 0; i < problem.nodeCount(); ++i) {
            if (estimate.placed[i] == 0) {
                std::fprintf(out, "%u,,,,,,0\n", static_cast<unsigned>(problem.ids[i]));
                continue;
            }
            const engine::Matrix2 &c = confidence.covariance_m2[i];
            std::fprintf(out, "%u,%.17g,%.17g,%.17g,%.17g,%.17g,1\n", static_cast<unsigned>(problem.ids[i]),
                         estimate.position_m[i].x(), estimate.position_m[i].y(), c(0, 0), c(0, 1), c(1, 1));
        }
        std::fclose(out);
        std::printf("cost_nats %.6f\nconnectivity_nats %.3f\nnlos_fraction %.4f\nnlos_mean_excess_m "
                    "%.4f\nvariance_factor %.4f\nnodes %u\nlinks %zu\n",
                    engine::mapCost(problem, estimate, likelihood),
                    engine::connectivityCost(problem, estimate).cost_nats, likelihood.params().nlos_fraction,
                    likelihood.params().nlos_mean_excess_m, confidence.variance_factor, problem.nodeCount(),
                    problem.links.size());
    } catch (const std::exception &error) {
        std::fprintf(stderr, "cdro-reference: %s\n", error.what());
        return 1;
    }
    return 0;
}

// An exception that escapes (from setting up the options, or a library's) ends the run with its
// message and status 1, not with std::terminate's abort.
int main(int argc, char **argv)
{
    try {
        return runMain(argc, argv);
    } catch (const std::exception &error) {
        std::fprintf(stderr, "cdro-reference: %s\n", error.what());
        return 1;
    }
}
