// cdro-bench-families: the global solve and the engine on the building families of
// host/netgen (families.hpp), against the truth-started robust solve. Figures only.
//
//   cdro-bench-families --family corridor --draws 5 [--seed 1] [--nodes N] [--engine]
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <limits>
#include <map>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <Eigen/LU>

#include "cdro/engine/alignment.hpp"
#include "cdro/engine/engine.hpp"
#include "cdro/engine/foldable.hpp"
#include "cdro/engine/global_solve.hpp"
#include "cdro/engine/map_lift.hpp"
#include "cdro/engine/map_refine.hpp"
#include "cdro/engine/range_model.hpp"
#include "cdro/netgen/families.hpp"
#include "cdro/netgen/stream.hpp"

namespace {

using namespace cdro;
using engine::Vector2;

double seconds() { return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count(); }

struct Fit {
    double rmse_m = std::numeric_limits<double>::quiet_NaN();
    double worst_m = std::numeric_limits<double>::quiet_NaN();
    uint32_t placed = 0;
    uint32_t over_1m = 0;
};

Fit fitToTruth(const std::vector<Vector2> &estimate, const std::vector<Vector2> &truth)
{
    Fit fit;
    fit.placed = static_cast<uint32_t>(estimate.size());
    if (estimate.size() < 2) {
        return fit;
    }
    const engine::AlignedErrors aligned = engine::alignedErrors(estimate, truth, true);
    fit.rmse_m = aligned.rmse_m;
    fit.worst_m = aligned.worst_m;
    fit.over_1m = static_cast<uint32_t>(aligned.countOver(1.0));
    return fit;
}

// The links as the engine keeps them: the median of the last 15 projected ranges.
engine::MapProblem problemFrom(const netgen::World &world, const std::vector<netgen::GeneratedRange> &ranges,
                               std::map<engine::NodeId, uint32_t> &number)
{
    engine::MapProblem problem;
    std::vector<engine::NodeId> ids;
    for (const netgen::WorldNode &node : world.nodes) {
        ids.push_back(node.id);
    }
    std::sort(ids.begin(), ids.end());
    for (size_t i = 0; i < ids.size(); ++i) {
        number[ids[i]] = static_cast<uint32_t>(i);
    }
    problem.ids = ids;
    std::map<engine::NodeId, const netgen::WorldNode *> by_id;
    for (const netgen::WorldNode &node : world.nodes) {
        by_id[node.id] = &node;
    }
    std::map<std::pair<uint32_t, uint32_t>, std::vector<double>> windows;
    for (const netgen::GeneratedRange &range : ranges) {
        const netgen::WorldNode &a = *by_id[range.from];
        const netgen::WorldNode &b = *by_id[range.to];
        double planar = range.range_m;
        if (a.height_known && b.height_known) {
            bool clamped = false;
            planar = engine::projectRange(range.range_m, a.position_m.z() - b.position_m.z(), &clamped);
        }
        uint32_t x = number[range.from];
        uint32_t y = number[range.to];
        if (y < x) {
            std::swap(x, y);
        }
        std::vector<double> &w = windows[{x, y}];
        w.push_back(planar);
        if (w.size() > 15) {
            w.erase(w.begin());
        }
    }
    for (auto &[pair, w] : windows) {
        std::vector<double> sorted = w;
        std::sort(sorted.begin(), sorted.end());
        const size_t mid = sorted.size() / 2;
        const double median = sorted.size() % 2 == 1 ? sorted[mid] : 0.5 * (sorted[mid - 1] + sorted[mid]);
        problem.links.push_back(engine::MapLink{pair.first, pair.second, median});
    }
    problem.finish();
    if (std::getenv("CDRO_BENCH_NO_UNHEARD") == nullptr) {
        std::fill(problem.listens.begin(), problem.listens.end(), uint8_t{1});
        problem.unheard_radius_m = engine::unheardRadiusFor(problem, 0.6);
    }
    return problem;
}

} // namespace

