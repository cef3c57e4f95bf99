// placement: candidates and decisions for two versus three or more constraints, the mirror
// ambiguity of collinear neighbours (which the global solve, not placement, decides), and the
// frame triangle.
#include <cmath>

#include <gtest/gtest.h>

#include "cdro/engine/placement.hpp"
#include "support.hpp"

namespace cdro::enginetest {
namespace {

using engine::chooseFrameTriangle;
using engine::choosePlacement;
using engine::MapState;
using engine::PlacementCandidate;
using engine::placementCandidates;
using engine::PlacementDecision;
using engine::PlacementParams;
using engine::PointSolverParams;
using engine::RangeConstraint;
using engine::RangeLikelihood;

std::vector<RangeConstraint> exactConstraints(const Vector2 &truth_m, const std::vector<Vector2> &anchors_m)
{
    std::vector<RangeConstraint> constraints;
    for (const Vector2 &anchor : anchors_m) {
        RangeConstraint c;
        c.anchor_m = anchor;
        c.range_m = (anchor - truth_m).norm();
        constraints.push_back(c);
    }
    return constraints;
}

std::vector<PlacementCandidate> candidatesFor(const std::vector<RangeConstraint> &constraints)
{
    return placementCandidates(constraints, RangeLikelihood(), PointSolverParams{}, PlacementParams{});
}

bool hasCandidateNear(const std::vector<PlacementCandidate> &candidates, const Vector2 &point_m, double tolerance_m)
{
    for (const PlacementCandidate &c : candidates) {
        if ((c.position_m - point_m).norm() < tolerance_m) {
            return true;
        }
    }
    return false;
}

TEST(Placement, TwoConstraintsGiveTwoMirrorCandidatesAndNoDecision)
{
    const Vector2 truth_m(2.0, 3.0);
    const auto constraints = exactConstraints(truth_m, {Vector2(0.0, 0.0), Vector2(6.0, 0.0)});
    const auto candidates = candidatesFor(constraints);
    ASSERT_EQ(candidates.size(), 2U);
    EXPECT_TRUE(hasCandidateNear(candidates, truth_m, 1e-6));
    EXPECT_TRUE(hasCandidateNear(candidates, Vector2(2.0, -3.0), 1e-6));
    EXPECT_NEAR(candidates[0].cost, candidates[1].cost, 1e-9);
    const auto choice = choosePlacement(candidates, constraints.size(), PlacementParams{});
    EXPECT_EQ(choice.decision, PlacementDecision::Ambiguous);
}

TEST(Placement, ThreeNonCollinearConstraintsDecide)
{
    const Vector2 truth_m(2.0, 3.0);
    const auto constraints = exactConstraints(truth_m, {Vector2(0.0, 0.0), Vector2(6.0, 0.0), Vector2(0.0, 6.0)});
    const auto candidates = candidatesFor(constraints);
    ASSERT_GE(candidates.size(), 1U);
    EXPECT_LT((candidates[0].position_m - truth_m).norm(), 1e-6);
    for (size_t i = 1; i < candidates.size(); ++i) {
        EXPECT_GE(candidates[i].cost, candidates[i - 1].cost); // best first
        EXPECT_GE((candidates[i].position_m - candidates[0].position_m).norm(), PlacementParams{}.distinct_m);
    }
    const auto choice = choosePlacement(candidates, constraints.size(), PlacementParams{});
    EXPECT_EQ(choice.decision, PlacementDecision::Placed);
    EXPECT_LT((choice.chosen.position_m - truth_m).norm(), 1e-6);
    // A rival within the ambiguity gap would have stopped it: the gap is what decides.
    PlacementParams demanding;
    demanding.ambiguity_gap_nats = 1e6;
    if (candidates.size() > 1) {
        EXPECT_EQ(choosePlacement(candidates, constraints.size(), demanding).decision, PlacementDecision::Ambiguous);
    }
}

TEST(Placement, CollinearNeighboursLeaveTheMirrorImageAmbiguous)
{
    const Vector2 truth_m(3.0, 4.0);
    const Vector2 mirror_m(3.0, -4.0);
    const auto constraints = exactConstraints(truth_m, {Vector2(0.0, 0.0), Vector2(5.0, 0.0), Vector2(12.0, 0.0)});
    const auto candidates = candidatesFor(constraints);
    ASSERT_EQ(candidates.size(), 2U);
    EXPECT_TRUE(hasCandidateNear(candidates, truth_m, 1e-6));
    EXPECT_TRUE(hasCandidateNear(candidates, mirror_m, 1e-6));
    const PlacementParams params;
    EXPECT_EQ(choosePlacement(candidates, constraints.size(), params).decision, PlacementDecision::Ambiguous);
}

// A node heard by 40 neighbours (every pair of a hall ranging) is seeded from pairs of its shortest
// links only; even when those 16 are all on one line (their pairs give the mirror image as often
// as the truth), the polish on every link finds the truth, and it comes first.
TEST(Placement, ANodeWithManyNeighboursIsFoundFromItsShortestLinks)
{
    const Vector2 truth_m(7.0, 2.0);
    std::vector<Vector2> anchors_m;
    anchors_m.reserve(40);
    for (int i = 0; i < 16; ++i) {
        anchors_m.emplace_back(static_cast<double>(i), 0.0); // the closest: collinear
    }
    for (int i = 0; i < 24; ++i) {
        const double angle = 0.26 * static_cast<double>(i);
        anchors_m.emplace_back(truth_m + 25.0 * Vector2(std::cos(angle), std::sin(angle)));
    }
    const auto constraints = exactConstraints(truth_m, anchors_m);
    const auto candidates = candidatesFor(constraints);
    ASSERT_GE(candidates.size(), 1U);
    EXPECT_LT((candidates[0].position_m - truth_m).norm(), 1e-6);
    EXPECT_EQ(choosePlacement(candidates, constraints.size(), PlacementParams{}).decision, PlacementDecision::Placed);
}

TEST(Placement, TangentCirclesGiveOneCandidateAndNoDecision)
{
    const auto constraints = exactConstraints(Vector2(2.0, 0.0), {Vector2(0.0, 0.0), Vector2(4.0, 0.0)});
    const auto candidates = candidatesFor(constraints);
    ASSERT_EQ(candidates.size(), 1U);
    EXPECT_LT((candidates[0].position_m - Vector2(2.0, 0.0)).norm(), 1e-9);
    EXPECT_EQ(choosePlacement(candidates, 2, PlacementParams{}).decision, PlacementDecision::Ambiguous);
}

TEST(Placement, NoUsableBaselineGivesNoCandidate)
{
    // Neighbours 0.5 m apart (below min_baseline_m = 1 m): no intersection is trusted.
    const auto constraints = exactConstraints(Vector2(3.0, 4.0), {Vector2(0.0, 0.0), Vector2(0.5, 0.0)});
    const auto candidates = candidatesFor(constraints);
    EXPECT_TRUE(candidates.empty());
    EXPECT_EQ(choosePlacement(candidates, 2, PlacementParams{}).decision, PlacementDecision::NoCandidate);
    EXPECT_TRUE(candidatesFor({}).empty());
}

// ---- the frame triangle -------------------------------------------------------------------

struct FrameFixture {
    MapState network;
    std::vector<Vector2> truth_m;
    void link(uint32_t a, uint32_t b)
    {
        const uint32_t index = network.addLink(a, b, 15);
        network.links[index].representative_m = (truth_m[a] - truth_m[b]).norm();
    }
    double range(uint32_t a, uint32_t b) const { return (truth_m[a] - truth_m[b]).norm(); }
};

// A, B, C nearly on a line (C 0.2 m off it), D well off it; every pair linked.
FrameFixture nearlyCollinear()
{
    FrameFixture f;
    f.truth_m = {Vector2(0.0, 0.0), Vector2(10.0, 0.0), Vector2(20.0, 0.2), Vector2(5.0, 8.0)};
    for (NodeId id : {NodeId(1), NodeId(2), NodeId(3), NodeId(4)}) {
        f.network.addNode(id);
    }
    for (uint32_t a = 0; a < 4; ++a) {
        for (uint32_t b = a + 1; b < 4; ++b) {
            f.link(a, b);
        }
    }
    return f;
}

void expectTriangleConsistent(const FrameFixture &f, const engine::FrameTriangle &t)
{
    EXPECT_EQ(t.origin_m, Vector2::Zero());
    EXPECT_EQ(t.x_axis_m.y(), 0.0);
    EXPECT_GT(t.x_axis_m.x(), 0.0);
    EXPECT_GT(t.positive_y_m.y(), 0.0);
    EXPECT_NEAR(t.x_axis_m.norm(), f.range(t.origin, t.x_axis), 1e-9);
    EXPECT_NEAR(t.positive_y_m.norm(), f.range(t.origin, t.positive_y), 1e-9);
    EXPECT_NEAR((t.positive_y_m - t.x_axis_m).norm(), f.range(t.x_axis, t.positive_y), 1e-9);
}

TEST(FrameTriangle, PrefersANonCollinearTriangle)
{
    const FrameFixture f = nearlyCollinear();
    const auto triangle = chooseFrameTriangle(f.network, PlacementParams{}, std::vector<bool>(4, true), std::nullopt);
    ASSERT_TRUE(triangle.has_value());
    // D (index 3) is in it: A, B, C alone are 0.1 m from a line.
    EXPECT_TRUE(triangle->origin == 3 || triangle->x_axis == 3 || triangle->positive_y == 3);
    expectTriangleConsistent(f, *triangle);
    // The baseline p0-p1 is the triangle's longest side.
    const double baseline = f.range(triangle->origin, triangle->x_axis);
    EXPECT_GE(baseline, f.range(triangle->origin, triangle->positive_y));
    EXPECT_GE(baseline, f.range(triangle->x_axis, triangle->positive_y));
}

TEST(FrameTriangle, TakesThePreferredTriangleWhenUsable)
{
    const FrameFixture f = nearlyCollinear();
    const std::vector<bool> all(4, true);
    const std::optional<std::array<uint32_t, 3>> preferred = std::array<uint32_t, 3>{3, 0, 1};
    const auto triangle = chooseFrameTriangle(f.network, PlacementParams{}, all, preferred);
    ASSERT_TRUE(triangle.has_value());
    EXPECT_EQ(triangle->origin, 3U);
    EXPECT_EQ(triangle->x_axis, 0U);
    EXPECT_EQ(triangle->positive_y, 1U);
    expectTriangleConsistent(f, *triangle);
}

TEST(FrameTriangle, IgnoresAPreferredTriangleThatCannotBeUsed)
{
    FrameFixture f = nearlyCollinear();
    const std::vector<bool> all(4, true);
    const auto fallback = chooseFrameTriangle(f.network, PlacementParams{}, all, std::nullopt);
    ASSERT_TRUE(fallback.has_value());
    const auto same = [&](const std::optional<engine::FrameTriangle> &t) {
        return t && t->origin == fallback->origin && t->x_axis == fallback->x_axis &&
               t->positive_y == fallback->positive_y;
    };
    // Collinear: the preference is ignored.
    EXPECT_TRUE(same(chooseFrameTriangle(f.network, PlacementParams{}, all, std::array<uint32_t, 3>{0, 1, 2})));
    // Naming an unknown node.
    EXPECT_TRUE(
        same(chooseFrameTriangle(f.network, PlacementParams{}, all, std::array<uint32_t, 3>{0, engine::kNoIndex, 3})));
    // Not eligible: a triangle without that node is chosen.
    std::vector<bool> without_d = all;
    without_d[3] = false;
    const auto no_d = chooseFrameTriangle(f.network, PlacementParams{}, without_d, std::array<uint32_t, 3>{3, 0, 1});
    // Only A, B, C are left and they are nearly collinear: nothing usable.
    EXPECT_FALSE(no_d.has_value());
    // Not linked: a fifth node E ranged to A and B only.
    f.truth_m.push_back(Vector2(3.0, -6.0));
    f.network.addNode(5);
    f.link(0, 4);
    f.link(1, 4);
    const std::vector<bool> five(5, true);
    const auto unlinked = chooseFrameTriangle(f.network, PlacementParams{}, five, std::array<uint32_t, 3>{4, 3, 0});
    ASSERT_TRUE(unlinked.has_value());
    EXPECT_FALSE(unlinked->origin == 4 && unlinked->x_axis == 3 && unlinked->positive_y == 0);
    expectTriangleConsistent(f, *unlinked);
}

TEST(FrameTriangle, NothingUsableYieldsNothing)
{
    FrameFixture f;
    f.truth_m = {Vector2(0.0, 0.0), Vector2(5.0, 0.0), Vector2(11.0, 0.3), Vector2(16.0, 0.0)};
    for (NodeId id = 1; id <= 4; ++id) {
        f.network.addNode(id);
    }
    // A path has no triangle at all.
    f.link(0, 1);
    f.link(1, 2);
    f.link(2, 3);
    EXPECT_FALSE(chooseFrameTriangle(f.network, PlacementParams{}, std::vector<bool>(4, true), std::nullopt));
    // Triangles, but all within 1 m of a line.
    f.link(0, 2);
    f.link(1, 3);
    EXPECT_FALSE(chooseFrameTriangle(f.network, PlacementParams{}, std::vector<bool>(4, true), std::nullopt));
    PlacementParams lenient;
    lenient.min_triangle_height_m = 0.05;
    EXPECT_TRUE(chooseFrameTriangle(f.network, lenient, std::vector<bool>(4, true), std::nullopt));
}

} // namespace
} // namespace cdro::enginetest
