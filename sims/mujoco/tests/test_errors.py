"""Bad input ends one episode with the package's error, and the next episode runs: a world
the model cannot be built from, a lidar that fails, a NaN state from the physics."""

import math

import numpy as np
import pytest

from adp_mujoco import JackalSim, LidarError, PhysicsError, SimError, WorldError, run_episode
from conftest import open_world


@pytest.mark.parametrize(
    "world, message",
    [
        ({"cylinders": []}, "missing field `start`"),
        (dict(open_world(), cylinders=[(1.0, math.nan, 0.1)]), "cylinders\\[0\\]"),
        (dict(open_world(), cylinders=[(1.0, 1.0, 0.0)]), "radius 0.0 <= 0"),
        (dict(open_world(), cylinders=[(1.0, 1.0)]), "expected 3"),
        (dict(open_world(), cylinders="none"), "must be a list"),
        (dict(open_world(), start=(0.0, 0.0)), "field `start`"),
        (dict(open_world(), walls=[(1.0, 1.0, 0.0, 2.0)]), "walls\\[0\\]"),
        (dict(open_world(), goal_radius=-1.0), "must be > 0"),
        (dict(open_world(), moving=3), "moving obstacles"),
        (open_world(cylinders=[(0.1, 0.0, 0.2)]), "inside an obstacle"),
        ("/nonexistent/world.json", "world file"),
        ([1, 2], "not a world id"),
    ],
)
def test_a_world_that_cannot_be_built(world, message):
    with pytest.raises(WorldError, match=message):
        JackalSim(world)


def test_a_file_that_is_not_json(tmp_path):
    bad = tmp_path / "w.json"
    bad.write_text("{not json")
    with pytest.raises(WorldError, match="not JSON"):
        JackalSim(str(bad))


def test_an_unknown_world_id():
    pytest.importorskip("adp_runtime")
    with pytest.raises(WorldError, match="does not exist"):
        JackalSim(123456)


def test_a_lidar_that_fails():
    sim = JackalSim(open_world())

    def broken(data):
        raise RuntimeError("the sensor stopped")

    sim.lidar.cast = broken
    with pytest.raises(LidarError, match="the sensor stopped"):
        sim.step((0.5, 0.0))
    assert sim.status == "error" and "sensor" in sim.result()["error"]

    sim = JackalSim(open_world())
    sim.lidar.cast = lambda data: np.full(720, np.nan)
    with pytest.raises(LidarError, match="non-finite"):
        sim.step((0.5, 0.0))
    sim = JackalSim(open_world())
    sim.lidar.cast = lambda data: np.ones(10)
    with pytest.raises(LidarError, match="expected \\(720,\\)"):
        sim.step((0.5, 0.0))


def test_a_nan_state_from_the_physics():
    sim = JackalSim(open_world())
    sim.step((0.5, 0.0))
    sim.data.qvel[0] = math.nan
    with pytest.raises(PhysicsError):
        sim.step((0.5, 0.0))
    assert sim.status == "error"
    # Ended: further steps change nothing.
    assert sim.step((0.5, 0.0)) == "error"


def test_a_bad_command():
    sim = JackalSim(open_world())
    with pytest.raises(SimError, match="not finite"):
        sim.step((math.inf, 0.0))


def test_the_next_episode_runs_after_a_failed_one():
    pytest.importorskip("adp_runtime")
    results = [run_episode(w, seed=0, max_cycles=20) for w in ({"cylinders": []}, open_world())]
    assert results[0]["status"] == "error" and "missing field" in results[0]["error"]
    assert results[1]["status"] in ("running", "timed_out", "succeeded") and results[1]["error"] is None
    assert results[1]["cycles"] > 0
