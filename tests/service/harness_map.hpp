// The harness's stand-in for the engine: it records every frame and odometry message it is
// given (one JSON line each, for the tests to compare) and keeps a map built from what arrived. It estimates
// nothing: nodes are laid out on a 5 m circle in id order, their variance shrinks with the
// ranges they took part in, links carry the last range and the median of the last 9 (the
// live map's residual is that median minus the distance on the circle); a node's "components"
// are rings of 8 Gaussians around its neighbours at the last range; the robot (the device's own
// node, once odometry has come) is dead-reckoned from the odometry steps. Enough for every
// output to have real content that follows the input.
#pragma once

#include <cstdio>
#include <map>
#include <string>
#include <vector>

#include "cdro/service/checkpoint.hpp"
#include "cdro/service/consumer.hpp"
#include "cdro/service/map_state.hpp"
#include "cdro/service/odometry.hpp"

class HarnessEngine final : public cdro::service::FrameConsumer,
                            public cdro::service::MapSource,
                            public cdro::service::CheckpointProvider,
                            public cdro::service::OdometryConsumer {
public:
    explicit HarnessEngine(const std::string &received_path);
    ~HarnessEngine() override;

    void onRange(const cdro_range_t &range, const cdro::service::FrameContext &context) override;
    void onMotion(const cdro_motion_t &motion, const cdro::service::FrameContext &context) override;
    void onHello(const cdro_hello_t &hello, const cdro::service::FrameContext &context) override;
    void onStatus(const cdro_status_t &status, const cdro::service::FrameContext &context) override;
    void onNodeList(const cdro_node_list_t &list, const cdro::service::FrameContext &context) override;
    void onDeviceError(const cdro_error_t &error, const cdro::service::FrameContext &context) override;
    void onDeviceReset(cdro::service::DeviceResetReason reason, const cdro::service::FrameContext &context) override;
    void onOdometry(const cdro::service::OdometryMessage &message) override;

    uint64_t revision() const override { return revision_; }
    void fill(cdro::service::MapState &map) const override;
    std::optional<cdro::service::NodeComponents> components(uint16_t id) const override;

    cdro::service::SogSnapshot snapshot() override;
    void restore(const cdro::service::SogSnapshot &snapshot) override;

private:
    struct Node {
        uint32_t ranges = 0;
        bool moving = false;
    };
    struct Link {
        double last_range_m = 0.0;
        uint32_t count = 0;
        std::vector<double> recent_m; // m, the last ranges, for the link's median
    };
    void record(const std::string &line);
    void position(uint16_t id, double *x_m, double *y_m) const;

    std::FILE *received_ = nullptr;
    std::map<uint16_t, Node> nodes_;
    std::map<std::pair<uint16_t, uint16_t>, Link> links_;
    uint64_t revision_ = 0;
    uint32_t ranges_ = 0;
    uint16_t own_id_ = 0; // the device's node (HELLO), carried by the robot
    bool have_robot_ = false;
    double robot_x_m_ = 0.0; // m, dead reckoning from 0, 0
    double robot_y_m_ = 0.0; // m
    double robot_heading_rad_ = 0.0;
    uint32_t odometry_steps_ = 0;
};
