// A carried node's track (host/netgen/include/cdro/netgen/track.hpp): where it is at the ends of
// its legs and in between, a stretch given by its speed walks as the same stretch given by its end time,
// waypoints without z keep the node's height, and the accelerometer reads exactly 1 g at rest
// and the gait while carried.
#include <gtest/gtest.h>

#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

#include "cdro/netgen/track.hpp"

using cdro::netgen::Gait;
using cdro::netgen::Stretch;
using cdro::netgen::Track;
using cdro::netgen::Vector3;

namespace {

constexpr double kPi = 3.14159265358979323846;

// From (0, 0, 1) m at 2 s: 3 m along x, then 4 m along y, at 1 m/s (legs end at 5 and 9 s).
Stretch lShaped()
{
    Stretch s;
    s.start_s = 2.0;
    s.speed_mps = 1.0;
    s.waypoints = {{3.0, 0.0, std::nullopt}, {3.0, 4.0, std::nullopt}};
    return s;
}

const Vector3 kStart(0.0, 0.0, 1.0); // m

void expectAt(const Track &track, double t_s, const Vector3 &expected_m)
{
    const Vector3 p = track.positionM(t_s);
    EXPECT_DOUBLE_EQ(p.x(), expected_m.x()) << "x at " << t_s << " s";
    EXPECT_DOUBLE_EQ(p.y(), expected_m.y()) << "y at " << t_s << " s";
    EXPECT_DOUBLE_EQ(p.z(), expected_m.z()) << "z at " << t_s << " s";
}

// The error a track of these stretches is refused with ("(accepted)" if none).
std::string refusal(const Stretch &stretch, const Stretch &second = {})
{
    std::vector<Stretch> stretches{stretch};
    if (!second.waypoints.empty()) {
        stretches.push_back(second);
    }
    try {
        const Track track(kStart, stretches, Gait{});
        (void)track;
    } catch (const std::invalid_argument &e) {
        return e.what();
    }
    return "(accepted)";
}

} // namespace

TEST(Track, PositionsAtTheLegEndsAndBetween)
{
    const Track track(kStart, {lShaped()}, Gait{});
    ASSERT_EQ(track.legs().size(), 2U);
    EXPECT_DOUBLE_EQ(track.legs()[0].t1_s, 5.0);
    EXPECT_DOUBLE_EQ(track.legs()[1].t0_s, 5.0);
    EXPECT_DOUBLE_EQ(track.legs()[1].t1_s, 9.0);
    expectAt(track, 0.0, kStart);
    expectAt(track, 2.0, kStart); // leaves at 2 s
    expectAt(track, 3.5, {1.5, 0.0, 1.0});
    expectAt(track, 5.0, {3.0, 0.0, 1.0}); // the first leg's end
    expectAt(track, 7.0, {3.0, 2.0, 1.0});
    expectAt(track, 9.0, {3.0, 4.0, 1.0}); // the last leg's end, and it stays there
    expectAt(track, 1000.0, {3.0, 4.0, 1.0});
    EXPECT_FALSE(track.moving(1.999));
    EXPECT_TRUE(track.moving(2.0));
    EXPECT_TRUE(track.moving(8.999));
    EXPECT_FALSE(track.moving(9.0));
}

TEST(Track, AStandingNodeStaysWhereItIs)
{
    const Track track(Vector3(4.0, -2.0, 0.5));
    EXPECT_TRUE(track.legs().empty());
    expectAt(track, 0.0, {4.0, -2.0, 0.5});
    expectAt(track, 1e5, {4.0, -2.0, 0.5});
    EXPECT_FALSE(track.moving(3.0));
}

TEST(Track, TheEndTimeGivesTheSpeedOfThePath)
{
    // 7 m in 3.5 s: the same walk as at 2 m/s, ending at 5.5 s.
    Stretch by_speed = lShaped();
    by_speed.speed_mps = 2.0;
    Stretch by_end = lShaped();
    by_end.speed_mps = 0.0;
    by_end.end_s = 5.5;
    const Track a(kStart, {by_speed}, Gait{});
    const Track b(kStart, {by_end}, Gait{});
    ASSERT_EQ(b.legs().size(), 2U);
    EXPECT_DOUBLE_EQ(b.legs()[0].t1_s, 3.5);
    EXPECT_DOUBLE_EQ(b.legs()[1].t1_s, 5.5);
    for (double t_s = 0.0; t_s < 7.0; t_s += 0.25) {
        EXPECT_DOUBLE_EQ(a.positionM(t_s).x(), b.positionM(t_s).x()) << t_s << " s";
        EXPECT_DOUBLE_EQ(a.positionM(t_s).y(), b.positionM(t_s).y()) << t_s << " s";
    }
    expectAt(b, 4.5, {3.0, 2.0, 1.0});
    EXPECT_FALSE(b.moving(5.5));
}

