"""The adp_runtime package: a navigator built from a configuration file drives a BARN world
to its goal, repeats itself, refuses bad input with a stop and loses nothing, and can be
shared between threads."""

import math
import pathlib
import threading

import pytest

import adp_runtime

ROOT = pathlib.Path(__file__).resolve().parents[2]
CONFIG = ROOT / "runtime" / "examples" / "runtime.toml"


def drive(world, seed, on_cycle=None):
    nav = adp_runtime.Navigator(str(CONFIG))
    sim = adp_runtime.Sim(nav, world, seed)
    outputs = []
    status = "running"
    while status == "running":
        inputs = sim.observe()
        if on_cycle is not None:
            on_cycle(nav, inputs)
        out = nav.cycle(**inputs)
        outputs.append(out)
        status = sim.step(out)
    return sim.result(), outputs


def test_drives_a_world_to_the_goal_and_repeats_itself():
    (status, time_s, score), outputs = drive(3, 5)
    assert status == "succeeded"
    assert 0.0 < score <= 1.0 and time_s > 0.0
    assert outputs[0].agent_step and outputs[0].planned
    steps, horizon, first = outputs[0].schedule
    assert 15 <= steps <= 22 and 1.6 <= horizon <= 2.2 + 1e-9 and 0.0 < first < 0.2
    # One agent step every five control periods.
    assert [o.agent_step for o in outputs[:10]] == [True] + [False] * 4 + [True] + [False] * 4
    again, outputs_again = drive(3, 5)
    assert again == (status, time_s, score)
    assert outputs_again == outputs


def test_the_c_example_and_python_agree():
    # The C example prints this line for world 3, seed 5 (runtime-capi/tests/c_example.rs
    # checks it against the Rust API).
    (status, time_s, score), outputs = drive(3, 5)
    line = (
        f"world 3: {status} in {time_s:.2f} s, score {score:.3f}; {len(outputs)} cycles, "
        f"{sum(o.planned for o in outputs)} planned, {sum(o.agent_step for o in outputs)} "
        "agent steps, 0 refused"
    )
    assert line.startswith("world 3: succeeded in 6.27 s, score 0.500; 133 cycles")


@pytest.mark.parametrize(
    "change, kind, message",
    [
        (lambda i: i.update(ranges=i["ranges"][1:]), "scan", "scan: 719 ranges, but the configured lidar has 720 beams"),
        (lambda i: i["ranges"].__setitem__(3, math.nan), "scan", "scan: range 3 is NaN"),
        (lambda i: i.update(odom_stamp_s=i["stamp_s"] - 1.0), "odometry", "odometry: 1.000 s older than the scan"),
        (lambda i: i.update(pose=(math.nan, 0.0, 0.0)), "odometry", "odometry: pose.x = NaN is not finite"),
        (lambda i: i.update(goal=(0.0, math.inf)), "goal", "goal: (0, inf) is not finite"),
        (lambda i: i.update(path=[]), "path", "global path: empty"),
    ],
)
def test_bad_input_is_refused_with_a_stop_and_loses_nothing(change, kind, message):
    nav = adp_runtime.Navigator(str(CONFIG))
    clean = adp_runtime.Navigator(str(CONFIG))
    sim = adp_runtime.Sim(nav, 10, 1)
    for _ in range(12):
        inputs = sim.observe()
        bad = dict(inputs, ranges=list(inputs["ranges"]))
        change(bad)
        with pytest.raises(adp_runtime.RefusedInput) as refused:
            nav.cycle(**bad)
        got_message, got_kind = refused.value.args
        assert got_kind == kind
        assert got_message.startswith(message)
        assert adp_runtime.STOP == (0.0, 0.0)
        out = nav.cycle(**inputs)
        assert out == clean.cycle(**inputs)
        sim.step(out)


def test_a_bad_configuration_names_the_file_and_key(tmp_path):
    bad = tmp_path / "runtime.toml"
    bad.write_text('planner = "dwa"\nmax_speed = 1.5\nspeed = 2\n')
    with pytest.raises(adp_runtime.ConfigError, match="unknown field `speed`") as e:
        adp_runtime.Navigator(str(bad))
    assert str(bad) in str(e.value)
    missing = tmp_path / "nowhere.toml"
    with pytest.raises(adp_runtime.ConfigError, match="cannot read"):
        adp_runtime.Navigator(str(missing))
    with pytest.raises(ValueError, match="world 300 does not exist"):
        adp_runtime.Sim(adp_runtime.Navigator(str(CONFIG)), 300)


def test_a_navigator_is_shared_between_threads():
    nav = adp_runtime.Navigator(str(CONFIG))
    errors = []

    def worker(world):
        try:
            sim = adp_runtime.Sim(nav, world, 0)
            for _ in range(20):
                sim.step(nav.cycle(**sim.observe()))
        except Exception as e:  # pragma: no cover - reported below
            errors.append(e)

    threads = [threading.Thread(target=worker, args=(w,)) for w in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    assert nav.beams == 720 and nav.planner == "dwa"


def test_the_example_drives_a_world():
    import subprocess
    import sys

    run = subprocess.run(
        [sys.executable, str(ROOT / "runtime-py" / "examples" / "drive_world.py"), str(CONFIG), "3", "5"],
        capture_output=True,
        text=True,
    )
    assert run.returncode == 0, run.stderr
    assert run.stdout.startswith("world 3: succeeded in 6.27 s, score 0.500; 133 cycles, 0 refused")
