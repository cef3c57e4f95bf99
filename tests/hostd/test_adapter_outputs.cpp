// The outputs' view of the engine, update by update (EngineAdapter::updateEstimates): after every
// range the map the adapter keeps up to date holds exactly what a whole fill() holds, and the
// positions it names as changed include every node whose estimate changed, so that the outputs,
// which look at those alone, miss nothing. Held in the three shapes the adapter converts: the
// static map (nodes appearing, global solves moving them all, a node carried), a robot (the
// movement stage), and tags tracked in 3D. And it is what makes an update cheap: in a settled
// map, a range changes a handful of nodes.
#include <algorithm>
#include <cstdio>
#include <vector>

#include <gtest/gtest.h>

#include "cdro/engine/engine.hpp"
#include "cdro/engine/movement.hpp"
#include "cdro/hostd/engine_adapter.hpp"
#include "cdro/service/map_state.hpp"
#include "robot_world.hpp"
#include "simulated_flight.hpp"
#include "support.hpp"

namespace cdro::enginetest {
namespace {

using engine::Engine;

// Calls updateEstimates after each update as the service does, and checks it against a whole
// fill() and against what truly changed.
class UpdateCheck {
public:
    explicit UpdateCheck(hostd::EngineAdapter &adapter) : adapter_(adapter) {}

