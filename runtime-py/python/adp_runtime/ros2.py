"""A ROS 2 node that runs the ADP runtime: LaserScan, Odometry and a goal in, cmd_vel out.

    python -m adp_runtime.ros2 --ros-args -p config:=/path/to/runtime.toml

Topics (relative names, so they follow the node's namespace and remappings):

* ``scan`` (sensor_msgs/LaserScan), subscribed: every scan runs one control cycle, so the
  lidar's rate is the control rate (the runtime's ``control_dt``, 20 Hz by default). Its
  beams must be the configured lidar's (``[episode.lidar]``: count and field of view,
  increasing angle, centred on the heading).
* ``odom`` (nav_msgs/Odometry), subscribed: the believed pose in the fixed frame and the
  velocity in the robot frame; older than ``max_odometry_age_s`` at a scan is refused.
* ``goal_pose`` (geometry_msgs/PoseStamped), subscribed: the goal in the same fixed frame. A
  new goal starts a new run; within ``goal_tolerance_m`` of it the node stops and drops it.
* ``cmd_vel`` (geometry_msgs/Twist), published after every scan: the planner's command, or a
  stop when there is no goal, no odometry yet, or the runtime refused the input (a goal
  farther than ``max_goal_distance_m`` included) or failed inside (the reason is logged).
  Commands are inside the configured speed and turn limits.

Parameters: ``config`` (the runtime configuration file, required), ``goal_tolerance_m``
(default 0.3).
"""

import math
import sys

import rclpy
from geometry_msgs.msg import PoseStamped, Twist
from nav_msgs.msg import Odometry
from rclpy.node import Node
from sensor_msgs.msg import LaserScan

import adp_runtime


def stamp_s(header):
    """A message header's stamp in seconds."""
    return header.stamp.sec + header.stamp.nanosec * 1e-9


def yaw_of(q):
    """The heading of a quaternion (rotation about z)."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


class AdpNode(Node):
    """The runtime behind ROS 2 topics (see the module docs)."""

    def __init__(self):
        super().__init__("adp_runtime")
        config = self.declare_parameter("config", "").value
        self.goal_tolerance = self.declare_parameter("goal_tolerance_m", 0.3).value
        if not config:
            raise adp_runtime.ConfigError("parameter `config` (the runtime configuration file) is not set")
        self.nav = adp_runtime.Navigator(config)
        self.odom = None
        self.goal = None
        self.cmd = self.create_publisher(Twist, "cmd_vel", 10)
        self.create_subscription(LaserScan, "scan", self.on_scan, 10)
        self.create_subscription(Odometry, "odom", self.on_odom, 10)
        self.create_subscription(PoseStamped, "goal_pose", self.on_goal, 10)
        self.get_logger().info(
            f"{self.nav.planner} on {config}: {self.nav.beams} beams over {self.nav.fov_deg} deg, "
            f"one cycle per scan (control_dt {self.nav.control_dt} s)"
        )

    def on_odom(self, msg):
        p = msg.pose.pose
        t = msg.twist.twist
        self.odom = (
            (p.position.x, p.position.y, yaw_of(p.orientation)),
            (t.linear.x, t.angular.z),
            stamp_s(msg.header),
        )

    def on_goal(self, msg):
        self.goal = (msg.pose.position.x, msg.pose.position.y)
        self.get_logger().info(f"goal ({self.goal[0]:.2f}, {self.goal[1]:.2f})")

    def publish(self, v, w):
        msg = Twist()
        msg.linear.x = float(v)
        msg.angular.z = float(w)
        self.cmd.publish(msg)

    def on_scan(self, msg):
        if self.goal is None or self.odom is None:
            self.publish(*adp_runtime.STOP)
            return
        pose, vel, odom_stamp = self.odom
        if math.hypot(pose[0] - self.goal[0], pose[1] - self.goal[1]) <= self.goal_tolerance:
            self.get_logger().info("goal reached")
            self.goal = None
            self.publish(*adp_runtime.STOP)
            return
        fov = msg.angle_max - msg.angle_min
        if abs(math.degrees(fov) - self.nav.fov_deg) > max(math.degrees(abs(msg.angle_increment)), 1e-6):
            self.get_logger().warning(
                f"scan: field of view {math.degrees(fov):.2f} deg, but the configured lidar has "
                f"{self.nav.fov_deg} deg; stopping"
            )
            self.publish(*adp_runtime.STOP)
            return
        try:
            out = self.nav.cycle(stamp_s(msg.header), list(msg.ranges), pose, vel, odom_stamp, self.goal)
        except (adp_runtime.RefusedInput, adp_runtime.InternalError) as e:
            self.get_logger().warning(f"{e.args[0]}; stopping")
            self.publish(*adp_runtime.STOP)
            return
        self.publish(*out.command)


def main(args=None):
    rclpy.init(args=args)
    try:
        node = AdpNode()
    except (adp_runtime.ConfigError, ValueError) as e:
        print(f"adp_runtime.ros2: {e}", file=sys.stderr)
        rclpy.shutdown()
        return 2
    try:
        rclpy.spin(node)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