TEST(Track, AWaypointWithoutZKeepsTheHeight)
{
    // Up the stairs to 2.5 m, then a stretch whose waypoint gives no z: back at the node's own
    // height, 1 m, as a scenario file's [x, y] waypoint is.
    Stretch stairs;
    stairs.start_s = 0.0;
    stairs.speed_mps = 1.0;
    stairs.waypoints = {{0.0, 1.5, 2.5}}; // 1.5 m across, 1.5 m up: ends at sqrt(4.5) s
    Stretch on;
    on.start_s = 10.0;
    on.speed_mps = 1.0;
    on.waypoints = {{4.0, 1.5, std::nullopt}};
    const Track track(kStart, {on, stairs}, Gait{}); // in any order
    expectAt(track, std::sqrt(4.5) / 2.0, {0.0, 0.75, 1.75});
    expectAt(track, 5.0, {0.0, 1.5, 2.5});
    expectAt(track, 100.0, {4.0, 1.5, 1.0});
    const Track flat(kStart, {lShaped()}, Gait{});
    for (double t_s = 0.0; t_s < 10.0; t_s += 0.5) {
        EXPECT_EQ(flat.positionM(t_s).z(), 1.0) << t_s << " s";
    }
}

TEST(Track, TheAccelerometerReadsOneGAtRestAndTheGaitWhileCarried)
{
    const Gait gait{250.0, 2.0}; // mg, Hz
    Stretch later = lShaped();
    later.start_s = 20.0;
    later.waypoints = {{6.0, 4.0, std::nullopt}}; // 3 m along +x from (3, 4): until 23 s
    const Track track(kStart, {lShaped(), later}, gait);
    for (const double t_s : {0.0, 1.99, 9.0, 15.0, 23.0, 100.0}) {
        const Vector3 a = track.accelMg(t_s);
        EXPECT_EQ(a.x(), 0.0) << t_s << " s";
        EXPECT_EQ(a.y(), 0.0) << t_s << " s";
        EXPECT_EQ(a.z(), 1000.0) << t_s << " s";
    }
    // A quarter step after each stretch starts, the bounce is at its top; the surge (along x on
    // the first leg) is at zero, the sway at 0.2 * 250 * sin(pi / 4).
    for (const double start_s : {2.0, 20.0}) {
        const Vector3 a = track.accelMg(start_s + 0.125);
        EXPECT_NEAR(a.z(), 1250.0, 1e-9) << "stretch at " << start_s << " s";
        EXPECT_NEAR(a.x(), 0.0, 1e-9);
        EXPECT_NEAR(a.y(), 50.0 * std::sin(kPi / 4.0), 1e-9);
    }
    // On the second leg (along +y) the surge is along y: at a whole step it is 0.3 * 250.
    const Vector3 a = track.accelMg(6.0);
    EXPECT_NEAR(a.y(), 75.0, 1e-9);
    EXPECT_NEAR(a.z(), 1000.0, 1e-9);
}

TEST(Track, BackToBackStretchesMakeOneSpan)
{
    Stretch next;
    next.start_s = 9.0; // where lShaped ends
    next.speed_mps = 0.5;
    next.waypoints = {{3.0, 5.0, std::nullopt}};
    Stretch later = next;
    later.start_s = 20.0;
    later.waypoints = {{3.0, 6.0, std::nullopt}};
    const Track track(kStart, {lShaped(), next, later}, Gait{});
    const std::vector<Track::Span> spans = track.spans();
    ASSERT_EQ(spans.size(), 2U);
    EXPECT_DOUBLE_EQ(spans[0].from_s, 2.0);
    EXPECT_DOUBLE_EQ(spans[0].to_s, 11.0);
    EXPECT_DOUBLE_EQ(spans[0].length_m, 8.0);
    EXPECT_DOUBLE_EQ(spans[1].from_s, 20.0);
    EXPECT_DOUBLE_EQ(spans[1].to_s, 22.0);
    EXPECT_DOUBLE_EQ(spans[1].length_m, 1.0);
}

TEST(Track, AStretchThatCannotBeWalkedIsRefusedSayingWhy)
{
    Stretch none = lShaped();
    none.waypoints.clear();
    EXPECT_NE(refusal(none).find("the stretch at 2.000000 s has no waypoints"), std::string::npos) << refusal(none);

    Stretch backwards = lShaped();
    backwards.speed_mps = 0.0;
    backwards.end_s = 1.0;
    EXPECT_NE(refusal(backwards).find("ends at 1.000000 s, not after it starts"), std::string::npos)
        << refusal(backwards);

    Stretch negative = lShaped();
    negative.speed_mps = -1.0;
    EXPECT_NE(refusal(negative).find("speed -1.000000 m/s: it must be positive"), std::string::npos)
        << refusal(negative);

    Stretch still = lShaped();
    still.waypoints = {{0.0, 0.0, std::nullopt}}; // where it stands: no speed from an end time
    still.speed_mps = 0.0;
    still.end_s = 4.0;
    EXPECT_NE(refusal(still).find("speed 0.000000 m/s"), std::string::npos) << refusal(still);

    Stretch nan = lShaped();
    nan.waypoints[1].x_m = std::nan("");
    EXPECT_NE(refusal(nan).find("a waypoint that is not finite"), std::string::npos) << refusal(nan);

    Stretch overlapping = lShaped();
    overlapping.start_s = 8.0; // lShaped walks until 9 s
    const std::string overlap = refusal(lShaped(), overlapping);
    EXPECT_NE(overlap.find("the stretch at 8.000000 s starts before the previous one ends at 9.000000 s"),
              std::string::npos)
        << overlap;
}