    void afterUpdate()
    {
        const std::vector<service::NodeEstimate> before = map_.nodes;
        adapter_.updateEstimates(map_, changed_);
        service::MapState whole;
        adapter_.fill(whole);
        ASSERT_EQ(map_.nodes.size(), whole.nodes.size()) << "update " << updates_;
        for (size_t i = 0; i < whole.nodes.size(); ++i) {
            ASSERT_TRUE(service::sameEstimate(map_.nodes[i], whole.nodes[i]))
                << "update " << updates_ << ": node " << whole.nodes[i].id << " differs from a whole fill";
        }
        ASSERT_EQ(map_.robot.has_value(), whole.robot.has_value());
        if (whole.robot) {
            ASSERT_TRUE(service::sameEstimate(*map_.robot, *whole.robot)) << "update " << updates_;
        }
        ASSERT_TRUE(std::is_sorted(changed_.begin(), changed_.end()));
        const std::vector<size_t> truly = service::changedNodes(before, map_.nodes);
        ASSERT_TRUE(std::includes(changed_.begin(), changed_.end(), truly.begin(), truly.end()))
            << "update " << updates_ << ": a changed node was not named";
        ++updates_;
        named_.push_back(changed_.size());
    }
    size_t updates() const { return updates_; }
    size_t nodes() const { return map_.nodes.size(); }
    // The median number of nodes named per update over the last `last` updates.
    size_t medianNamed(size_t last) const
    {
        std::vector<size_t> tail(named_.end() - static_cast<std::ptrdiff_t>(std::min(last, named_.size())),
                                 named_.end());
        std::nth_element(tail.begin(), tail.begin() + static_cast<std::ptrdiff_t>(tail.size() / 2), tail.end());
        return tail[tail.size() / 2];
    }

private:
    hostd::EngineAdapter &adapter_;
    service::MapState map_;
    std::vector<size_t> changed_;
    size_t updates_ = 0;
    std::vector<size_t> named_;
};

TEST(AdapterOutputs, TheStaticMapUpdatedRangeByRangeIsTheWholeMapAndASettledRangeChangesAFew)
{
    const uint64_t seed = testSeed(4307);
    SCOPED_TRACE(seedTrace(seed));
    Random random(seed);
    const TestNetwork network = randomNetwork(random, 40, 8.0, true);
    const std::vector<TestRange> ranges = roundRobin(network, random, 12, 0.1);
    Engine engine;
    for (size_t i = 0; i < network.ids.size(); ++i) {
        engine.setHeight(network.ids[i], network.height_m[i]);
    }
    hostd::EngineAdapter adapter(engine);
    UpdateCheck check(adapter);
    const NodeId carried = network.ids[7];
    for (size_t k = 0; k < ranges.size(); ++k) {
        if (k == ranges.size() / 2) {
            engine.setMoving(carried, true); // a motion report: the node's lifecycle and its neighbours'
            check.afterUpdate();
        }
        if (k == ranges.size() / 2 + 200) {
            engine.setMoving(carried, false);
            check.afterUpdate();
        }
        engine.addRange(ranges[k].from, ranges[k].to, ranges[k].range_m, 0.01 * static_cast<double>(k));
        check.afterUpdate();
        if (HasFatalFailure()) {
            return;
        }
    }
    ASSERT_EQ(check.nodes(), network.ids.size());
    // Measured: a median of 5 of the 40 nodes named per range over the last two sweeps. A
    // conversion of every node on every range would name 40.
    const size_t median = check.medianNamed(2 * network.links.size());
    std::printf("static map: %zu updates, median %zu of %zu nodes named per range at the end\n", check.updates(),
                median, check.nodes());
    EXPECT_LE(median, check.nodes() / 4);
    // And most updates converted only what the engine named (output_changes.hpp), not the map.
    std::printf("static map: %llu of %zu updates converted only the nodes the engine named\n",
                static_cast<unsigned long long>(adapter.updatesOfNamedNodes()), check.updates());
    EXPECT_GT(adapter.updatesOfNamedNodes(), check.updates() / 2);
}

TEST(AdapterOutputs, ARobotsMapUpdatedStepByStepIsTheWholeMap)
{
    const uint64_t seed = testSeed(4308);
    SCOPED_TRACE(seedTrace(seed));
    netgen::RobotWorldSpec spec;
    spec.ids = {11, 12, 13, 14, 15};
    spec.truth_m = {{0.0, 0.0}, {12.0, 1.0}, {18.0, 10.0}, {6.0, 15.0}, {8.0, 6.0}};
    spec.height_m = {2.0, 2.4, 1.6, 2.2, 2.6};
    for (size_t a = 0; a < spec.ids.size(); ++a) {
        for (size_t b = a + 1; b < spec.ids.size(); ++b) {
            spec.links.emplace_back(a, b);
        }
    }
    spec.robot_start = Pose2{4.0, 3.0, 0.7};
    spec.stand_s = 15.0;
    spec.drive = {{12.0, 0.5, 0.0}, {kPi, 0.2, 0.5}, {10.0, 0.5, 0.0}};
    spec.carry = Carry{15, 25.0, 30.0, Vector2(10.0, 11.0)};
    const World world = simulate(spec, seed);
    Engine engine;
    engine.setHeight(spec.robot_id, spec.robot_height_m);
    for (size_t i = 0; i < spec.ids.size(); ++i) {
        engine.setHeight(spec.ids[i], spec.height_m[i]);
    }
    engine::MovementParams params;
    params.robot_id = spec.robot_id;
    engine::MovementStage stage(engine, params);
    hostd::EngineAdapter adapter(engine, &stage);
    UpdateCheck check(adapter);
    bool localized = false;
    for (const Event &event : world.events) {
        switch (event.kind) {
        case Event::Kind::Odometry: stage.addOdometry(event.t_s, event.step); break;
        case Event::Kind::Range: stage.addRange(event.from, event.to, event.range_m, event.t_s); break;
        case Event::Kind::Motion: stage.setMoving(event.id, event.moving, event.t_s); break;
        }
        check.afterUpdate();
        if (HasFatalFailure()) {
            return;
        }
        localized = localized || (stage.robot() && stage.robot()->localized);
    }
    EXPECT_TRUE(localized); // the robot's pose was among what was checked
    EXPECT_EQ(check.nodes(), spec.ids.size() + 1);
}

TEST(AdapterOutputs, TagsTrackedInThreeDUpdatedRangeByRangeAreTheWholeMap)
{
    const uint64_t seed = testSeed(4309);
    SCOPED_TRACE(seedTrace(seed));
    const std::vector<engine::NodeId> tags = {10, 20};
    FlightSchedule schedule;
    schedule.duration_s = 20.0;
    const std::vector<FlightRange> ranges = simulateFlight(seed, tags, schedule);
    Engine engine;
    fixFlightAnchors(engine);
    for (const engine::NodeId tag : tags) {
        engine.trackMoving3D(tag);
    }
    hostd::EngineAdapter adapter(engine, nullptr, {tags.begin(), tags.end()});
    UpdateCheck check(adapter);
    for (const FlightRange &range : ranges) {
        engine.addRange(range.from, range.to, range.range_m, range.t_s);
        check.afterUpdate();
        if (HasFatalFailure()) {
            return;
        }
    }
    EXPECT_EQ(check.nodes(), tags.size()); // the fixed anchors have no link of the static map
}

} // namespace
} // namespace cdro::enginetest
