"""The world accessors a simulator outside the project builds its worlds from: `world(id)`
gives a catalog world as plain data, the same obstacles, start and goal the project's
simulator runs; `select_worlds` resolves a split as `adp eval --worlds` does; and
`Navigator.episode` states the episode rules and the lidar."""

import math
import pathlib

import pytest

import adp_runtime

ROOT = pathlib.Path(__file__).resolve().parents[2]
CONFIG = ROOT / "runtime" / "examples" / "runtime.toml"


def test_a_barn_world_as_data():
    w = adp_runtime.world(0)
    # sim/data/barn/obstacles.jsonl, world 0: 209 cylinders of r = 0.075 m.
    assert w["id"] == 0 and len(w["cylinders"]) == 209
    assert all(r == 0.075 for _, _, r in w["cylinders"])
    assert w["walls"] == [] and w["moving"] == 0
    assert w["start"] == (-2.25, 3.0, math.pi / 2) and w["goal"] == (-2.25, 13.0)
    assert w["goal_radius"] == 1.0
    assert w["optimal_time_s"] == pytest.approx(w["path_length_m"] / 2.0)
    assert w["optimal_time_s"] == pytest.approx(6.796149)
    assert len(w["reference_path"]) > 10


def test_the_data_is_the_world_the_project_simulates():
    # A straight drive from the start in the project's simulator collides where world 3's
    # data puts the first obstacle ahead, or not at all when the lane is clear.
    w = adp_runtime.world(3)
    nav = adp_runtime.Navigator(str(CONFIG))
    sim = adp_runtime.Sim(nav, 3, 0)
    x0, y0, _ = w["start"]
    ahead = [y - r for x, y, r in w["cylinders"] if abs(x - x0) < 0.215 + r and y > y0]
    status = "running"
    for _ in range(400):
        status = sim.drive((0.5, 0.0))
        if status != "running":
            break
    if ahead:
        assert status == "collided"
    else:
        assert status in ("succeeded", "running", "timed_out")


def test_dynabarn_and_generated_worlds_and_unknown_ids():
    assert adp_runtime.world(300)["moving"] > 0
    assert len(adp_runtime.world(1_000_000)["cylinders"]) > 0
    with pytest.raises(ValueError, match="world 400 does not exist"):
        adp_runtime.world(400)


def test_select_worlds_reads_the_split_files():
    test = adp_runtime.select_worlds("test")
    assert len(test) == 225 and test == sorted(set(test))
    assert adp_runtime.select_worlds("hardest50") == test[-50:]
    assert adp_runtime.select_worlds("0..3,7") == [0, 1, 2, 7]
    with pytest.raises(ValueError, match="nosuchsplit"):
        adp_runtime.select_worlds("nosuchsplit")


def test_the_episode_rules_and_the_lidar():
    e = adp_runtime.Navigator(str(CONFIG)).episode
    assert e["control_dt"] == 0.05 and e["timeout_s"] == 100.0
    assert e["clock_start_distance"] == 0.1 and e["physics_dt"] <= 0.01
    assert e["lidar"]["beams"] == 720 and e["lidar"]["fov_deg"] == 270.0
    assert e["lidar"]["noise_sigma"] == 0.001
    assert e["footprint"] == {"half_length": 0.254, "half_width": 0.215}
    assert e["max_v"] == 2.0 and e["max_w"] == 4.0
