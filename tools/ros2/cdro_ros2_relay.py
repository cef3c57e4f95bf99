#!/usr/bin/env python3
"""cdro_ros2_relay: cdro-hostd's live stream as ROS 2 topics (an rclpy node). docs/ros2.md.

NOT RUN HERE: the development machine (Debian 12) has no ROS 2. What is tested is the message
content it publishes: it fills the messages from the same dicts that `cdro-export --ros2`
writes, and tests/tools/test_export.py decodes those (CDR, ROS 2 Humble definitions) and checks
them against the service's JSON. This script itself is not imported by any test.

Publishes (REP-105 frames: map -> odom -> base_link, map -> odom the identity, because the
stream carries one robot estimate and no separate odometry):
  /cdro/robot/pose   geometry_msgs/msg/PoseWithCovarianceStamped  the robot (x, y, yaw; 6x6 covariance)
  /cdro/markers      visualization_msgs/msg/MarkerArray           node spheres, 2-sigma ellipses, labels; links (--sse)
  /tf                tf2_msgs/msg/TFMessage (tf2_ros broadcaster)  map -> odom, odom -> base_link
  /cdro/health       std_msgs/msg/String                          the health line's JSON

Needs: a sourced ROS 2 (Humble or later: rclpy, tf2_ros, rosidl_runtime_py, geometry_msgs,
visualization_msgs, std_msgs) and the cdro_tools package on the path; it uses only
cdro_tools.export.stream and .ros2, which need nothing beyond the standard library:

  source /opt/ros/humble/setup.bash
  PYTHONPATH=/path/to/cdro-slam/tools python3 tools/ros2/cdro_ros2_relay.py --sse http://127.0.0.1:8080/
  cdro-hostd --config config/cdro-hostd.example.yaml | PYTHONPATH=... python3 tools/ros2/cdro_ros2_relay.py --jsonl -
"""
from __future__ import annotations

import argparse
import json
import sys
import threading

import rclpy
from geometry_msgs.msg import PoseWithCovarianceStamped, TransformStamped
from rclpy.node import Node
from rosidl_runtime_py.set_message import set_message_fields
from std_msgs.msg import String
from tf2_ros import TransformBroadcaster
from visualization_msgs.msg import MarkerArray

from cdro_tools.export import ros2
from cdro_tools.export.stream import MapState, Tally, follow_sse, parse_jsonl_line, seconds_to_ns, unix_time_s


def filled(message_type, fields: dict):
    message = message_type()
    set_message_fields(message, fields)
    return message


class Relay(Node):
    def __init__(self):
        super().__init__("cdro_relay")
        self.pose_publisher = self.create_publisher(PoseWithCovarianceStamped, ros2.TOPIC_POSE, 10)
        self.marker_publisher = self.create_publisher(MarkerArray, ros2.TOPIC_MARKERS, 10)
        self.health_publisher = self.create_publisher(String, ros2.TOPIC_HEALTH, 10)
        self.tf = TransformBroadcaster(self)
        self.state = MapState()
        self.lock = threading.Lock()
        self.last_robot = None

    def stamp_ns(self, obj: dict | None) -> int:
        """The stream's t_unix_s when it has one, else this node's clock."""
        t_unix = unix_time_s(obj)
        return seconds_to_ns(t_unix) if t_unix is not None else self.get_clock().now().nanoseconds

    def publish_robot(self) -> None:
        robot = self.state.robot
        if robot is None or robot == self.last_robot:
            return
        self.last_robot = robot
        t_ns = self.stamp_ns(robot)
        self.pose_publisher.publish(filled(PoseWithCovarianceStamped, ros2.robot_pose(robot, t_ns)))
        self.tf.sendTransform([filled(TransformStamped, t) for t in ros2.transforms(robot, t_ns)["transforms"]])

    def line(self, obj: dict) -> None:
        with self.lock:
            kind = self.state.apply(obj)
            t_ns = self.stamp_ns(obj)
            if kind == "node":
                self.marker_publisher.publish(filled(MarkerArray, ros2.markers(self.state, t_ns, {obj["id"]})))
            elif kind == "robot":
                self.publish_robot()
            else:
                self.health_publisher.publish(String(data=json.dumps(self.state.health)))

    def map_event(self, event: dict, tally: Tally, where: str) -> None:
        with self.lock:
            self.state.apply_map(event, tally, where)
            t_ns = self.stamp_ns(event)
            self.marker_publisher.publish(filled(MarkerArray, ros2.markers(self.state, t_ns)))
            self.publish_robot()
            if self.state.health is not None:
                self.health_publisher.publish(String(data=json.dumps(self.state.health)))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="cdro_ros2_relay", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--sse", metavar="URL", help="the live map (http://127.0.0.1:8080/)")
    source.add_argument("--jsonl", metavar="FILE", help="cdro-hostd's JSON Lines: - for stdin, or a file read once")
    args, ros_args = parser.parse_known_args(argv)

    rclpy.init(args=[sys.argv[0], *ros_args])  # rcl takes the first argument as the program
    relay = Relay()
    tally = Tally(args.sse or args.jsonl)
    stop = threading.Event()

    def read():
        def log(message):
            relay.get_logger().info(message)
        if args.sse:
            for number, event in enumerate(follow_sse(args.sse, tally, stop.is_set, log), start=1):
                relay.map_event(event, tally, f"event {number}")
        else:
            stream = sys.stdin if args.jsonl == "-" else open(args.jsonl, encoding="utf-8", errors="replace")
            for number, text in enumerate(stream, start=1):
                obj = parse_jsonl_line(text, f"{args.jsonl}:{number}", tally)
                if obj is not None:
                    relay.line(obj)
            log("the input ended; spinning until Ctrl-C")

    threading.Thread(target=read, daemon=True).start()
    try:
        rclpy.spin(relay)
    except KeyboardInterrupt:
        pass
    finally:
        stop.set()
        print(tally.summary(), file=sys.stderr)
        relay.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
