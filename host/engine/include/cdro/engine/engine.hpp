// engine.hpp: the CDRO-SLAM initialization stage, the front door of a pipeline of steps, one
// range at a time (docs/engine.md):
//
//   1. range_intake.hpp    refuse what is no range; project to the plane; keep it in its link's window
//   2. motion_tracker.hpp  a range far from the map and from its link's history: is a node moving?
//   3. global_step.hpp     when the links have grown (or gone quiet): the global solve, adopted
//   4. placement_step.hpp  place what can be placed: the frame triangle, then multilateration
//   5. sog_bank.hpp        both ends placed: the SoGs' EKF updates and cooperative weights (eq. 5-15)
//   6. per end: merge (eq. 12-14), refine (refiner.hpp), convergence (convergence.hpp, eq. 16 and
//      the honesty checks); a moving end follows its track (motion_tracker.hpp)
//   7. a bounded number of neighbour updates, so that what one range taught spreads
// settle() runs the global solve on what came since it last ran, then step 7 until nothing moves
// (the end of a file, or idle time). The outputs are in output_frame.hpp's frame.
//
// State: one MapState (map_state.hpp), a plain value the steps read and change; the steps keep
// their own parameters and counters and know nothing of the engine.
// Determinism: no clock, no randomness, no iteration over hash maps; the same calls in the same
// order give the same estimates, bit for bit. Threads: none; call from one thread.
#pragma once

#include <array>
#include <cstdint>
#include <deque>
#include <functional>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "cdro/engine/alignment.hpp"
#include "cdro/engine/convergence.hpp"
#include "cdro/engine/global_step.hpp"
#include "cdro/engine/map_state.hpp"
#include "cdro/engine/motion_track_3d.hpp"
#include "cdro/engine/motion_tracker.hpp"
#include "cdro/engine/output_changes.hpp"
#include "cdro/engine/output_frame.hpp"
#include "cdro/engine/params.hpp"
#include "cdro/engine/placement_step.hpp"
#include "cdro/engine/range_intake.hpp"
#include "cdro/engine/range_likelihood.hpp"
#include "cdro/engine/refiner.hpp"
#include "cdro/engine/ring_sog.hpp"
#include "cdro/engine/sog_bank.hpp"

namespace cdro::engine {

// Every step's counters, and the front door's own.
struct EngineCounters {
    RangeIntakeCounters intake;
    SogBankCounters sogs;
    PlacementCounters placement;
    RefinerCounters refinement;
    GlobalStepCounters solve;
    ConvergenceCounters convergence;
    MotionCounters motion;
    uint64_t ranges_used = 0;   // both ends placed: the filter took it
    uint64_t ranges_stored = 0; // kept; an end not placed yet
    uint64_t node_updates = 0;  // merges (after a range or as a neighbour)
    uint64_t relaxations = 0;   // neighbour updates (step 7)
};

// A node's estimate in the output frame.
struct NodeOutput {
    NodeId id = 0;
    NodeRole role = NodeRole::Free;
    NodeLifecycle lifecycle = NodeLifecycle::Unplaced;
    NodeDoubt doubt = NodeDoubt::None; // why it is not converged
    std::array<NodeId, 2> hinge{};     // Foldable: the nodes it hangs on (hinge_nodes of them, by id)
    uint8_t hinge_nodes = 0;
    bool height_known = false;
    double height_m = 0.0;                   // m
    uint32_t link_count = 0;                 // links to other nodes
    Vector2 position_m = Vector2::Zero();    // m
    Matrix2 covariance_m2 = Matrix2::Zero(); // m^2 (the global solve's where it has one)

    bool placed() const { return lifecycle != NodeLifecycle::Unplaced; }
    bool converged() const { return lifecycle == NodeLifecycle::Converged; }
    bool moving() const { return lifecycle == NodeLifecycle::Moving; }
    bool fixed() const { return role == NodeRole::Fixed; }
};

struct LinkOutput {
    NodeId a = 0; // smaller id
    NodeId b = 0;
    double last_range_m = 0.0; // m, as measured (3D)
    double range_m = 0.0;      // m, the link's range: median of its window, projected
    uint32_t range_count = 0;
    double inlier_probability = 1.0; // line-of-sight probability at the last refinement
};

// One SoG describing a node (output frame).
struct RingOutput {
    NodeId center = 0;
    NodeId target = 0;
    std::vector<SogComponentState> components;
};

class Engine {
public:
    explicit Engine(const EngineParams &params = {});

    // Known facts, before the ranges that need them: a node's height (m), a node with known
    // coordinates (m, output frame) that stays fixed (before the first range; throws
    // std::logic_error after). Two or more fixed nodes define the frame; a single one only
    // says where the map sits.
    void setHeight(NodeId id, double height_m);
    void setFixed(NodeId id, const Vector2 &position_m);

