#include "cdro/netgen/families.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>
#include <utility>

namespace cdro::netgen {

const char *familyName(Family family)
{
    switch (family) {
    case Family::Random: return "random";
    case Family::Corridor: return "corridor";
    case Family::Wings: return "wings";
    case Family::Walls: return "walls";
    case Family::Biased: return "biased";
    }
    return "unknown";
}

std::optional<Family> parseFamily(const std::string &name)
{
    for (Family family : allFamilies()) {
        if (name == familyName(family)) {
            return family;
        }
    }
    return std::nullopt;
}

std::vector<Family> allFamilies()
{
    return {Family::Random, Family::Corridor, Family::Wings, Family::Walls, Family::Biased};
}

namespace {

// How the radio hears through walls.
struct Radio {
    double reach_m = 20.0;          // m, in the open
    double wall_attenuation = 0.65; // reach is multiplied by this per wall crossed
    uint32_t max_walls = 2;         // beyond this many walls nothing is heard
    double excess_per_wall_min_m = 0.1;
    double excess_per_wall_max_m = 0.6;
    double obstructed_fraction = 0.05; // line-of-sight pairs with furniture or people in the way
    double obstructed_mean_m = 0.4;    // m, their excess ~ Exp(this)
};

void addNode(World &world, const Vector3 &position_m)
{
    WorldNode node;
    node.position_m = position_m;
    world.nodes.push_back(node);
}

// Every pair that hears each other, with its walls and persistent excess.
void hearLinks(World &world, const Radio &radio, Random &random)
{
    world.links.clear();
    for (uint32_t i = 0; i < world.nodes.size(); ++i) {
        for (uint32_t j = i + 1; j < world.nodes.size(); ++j) {
            const Vector2 a = world.nodes[i].position_m.head<2>();
            const Vector2 b = world.nodes[j].position_m.head<2>();
            const double distance_m = (a - b).norm();
            if (distance_m > radio.reach_m) {
                continue;
            }
            const uint32_t walls = wallsCrossed(world.walls, a, b);
            const double reach_m = radio.reach_m * std::pow(radio.wall_attenuation, static_cast<double>(walls)) *
                                   random.uniform(0.85, 1.0);
            if (walls > radio.max_walls || distance_m > reach_m || distance_m < 0.3) {
                continue;
            }
            WorldLink link;
            link.a = i;
            link.b = j;
            link.walls = walls;
            for (uint32_t w = 0; w < walls; ++w) {
                link.excess_m += random.uniform(radio.excess_per_wall_min_m, radio.excess_per_wall_max_m);
            }
            if (walls == 0 && random.chance(radio.obstructed_fraction)) {
                link.excess_m += random.exponential(radio.obstructed_mean_m);
            }
            world.links.push_back(link);
        }
    }
}

void finish(World &world, Random &random, const FamilyOptions &options)
{
    const std::vector<NodeId> ids = drawNodeIds(random, world.nodes.size());
    for (size_t i = 0; i < world.nodes.size(); ++i) {
        world.nodes[i].id = ids[i];
        world.nodes[i].height_known = options.heights_known;
    }
}

double heightM(Random &random) { return random.uniform(0.3, 2.8); }

// ---- random ---------------------------------------------------------------------------------

World drawRandom(Random &random, const FamilyOptions &options)
{
    World world;
    const uint32_t count = options.nodes > 0 ? options.nodes : static_cast<uint32_t>(15 + random.below(5));
    const double side_m = std::sqrt(25.0 * static_cast<double>(count));
    while (world.nodes.size() < count) {
        // y is drawn before x: what GCC made of the one-expression form the published worlds were
        // drawn with (argument order is the compiler's choice); written out, every compiler agrees.
        const double y_m = random.uniform(0.0, side_m);
        const double x_m = random.uniform(0.0, side_m);
        const Vector2 candidate(x_m, y_m);
        bool crowded = false;
        for (const WorldNode &other : world.nodes) {
            crowded = crowded || (other.position_m.head<2>() - candidate).norm() < 1.0;
        }
        if (!crowded) {
            addNode(world, Vector3(candidate.x(), candidate.y(), heightM(random)));
        }
    }
    // The mean degree asked for: the (n d / 2) shortest pairs are the links.
    std::vector<std::pair<double, std::pair<uint32_t, uint32_t>>> pairs;
    for (uint32_t i = 0; i < count; ++i) {
        for (uint32_t j = i + 1; j < count; ++j) {
            pairs.push_back(
                {(world.nodes[i].position_m.head<2>() - world.nodes[j].position_m.head<2>()).norm(), {i, j}});
        }
    }
    const size_t wanted =
        std::min(pairs.size(), static_cast<size_t>(std::lround(0.5 * options.degree * static_cast<double>(count))));
    std::partial_sort(pairs.begin(), pairs.begin() + static_cast<std::ptrdiff_t>(wanted), pairs.end());
    const double nlos = options.nlos_fraction >= 0.0 ? options.nlos_fraction : 0.10;
    for (size_t k = 0; k < wanted; ++k) {
        WorldLink link;
        link.a = pairs[k].second.first;
        link.b = pairs[k].second.second;
        if (random.chance(nlos)) {
            link.excess_m = 0.1 + random.exponential(0.8);
        }
        world.links.push_back(link);
    }
    world.noise = RangeNoise{0.10, 0.02, 1.0};
    std::ostringstream text;
    text << count << " nodes in " << side_m << " m x " << side_m << " m, mean degree " << options.degree << ", "
         << nlos * 100.0 << " % NLOS links";
    world.description = text.str();
    return world;
}

// ---- corridor -------------------------------------------------------------------------------

struct Box {
    Vector2 low_m;
    Vector2 high_m;
    bool overlaps(const Box &other, double margin_m) const
    {
        return low_m.x() < other.high_m.x() - margin_m && other.low_m.x() < high_m.x() - margin_m &&
               low_m.y() < other.high_m.y() - margin_m && other.low_m.y() < high_m.y() - margin_m;
    }
};

// The four walls of a room, with a door gap (0.9 m) on the side facing the corridor.
void addRoomWalls(World &world, const Box &room, int door_side, Random &random)
{
    const Vector2 corners[4] = {room.low_m, Vector2(room.high_m.x(), room.low_m.y()), room.high_m,
                                Vector2(room.low_m.x(), room.high_m.y())};
    for (int side = 0; side < 4; ++side) {
        const Vector2 from = corners[side];
        const Vector2 to = corners[(side + 1) % 4];
        if (side != door_side) {
            world.walls.push_back({from, to});
            continue;
        }
        const double length = (to - from).norm();
        const double door_m = 0.9;
        const double at = random.uniform(0.2, 0.8) * (length - door_m);
        const Vector2 unit = (to - from) / length;
        world.walls.push_back({from, from + at * unit});
        world.walls.push_back({from + (at + door_m) * unit, to});
    }
}

World drawCorridor(Random &random, const FamilyOptions &options)
{
    World world;
    // Arms as rectangles: a horizontal spine and, for L, T and U shapes, vertical arms.
    const int shape = static_cast<int>(random.below(4)); // 0 I, 1 L, 2 T, 3 U
    const double width_m = random.uniform(1.8, 2.6);
    const double spine_m = random.uniform(30.0, 45.0);
    std::vector<Box> corridors;
    corridors.push_back({Vector2(0.0, -0.5 * width_m), Vector2(spine_m, 0.5 * width_m)});
    auto vertical_arm = [&](double x_m, bool up) {
        const double length_m = random.uniform(25.0, 40.0);
        const double low = up ? 0.5 * width_m : -0.5 * width_m - length_m;
        const double high = up ? 0.5 * width_m + length_m : -0.5 * width_m;
        corridors.push_back({Vector2(x_m - 0.5 * width_m, low), Vector2(x_m + 0.5 * width_m, high)});
    };
    if (shape == 1) {
        vertical_arm(spine_m - 0.5 * width_m, true);
    } else if (shape == 2) {
        vertical_arm(0.5 * spine_m, true);
    } else if (shape == 3) {
        vertical_arm(0.5 * width_m, true);
        vertical_arm(spine_m - 0.5 * width_m, true);
    }
    // Rooms along both sides of every arm, kept where they overlap no corridor and no room.
    std::vector<Box> rooms;
    std::vector<int> door_sides;
    for (size_t arm = 0; arm < corridors.size(); ++arm) {
        const Box &corridor = corridors[arm];
        const bool horizontal = arm == 0;
        const double start = horizontal ? corridor.low_m.x() : corridor.low_m.y();
        const double end = horizontal ? corridor.high_m.x() : corridor.high_m.y();
        for (int side = 0; side < 2; ++side) {
            double along = start;
            while (along < end - 2.5) {
                const double room_width = std::min(random.uniform(3.0, 6.0), end - along);
                const double depth = random.uniform(4.0, 7.0);
                Box room;
                int door_side = 0;
                if (horizontal) {
                    room = side == 0 ? Box{Vector2(along, corridor.high_m.y()),
                                           Vector2(along + room_width, corridor.high_m.y() + depth)}
                                     : Box{Vector2(along, corridor.low_m.y() - depth),
                                           Vector2(along + room_width, corridor.low_m.y())};
                    door_side = side == 0 ? 0 : 2; // the side on the corridor
                } else {
                    room = side == 0 ? Box{Vector2(corridor.high_m.x(), along),
                                           Vector2(corridor.high_m.x() + depth, along + room_width)}
                                     : Box{Vector2(corridor.low_m.x() - depth, along),
                                           Vector2(corridor.low_m.x(), along + room_width)};
                    door_side = side == 0 ? 3 : 1;
                }
                along += room_width;
                bool free = true;
                for (const Box &other : corridors) {
                    free = free && !room.overlaps(other, 0.01);
                }
                for (const Box &other : rooms) {
                    free = free && !room.overlaps(other, 0.01);
                }
                if (free) {
                    rooms.push_back(room);
                    door_sides.push_back(door_side);
                }
            }
        }
    }
    for (size_t r = 0; r < rooms.size(); ++r) {
        addRoomWalls(world, rooms[r], door_sides[r], random);
    }
    // Candidate places: on the corridor walls every 3-7 m (nearly collinear, as mounted), and in
    // rooms near a wall.
    std::vector<Vector3> places;
    for (size_t arm = 0; arm < corridors.size(); ++arm) {
        const Box &corridor = corridors[arm];
        const bool horizontal = arm == 0;
        const double start = horizontal ? corridor.low_m.x() : corridor.low_m.y();
        const double end = horizontal ? corridor.high_m.x() : corridor.high_m.y();
        for (double along = start + random.uniform(0.5, 3.0); along < end; along += random.uniform(3.0, 7.0)) {
            const bool first_side = random.chance(0.5);
            const double across = horizontal ? (first_side ? corridor.high_m.y() - 0.15 : corridor.low_m.y() + 0.15)
                                             : (first_side ? corridor.high_m.x() - 0.15 : corridor.low_m.x() + 0.15);
            places.push_back(horizontal ? Vector3(along, across, heightM(random))
                                        : Vector3(across, along, heightM(random)));
        }
    }
    const size_t corridor_places = places.size();
    for (const Box &room : rooms) {
        const Vector2 size = room.high_m - room.low_m;
        // Near one of the walls, somewhere along it.
        const int wall = static_cast<int>(random.below(4));
        const double u = random.uniform(0.15, 0.85);
        Vector2 p = room.low_m + Vector2(u * size.x(), u * size.y());
        if (wall == 0) {
            p.y() = room.low_m.y() + 0.2;
        } else if (wall == 1) {
            p.x() = room.high_m.x() - 0.2;
        } else if (wall == 2) {
            p.y() = room.high_m.y() - 0.2;
        } else {
            p.x() = room.low_m.x() + 0.2;
        }
        places.push_back(Vector3(p.x(), p.y(), heightM(random)));
    }
    const uint32_t wanted = options.nodes > 0 ? options.nodes : static_cast<uint32_t>(30 + random.below(51));
    // Keep every corridor place (the spine of the network) and fill with rooms, or thin both.
    std::vector<size_t> order(places.size());
    for (size_t i = 0; i < order.size(); ++i) {
        order[i] = i;
    }
    random.shuffle(order);
    std::stable_partition(order.begin(), order.end(), [&](size_t i) { return i < corridor_places; });
    if (order.size() > wanted) {
        // Thin the corridor and the rooms alike, in proportion.
        random.shuffle(order);
        order.resize(wanted);
    }
    std::sort(order.begin(), order.end());
    for (size_t i : order) {
        addNode(world, places[i]);
    }
    Radio radio;
    radio.reach_m = random.uniform(12.0, 25.0);
    radio.wall_attenuation = 0.65;
    radio.max_walls = 2;
    radio.excess_per_wall_min_m = 0.1;
    radio.excess_per_wall_max_m = 0.6;
    radio.obstructed_fraction = options.nlos_fraction >= 0.0 ? options.nlos_fraction : 0.05;
    hearLinks(world, radio, random);
    world.noise = RangeNoise{0.13, 0.03, 1.2};
    static const char *const kShapes[4] = {"I", "L", "T", "U"};
    std::ostringstream text;
    text << kShapes[shape] << "-shaped corridor " << width_m << " m wide, " << corridors.size() << " arm(s), "
         << rooms.size() << " rooms, " << world.nodes.size() << " nodes, reach " << radio.reach_m << " m";
    world.description = text.str();
    return world;
}

// ---- wings ----------------------------------------------------------------------------------

World drawWings(Random &random, const FamilyOptions &options)
{
    World world;
    const uint32_t wing_count = random.chance(0.5) ? 2U : 3U;
    const double reach_m = random.uniform(10.0, 14.0);
    std::vector<std::vector<uint32_t>> members(wing_count);
    std::vector<Box> boxes;
    double x_m = 0.0;
    for (uint32_t w = 0; w < wing_count; ++w) {
        const double width = random.uniform(14.0, 22.0);
        const double depth = random.uniform(12.0, 20.0);
        Box box;
        if (w < 2) {
            box = {Vector2(x_m, 0.0), Vector2(x_m + width, depth)};
            x_m += width + random.uniform(4.0, 10.0);
        } else {
            // The third wing stands above the second one (an L of wings).
            const Box &second = boxes[1];
            const double y = second.high_m.y() + random.uniform(4.0, 10.0);
            box = {Vector2(second.low_m.x(), y), Vector2(second.low_m.x() + width, y + depth)};
        }
        boxes.push_back(box);
        const uint32_t count = options.nodes > 0 ? std::max<uint32_t>(options.nodes / wing_count, 6U)
                                                 : static_cast<uint32_t>(10 + random.below(13));
        uint32_t tries = 0;
        while (members[w].size() < count && tries++ < 100000) {
            const Vector2 p(random.uniform(box.low_m.x(), box.high_m.x()),
                            random.uniform(box.low_m.y(), box.high_m.y()));
            bool crowded = false;
            for (uint32_t other : members[w]) {
                crowded = crowded || (world.nodes[other].position_m.head<2>() - p).norm() < 1.5;
            }
            if (!crowded) {
                members[w].push_back(static_cast<uint32_t>(world.nodes.size()));
                addNode(world, Vector3(p.x(), p.y(), heightM(random)));
            }
        }
    }
    std::vector<uint32_t> wing_of(world.nodes.size(), 0);
    for (uint32_t w = 0; w < wing_count; ++w) {
        for (uint32_t node : members[w]) {
            wing_of[node] = w;
        }
    }
    const double nlos = options.nlos_fraction >= 0.0 ? options.nlos_fraction : 0.08;
    for (uint32_t i = 0; i < world.nodes.size(); ++i) {
        for (uint32_t j = i + 1; j < world.nodes.size(); ++j) {
            if (wing_of[i] != wing_of[j]) {
                continue;
            }
            const double d = (world.nodes[i].position_m.head<2>() - world.nodes[j].position_m.head<2>()).norm();
            if (d <= reach_m * random.uniform(0.85, 1.0)) {
                WorldLink link;
                link.a = i;
                link.b = j;
                if (random.chance(nlos)) {
                    link.excess_m = 0.1 + random.exponential(0.6);
                }
                world.links.push_back(link);
            }
        }
    }
    // Between consecutive wings: 2-4 of the shortest pairs, with distinct ends where possible.
    uint32_t joins = 0;
    for (uint32_t w = 1; w < wing_count; ++w) {
        std::vector<std::pair<double, std::pair<uint32_t, uint32_t>>> pairs;
        for (uint32_t i : members[w - 1]) {
            for (uint32_t j : members[w]) {
                pairs.push_back({(world.nodes[i].position_m.head<2>() - world.nodes[j].position_m.head<2>()).norm(),
                                 {std::min(i, j), std::max(i, j)}});
            }
        }
        std::sort(pairs.begin(), pairs.end());
        const size_t wanted = 2 + random.below(3);
        std::vector<uint32_t> used;
        std::vector<std::pair<uint32_t, uint32_t>> chosen;
        for (int pass = 0; pass < 2 && chosen.size() < wanted; ++pass) {
            for (const auto &[distance, pair] : pairs) {
                if (chosen.size() >= wanted || distance > 2.5 * reach_m) {
                    break;
                }
                const bool fresh = std::find(used.begin(), used.end(), pair.first) == used.end() &&
                                   std::find(used.begin(), used.end(), pair.second) == used.end();
                const bool taken = std::find(chosen.begin(), chosen.end(), pair) != chosen.end();
                if (!taken && (fresh || pass == 1)) {
                    chosen.push_back(pair);
                    used.push_back(pair.first);
                    used.push_back(pair.second);
                }
            }
        }
        for (const auto &[a, b] : chosen) {
            WorldLink link;
            link.a = a;
            link.b = b;
            link.walls = 1;
            link.excess_m = random.chance(0.5) ? random.uniform(0.1, 0.8) : 0.0; // through the wing's wall
            world.links.push_back(link);
            ++joins;
        }
    }
    world.noise = RangeNoise{0.10, 0.02, 1.0};
    std::ostringstream text;
    text << wing_count << " wings, " << world.nodes.size() << " nodes, reach " << reach_m << " m, " << joins
         << " links between wings";
    world.description = text.str();
    return world;
}

// ---- walls ----------------------------------------------------------------------------------

World drawWalls(Random &random, const FamilyOptions &options)
{
    World world;
    const uint32_t count = options.nodes > 0 ? options.nodes : static_cast<uint32_t>(100 + random.below(101));
    const double area_m2 = 20.0 * static_cast<double>(count);
    const double aspect = random.uniform(1.2, 2.0);
    const double height_m = std::sqrt(area_m2 / aspect);
    const double width_m = aspect * height_m;
    // A grid of rooms: wall lines every 6-12 m across and 6-10 m up, each cell edge a wall with
    // a door gap (1 m) in 60 % of them.
    std::vector<double> xs{0.0};
    while (xs.back() < width_m - 4.0) {
        xs.push_back(std::min(xs.back() + random.uniform(6.0, 12.0), width_m));
    }
    xs.back() = width_m;
    std::vector<double> ys{0.0};
    while (ys.back() < height_m - 4.0) {
        ys.push_back(std::min(ys.back() + random.uniform(6.0, 10.0), height_m));
    }
    ys.back() = height_m;
    auto add_wall = [&](const Vector2 &from, const Vector2 &to) {
        const double length = (to - from).norm();
        if (length > 2.0 && random.chance(0.6)) {
            const double at = random.uniform(0.2, 0.8) * (length - 1.0);
            const Vector2 unit = (to - from) / length;
            world.walls.push_back({from, from + at * unit});
            world.walls.push_back({from + (at + 1.0) * unit, to});
        } else {
            world.walls.push_back({from, to});
        }
    };
    for (size_t i = 1; i + 1 < xs.size(); ++i) {
        for (size_t j = 0; j + 1 < ys.size(); ++j) {
            add_wall(Vector2(xs[i], ys[j]), Vector2(xs[i], ys[j + 1]));
        }
    }
    for (size_t j = 1; j + 1 < ys.size(); ++j) {
        for (size_t i = 0; i + 1 < xs.size(); ++i) {
            add_wall(Vector2(xs[i], ys[j]), Vector2(xs[i + 1], ys[j]));
        }
    }
    while (world.nodes.size() < count) {
        const double y_m = random.uniform(0.2, height_m - 0.2); // y first: see drawRandom
        const double x_m = random.uniform(0.2, width_m - 0.2);
        const Vector2 p(x_m, y_m);
        bool crowded = false;
        for (const WorldNode &other : world.nodes) {
            crowded = crowded || (other.position_m.head<2>() - p).norm() < 1.0;
        }
        if (!crowded) {
            addNode(world, Vector3(p.x(), p.y(), heightM(random)));
        }
    }
    Radio radio;
    radio.reach_m = random.uniform(18.0, 25.0);
    radio.wall_attenuation = 0.7;
    radio.max_walls = 4;
    radio.excess_per_wall_min_m = 0.15;
    radio.excess_per_wall_max_m = 0.6;
    radio.obstructed_fraction = options.nlos_fraction >= 0.0 ? options.nlos_fraction : 0.05;
    hearLinks(world, radio, random);
    world.noise = RangeNoise{0.10, 0.03, 1.2};
    std::ostringstream text;
    text << count << " nodes on a " << width_m << " m x " << height_m << " m floor, "
         << (xs.size() - 1) * (ys.size() - 1) << " rooms, " << world.walls.size() << " wall segments, reach "
         << radio.reach_m << " m";
    world.description = text.str();
    return world;
}

// ---- biased ---------------------------------------------------------------------------------

World drawBiased(Random &random, const FamilyOptions &options)
{
    World world;
    const uint32_t count = options.nodes > 0 ? options.nodes : static_cast<uint32_t>(8 + random.below(5));
    // A room for up to 12 nodes (the family's own counts); more nodes get a larger room at the
    // same density, so that 1.5 m apart they always fit.
    const double grow = std::sqrt(std::max(1.0, static_cast<double>(count) / 12.0));
    const double width_m = grow * random.uniform(8.0, 14.0);
    const double depth_m = grow * random.uniform(6.0, 10.0);
    while (world.nodes.size() < count) {
        const double y_m = random.uniform(0.0, depth_m); // y first: see drawRandom
        const double x_m = random.uniform(0.0, width_m);
        const Vector2 p(x_m, y_m);
        bool crowded = false;
        for (const WorldNode &other : world.nodes) {
            crowded = crowded || (other.position_m.head<2>() - p).norm() < 1.5;
        }
        if (!crowded) {
            addNode(world, Vector3(p.x(), p.y(), random.uniform(0.5, 2.5)));
        }
    }
    for (WorldNode &node : world.nodes) {
        node.antenna_delay_m = random.uniform(0.0, 0.9);
    }
    const double nlos = options.nlos_fraction >= 0.0 ? options.nlos_fraction : 0.0;
    for (uint32_t i = 0; i < count; ++i) {
        for (uint32_t j = i + 1; j < count; ++j) {
            WorldLink link;
            link.a = i;
            link.b = j;
            link.excess_m = random.uniform(0.0, 0.2) + (random.chance(nlos) ? random.exponential(0.5) : 0.0);
            world.links.push_back(link);
        }
    }
    world.noise = RangeNoise{0.02, 0.0, 1.0};
    std::ostringstream text;
    text << count << " nodes in a " << width_m << " m x " << depth_m << " m room, all pairs, antenna delays 0-0.9 m";
    world.description = text.str();
    return world;
}

} // namespace

World makeWorld(Family family, uint64_t seed, const FamilyOptions &options)
{
    for (uint32_t attempt = 0; attempt < 1000; ++attempt) {
        Random random(mixSeed(mixSeed(seed) ^ (static_cast<uint64_t>(family) << 32U) ^ attempt));
        World world;
        switch (family) {
        case Family::Random: world = drawRandom(random, options); break;
        case Family::Corridor: world = drawCorridor(random, options); break;
        case Family::Wings: world = drawWings(random, options); break;
        case Family::Walls: world = drawWalls(random, options); break;
        case Family::Biased: world = drawBiased(random, options); break;
        }
        if (world.nodes.size() < 4 || !world.connected()) {
            continue;
        }
        finish(world, random, options);
        world.family = familyName(family);
        world.seed = seed;
        return world;
    }
    throw std::runtime_error(std::string("no connected ") + familyName(family) + " network in 1000 draws");
}

} // namespace cdro::netgen
