"""The Jackal model: its mass and geometry are the published ones, it rests on its four
wheels, drives straight at the commanded speed, turns the way it is told, and its wheel
odometry drifts from the truth when the wheels slip."""

import math

import mujoco
import numpy as np
import pytest

from adp_mujoco import JackalParams, JackalSim, SkidSteer
from conftest import open_world


def drive(sim, command, cycles):
    for _ in range(cycles):
        assert sim.step(command) == "running"


def test_mass_and_geometry_follow_the_urdf():
    sim = JackalSim(open_world())
    p = sim.params
    # URDF: chassis 16.523 kg and four 0.477 kg wheels.
    assert sim.model.body_subtreemass[sim.model.body("jackal").id] == pytest.approx(16.523 + 4 * 0.477)
    assert sim.model.opt.timestep <= 0.002
    assert sim.substeps * sim.model.opt.timestep == pytest.approx(0.05)
    fl = sim.model.body("front_left_wheel").pos
    rr = sim.model.body("rear_right_wheel").pos
    assert fl[0] - rr[0] == pytest.approx(p.wheelbase)
    assert fl[1] - rr[1] == pytest.approx(p.track)
    assert sim.model.geom("front_left_tyre").size[0] == pytest.approx(0.098)


def test_rests_on_four_wheels():
    sim = JackalSim(open_world())
    drive(sim, (0.0, 0.0), 20)
    x, y, yaw = sim.true_pose()
    assert abs(x) < 1e-3 and abs(y) < 1e-3 and abs(yaw) < 1e-3
    assert sim.data.qpos[2] == pytest.approx(sim.params.ride_height, abs=1e-3)
    touching = {sim.model.geom(sim.data.contact[i].geom2).name for i in range(sim.data.ncon)}
    touching |= {sim.model.geom(sim.data.contact[i].geom1).name for i in range(sim.data.ncon)}
    assert {"front_left_tyre", "rear_left_tyre", "front_right_tyre", "rear_right_tyre"} <= touching


def test_drives_straight_at_the_commanded_speed_after_the_latency():
    sim = JackalSim(open_world(goal=(30.0, 0.0)))
    sim.step((1.0, 0.0))
    assert sim.true_velocity()[0] < 0.05  # the command waits out the 50 ms latency
    drive(sim, (1.0, 0.0), 29)
    v, w = sim.true_velocity()
    assert v == pytest.approx(1.0, abs=0.02) and abs(w) < 0.02
    x, y, _ = sim.true_pose()
    assert 1.0 < x < 1.5 and abs(y) < 0.02
    ox, oy, _ = sim.odom_pose
    assert math.hypot(ox - x, oy - y) < 0.05


def test_the_torque_limit_bounds_the_acceleration():
    sim = JackalSim(open_world(goal=(30.0, 0.0)), command_latency_s=0.0)
    sim.step((2.0, 0.0))
    sim.step((2.0, 0.0))
    # 4 wheels x 3 N m / 0.098 m on 18.4 kg is at most 6.6 m/s^2; the tyres carry less.
    v = sim.true_velocity()[0]
    assert 0.0 < v < 6.6 * 0.1
    assert np.all(np.abs(sim.data.actuator_force) <= sim.params.max_wheel_torque + 1e-9)


def test_turns_counter_clockwise_for_a_positive_yaw_rate_and_odometry_drifts():
    gyro = JackalSim(open_world(), seed=1)
    wheels = JackalSim(open_world(), seed=1, odometry="wheels")
    for sim in (gyro, wheels):
        drive(sim, (0.0, 1.5), 40)
        assert sim.true_velocity()[1] > 0.2
    true_yaw = gyro.true_pose()[2]
    assert true_yaw > 0.5
    # The wheels slip when a skid-steer base turns: the encoders' yaw is off by far more
    # than the gyro's.
    wheel_err = abs(math.remainder(wheels.odom_pose[2] - wheels.true_pose()[2], math.tau))
    gyro_err = abs(math.remainder(gyro.odom_pose[2] - true_yaw, math.tau))
    assert wheel_err > 0.1 and gyro_err < 0.05


def test_the_skid_steer_mapping():
    p = JackalParams()
    c = SkidSteer(p)
    c.command(1.0, 0.0)
    assert c.step(1.0) == pytest.approx([1.0 / p.wheel_radius] * 4)
    c = SkidSteer(p)
    c.command(0.0, 1.0)
    left, _, right, _ = c.step(1.0)
    assert right == pytest.approx(-left) and right == pytest.approx(p.effective_track / 2 / p.wheel_radius)
    # Rate limits: 20 m/s^2 -> 0.2 m/s after 10 ms.
    c = SkidSteer(p)
    c.command(2.0, 0.0)
    assert c.step(0.01)[0] == pytest.approx(0.2 / p.wheel_radius)
    # Saturation keeps the curvature: both sides scaled by one factor.
    c = SkidSteer(p)
    c.command(2.0, 4.0)
    left, _, right, _ = c.step(10.0)
    assert max(abs(left), abs(right)) == pytest.approx(p.max_wheel_speed)
    v = (left + right) / 2 * p.wheel_radius
    w = (right - left) * p.wheel_radius / p.effective_track
    assert w / v == pytest.approx(4.0 / 2.0)
    c.command(9.0, -9.0)
    assert c.target == (p.max_v, -p.max_w)


def test_the_model_is_plain_mjcf():
    sim = JackalSim(open_world(cylinders=[(3.0, 1.0, 0.2)]))
    assert sim.model.ngeom == 8  # ground, chassis, footprint, 4 tyres, the cylinder
    assert isinstance(sim.model, mujoco.MjModel)
