"""A ROS 2 node that runs the ADP runtime: LaserScan, Odometry and a goal in, cmd_vel out.

    python -m adp_runtime.ros2 --ros-args -p config:=/path/to/runtime.toml

Topics (relative names, so they follow the node's namespace and remappings, e.g.
``--ros-args -r scan:=/front/scan``):

* ``scan`` (sensor_msgs/LaserScan), subscribed with the sensor-data QoS profile (best effort,
  as lidar drivers publish; a best-effort subscription also hears a reliable publisher):
  every scan runs one control cycle, so the lidar's rate is the control rate (the runtime's
  ``control_dt``, 20 Hz by default). Its beams must be the configured lidar's (``[lidar]``:
  count and field of view, increasing angle, centred on the laser's heading).
* ``odom`` (nav_msgs/Odometry), subscribed: the believed pose in the fixed frame and the
  velocity in the robot frame; older than ``max_odometry_age_s`` at a scan is refused.
* ``goal_pose`` (geometry_msgs/PoseStamped), subscribed: the goal, in the fixed frame (a goal
  in another frame is refused and dropped; an empty ``frame_id`` is taken as the fixed
  frame). A new goal starts a new run.
* ``cmd_vel`` (geometry_msgs/Twist), published after every scan: the planner's command, or a
  stop when there is no goal, no odometry yet, the run has arrived, or the runtime refused
  the input (a goal farther than ``max_goal_distance_m`` included) or failed inside (the
  reason is logged). Commands are inside the configured speed and turn limits. A stop is
  also published when the scan or the odometry goes stale (nothing for ``watchdog_s``),
  and when the node shuts down (SIGINT, SIGTERM).
* ``goal_reached`` (geometry_msgs/PoseStamped), published once per goal: the goal, when the
  runtime says the run has arrived (within its ``goal_tolerance_m``).

Parameters: ``config`` (the runtime configuration file, required); ``scan_qos``
(``sensor_data``, the default, or ``reliable``); ``watchdog_s`` (default 0.5: ten control
periods); ``fixed_frame`` (the frame of poses and goals; default empty: the odometry's
``header.frame_id``).
"""

import math
import signal
import sys
import time

import rclpy
from geometry_msgs.msg import PoseStamped, Twist
from nav_msgs.msg import Odometry
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import LaserScan

import adp_runtime

# How long a shutdown waits for subscribers to acknowledge the final stop.
FINAL_STOP_ACK_S = 1.0


def stamp_s(header):
    """A message header's stamp in seconds."""
    return header.stamp.sec + header.stamp.nanosec * 1e-9


