"""A MuJoCo actor in a training run: `MujocoEnvironment` behind `adp_client.Actor` stores
steps in a real `adp learner` (target/release/adp, or $ADP_BIN), which verifies every
episode's checksum and exports a policy; and its reward terms are the Rust actors'."""

import json
import math
import os
import pathlib
import subprocess
import threading
import time

import numpy as np
import pytest

if os.environ.get("ADP_REQUIRE_LEARNER") == "1":
    # CI: the training test must run, not skip.
    import adp_client
else:
    adp_client = pytest.importorskip("adp_client")
pytest.importorskip("adp_runtime")

from adp_mujoco.training import MujocoEnvironment, footprint_clearance, obstacle_penalty  # noqa: E402

REPO = pathlib.Path(__file__).resolve().parents[3]
ADP = pathlib.Path(os.environ.get("ADP_BIN", REPO / "target" / "release" / "adp"))

CONFIG = """[env]
laser_clip_m = 2.5

[td3]
warmup_steps = 64
rate_tolerance = 64.0
actor_warmup_updates = 0

[service]
shared_memory = false
heartbeat_ms = 200
lease_ttl_ms = 5000
status_every_s = 0.2
"""


def test_clearance_and_penalty_are_the_rust_actors():
    # actor/src/reward.rs tests: ten returns 0.1 m ahead of the front bumper, one far away.
    fp = (0.254, 0.215)
    ranges = np.array([0.354] * 10 + [5.0])
    angles = np.zeros(11)
    assert footprint_clearance(ranges, angles, 30.0, *fp) == pytest.approx(0.1)
    # 0.05 m off the left side; a corner point at (0.3, 0.3); inside counts as 0.
    assert footprint_clearance(np.full(10, 0.265), np.full(10, math.pi / 2), 30.0, *fp) == pytest.approx(0.05)
    corner = footprint_clearance(np.full(10, math.hypot(0.3, 0.3)), np.full(10, math.pi / 4), 30.0, *fp)
    assert corner == pytest.approx(math.hypot(0.046, 0.085))
    assert footprint_clearance(np.full(10, 0.1), np.zeros(10), 30.0, *fp) == 0.0
    assert footprint_clearance(np.full(10, 30.0), np.zeros(10), 30.0, *fp) == math.inf
    assert obstacle_penalty(0.1, 0.4, -1.0) == pytest.approx(-(0.75 ** 2))
    assert obstacle_penalty(0.5, 0.4, -1.0) == 0.0


def run_info(max_agent_steps=400):
    from adp_client._proto import adp_pb2 as pb

    env = pb.EnvConfig(agent_period_cycles=5, max_agent_steps=max_agent_steps, laser_clip_m=2.5,
                       progress_scale=1.0, step_penalty=-0.01, obstacle_threshold_m=0.3, obstacle_scale=-0.1,
                       collision_reward=-10.0, timeout_reward=0.0, success_reward=10.0, reward_scale=0.1)
    space = adp_client.ActionSpace("decremental")
    return adp_client.RunInfo(run_id="test", incarnation=1, actor_id=1, obs_dim=720 + space.dim + 6,
                              act_dim=space.dim, action_space=space, planner="dwa", max_speed=1.5, run_seed=0,
                              policy_dims=[], heartbeat_ms=200, lease_ttl_ms=2000, env=env,
                              action_map=adp_client.ActionMap(), laser_layout="scan")


def test_an_episode_by_hand_and_a_bad_world_keeps_the_actor_serving():
    env = MujocoEnvironment()
    info = run_info()
    env.configure(info)
    # A world id no world has: the episode ends at its first step, as a timeout with the
    # error, and the next episode runs.
    obs = env.reset(400, 1)
    assert obs.shape == (info.obs_dim,) and not obs.any()
    _, reward, terminal, truncated, out = env.step(np.zeros(info.act_dim, dtype=np.float32))
    assert (reward, terminal, truncated) == (0.0, False, True)
    assert out["outcome"] == "timeout" and "world 400 does not exist" in out["error"] and env.errors == 1
    obs = env.reset(3, 1)
    assert obs.shape == (info.obs_dim,) and np.all(np.isfinite(obs)) and np.all(np.abs(obs[:720]) <= 1.0)
    # The DDP-centred action map's zero action is DDP's schedule: world 3 is reached.
    total, steps, out = 0.0, 0, {}
    while not out:
        obs, reward, terminal, truncated, out = env.step(np.zeros(info.act_dim, dtype=np.float32))
        total += reward
        steps += 1
    assert out["outcome"] == "success" and terminal and not truncated, out
    assert out["score"] > 0 and reward > 0.9 and 10 < steps < 60
    # The agent step cap truncates.
    env = MujocoEnvironment()
    env.configure(run_info(max_agent_steps=3))
    env.reset(3, 1)
    ends = [env.step(np.zeros(4, dtype=np.float32))[2:4] for _ in range(3)]
    assert ends == [(False, False), (False, False), (False, True)]


def wait_for(what, pred, limit=300.0):
    end = time.monotonic() + limit
    while time.monotonic() < end:
        v = pred()
        if v:
            return v
        time.sleep(0.2)
    pytest.fail(f"waited {limit} s for {what}")


def status(run):
    try:
        return json.loads((run / "status.json").read_text())
    except (OSError, ValueError):
        return None


def test_a_mujoco_actor_stores_steps_in_a_real_learner(tmp_path):
    if not ADP.is_file():
        if os.environ.get("ADP_REQUIRE_LEARNER") == "1":
            pytest.fail(f"the adp binary {ADP} is missing")
        pytest.skip(f"no adp binary at {ADP} (cargo build --release, or set ADP_BIN)")
    cfg = tmp_path / "run.toml"
    cfg.write_text(CONFIG)
    run = tmp_path / "run"
    log = open(tmp_path / "learner.log", "w")
    learner = subprocess.Popen([str(ADP), "learner", "--config", str(cfg), "--steps", "200",
                                "--listen", "127.0.0.1:0", "--out", str(run)],
                               stdout=log, stderr=subprocess.STDOUT)
    env = MujocoEnvironment()
    errors = []
    try:
        wait_for("learner.addr", lambda: (run / "learner.addr").is_file() or learner.poll() is not None)
        assert learner.poll() is None, (tmp_path / "learner.log").read_text()
        addr = (run / "learner.addr").read_text().strip()
        actor = adp_client.Actor(addr, env, token_file=str(run / "token"), log=lambda line: None)

        def serve():
            try:
                actor.run()
            except Exception as e:  # reported below
                errors.append(e)

        t = threading.Thread(target=serve, daemon=True)
        t.start()
        wait_for("the learner to finish", lambda: learner.poll() is not None, limit=600.0)
        t.join(timeout=60)
        assert learner.returncode == 0, (tmp_path / "learner.log").read_text()
    finally:
        if learner.poll() is None:
            learner.kill()
            learner.wait()
        log.close()
    assert not errors, errors
    s = status(run)
    assert s["finished"] and s["inserts"] >= s["budget"] == 200, s
    assert s["episodes_verified"] >= 1 and s["episodes_mismatched"] == 0, s
    assert actor.episodes >= 1 and env.errors == 0
    for f in ("policy.onnx", "policy.safetensors", "policy.json"):
        assert (run / "export" / f).is_file(), f
