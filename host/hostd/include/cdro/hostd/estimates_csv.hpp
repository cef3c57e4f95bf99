// estimates_csv.hpp: the estimate CSV files written by the offline mode.
//   nodes: id,x,y,var_x,cov_xy,var_y,converged,status,reason   status: the node's lifecycle
//          (unplaced, placed, converged, moving, settling); reason: why a placed node is not
//          converged (too few links, ambiguous, foldable, flexible, unsettled; empty otherwise)
//   trace: ranges,id,x,y,var_x,cov_xy,var_y,converged,status,reason,t   (a snapshot every N ranges,
//          the same columns as nodes; t in s of the last range, empty when the ranges have no time)
// Numbers are written with 17 significant digits, so that the same run gives the same bytes
// and a file read back gives the same doubles.
#pragma once

#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include "cdro/engine/engine.hpp"

namespace cdro::hostd {

void writeNodesHeader(std::FILE *out);
void writeNodeRow(std::FILE *out, const engine::NodeOutput &node);
void writeTraceHeader(std::FILE *out);
void writeTraceRows(std::FILE *out, uint64_t ranges, const std::vector<engine::NodeOutput> &nodes,
                    const double *t_s = nullptr);

} // namespace cdro::hostd