    // One range between two nodes, as measured (3D, m), at time t_s (s; NaN when unknown: the
    // initialization does not need it, tracking a moving node does).
    RangeVerdict addRange(NodeId from, NodeId to, double range_m,
                          double t_s = std::numeric_limits<double>::quiet_NaN());

    // A motion report (MOTION frame, motion CSV): the node is moving or still (params.motion).
    void setMoving(NodeId id, bool moving);

    // A node that moves from the start and never stops, its height not known (a tag on a drone):
    // tracked in 3D (motion_track_3d.hpp) from its ranges to the fixed nodes of known height
    // (setFixed + setHeight: the anchors) and to the other nodes tracked so; its ranges never
    // enter the static map, which is estimated exactly as without it. Before its first range,
    // before the first range of any node tracked so (the anchors are taken then); throws
    // std::logic_error for a node that is fixed, has a known height or has ranges already.
    // addRange() then says Used for a range a track took, Stored for one it did not use (refused
    // as an outlier, another end not started, or a static end that is no anchor: counted in
    // flightCounters())
    // and needs the range's time (RejectedValue without it). Checkpoints hold the tracks
    // (flightSaved, restoreFlights).
    void trackMoving3D(NodeId id);
    // Two nodes tracked in 3D on one rigid body, separation_m (m) apart (a drone's two tags): each
    // one's ranges move the other (motion_track_3d.hpp). Throws std::invalid_argument.
    void trackOnOneBody(NodeId a, NodeId b, double separation_m) { flights_.addBody(a, b, separation_m); }
    std::optional<FlightEstimate> flightEstimate(NodeId id) const { return flights_.estimate(id); }
    const FlightCounters &flightCounters() const { return flights_.counters(); }
    const std::vector<FlightNlosCount> &flightNlosCounts() const { return flights_.nlosCounts(); }
    // The 3D tracks' whole state, and back (FlightTracks::saved, restore: after trackMoving3D and
    // trackOnOneBody, before the first range; throws std::invalid_argument).
    FlightTracks::Saved flightSaved() const { return flights_.saved(); }
    FlightTracks::RestoreReport restoreFlights(const FlightTracks::Saved &saved);

    // The movement stage's EKF owns this node's position: here it is an anchor at that position
    // (not refined, not placed again) until unpinned.
    void pinNode(NodeId id, const Vector2 &position_m, const Matrix2 &covariance_m2);
    void unpinNode(NodeId id);
    // A node that will move (the robot's own tag): never one of the output frame's three nodes,
    // since the frame follows its nodes and one that moves would carry every output with it.
    // Before its first range (a triangle already holding it is kept).
    void excludeFromFrame(NodeId id) { frame_.exclude(id); }
    // While held, no frame triangle is placed: nodes are placed only from fixed or pinned ones
    // (the movement stage's own frame).
    void holdFrame(bool held) { frame_held_ = held; }

    // Runs the global solve if links appeared since it last ran, then updates neighbours until no
    // node moves more than refinement.relax_threshold_m, or max_updates were made. Returns the
    // updates made.
    uint64_t settle(uint64_t max_updates);

    // Outputs, in the output frame (see outputTransform()).
    std::vector<NodeOutput> estimates() const; // every known node, by id
    std::optional<NodeOutput> estimate(NodeId id) const;
    std::vector<LinkOutput> links() const;                    // by (a, b)
    std::vector<RingOutput> ringsDescribing(NodeId id) const; // SoG_ij for every neighbour i
    RigidTransform outputTransform() const { return frame_.transform(map_); }
    // For outputs that convert only what changed (output_changes.hpp): the positions in
    // estimates() whose outputs may have changed since the last call, or all; and the outputs at
    // some positions of estimates(). One caller: each call starts a new interval.
    OutputChanges takeOutputChanges() { return output_changes_.take(map_, revision_, outputTransform()); }
    std::vector<NodeOutput> estimatesAt(const std::vector<uint32_t> &positions) const;

    // Decisions worth explaining (placements, solves, motion) as one-line messages, for the
    // service's debug log and for investigations. Off when empty.
    void setTrace(std::function<void(const std::string &)> sink) { trace_ = std::move(sink); }

    uint64_t revision() const { return revision_; }
    EngineCounters counters() const;
    const EngineParams &params() const { return params_; }
    const MapState &map() const { return map_; }
    // The frame triangle's nodes (ids), once placed.
    std::optional<std::array<NodeId, 3>> frameNodes() const;

