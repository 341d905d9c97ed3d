"""The ROS 2 node (``python -m adp_runtime.ros2``), started as its own process, drives a
simulated BARN robot over ROS 2 topics to its goal, hears a lidar on the sensor-data (best
effort) QoS profile, says when the runtime arrives, publishes a stop for an input the runtime
refuses, for a goal in another frame, when its inputs go stale and when it is terminated,
and follows a remapped scan topic.
Skipped when rclpy cannot be imported, unless ADP_REQUIRE_ROS2=1 (CI sets it)."""

import math
import os
import pathlib
import queue
import signal
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
from rclpy.qos import qos_profile_sensor_data  # noqa: E402
from sensor_msgs.msg import LaserScan  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[2]
CONFIG = ROOT / "runtime" / "examples" / "runtime.toml"
# A guard against a deadlock (a node that never answers), not a time limit on the work.
WATCHDOG_S = 120.0


def stamp(msg, t, frame="map"):
    msg.header.stamp.sec = int(t)
    msg.header.stamp.nanosec = int(round((t - int(t)) * 1e9)) % 1_000_000_000
    msg.header.frame_id = frame


class Bridge(Node):
    """The simulated robot's side: publishes its scan (with the QoS `scan_qos`), odometry and
    goal, takes cmd_vel and goal_reached."""

    def __init__(self, nav, scan_qos=10, scan_topic="scan"):
        super().__init__("adp_test_bridge")
        self.beams, self.fov = nav.beams, math.radians(nav.fov_deg)
        self.scan = self.create_publisher(LaserScan, scan_topic, scan_qos)
        self.odom = self.create_publisher(Odometry, "odom", 10)
        self.goal = self.create_publisher(PoseStamped, "goal_pose", 10)
        self.commands = queue.Queue()
        self.reached = queue.Queue()
        self.create_subscription(Twist, "cmd_vel", lambda m: self.commands.put((m.linear.x, m.angular.z)), 10)
        self.create_subscription(PoseStamped, "goal_reached", self.reached.put, 10)

    def spin_until(self, done, what):
        deadline = time.monotonic() + WATCHDOG_S
        while not done():
            assert time.monotonic() < deadline, f"watchdog: no {what}"
            rclpy.spin_once(self, timeout_sec=0.05)

    def handshake(self, inputs):
        """Publishes `inputs` until the node answers: a best-effort subscription matches its
        publisher a little after the publisher sees it, and drops what came before. Without
        a goal every answer is a stop; the answers to the repeats are drained."""
        deadline = time.monotonic() + WATCHDOG_S
        while self.commands.empty():
            assert time.monotonic() < deadline, "watchdog: the node never answered a scan"
            self.publish(inputs)
            until = time.monotonic() + 0.2
            while self.commands.empty() and time.monotonic() < until:
                rclpy.spin_once(self, timeout_sec=0.05)
        until = time.monotonic() + 0.5
        while time.monotonic() < until:
            rclpy.spin_once(self, timeout_sec=0.05)
        while not self.commands.empty():
            assert self.commands.get() == adp_runtime.STOP

    def send_goal(self, x, y, frame="map"):
        msg = PoseStamped()
        stamp(msg, 0.0, frame)
        msg.pose.position.x, msg.pose.position.y = x, y
        msg.pose.orientation.w = 1.0
        self.goal.publish(msg)
        # Let the node take it before the next scan (topics are not ordered between them).
        until = time.monotonic() + 0.2
        while time.monotonic() < until:
            rclpy.spin_once(self, timeout_sec=0.05)

    def send(self, inputs, ranges=None):
        """Publishes one period's odometry and scan and returns the node's command."""
        self.publish(inputs, ranges)
        self.spin_until(lambda: not self.commands.empty(), "cmd_vel after a scan")
        return self.commands.get()

    def publish(self, inputs, ranges=None):
        """Publishes one period's odometry and scan."""
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


def start_node(config, bridge_qos=10, ros_args=(), scan_topic="scan"):
    """Starts the node on `config` (with the extra `ros_args`, e.g. remappings) and a bridge
    whose scan publisher has the QoS `bridge_qos` and the topic `scan_topic`; returns (nav,
    bridge, proc) once they see each other. The caller ends them with `end`."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(os.getpid() % 100 + 1), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    os.environ.update(env)
    args = [sys.executable, "-m", "adp_runtime.ros2", "--ros-args", "-p", f"config:={config}"]
    args += list(ros_args)
    proc = subprocess.Popen(args, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    rclpy.init()
    nav = adp_runtime.Navigator(str(config))
    bridge = Bridge(nav, bridge_qos, scan_topic)
    bridge.spin_until(
        lambda: proc.poll() is None
        and bridge.scan.get_subscription_count() > 0
        and bridge.odom.get_subscription_count() > 0
        and bridge.goal.get_subscription_count() > 0
        and bridge.count_publishers("cmd_vel") > 0
        and bridge.count_publishers("goal_reached") > 0
        or proc.poll() is not None,
        "discovery of the node",
    )
    if proc.poll() is not None:
        end(bridge, proc)
        pytest.fail(proc.stdout.read())
    bridge.handshake(adp_runtime.Sim(nav, 0, 0).observe())
    return nav, bridge, proc


def end(bridge, proc):
    if proc.poll() is None:
        proc.terminate()
    try:
        proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
    bridge.destroy_node()
    rclpy.shutdown()


@pytest.fixture
def ros_node():
    nav, bridge, proc = start_node(CONFIG)
    try:
        yield nav, bridge, proc
    finally:
        end(bridge, proc)


def drive(bridge, sim, until):
    """Sends the simulated robot's inputs each period and drives it with the node's command
    until `until(command)`; returns the run's status."""
    status, periods = "running", 0
    while status == "running":
        cmd = bridge.send(sim.observe())
        status = sim.drive(cmd)
        periods += 1
        assert periods < 2000, "the robot did not finish"
        if until(cmd):
            break
    return status


