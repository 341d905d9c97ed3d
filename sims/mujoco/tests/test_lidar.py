"""The lidar: 720 beams over 270 degrees by MuJoCo ray casting, seeing obstacles at the
ranges geometry gives, never the robot itself nor the ground, with the project's noise."""

import math

import numpy as np
import pytest

from adp_mujoco import DEFAULT_EPISODE, JackalSim
from conftest import open_world


def quiet():
    lidar = dict(DEFAULT_EPISODE["lidar"], noise_sigma=0.0)
    return dict(DEFAULT_EPISODE, lidar=lidar)


def test_sees_a_wall_at_the_right_range():
    # A wall whose near face is 3 m ahead of the robot's centre (the lidar's axis).
    sim = JackalSim(open_world(goal=(1.5, 0.0), walls=[(3.0, -5.0, 3.2, 5.0)]), episode=quiet())
    r = sim.ranges
    assert r.shape == (720,)
    angles = np.linspace(-0.75 * math.pi, 0.75 * math.pi, 720)
    ahead = np.abs(angles) < math.radians(30)
    np.testing.assert_allclose(r[ahead], 3.0 / np.cos(angles[ahead]), atol=1e-6)
    # Beams pointing away from the wall see nothing: max range.
    assert np.all(r[np.abs(angles) > math.radians(100)] == 30.0)


def test_sees_a_cylinder_at_centre_distance_less_radius():
    sim = JackalSim(open_world(cylinders=[(0.0, 2.0, 0.3)]), episode=quiet())
    left = sim.ranges[np.argmin(np.abs(sim.lidar.angles - math.pi / 2))]
    assert left == pytest.approx(1.7, abs=2e-3)  # the beam nearest 90 degrees


def test_never_sees_the_robot_or_the_ground():
    sim = JackalSim(open_world(), episode=quiet())
    assert np.all(sim.ranges == 30.0)


def test_noise_is_the_projects():
    wall = [(3.0, -5.0, 3.2, 5.0)]
    sim = JackalSim(open_world(goal=(1.5, 0.0), walls=wall), seed=4)
    truth = JackalSim(open_world(goal=(1.5, 0.0), walls=wall), episode=quiet()).ranges
    hit = truth < 30.0
    err = sim.ranges[hit] - truth[hit]
    assert 0.0007 < err.std() < 0.0013 and abs(err.mean()) < 3e-4
    # The same seed gives the same scan; another seed another.
    again = JackalSim(open_world(goal=(1.5, 0.0), walls=wall), seed=4).ranges
    other = JackalSim(open_world(goal=(1.5, 0.0), walls=wall), seed=5).ranges
    assert np.array_equal(sim.ranges, again) and not np.array_equal(sim.ranges, other)


def test_dropout_and_clamping():
    lidar = dict(DEFAULT_EPISODE["lidar"], noise_sigma=0.0, dropout=0.5, min_range=0.5)
    ep = dict(DEFAULT_EPISODE, lidar=lidar)
    sim = JackalSim(open_world(cylinders=[(0.0, 0.6, 0.3)], goal=(3.0, 0.0)), episode=ep, seed=2)
    r = sim.ranges
    assert r.min() >= 0.5 and r.max() <= 30.0
    dropped = np.mean(r == 30.0)
    assert 0.4 < dropped < 0.95  # half the beams dropped, besides the ones that see nothing
