"""The ROS 2 node (``python -m adp_runtime.ros2``), started as its own process, drives a
simulated BARN robot over ROS 2 topics to its goal, and publishes a stop for an input the
runtime refuses. Skipped when rclpy cannot be imported, unless ADP_REQUIRE_ROS2=1 (CI sets it)."""

import math
import os
import pathlib
import queue
import subprocess
import sys
import time

import pytest

import adp_runtime

if os.environ.get("ADP_REQUIRE_ROS2") != "1":
    pytest.importorskip("rclpy", reason="ROS 2's rclpy is not installed (CI installs it)")

import rclpy  # noqa: E402
from geometry_msgs.msg import PoseStamped, Twist  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.node import Node  # noqa: E402
from sensor_msgs.msg import LaserScan  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[2]
CONFIG = ROOT / "runtime" / "examples" / "runtime.toml"
# A guard against a deadlock (a node that never answers), not a time limit on the work.
WATCHDOG_S = 120.0


def stamp(msg, t):
    msg.header.stamp.sec = int(t)
    msg.header.stamp.nanosec = int(round((t - int(t)) * 1e9)) % 1_000_000_000
    msg.header.frame_id = "map"


class Bridge(Node):
    """The simulated robot's side: publishes its scan, odometry and goal, takes cmd_vel."""

    def __init__(self, nav):
        super().__init__("adp_test_bridge")
        self.beams, self.fov = nav.beams, math.radians(nav.fov_deg)
        self.scan = self.create_publisher(LaserScan, "scan", 10)
        self.odom = self.create_publisher(Odometry, "odom", 10)
        self.goal = self.create_publisher(PoseStamped, "goal_pose", 10)
        self.commands = queue.Queue()
        self.create_subscription(Twist, "cmd_vel", lambda m: self.commands.put((m.linear.x, m.angular.z)), 10)

    def spin_until(self, done, what):
        deadline = time.monotonic() + WATCHDOG_S
        while not done():
            assert time.monotonic() < deadline, f"watchdog: no {what}"
            rclpy.spin_once(self, timeout_sec=0.05)

    def send_goal(self, x, y):
        msg = PoseStamped()
        stamp(msg, 0.0)
        msg.pose.position.x, msg.pose.position.y = x, y
        msg.pose.orientation.w = 1.0
        self.goal.publish(msg)

    def send(self, inputs, ranges=None):
        """Publishes one period's odometry and scan and returns the node's command."""
        t = inputs["stamp_s"]
        o = Odometry()
        stamp(o, inputs["odom_stamp_s"])
        x, y, yaw = inputs["pose"]
        o.pose.pose.position.x, o.pose.pose.position.y = x, y
        o.pose.pose.orientation.z, o.pose.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
        o.twist.twist.linear.x, o.twist.twist.angular.z = inputs["vel"]
        self.odom.publish(o)
        s = LaserScan()
        stamp(s, t)
        s.angle_min, s.angle_max = -self.fov / 2, self.fov / 2
        s.angle_increment = self.fov / (self.beams - 1)
        s.range_min, s.range_max = 0.0, 100.0
        s.ranges = [float(r) for r in (ranges if ranges is not None else inputs["ranges"])]
        self.scan.publish(s)
        self.spin_until(lambda: not self.commands.empty(), "cmd_vel after a scan")
        return self.commands.get()


@pytest.fixture
def ros_node():
    env = dict(os.environ, ROS_DOMAIN_ID=str(os.getpid() % 100 + 1), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    os.environ.update(env)
    proc = subprocess.Popen(
        [sys.executable, "-m", "adp_runtime.ros2", "--ros-args", "-p", f"config:={CONFIG}"],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    rclpy.init()
    nav = adp_runtime.Navigator(str(CONFIG))
    bridge = Bridge(nav)
    try:
        bridge.spin_until(
            lambda: proc.poll() is None
            and bridge.scan.get_subscription_count() > 0
            and bridge.odom.get_subscription_count() > 0
            and bridge.goal.get_subscription_count() > 0
            and bridge.count_publishers("cmd_vel") > 0
            or proc.poll() is not None,
            "discovery of the node",
        )
        assert proc.poll() is None, proc.stdout.read()
        yield nav, bridge, proc
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
        bridge.destroy_node()
        rclpy.shutdown()


def test_the_node_drives_a_world_and_stops_for_a_goal_out_of_reach(ros_node):
    nav, bridge, proc = ros_node
    sim = adp_runtime.Sim(nav, 3, 5)
    # Before a goal the node answers every scan with a stop.
    assert bridge.send(sim.observe()) == adp_runtime.STOP
    gx, gy = sim.observe()["goal"]
    bridge.send_goal(gx, gy)
    bridge.spin_until(lambda: True, "goal")
    status, periods = "running", 0
    while status == "running":
        cmd = bridge.send(sim.observe())
        status = sim.drive(cmd)
        periods += 1
        assert periods < 2000, "the robot did not finish"
    assert status == "succeeded", sim.result()
    # A goal 14 km away (once an abort of the whole process): the node publishes a stop, says
    # why, and still answers the next scan.
    bridge.send_goal(gx + 14000.0, gy)
    bridge.spin_until(lambda: True, "goal")
    inputs = sim.observe()
    assert bridge.send(inputs) == adp_runtime.STOP
    assert bridge.send(sim.observe()) == adp_runtime.STOP
    assert proc.poll() is None
    proc.terminate()
    log = proc.communicate(timeout=30)[0]
    assert "m from the robot; at most 50 m (max_goal_distance_m)" in log, log
