"""Episodes driven by the project's runtime: its planner brings the Jackal to the goal of
an open world and of an easy BARN world, a drive into an obstacle is a collision, a robot
that does not move times out, all by the project's episode rules."""

import json

import pytest

adp_runtime = pytest.importorskip("adp_runtime")

from adp_mujoco import DEFAULT_EPISODE, JackalSim, decremental_schedule, navigator, run_episode  # noqa: E402
from conftest import open_world  # noqa: E402


def test_default_rules_are_the_runtimes():
    ep = navigator().episode
    for key in ("control_dt", "timeout_s", "clock_start_distance"):
        assert DEFAULT_EPISODE[key] == ep[key]
    for key, value in DEFAULT_EPISODE["lidar"].items():
        assert ep["lidar"][key] == value


def test_the_runtimes_planner_reaches_the_goal_of_an_open_world():
    world = open_world(goal=(6.0, 0.0), cylinders=[(3.0, 1.5, 0.1), (3.0, -1.5, 0.1)])
    r = run_episode(world, navigator("dwa", 1.5, fixed="ddp"), seed=0)
    assert r["status"] == "succeeded", r
    assert r["error"] is None and r["refused"] == 0
    # 5 m to the goal circle at up to 1.5 m/s.
    assert 3.0 < r["time_s"] < 15.0 and r["score"] > 0.0
    assert r["distance_m"] >= 4.9


def test_the_runtimes_planner_reaches_the_goal_of_an_easy_barn_world():
    r = run_episode(3, navigator("dwa", 1.5, fixed="ddp"), seed=0)
    assert r["status"] == "succeeded", r
    assert 0.0 < r["score"] <= 0.5


def test_a_mppi_navigator_drives_too():
    world = open_world(goal=(5.0, 0.0))
    r = run_episode(world, navigator("mppi", 1.5, fixed="ddp"), seed=0)
    assert r["status"] == "succeeded", r


def test_driving_into_an_obstacle_is_a_collision():
    # Straight at a cylinder 2 m ahead: the footprint's front (0.254 m ahead of the centre)
    # touches its surface (r = 0.3) when the centre is 2 - 0.3 - 0.254 = 1.446 m along.
    sim = JackalSim(open_world(goal=(8.0, 0.0), cylinders=[(2.0, 0.0, 0.3)]))
    status = "running"
    while status == "running":
        status = sim.step((0.8, 0.0))
    assert status == "collided"
    x, y, _ = sim.true_pose()
    assert x == pytest.approx(1.446, abs=0.03) and abs(y) < 0.05
    assert sim.result()["score"] == 0.0
    # An ended run stays ended.
    assert sim.step((0.8, 0.0)) == "collided"


def test_standing_still_times_out_and_the_clock_waits_for_motion():
    ep = dict(DEFAULT_EPISODE, timeout_s=1.0)
    sim = JackalSim(open_world(), episode=ep)
    status = "running"
    while status == "running":
        status = sim.step((0.0, 0.0))
    assert status == "timed_out"
    assert sim.clock_start is None and sim.result()["time_s"] == pytest.approx(1.0, abs=0.003)
    moving = JackalSim(open_world(goal=(30.0, 0.0)), episode=dict(DEFAULT_EPISODE, timeout_s=2.0))
    while moving.step((1.0, 0.0)) == "running":
        pass
    # The clock started after 0.1 m, about 0.15 s in (latency and acceleration).
    assert 0.1 < moving.clock_start < 0.4
    assert moving.time == pytest.approx(moving.clock_start + 2.0, abs=0.003)


def test_a_world_file_gives_the_same_world(tmp_path):
    path = tmp_path / "world3.json"
    path.write_text(json.dumps(adp_runtime.world(3)))
    a, b = JackalSim(str(path), seed=1), JackalSim(3, seed=1)
    assert a.model.ngeom == b.model.ngeom
    assert (a.ranges == b.ranges).all()


def test_ddp_as_a_given_schedule_matches_the_fixed_one():
    dts, checks = decremental_schedule()
    assert sum(dts) == pytest.approx(2.0) and len(dts) == 20 and checks[-1] == 0
    assert dts[0] < dts[-1]


@pytest.mark.skipif(not hasattr(adp_runtime.Navigator, "set_schedule"), reason="runtime without set_schedule")
def test_a_schedule_chosen_outside_drives_the_planner():
    # A training actor's loop: every agent step (5 cycles) something outside the runtime (the
    # learner's policy) chooses the schedule; here p alternates between DDP's 1.7 and 1.0.
    chosen = []

    def policy(sim, k):
        p = 1.7 if k % 2 == 0 else 1.0
        chosen.append(p)
        return decremental_schedule(p=p)

    world = open_world(goal=(5.0, 0.0))
    r = run_episode(world, navigator("dwa", 1.5), seed=0, schedule=policy)
    assert r["status"] == "succeeded", r
    assert len(chosen) == (r["cycles"] + 4) // 5
    # The same given DDP schedule every step plans exactly as the fixed DDP navigator.
    fixed = run_episode(world, navigator("dwa", 1.5), seed=0)
    given = run_episode(world, navigator("dwa", 1.5, fixed="vanilla"), seed=0,
                        schedule=lambda sim, k: decremental_schedule())
    assert (given["status"], given["time_s"], given["distance_m"]) == (fixed["status"], fixed["time_s"], fixed["distance_m"])
