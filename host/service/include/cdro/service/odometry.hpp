// odometry.hpp: how the robot's wheel odometry reaches the estimator's movement stage.
//
// The robot's computer sends odometry to cdro-hostd (UDP on loopback, or an MQTT topic; the
// message format is in docs/service.md, "Odometry input"). The service parses and checks
// every message, converts velocities to a step, appends each accepted message to the capture
// and hands it to the OdometryConsumer (the engine adapter implements it). Like
// FrameConsumer, it is called on the event loop thread only: live in arrival order, on
// --replay in capture order, interleaved with the device frames exactly as they were, with
// the same values. A consumer must not read any clock of its own, only t_s.
#pragma once

namespace cdro::service {

struct OdometryMessage {
    double t_s;          // s since the Unix epoch, the same clock as FrameContext::host_unix_us / 1e6
    double distance_m;   // m travelled since the previous message (negative when reversing)
    double dheading_rad; // rad, heading change since the previous message (counter-clockwise
                         // positive); Plaza convention: the step advances along the heading
                         // at its mid-point (previous heading + dheading_rad / 2)
};

class OdometryConsumer {
public:
    virtual ~OdometryConsumer() = default;
    virtual void onOdometry(const OdometryMessage &message) = 0;
};

} // namespace cdro::service
