// params.hpp: every parameter of the engine, with its default and unit. docs/engine.md lists
// them with the reasons for the defaults; the config file's `engine:` section and the command
// line set them (host/hostd/include/cdro/hostd/engine_config.hpp).
#pragma once

#include <cstdint>

#include "cdro/engine/placement.hpp"
#include "cdro/engine/range_likelihood.hpp"
#include "cdro/engine/ring_sog.hpp"
#include "cdro/engine/types.hpp"

namespace cdro::engine {

struct RangeParams {
    double sigma_m = 0.10;                // m, line-of-sight range noise (Pozyx nominal 0.1 m)
    double max_range_m = 100.0;           // m, longer ranges are absurd (Pozyx's maximum) and rejected
    uint32_t window = 15;                 // ranges per link in its median (1..32)
    double unknown_height_spread_m = 0.5; // m, std of the heights of the nodes whose height is not
                                          // given: their ranges are used as read (3D), and the map's
                                          // ellipses carry what the height differences may add to them
};

struct SogUpdateParams {
    bool collapse_reset = true;      // a ring whose weights all sit at the floor is reset to the
                                     // evidence (EKF-GSF); false, with weight_floor 0: the paper's
                                     // bookkeeping, where a ring can lock onto a wrong mode
    bool rings_follow_center = true; // a SoG moves with its centre's estimate (relative to it);
                                     // false: the paper's rings stay where they were generated and
                                     // only the EKF pulls them towards the ring around the centre
    bool cooperative = true;         // weights from the other nodes' ranges (eq. 8-11); false:
                                     // from the ring's own range only (the ablation)
    bool weight_transfer = true;     // eq. 15 after every weight update
    double transfer_sigma_m = 0.5;   // m, sigma of eq. 15
    double gate_sigma = 4.0;         // EKF innovation gate, in standard deviations
    double process_noise_m2 = 1e-6;  // m^2 added to each component's covariance per update
    uint32_t full_update_every = 16; // every k-th range of a ring updates all its components;
                                     // the others only its active set (ring_sog.hpp). 1 = always
                                     // all, exactly the paper's filter
};

struct RefinementParams {
    bool enabled = true;                  // polish the merged estimate against every link (robust
                                          // Gauss-Newton); false: the merged SoG is the estimate
    uint32_t max_iterations = 5;          // Gauss-Newton iterations per update
    double hypothesis_switch_m = 1.0;     // m, a merged SoG this far from the estimate is tried too
    double switch_gap_nats = 2.0;         // nats, it must explain the links this much better
    uint32_t relax_per_range = 8;         // neighbour updates after each range (bounded work)
    double relax_threshold_m = 3e-3;      // m, a node that moved more than this updates its neighbours
    uint32_t settle_per_placed = 20;      // neighbour updates per node placed, before the next placement
    uint32_t settle_per_range = 4;        // of those, paid after each range (more waits for the next
                                          // range; settle() pays them all at once)
    double inconsistent_residual_m = 1.5; // m, a link residual beyond this (and 4 range sigmas) is inconsistent
    double inconsistent_fraction = 0.5;   // more than this share of a node's links (and >= 2)
                                          // inconsistent: the node is placed again
    uint32_t max_placements = 4;          // times one node may be placed (then it stays)
};

// The global solve (global_step.hpp): the map of all the links seen so far, found whatever
// order they came in, adopted when it explains the links better than the map the filter holds.
// It runs when the link graph has grown (a logarithmic number of times), once more when no link
// has appeared for a while, and at settle(); never once every link is known and the map adopted.
struct SolveParams {
    bool enabled = true;                // false: the streaming filter alone (the paper's, streaming)
    double link_growth = 1.25;          // run again when the links have grown by this factor
    uint32_t min_links = 6;             // not before this many links
    double quiet_ranges_per_link = 2.0; // and once no link has appeared for this many ranges per
                                        // link, if links appeared since it last ran
    double min_gain_nats = 1.0;         // nats, how much better the solve's map must explain the links
    double adopt_after_sweeps = 0.25;   // > 0: the solve runs on a worker thread, its map adopted
                                        // this many ranges per link after it started (the estimates do
                                        // not depend on its timing: docs/engine.md); 0: it runs inside
                                        // the addRange that makes it due, adopted at once
    bool range_offsets = true;          // estimate each node's range offset (uncalibrated antenna
                                        // delays, range_offsets.hpp); false: radios known calibrated
    bool connectivity = true;           // judge rival maps by which pairs heard each other too
                                        // (map_connectivity.hpp); false when pairs were left unranged
                                        // by choice, not because they could not hear each other
    uint32_t threads = 0;               // threads a solve refines its starts on (0: one per core); the
                                        // estimates are the same for any number, only the time differs
};

// Moving nodes (paper Fig. 4): a node reported moving stops being an anchor for the others; every
// new range to it resets the SoG centred on the ranging neighbour (eq. 5-7 around that
// neighbour, with this range), which is weighted by the other neighbours' latest ranges and
// merged, and the estimate is refined against the latest ranges; its links use their newest
// range instead of a median. When it stops, its links start fresh, the SoGs centred on it are
// generated again, and it converges again. Nodes without accelerometer reports are watched by a
// fallback detector on range residuals.
struct MotionParams {
    bool reset = true;                      // false: --no-motion-reset, moving nodes handled as static
    bool infer_from_ranges = true;          // the fallback detector for nodes without reports
                                            // (with range times: motion_tracker.cpp's walk test;
                                            // without, the four keys below)
    double inferred_residual_m = 0.5;       // m, a range this far from the map and from its link's
                                            // recent median is large
    uint32_t inferred_window = 8;           // of the node's last ranges (<= 16) ...
    uint32_t inferred_min_large = 4;        // ... this many large ones ...
    uint32_t inferred_min_links = 2;        // ... on this many different links: the node moves
    double inferred_still_speed_mps = 0.25; // m/s, an inferred-moving node whose track is slower ...
    double inferred_still_m = 0.15;         // m, (without a track: that stays within this) ...
    uint32_t inferred_still_updates = 12;   // ... for this many updates in a row has stopped
    bool track = true;                      // a constant-velocity track while moving (needs range times)
    double track_accel_sigma_mps2 = 0.5;    // m/s^2, how fast a carried node may change its velocity
    double track_speed_sigma_mps = 1.5;     // m/s, prior std of its speed when it starts
    uint32_t track_warmup = 3;              // ranges before the track is the estimate
    double track_max_speed_mps = 3.0;       // m/s, a carried node is not faster; the track's speed is capped
    // Nodes declared moving with no known height (Engine::trackMoving3D, motion_track_3d.hpp): each
    // velocity component an Ornstein-Uhlenbeck process; chosen on seeded simulated flights
    // (tests/tools/test_tracking.py), never on MiLUV.
    double flight_speed_sigma_mps = 0.7; // m/s, its stationary sigma per axis (3D speed > 2 m/s with p 4 %)
    double flight_speed_tau_s = 2.0;     // s, its correlation time (how long a heading lasts)
    double flight_floor_z_m = 0.0;       // m, the floor: tracked nodes stay between it and the anchors' mean height
};

// Converged means: the estimate has settled (eq. 16), the node has three or more placed
// neighbours, no distinct position or rival map explains its links about as well, its part
// cannot fold, and neither one unnoticed link error nor the map's own uncertainty (its 95 %
// region) could put it more than `reliable_m` away (convergence.hpp).
struct ConvergenceParams {
    double reliable_m = 1.0;         // m, what converged promises at most
    double common_excess_m = 0.3;    // m, std of an excess that every link may share unseen: walls
                                     // make links read long (0.1-0.35 m a blocked path in
                                     // kolakowski-nlos), by less than the NLOS model can tell from
                                     // noise, and a map whose links nearly all cross a wall reads
                                     // larger than the building (docs/results.md, walls)
    double room_excess_m = 0.3;      // m, std of an excess all of a node's links share: the walls of
                                     // its room are on every link that leaves it, and where its
                                     // links leave it one way the map moves it outward unseen;
                                     // 0 in an open hall or plant (docs/engine.md, "Confidence")
    double smoothing = 0.9;          // alpha of eq. 16 (0.9-0.95 in the paper)
    double threshold_m = 0.01;       // m, step of the moving average under which a node is still
    uint32_t consecutive = 5;        // still updates in a row to count as converged ...
    uint32_t min_updates = 15;       // ... and at least this many updates since it was placed
    double unconverge_factor = 10.0; // a step above factor * threshold clears convergence
};

struct FrameParams {
    NodeId origin = 0;     // the named frame: this node at (0, 0),
    NodeId x_axis = 0;     // this one on the +x axis,
    NodeId positive_y = 0; // this one on the +y side. 0 = the frame triangle's own
};

struct EngineParams {
    RangeParams range;
    RangeLikelihoodParams likelihood;
    RingSogParams ring; // radial_sigma_m is always range.sigma_m (sigma_s)
    SogUpdateParams sog;
    PlacementParams placement;
    RefinementParams refinement;
    SolveParams solve;
    MotionParams motion;
    ConvergenceParams convergence;
    FrameParams frame;
};

} // namespace cdro::engine