def yaw_of(q):
    """The heading of a quaternion (rotation about z)."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def scan_profile(name):
    """The QoS profile of the scan subscription named by the ``scan_qos`` parameter."""
    if name == "sensor_data":
        return qos_profile_sensor_data
    if name == "reliable":
        return QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    raise ValueError(f"parameter scan_qos = {name!r}: expected 'sensor_data' or 'reliable'")


class AdpNode(Node):
    """The runtime behind ROS 2 topics (see the module docs)."""

    def __init__(self):
        super().__init__("adp_runtime")
        config = self.declare_parameter("config", "").value
        qos = self.declare_parameter("scan_qos", "sensor_data").value
        self.watchdog_s = float(self.declare_parameter("watchdog_s", 0.5).value)
        self.fixed_frame = self.declare_parameter("fixed_frame", "").value
        if not config:
            raise adp_runtime.ConfigError("parameter `config` (the runtime configuration file) is not set")
        if not (math.isfinite(self.watchdog_s) and self.watchdog_s > 0):
            raise ValueError(f"parameter watchdog_s = {self.watchdog_s}: must be > 0 (seconds)")
        self.nav = adp_runtime.Navigator(config)
        self.odom = None
        self.odom_frame = ""
        self.goal = None
        self.arrived = False
        # Receipt times (monotonic clock) of the last scan and odometry, for the watchdog.
        self.last_scan = self.last_odom = None
        self.moving = False
        self.cmd = self.create_publisher(Twist, "cmd_vel", 10)
        self.reached = self.create_publisher(PoseStamped, "goal_reached", 10)
        # Odometry and goals first: the executor serves ready subscriptions in this order, so
        # a scan cycles on the odometry and goal that came with it.
        self.create_subscription(Odometry, "odom", self.on_odom, 10)
        self.create_subscription(PoseStamped, "goal_pose", self.on_goal, 10)
        self.create_subscription(LaserScan, "scan", self.on_scan, scan_profile(qos))
        self.create_timer(self.watchdog_s / 4, self.on_watchdog)
        self.get_logger().info(
            f"{self.nav.planner} on {config}: {self.nav.beams} beams over {self.nav.fov_deg} deg "
            f"(scan QoS {qos}), one cycle per scan (control_dt {self.nav.control_dt} s), "
            f"stop when inputs are {self.watchdog_s} s stale"
        )

    def on_odom(self, msg):
        p = msg.pose.pose
        t = msg.twist.twist
        self.odom = (
            (p.position.x, p.position.y, yaw_of(p.orientation)),
            (t.linear.x, t.angular.z),
            stamp_s(msg.header),
        )
        self.odom_frame = msg.header.frame_id
        self.last_odom = time.monotonic()

    def on_goal(self, msg):
        self.goal = msg
        self.arrived = False
        p = msg.pose.position
        self.get_logger().info(f"goal ({p.x:.2f}, {p.y:.2f}) in frame '{msg.header.frame_id}'")

    def publish(self, v, w):
        msg = Twist()
        msg.linear.x = float(v)
        msg.angular.z = float(w)
        self.cmd.publish(msg)
        self.moving = (v, w) != tuple(adp_runtime.STOP)

    def stop(self, why):
        """Publishes a stop, logging `why` when the robot was moving."""
        if self.moving and why:
            self.get_logger().warning(f"{why}; stopping")
        self.publish(*adp_runtime.STOP)

    def on_watchdog(self):
        if not self.moving:
            return
        now = time.monotonic()
        for name, last in (("scan", self.last_scan), ("odometry", self.last_odom)):
            if last is None or now - last > self.watchdog_s:
                self.stop(f"no {name} for more than {self.watchdog_s} s (watchdog_s)")
                return

    def goal_frame_fits(self):
        """Whether the goal is in the fixed frame; refuses (drops) it otherwise."""
        fixed = self.fixed_frame or self.odom_frame
        frame = self.goal.header.frame_id
        if not frame or not fixed or frame == fixed:
            return True
        self.get_logger().warning(
            f"goal in frame '{frame}', but poses are in '{fixed}' "
            f"({'fixed_frame' if self.fixed_frame else 'the odometry frame'}): goal refused; "
            f"send it in '{fixed}'"
        )
        self.goal = None
        return False

    def on_scan(self, msg):
        self.last_scan = time.monotonic()
        if self.goal is None or self.odom is None or not self.goal_frame_fits():
            self.stop("")
            return
        fov = msg.angle_max - msg.angle_min
        if abs(math.degrees(fov) - self.nav.fov_deg) > max(math.degrees(abs(msg.angle_increment)), 1e-6):
            self.get_logger().warning(
                f"scan: field of view {math.degrees(fov):.2f} deg, but the configured lidar has "
                f"{self.nav.fov_deg} deg ([lidar] fov_deg); stopping"
            )
            self.publish(*adp_runtime.STOP)
            return
        pose, vel, odom_stamp = self.odom
        goal = (self.goal.pose.position.x, self.goal.pose.position.y)
        try:
            out = self.nav.cycle(stamp_s(msg.header), list(msg.ranges), pose, vel, odom_stamp, goal)
        except (adp_runtime.RefusedInput, adp_runtime.InternalError) as e:
            self.get_logger().warning(f"{e.args[0]}; stopping")
            self.publish(*adp_runtime.STOP)
            return
        self.publish(*out.command)
        if out.arrived and not self.arrived:
            self.arrived = True
            self.get_logger().info(f"goal ({goal[0]:.2f}, {goal[1]:.2f}) reached")
            self.reached.publish(self.goal)

    def final_stop(self):
        """Publishes a stop and waits (briefly) until the subscribers have it."""
        self.publish(*adp_runtime.STOP)
        self.cmd.wait_for_all_acked(Duration(seconds=FINAL_STOP_ACK_S))
        self.get_logger().info("shutting down: stop published")


def main(args=None):
    # The node's own handlers, so that a signal lets it publish a final stop before the ROS
    # context shuts down (rclpy's would shut the context first).
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    try:
        node = AdpNode()
    except (adp_runtime.ConfigError, ValueError) as e:
        print(f"adp_runtime.ros2: {e}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    signalled = []
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, lambda number, _frame: signalled.append(number))
    try:
        while not signalled and rclpy.ok():
            rclpy.spin_once(node, timeout_sec=0.05)
    finally:
        if rclpy.ok():
            node.final_stop()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