def test_the_node_drives_a_world_and_stops_for_a_goal_out_of_reach(ros_node):
    nav, bridge, proc = ros_node
    sim = adp_runtime.Sim(nav, 3, 5)
    # Before a goal the node answers every scan with a stop.
    assert bridge.send(sim.observe()) == adp_runtime.STOP
    gx, gy = sim.observe()["goal"]
    bridge.send_goal(gx, gy)
    status = drive(bridge, sim, lambda _: False)
    assert status == "succeeded", sim.result()
    # A goal 14 km away (once an abort of the whole process): the node publishes a stop, says
    # why, and still answers the next scan.
    bridge.send_goal(gx + 14000.0, gy)
    inputs = sim.observe()
    assert bridge.send(inputs) == adp_runtime.STOP
    assert bridge.send(sim.observe()) == adp_runtime.STOP
    assert proc.poll() is None
    proc.terminate()
    log = proc.communicate(timeout=30)[0]
    assert "m from the robot; at most 50 m (max_goal_distance_m)" in log, log


def test_a_best_effort_lidar_is_heard_arrival_is_published_and_other_frames_are_refused(tmp_path):
    # Arrival 2.5 m from the goal, before BARN's 1 m success radius ends the simulated run.
    config = tmp_path / "runtime.toml"
    config.write_text(CONFIG.read_text().replace('policy = "policy"', f'policy = "{CONFIG.parent / "policy"}"')
                      + "goal_tolerance_m = 2.5\n")
    nav, bridge, proc = start_node(config, qos_profile_sensor_data)
    try:
        sim = adp_runtime.Sim(nav, 3, 5)
        gx, gy = sim.observe()["goal"]
        # A goal in the robot's frame while poses are in `map`: refused, a stop.
        bridge.send_goal(1.0, 0.0, frame="base_link")
        assert bridge.send(sim.observe()) == adp_runtime.STOP
        assert bridge.send(sim.observe()) == adp_runtime.STOP
        # The goal in `map`: the robot drives (scans on best effort reach the node) and the
        # node says when the runtime arrives, then stops.
        bridge.send_goal(gx, gy)
        moved = []
        status = drive(bridge, sim, lambda cmd: moved.append(cmd != adp_runtime.STOP) or not bridge.reached.empty())
        assert status == "running" and any(moved), (status, sim.result())
        reached = bridge.reached.get()
        assert (reached.pose.position.x, reached.pose.position.y) == (gx, gy)
        assert reached.header.frame_id == "map"
        assert bridge.send(sim.observe()) == adp_runtime.STOP
        proc.terminate()
        log = proc.communicate(timeout=30)[0]
        assert "goal in frame 'base_link', but poses are in 'map' (the odometry frame): goal refused" in log, log
        assert "reached" in log, log
    finally:
        end(bridge, proc)


@pytest.fixture
def remapped_node():
    # The lidar on another topic, remapped on the command line.
    nav, bridge, proc = start_node(CONFIG, ros_args=["-r", "scan:=front/scan"], scan_topic="front/scan")
    try:
        yield nav, bridge, proc
    finally:
        end(bridge, proc)


def test_stale_inputs_and_a_terminate_end_in_a_stop(remapped_node):
    nav, bridge, proc = remapped_node
    sim = adp_runtime.Sim(nav, 3, 5)
    gx, gy = sim.observe()["goal"]
    bridge.send_goal(gx, gy)
    for _ in range(10):
        cmd = bridge.send(sim.observe())
        sim.drive(cmd)
    assert cmd != adp_runtime.STOP
    # The lidar falls silent: the watchdog publishes a stop unasked.
    bridge.spin_until(lambda: not bridge.commands.empty(), "stop from the watchdog")
    assert bridge.commands.get() == adp_runtime.STOP
    # Moving again, then SIGTERM: a final stop, a clean exit.
    for _ in range(3):
        cmd = bridge.send(sim.observe())
        sim.drive(cmd)
    assert cmd != adp_runtime.STOP
    proc.send_signal(signal.SIGTERM)
    bridge.spin_until(lambda: not bridge.commands.empty(), "final stop")
    assert bridge.commands.get() == adp_runtime.STOP
    log = proc.communicate(timeout=30)[0]
    assert proc.returncode == 0, log
    assert "Traceback" not in log and "shutting down: stop published" in log, log
    assert "no scan for more than 0.5 s (watchdog_s); stopping" in log, log