static int runMain(int argc, char **argv)
{
    CLI::App app{"cdro-bench-families: the global solve on the building families"};
    std::string family_name = "corridor";
    uint32_t draws = 5;
    uint64_t seed = 1;
    bool run_engine = false;
    netgen::FamilyOptions options;
    std::string heights = "known";
    app.add_option("--family", family_name);
    app.add_option("--draws", draws);
    app.add_option("--seed", seed);
    app.add_option("--nodes", options.nodes);
    app.add_option("--heights", heights);
    app.add_flag("--engine", run_engine, "also run the streaming engine");
    std::string dump_dir;
    app.add_option("--dump", dump_dir,
                   "write truth.csv, links.csv, solve.csv, reference.csv per draw under this folder");
    CLI11_PARSE(app, argc, argv);
    options.heights_known = heights == "known";
    const auto family = netgen::parseFamily(family_name);
    if (!family) {
        std::fprintf(stderr, "unknown family\n");
        return 2;
    }
    engine::RangeLikelihoodParams likelihood_params;
    if (const char *eps = std::getenv("CDRO_BENCH_EPS")) {
        likelihood_params.nlos_fraction = std::atof(eps);
    }
    if (const char *excess = std::getenv("CDRO_BENCH_EXCESS")) {
        likelihood_params.nlos_mean_excess_m = std::atof(excess);
    }
    const engine::RangeLikelihood likelihood = engine::mapLikelihood(likelihood_params);
    std::printf("%-10s %5s %5s %6s | %8s %8s %4s %5s %6s | %8s | %8s %5s | %s\n", "family", "seed", "nodes", "links",
                "solve_m", "worst_m", ">1m", "disp", "time_s", "truth_m", "engine_m", "conv", "best start");
    for (uint32_t k = 0; k < draws; ++k) {
        const uint64_t draw_seed = seed + k;
        const netgen::World world = netgen::makeWorld(*family, draw_seed, options);
        netgen::StreamOptions stream_options;
        stream_options.seed = draw_seed;
        const netgen::GeneratedStream stream = netgen::generateStream(world, stream_options);
        std::map<engine::NodeId, uint32_t> number;
        const engine::MapProblem problem = problemFrom(world, stream.ranges, number);
        std::vector<Vector2> truth(problem.nodeCount());
        for (const netgen::WorldNode &node : world.nodes) {
            truth[number[node.id]] = node.position_m.head<2>();
        }
        const double start = seconds();
        engine::GlobalSolveParams params;
        if (const char *rounds = std::getenv("CDRO_BENCH_LEARN")) {
            params.learn_rounds = static_cast<uint32_t>(std::atoi(rounds));
        }
        if (std::getenv("CDRO_BENCH_QUICK") != nullptr) {
            params.patch_start = false;
            params.growth_seeds = 1;
        }
        const engine::GlobalSolveResult solved = engine::solveGlobally(problem, likelihood, params);
        const double elapsed = seconds() - start;
        std::vector<Vector2> est;
        std::vector<Vector2> tru;
        uint32_t disputed = 0;
        for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
            if (solved.best.estimate.placed[node] != 0) {
                est.push_back(solved.best.estimate.position_m[node]);
                tru.push_back(truth[node]);
            }
            disputed += solved.disputed[node];
        }
        Fit fit = fitToTruth(est, tru);
        if (std::getenv("CDRO_BENCH_OFFSET") != nullptr) {
            // Alternate: the common range offset given the map, then the map given the offset.
            engine::MapProblem shifted = problem;
            engine::MapEstimate map = solved.best.estimate;
            double offset = 0.0;
            for (int round = 0; round < 6; ++round) {
                // Newton on c with the robust cost (numerical derivatives), prior N(0, 0.5^2).
                auto cost_at = [&](double c) {
                    engine::MapProblem p2 = problem;
                    for (engine::MapLink &l : p2.links) {
                        l.range_m -= c;
                    }
                    return engine::mapCost(p2, map, likelihood) + 0.5 * c * c / 0.25;
                };
                for (int it = 0; it < 20; ++it) {
                    const double h = 1e-3;
                    const double f0 = cost_at(offset);
                    const double fp = cost_at(offset + h);
                    const double fm = cost_at(offset - h);
                    const double g = (fp - fm) / (2 * h);
                    const double H = std::max((fp - 2 * f0 + fm) / (h * h), 1e-3);
                    const double step = std::clamp(-g / H, -0.2, 0.2);
                    offset += step;
                    if (std::abs(step) < 1e-5) {
                        break;
                    }
                }
                shifted = problem;
                for (engine::MapLink &l : shifted.links) {
                    l.range_m -= offset;
                }
                engine::MapRefineParams rp;
                rp.stages = {engine::RefineStage{}};
                engine::refineMap(shifted, map, likelihood, rp);
            }
            std::vector<Vector2> oe;
            std::vector<Vector2> ot;
            for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
                if (map.placed[node] != 0) {
                    oe.push_back(map.position_m[node]);
                    ot.push_back(truth[node]);
                }
            }
            std::printf("      offset %.3f m: rmse %.3f (was %.3f)\n", offset, fitToTruth(oe, ot).rmse_m, fit.rmse_m);
        }
        engine::MapEstimate reference = engine::MapEstimate::unplaced(problem.nodeCount());
        for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
            reference.placed[node] = problem.node_links[node].empty() ? 0 : 1;
            reference.position_m[node] = truth[node];
        }
        engine::refineMap(problem, reference, likelihood);
        const double reference_cost = engine::mapCost(problem, reference, likelihood);
        std::vector<Vector2> ref_est;
        std::vector<Vector2> ref_tru;
        for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
            if (reference.placed[node] != 0) {
                ref_est.push_back(reference.position_m[node]);
                ref_tru.push_back(truth[node]);
            }
        }
        const Fit ref_fit = fitToTruth(ref_est, ref_tru);
        if (!dump_dir.empty()) {
            const std::string dir = dump_dir + "/" + family_name + "-" + std::to_string(draw_seed);
            std::system(("mkdir -p " + dir).c_str());
            auto write = [&](const std::string &name, const engine::MapEstimate &map) {
                std::FILE *f = std::fopen((dir + "/" + name).c_str(), "w");
                std::fprintf(f, "id,x,y,var_x,cov_xy,var_y,converged\n");
                for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
                    if (map.placed[node] != 0) {
                        std::fprintf(f, "%u,%.9g,%.9g,0,0,0,%d\n", problem.ids[node], map.position_m[node].x(),
                                     map.position_m[node].y(), solved.disputed[node] != 0 ? 0 : 1);
                    }
                }
                std::fclose(f);
            };
            write("solve.csv", solved.best.estimate);
            write("reference.csv", reference);
            std::FILE *t = std::fopen((dir + "/truth.csv").c_str(), "w");
            std::fprintf(t, "id,x,y\n");
            for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
                std::fprintf(t, "%u,%.9g,%.9g\n", problem.ids[node], truth[node].x(), truth[node].y());
            }
            std::fclose(t);
            std::FILE *l = std::fopen((dir + "/links.csv").c_str(), "w");
            std::fprintf(l, "a,b,range_m,distance_m\n");
            for (const engine::MapLink &link : problem.links) {
                std::fprintf(l, "%u,%u,%.6f,%.6f\n", problem.ids[link.a], problem.ids[link.b], link.range_m,
                             (truth[link.a] - truth[link.b]).norm());
            }
            std::fclose(l);
        }
        if (std::getenv("CDRO_BENCH_BASIN") != nullptr) {
            netgen::Random jitter(draw_seed * 7919);
            for (double amplitude : {0.5, 1.0, 2.0, 4.0, 8.0}) {
                for (int lifted = 0; lifted < 2; ++lifted) {
                    engine::MapEstimate jittered = reference;
                    for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
                        // y drawn before x, as GCC evaluated the two-argument form (the same draws).
                        const double dy = jitter.normal();
                        const double dx = jitter.normal();
                        jittered.position_m[node] = truth[node] + amplitude * Vector2(dx, dy);
                    }
                    if (lifted != 0) {
                        engine::liftedRefine(problem, jittered, likelihood, engine::MapLiftParams{}, false);
                    } else {
                        engine::refineMap(problem, jittered, likelihood);
                    }
                    std::vector<Vector2> be;
                    std::vector<Vector2> bt;
                    for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
                        if (jittered.placed[node] != 0) {
                            be.push_back(jittered.position_m[node]);
                            bt.push_back(truth[node]);
                        }
                    }
                    std::printf("      basin %4.1f m %s: cost %8.1f rmse %7.3f\n", amplitude,
                                lifted ? "lifted" : "planar", engine::mapCost(problem, jittered, likelihood),
                                fitToTruth(be, bt).rmse_m);
                }
            }
        }
        if (std::getenv("CDRO_BENCH_RANDOM") != nullptr) {
            netgen::Random jitter(draw_seed * 104729);
            const int starts = std::atoi(std::getenv("CDRO_BENCH_RANDOM"));
            double best_cost = 1e300;
            double best_rmse = std::numeric_limits<double>::quiet_NaN();
            int below_ref = 0;
            for (int r = 0; r < starts; ++r) {
                engine::MapEstimate jittered = reference;
                const double side = std::sqrt(static_cast<double>(problem.nodeCount()) * 60.0);
                for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
                    const double y_m = side * jitter.uniform(); // y first, as above
                    const double x_m = side * jitter.uniform();
                    jittered.position_m[node] = Vector2(x_m, y_m);
                }
                engine::MapLiftParams lift;
                lift.dimensions = 3 + static_cast<uint32_t>(r % 4);
                lift.lift_m = side / 4;
                engine::liftedRefine(problem, jittered, likelihood, lift, false);
                engine::escapeNodeMinima(problem, jittered, likelihood, engine::MapGrowthParams{}, 2.0);
                engine::refineMap(problem, jittered, likelihood);
                const double c = engine::mapCost(problem, jittered, likelihood);
                std::vector<Vector2> be;
                std::vector<Vector2> bt;
                for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
                    if (jittered.placed[node] != 0) {
                        be.push_back(jittered.position_m[node]);
                        bt.push_back(truth[node]);
                    }
                }
                below_ref += c <= reference_cost + 1.0 ? 1 : 0;
                if (c < best_cost) {
                    best_cost = c;
                    best_rmse = fitToTruth(be, bt).rmse_m;
                }
            }
            std::printf("      random starts %d: best cost %8.1f rmse %7.3f; %d within 1 nat of the reference\n",
                        starts, best_cost, best_rmse, below_ref);
        }
        // Honesty: which nodes the solve would call converged, and are they right?
        {
            const engine::MapModelError model_error{};
            engine::MapModelError with_prior = model_error;
            if (const char *prior = std::getenv("CDRO_BENCH_COMMON_EXCESS")) {
                with_prior.common_excess_m = std::max(with_prior.common_excess_m, std::atof(prior));
            }
            engine::MapCovariance confidence =
                engine::mapCovariance(problem, solved.best.estimate, likelihood, with_prior);
            // Model sensitivity: the best map refined under other NLOS models.
            std::vector<double> model_spread(problem.nodeCount(), 0.0);
            if (std::getenv("CDRO_BENCH_MODELS") != nullptr) {
                const double variants[][2] = {{0.05, 0.5}, {0.3, 0.5}, {0.5, 0.3}, {0.6, 1.0}};
                for (const auto &v : variants) {
                    engine::RangeLikelihoodParams vp = likelihood_params;
                    vp.nlos_fraction = v[0];
                    vp.nlos_mean_excess_m = v[1];
                    const engine::RangeLikelihood variant = engine::mapLikelihood(vp);
                    engine::MapEstimate again = solved.best.estimate;
                    engine::MapRefineParams rp;
                    rp.stages = {engine::RefineStage{}};
                    engine::refineMap(problem, again, variant, rp);
                    std::vector<Vector2> src;
                    std::vector<Vector2> dst;
                    for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
                        if (solved.best.estimate.placed[node] != 0 && confidence.main_part[node] != 0) {
                            src.push_back(again.position_m[node]);
                            dst.push_back(solved.best.estimate.position_m[node]);
                        }
                    }
                    const engine::RigidTransform back = engine::fitRigid(src, dst, false);
                    for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
                        if (solved.best.estimate.placed[node] != 0) {
                            model_spread[node] = std::max(
                                model_spread[node],
                                (back.apply(again.position_m[node]) - solved.best.estimate.position_m[node]).norm());
                        }
                    }
                }
                for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
                    confidence.covariance_m2[node] +=
                        0.25 * model_spread[node] * model_spread[node] * engine::Matrix2::Identity();
                }
            }
            std::vector<std::pair<uint32_t, uint32_t>> edges;
            for (const engine::MapLink &link : problem.links) {
                edges.emplace_back(link.a, link.b);
            }
            const engine::Foldable folds = engine::findFoldable(problem.nodeCount(), edges, solved.best.estimate.placed,
                                                                std::vector<uint8_t>(problem.nodeCount(), 0));
            const double threshold =
                std::getenv("CDRO_BENCH_RELIABLE") ? std::atof(std::getenv("CDRO_BENCH_RELIABLE")) : 1.0;
            // Resampling: drop a share of the links, refine from the best map, see what moves.
            std::vector<double> spread(problem.nodeCount(), 0.0);
            {
                netgen::Random pick(draw_seed * 31 + 7);
                const int resamples =
                    std::getenv("CDRO_BENCH_RESAMPLES") ? std::atoi(std::getenv("CDRO_BENCH_RESAMPLES")) : 12;
                const double drop = std::getenv("CDRO_BENCH_DROP") ? std::atof(std::getenv("CDRO_BENCH_DROP")) : 0.15;
                for (int r = 0; r < resamples; ++r) {
                    engine::MapProblem thinned = problem;
                    thinned.links.clear();
                    for (const engine::MapLink &link : problem.links) {
                        if (!pick.chance(drop)) {
                            thinned.links.push_back(link);
                        }
                    }
                    thinned.finish();
                    engine::MapEstimate again = solved.best.estimate;
                    engine::MapRefineParams rp;
                    rp.stages = {{2.0, -1.0, -1.0}, {1.0, -1.0, -1.0}};
                    engine::refineMap(thinned, again, likelihood, rp);
                    std::vector<Vector2> src;
                    std::vector<Vector2> dst;
                    for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
                        if (solved.best.estimate.placed[node] != 0 && confidence.main_part[node] != 0) {
                            src.push_back(again.position_m[node]);
                            dst.push_back(solved.best.estimate.position_m[node]);
                        }
                    }
                    const engine::RigidTransform back = engine::fitRigid(src, dst, false);
                    for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
                        if (solved.best.estimate.placed[node] != 0) {
                            const double d =
                                (back.apply(again.position_m[node]) - solved.best.estimate.position_m[node]).norm();
                            spread[node] += d * d / resamples;
                        }
                    }
                }
                for (double &v : spread) {
                    v = std::sqrt(v);
                }
            }
            const double spread_limit =
                std::getenv("CDRO_BENCH_SPREAD") ? std::atof(std::getenv("CDRO_BENCH_SPREAD")) : 0.3;
            uint32_t why_spread = 0;
            std::vector<uint32_t> converged;
            uint32_t why_reliability = 0, why_disputed = 0, why_fold = 0, why_links = 0;
            for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
                if (solved.best.estimate.placed[node] == 0) {
                    continue;
                }
                const bool links_ok = problem.node_links[node].size() >= 3;
                const bool fold_ok = folds.foldable[node] == 0;
                const bool dispute_ok = solved.disputed[node] == 0;
                const double big = 2.0 * std::sqrt(std::max(confidence.covariance_m2[node].trace() -
                                                                engine::minEigenvalue(confidence.covariance_m2[node]),
                                                            0.0));
                const bool reliable =
                    confidence.reliability_m[node] < threshold && confidence.main_part[node] != 0 && big < 1.0;
                why_links += links_ok ? 0U : 1U;
                why_fold += fold_ok ? 0U : 1U;
                why_disputed += dispute_ok ? 0U : 1U;
                why_reliability += reliable ? 0U : 1U;
                const bool steady = spread[node] < spread_limit;
                why_spread += steady ? 0U : 1U;
                if (links_ok && fold_ok && dispute_ok && reliable && steady) {
                    converged.push_back(node);
                }
            }
            if (std::getenv("CDRO_BENCH_NODES") != nullptr) {
                for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
                    std::printf("        node %5u links %2zu reliability %8.3f sd %6.3f disputed %u fold %u\n",
                                problem.ids[node], problem.node_links[node].size(), confidence.reliability_m[node],
                                std::sqrt(confidence.covariance_m2[node].trace()), solved.disputed[node],
                                folds.foldable[node]);
                }
                for (size_t l = 0; l < problem.links.size(); ++l) {
                    if (confidence.link_redundancy[l] < 0.1) {
                        std::printf("        weak link %u-%u redundancy %.4f\n", problem.ids[problem.links[l].a],
                                    problem.ids[problem.links[l].b], confidence.link_redundancy[l]);
                    }
                }
            }
            std::vector<Vector2> ce;
            std::vector<Vector2> ct;
            for (uint32_t node : converged) {
                ce.push_back(solved.best.estimate.position_m[node]);
                ct.push_back(truth[node]);
            }
            uint32_t covered2 = 0, covered95 = 0, wrong = 0;
            double crmse = std::numeric_limits<double>::quiet_NaN();
            if (ce.size() >= 3) {
                const engine::AlignedErrors aligned = engine::alignedErrors(ce, ct, true);
                crmse = aligned.rmse_m;
                wrong = static_cast<uint32_t>(aligned.countOver(1.0));
                for (size_t i = 0; i < converged.size(); ++i) {
                    const Vector2 e = aligned.fit.apply(ce[i]) - ct[i];
                    const engine::Matrix2 c = aligned.fit.applyToCovariance(confidence.covariance_m2[converged[i]]);
                    const double m2 = e.dot(c.inverse() * e);
                    covered2 += m2 <= 4.0 ? 1U : 0U;
                    covered95 += m2 <= 5.991 ? 1U : 0U;
                }
            }
            {
                // The solve's error with a scale allowed too (similarity fit): how much is scale.
                std::vector<Vector2> se;
                std::vector<Vector2> st;
                for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
                    if (solved.best.estimate.placed[node] != 0) {
                        se.push_back(solved.best.estimate.position_m[node]);
                        st.push_back(truth[node]);
                    }
                }
                const engine::RigidTransform rigid = engine::fitRigid(se, st, true);
                double best_scaled = rigid.rms_error_m;
                double best_factor = 1.0;
                for (double factor = 0.90; factor <= 1.10; factor += 0.0025) {
                    std::vector<Vector2> scaled = se;
                    for (Vector2 &p : scaled) {
                        p *= factor;
                    }
                    const double e = engine::fitRigid(scaled, st, true).rms_error_m;
                    if (e < best_scaled) {
                        best_scaled = e;
                        best_factor = factor;
                    }
                }
                std::printf("      scale-free rmse %.3f at scale %.4f\n", best_scaled, best_factor);
            }
            std::printf("      converged %zu/%u rmse %.3f wrong %u | 2-sigma %u 95%% %u | not: links %u fold %u "
                        "disputed %u unreliable %u spread %u | vf %.2f\n",
                        converged.size(), problem.nodeCount(), crmse, wrong, covered2, covered95, why_links, why_fold,
                        why_disputed, why_reliability, why_spread, confidence.variance_factor);
        }
        double engine_rmse = std::numeric_limits<double>::quiet_NaN();
        uint32_t engine_converged_wrong = 0;
        if (run_engine) {
            engine::Engine streaming;
            for (const netgen::WorldNode &node : world.nodes) {
                if (node.height_known) {
                    streaming.setHeight(node.id, node.position_m.z());
                }
            }
            for (const netgen::GeneratedRange &range : stream.ranges) {
                streaming.addRange(range.from, range.to, range.range_m, range.t_s);
            }
            streaming.settle(200000);
            std::vector<Vector2> e;
            std::vector<Vector2> t;
            std::vector<Vector2> ce;
            std::vector<Vector2> ct;
            for (const engine::NodeOutput &out : streaming.estimates()) {
                if (out.placed()) {
                    e.push_back(out.position_m);
                    t.push_back(truth[number[out.id]]);
                    if (out.converged()) {
                        ce.push_back(out.position_m);
                        ct.push_back(truth[number[out.id]]);
                    }
                }
            }
            engine_rmse = fitToTruth(e, t).rmse_m;
            engine_converged_wrong = fitToTruth(ce, ct).over_1m;
        }
        std::printf(
            "%-10s %5llu %5u %6zu | %8.3f %8.3f %4u %5u %6.2f | %8.3f %7.1f | %8.3f %5u | %s (%.1f nats, %zu rivals)\n",
            family_name.c_str(), static_cast<unsigned long long>(draw_seed), problem.nodeCount(), problem.links.size(),
            fit.rmse_m, fit.worst_m, fit.over_1m, disputed, elapsed, ref_fit.rmse_m, reference_cost, engine_rmse,
            engine_converged_wrong,
            (solved.best.origin + " eps " + std::to_string(solved.learnt_nlos_fraction).substr(0, 4) + " excess " +
             std::to_string(solved.learnt_nlos_mean_excess_m).substr(0, 4))
                .c_str(),
            solved.best.cost, solved.rivals.size());
        if (std::getenv("CDRO_BENCH_STARTS") != nullptr) {
            for (const engine::MapHypothesis &h : solved.all) {
                std::vector<Vector2> he;
                std::vector<Vector2> ht;
                for (uint32_t node = 0; node < problem.nodeCount(); ++node) {
                    if (h.estimate.placed[node] != 0) {
                        he.push_back(h.estimate.position_m[node]);
                        ht.push_back(truth[node]);
                    }
                }
                std::printf("      start %-40s cost %8.1f rmse %7.3f placed %zu\n", h.origin.c_str(), h.cost,
                            fitToTruth(he, ht).rmse_m, he.size());
            }
        }
        std::fflush(stdout);
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
        std::fprintf(stderr, "cdro-bench-families: %s\n", error.what());
        return 1;
    }
}