    // For checkpoints (the service's adapter writes them in common/'s SoG layout): the whole
    // state, exposed for reading (map(), counters(), solveSchedule()), and rebuilt from parts.
    struct RestoredLink {
        NodeId a = 0;
        NodeId b = 0;
        std::vector<double> window_m;
        uint32_t range_count = 0;
        double last_range_m = 0.0;
        double inlier_probability = 1.0;
        double solved_range_m = 0.0; // m
    };
    struct RestoredState {
        std::vector<NodeState> nodes; // their links are rebuilt from `links`
        std::vector<RestoredLink> links;
        std::vector<RingSog> rings;
        std::optional<std::array<NodeId, 3>> frame_nodes;
        RigidTransform frame_offset; // MapState::frame_offset
        EngineCounters counters;
        SolveSchedule solve_schedule;
        std::vector<NodeDoubt> structural_doubts; // per node, as structuralDoubts()
        uint64_t assessed_key = 0;
    };
    const SolveSchedule &solveSchedule() const { return global_.schedule(); }
    // A global solve started on the worker thread and not adopted yet.
    bool solvePending() const { return global_.pending(); }
    // Who adopts a global solve that runs on the worker thread. AfterLag (the default): addRange,
    // `solve.adopt_after_sweeps` sweeps after it started, waiting for the worker if it is not done
    // (the place depends on the range stream alone: CSV files, older captures). ByCaller: never
    // addRange; live, adoptFinishedSolve() between ranges once the worker is done, so that no range
    // waits for a solve, the caller recording where it adopted; a replay, adoptPendingSolve() at
    // those places (cdro-hostd: host events in the capture), for the same estimates bit for bit.
    enum class SolveAdoption : uint8_t { AfterLag, ByCaller };
    void setSolveAdoption(SolveAdoption adoption) { global_.setAdoptionByCaller(adoption == SolveAdoption::ByCaller); }
    // Adopts the pending solve if its worker is done, never waiting; whether it adopted.
    bool adoptFinishedSolve();
    // Adopts the pending solve, waiting for its worker; false when none is pending.
    bool adoptPendingSolve();
    // The convergence checks' whole-map doubts and the structure they were assessed on: a
    // restored engine decides as this one would, without assessing again.
    const std::vector<NodeDoubt> &structuralDoubts() const { return convergence_.structuralDoubts(); }
    // Whether the map holds the node (map numbering): a reference for nodes that move (Convergence::holds).
    bool holds(uint32_t node) const { return convergence_.holds(map_, node); }
    uint64_t assessedKey() const { return assessed_key_; }
    void restore(const RestoredState &state); // replaces everything; throws std::invalid_argument

private:
    uint32_t nodeIndex(NodeId id);
    NodeOutput outputOf(uint32_t node, const RigidTransform &transform) const; // node: map numbering
    RangeVerdict takeRange(NodeId from, NodeId to, double range_m, double t_s);
    // A node of the frame triangle moving or unplaced: another triangle (OutputFrame::ensureFrameNodes).
    void keepFrame();
    // Whether the neighbour updates a placement is owed are paid at once (settle()) or over the
    // ranges that follow, `settle_per_range` a range, the next placement waiting for them.
    enum class Settling : uint8_t { OverRanges, AtOnce };
    void runPlacement(Settling settling);
    void adoptPlaced(const std::vector<uint32_t> &nodes);
    void startGlobalSolve(bool settling);
    void adoptGlobalSolve();
    void updateNode(uint32_t node, bool after_range = false);
    void unplace(uint32_t node);
    void enqueueNeighbours(uint32_t node);
    void enqueue(uint32_t node);
    uint64_t relax(uint64_t budget, Settling settling); // returns the updates done
    void relaxAfterRange();
    void assess();
    RangeVerdict addFlightRange(NodeId from, NodeId to, double range_m, double t_s);
    // The 3D tracks' anchors: the fixed nodes of known height (id, x, y, z in m).
    std::vector<std::pair<NodeId, Vector3>> flightAnchors() const;
    void trace(const std::string &message) const
    {
        if (trace_) {
            trace_(message);
        }
    }

    EngineParams params_;
    RangeLikelihood likelihood_;
    MapState map_;
    RangeIntake intake_;
    SogBank sogs_;
    PlacementStep placement_;
    Refiner refiner_;
    Convergence convergence_;
    GlobalStep global_; // after convergence_: it keeps a copy of its whole-map checks
    MotionTracker motion_;
    FlightTracks flights_;
    OutputFrame frame_;
    std::deque<uint32_t> relax_queue_;
    std::vector<uint8_t> in_relax_queue_;
    bool placing_ = false;
    uint64_t settle_owed_ = 0; // neighbour updates the last placement is still owed
    bool frame_held_ = false;
    uint64_t ranges_used_ = 0;
    uint64_t ranges_stored_ = 0;
    uint64_t node_updates_ = 0;
    uint64_t relaxations_ = 0;
    uint64_t revision_ = 0;
    OutputChangeLog output_changes_;
    uint64_t assessed_key_ = 0; // the structure (links, placed set) at the last assessment
    std::function<void(const std::string &)> trace_;
};

} // namespace cdro::engine
