// families.hpp: the families of buildings the engine is judged on, each drawn from a seed.
// Every family draws its own sizes, shapes, radio reach and errors from the seed (within the
// ranges below), so ten seeds are ten different buildings; FamilyOptions can pin some of them.
//
//   random    nodes uniform in a square (25 m^2 per node), linked to the nearest pairs for a
//             mean degree of 10; a share of the links NLOS (persistent excess ~ Exp(0.8 m)).
//             15-19 nodes unless FamilyOptions::nodes says otherwise (100, 300, 1000 for scale).
//   corridor  an I-, L-, T- or U-shaped corridor (arms 25-45 m, 1.8-2.6 m wide) with rooms on
//             both sides (4-7 m deep, 3-6 m wide, doors on the corridor); 30-80 nodes on the
//             corridor walls and in rooms; radio reach 12-25 m, cut by each wall crossed; each
//             wall adds 0.1-0.6 m of persistent excess.
//   wings     two or three well-meshed wings (10-22 nodes each, 14-22 m x 12-20 m) that hear
//             each other over 2-4 links only.
//   walls     an office floor (100-200 nodes, 20 m^2 per node) divided into rooms by interior
//             walls with doors; the excess grows with every wall a link crosses (0.15-0.6 m
//             each), reach shrinks with them.
//   biased    8-12 nodes in one room, every pair heard, uncalibrated antenna delays (0-0.9 m a
//             node, so links read up to +1.8 m long) and tiny noise (0.02 m).
//
// Heights: nodes stand at 0.3-2.8 m; known to the engine unless FamilyOptions says otherwise
// (then ranges are 3D and nothing projects them). Sporadic NLOS readings, 2-3 % of the ranges,
// Exp(1.0-1.2 m) long, in every family but `biased`.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "cdro/netgen/world.hpp"

namespace cdro::netgen {

enum class Family : uint8_t { Random, Corridor, Wings, Walls, Biased };

const char *familyName(Family family);
std::optional<Family> parseFamily(const std::string &name);
std::vector<Family> allFamilies();

struct FamilyOptions {
    uint32_t nodes = 0;          // 0: the family's own draw
    double nlos_fraction = -1.0; // share of line-of-sight links with an obstruction; < 0: the family's
    double degree = 10.0;        // random: mean degree
    bool heights_known = true;   // false: the engine is told no height
};

// The world of family `family` drawn from `seed`, connected (redrawn until it is).
World makeWorld(Family family, uint64_t seed, const FamilyOptions &options = {});

} // namespace cdro::netgen
