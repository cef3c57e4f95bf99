// cdro-netgen: draws a network of one of the building families (families.hpp) from a seed and
// writes it as files that cdro-hostd, cdro-eval and cdro-sim read:
//
//   truth.csv    id,x,y,z          where every node truly is (m)
//   heights.csv  id,z              the heights the user knows (none with --heights unknown)
//   ranges.csv   t,from,to,range_m the range stream (stream.hpp), 3D ranges as measured
//   links.csv    a,b,walls,bias_m,distance_m   the pairs that hear each other and their
//                                  persistent error (antenna delays + NLOS excess)
//   world.txt    the family, the seed and what was drawn
//
//   cdro-netgen --family corridor --seed 3 --out /tmp/corridor-3
//   cdro-netgen --family random --nodes 300 --seed 1 --order staggered --out /tmp/r300
#include <cstdio>
#include <exception>
#include <filesystem>
#include <stdexcept>
#include <string>

#include <CLI/CLI.hpp>

#include "cdro/netgen/families.hpp"
#include "cdro/netgen/stream.hpp"

namespace {

using namespace cdro::netgen;

std::FILE *openOut(const std::filesystem::path &path)
{
    std::FILE *file = std::fopen(path.c_str(), "w");
    if (file == nullptr) {
        throw std::runtime_error("cannot write " + path.string());
    }
    return file;
}

} // namespace

static int runMain(int argc, char **argv)
{
    CLI::App app{"cdro-netgen: a seeded network of one of the building families, written as CSV files"};
    std::string family_name = "random";
    std::string order_name = "sweeps";
    std::string heights = "known";
    std::string out_dir;
    uint64_t seed = 1;
    uint64_t shuffle_seed = 0;
    FamilyOptions family_options;
    StreamOptions stream_options;
    std::string families_help = "building family:";
    for (Family family : allFamilies()) {
        families_help += std::string(" ") + familyName(family);
    }
    app.add_option("--family", family_name, families_help)->capture_default_str();
    app.add_option("--seed", seed, "the draw (printed; the same seed gives the same files)")->capture_default_str();
    app.add_option("--nodes", family_options.nodes, "number of nodes (0: the family draws it)")->capture_default_str();
    app.add_option("--nlos-fraction", family_options.nlos_fraction,
                   "share of line-of-sight links with an obstruction (< 0: the family's)")
        ->capture_default_str();
    app.add_option("--heights", heights, "known: heights.csv lists every node; unknown: it lists none")
        ->check(CLI::IsMember({"known", "unknown"}))
        ->capture_default_str();
    app.add_option("--order", order_name,
                   "sweeps, staggered (nodes switched on over --stagger-s) or late (one node last)")
        ->check(CLI::IsMember({"sweeps", "staggered", "late"}))
        ->capture_default_str();
    app.add_option("--sweeps", stream_options.sweeps, "sweeps over every link")->capture_default_str();
    app.add_option("--stagger-s", stream_options.stagger_s, "staggered: nodes switched on over this long (s)")
        ->capture_default_str();
    app.add_option("--shuffle", shuffle_seed,
                   "write the same ranges in an order drawn from this seed (0: as generated)")
        ->capture_default_str();
    app.add_option("--out", out_dir, "directory to write into (created)")->required();
    CLI11_PARSE(app, argc, argv);
    try {
        family_options.heights_known = heights == "known";
        const Family family = *parseFamily(family_name);
        const World world = makeWorld(family, seed, family_options);
        stream_options.order = *parseStreamOrder(order_name);
        stream_options.seed = seed;
        GeneratedStream stream = generateStream(world, stream_options);
        if (shuffle_seed != 0) {
            stream.ranges = shuffledStream(stream.ranges, shuffle_seed);
        }
        const std::filesystem::path dir(out_dir);
        std::filesystem::create_directories(dir);
        std::FILE *truth = openOut(dir / "truth.csv");
        std::FILE *known = openOut(dir / "heights.csv");
        std::fputs("id,x,y,z\n", truth);
        std::fputs("id,z\n", known);
        for (const WorldNode &node : world.nodes) {
            std::fprintf(truth, "%u,%.17g,%.17g,%.17g\n", static_cast<unsigned>(node.id), node.position_m.x(),
                         node.position_m.y(), node.position_m.z());
            if (node.height_known) {
                std::fprintf(known, "%u,%.17g\n", static_cast<unsigned>(node.id), node.position_m.z());
            }
        }
        std::fclose(truth);
        std::fclose(known);
        std::FILE *links = openOut(dir / "links.csv");
        std::fputs("a,b,walls,bias_m,distance_m\n", links);
        for (const WorldLink &link : world.links) {
            std::fprintf(links, "%u,%u,%u,%.17g,%.17g\n", static_cast<unsigned>(world.nodes[link.a].id),
                         static_cast<unsigned>(world.nodes[link.b].id), static_cast<unsigned>(link.walls),
                         world.biasM(link), world.distance3dM(link));
        }
        std::fclose(links);
        std::FILE *ranges = openOut(dir / "ranges.csv");
        std::fputs("t,from,to,range_m\n", ranges);
        for (const GeneratedRange &range : stream.ranges) {
            std::fprintf(ranges, "%.17g,%u,%u,%.17g\n", range.t_s, static_cast<unsigned>(range.from),
                         static_cast<unsigned>(range.to), range.range_m);
        }
        std::fclose(ranges);
        std::FILE *about = openOut(dir / "world.txt");
        std::fprintf(about, "family %s\nseed %llu\norder %s\nshuffle %llu\n%s\n", world.family.c_str(),
                     static_cast<unsigned long long>(seed), order_name.c_str(),
                     static_cast<unsigned long long>(shuffle_seed), world.description.c_str());
        if (stream.late_node != 0) {
            std::fprintf(about, "late node %u\n", static_cast<unsigned>(stream.late_node));
        }
        std::fclose(about);
        std::fprintf(stderr, "cdro-netgen: %s seed %llu: %s; %zu links, %zu ranges -> %s\n", world.family.c_str(),
                     static_cast<unsigned long long>(seed), world.description.c_str(), world.links.size(),
                     stream.ranges.size(), dir.c_str());
    } catch (const std::exception &error) {
        std::fprintf(stderr, "cdro-netgen: %s\n", error.what());
        return 1;
    }
    return 0;
}

// An exception that escapes (from setting up the options, before runMain's own handler) ends the
// run with its message and status 1, not with std::terminate's abort.
int main(int argc, char **argv)
{
    try {
        return runMain(argc, argv);
    } catch (const std::exception &error) {
        std::fprintf(stderr, "cdro-netgen: %s\n", error.what());
        return 1;
    }
}
