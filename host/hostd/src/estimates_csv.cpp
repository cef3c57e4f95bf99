#include "cdro/hostd/estimates_csv.hpp"

namespace cdro::hostd {

namespace {

void writeEstimateFields(std::FILE *out, const engine::NodeOutput &node)
{
    if (node.placed()) {
        std::fprintf(out, ",%.17g,%.17g,%.17g,%.17g,%.17g,%d", node.position_m.x(), node.position_m.y(),
                     node.covariance_m2(0, 0), node.covariance_m2(0, 1), node.covariance_m2(1, 1),
                     node.converged() ? 1 : 0);
    } else {
        std::fprintf(out, ",,,,,,0");
    }
    std::fprintf(out, ",%s,%s", engine::nodeLifecycleName(node.lifecycle), engine::nodeDoubtName(node.doubt));
}

} // namespace

void writeNodesHeader(std::FILE *out) { std::fputs("id,x,y,var_x,cov_xy,var_y,converged,status,reason\n", out); }

void writeNodeRow(std::FILE *out, const engine::NodeOutput &node)
{
    std::fprintf(out, "%u", static_cast<unsigned>(node.id));
    writeEstimateFields(out, node);
    std::fputc('\n', out);
}

void writeTraceHeader(std::FILE *out)
{
    std::fputs("ranges,id,x,y,var_x,cov_xy,var_y,converged,status,reason,t\n", out);
}

void writeTraceRows(std::FILE *out, uint64_t ranges, const std::vector<engine::NodeOutput> &nodes, const double *t_s)
{
    for (const engine::NodeOutput &node : nodes) {
        if (!node.placed()) {
            continue;
        }
        std::fprintf(out, "%llu,%u", static_cast<unsigned long long>(ranges), static_cast<unsigned>(node.id));
        writeEstimateFields(out, node);
        if (t_s != nullptr) {
            std::fprintf(out, ",%.17g\n", *t_s);
        } else {
            std::fputs(",\n", out);
        }
    }
}

} // namespace cdro::hostd
