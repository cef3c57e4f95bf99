// joint_solver.hpp: all placed nodes at once, by robust Levenberg-Marquardt over every link.
//
// The streaming refinement moves one node at a time against its neighbours (Gauss-Seidel). On a
// large network that converges slowly: what one side of a 150 m map learns reaches the other side
// only after as many sweeps as there are hops, so a coarse starting map (MDS-MAP, a multilateration
// from early ranges) is judged before it has settled. The initialization that runs again
// (engine.hpp) therefore solves every candidate map jointly: one sparse 2M x 2M system per
// iteration (Eigen's sparse LDL^T), weights from the robust likelihood (an EM step, as in
// point_solver.hpp), damping that adapts (Levenberg-Marquardt: a step that does not lower the cost
// is refused and the damping raised), and graduated non-convexity (the noise seen as larger in
// the first iterations, so that a disagreeing link still pulls before it is written off).
// Fixed, pinned and moving nodes stay where they are. The gauge (rotation, translation) is
// free; the damping keeps the system regular and the map where it started.
#pragma once

#include <cstdint>
#include <vector>

#include "cdro/engine/network.hpp"
#include "cdro/engine/range_likelihood.hpp"

namespace cdro::engine {

struct JointSolveParams {
    double range_sigma_m = 0.10;          // m, nominal noise
    std::vector<double> sigma_scales{8.0, 4.0, 2.0, 1.0}; // annealing stages, each a multiple of the noise
    uint32_t iterations_per_stage = 8;    // LM iterations per stage
    double initial_damping = 1e-3;        // lambda, relative to the mean diagonal
    double step_tolerance_m = 1e-4;       // m, a stage ends when every node moved less
};

struct JointSolveResult {
    double cost = 0.0;         // robust cost at the end (nats, nominal noise)
    uint32_t iterations = 0;   // accepted steps
    uint32_t refused = 0;      // steps that did not lower the cost
    uint32_t nodes = 0;        // nodes solved
};

// Moves the placed, not fixed, not pinned, not moving nodes of `network` to the joint optimum near
// where they are. Their covariances are left alone (the next refinement sets them).
JointSolveResult solveJointly(Network &network, const RangeLikelihood &likelihood, const JointSolveParams &params);

// The robust cost of every link between placed nodes (nats), at the given noise.
double jointCost(const Network &network, const RangeLikelihood &likelihood, double sigma_m);

} // namespace cdro::engine
