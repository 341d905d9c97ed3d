"""The adp_runtime package: a navigator built from a configuration file drives a BARN world
to its goal, repeats itself, refuses bad input (and input outside its envelope) with a stop
and loses nothing, keeps its commands inside the limits, reads NaN beams as no return, and
can be shared between threads."""

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
        (lambda i: i.update(goal=(14000.0, 0.0)), "goal", "goal: (14000, 0) is "),
        (lambda i: i.update(pose=(1e6, 0.0, 0.0)), "goal", "goal: "),
        (lambda i: i.update(goal=(1e300, 0.0)), "goal", "goal: (1e300, 0e0) is outside the envelope"),
        (lambda i: i.update(pose=(0.0, 0.0, 1e7)), "odometry", "odometry: pose.yaw = 1e7 rad is outside"),
        (lambda i: i.update(odom_stamp_s=i["stamp_s"] - 1.0), "odometry", "odometry: 1.000 s older than the scan"),
        (lambda i: i.update(odom_stamp_s=i["stamp_s"] + 1.0), "odometry", "odometry: stamped 1.000 s after the scan"),
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


def test_nan_and_infinite_beams_read_as_no_return(tmp_path):
    nav = adp_runtime.Navigator(str(CONFIG))
    clean = adp_runtime.Navigator(str(CONFIG))
    sim = adp_runtime.Sim(nav, 10, 1)
    for k in range(8):
        inputs = sim.observe()
        faulty = list(inputs["ranges"])
        no_return = list(inputs["ranges"])
        for j, bad in enumerate([math.nan, math.inf, -math.inf]):
            faulty[k * 40 + j * 7] = bad
            no_return[k * 40 + j * 7] = 30.0
        out = nav.cycle(**dict(inputs, ranges=faulty))
        assert out == clean.cycle(**dict(inputs, ranges=no_return))
        sim.step(out)
    strict = tmp_path / "strict.toml"
    strict.write_text('planner = "dwa"\nmax_speed = 1.5\nnan_as_no_return = false\n')
    inputs = sim.observe()
    inputs["ranges"][3] = math.nan
    with pytest.raises(adp_runtime.RefusedInput, match=r"scan: range 3 is NaN \(nan_as_no_return = false\)"):
        adp_runtime.Navigator(str(strict)).cycle(**inputs)


@pytest.mark.parametrize("planner", ["dwa", "mppi", "log-mppi", "system"])
def test_commands_stay_inside_the_limits_whatever_the_measured_velocity(tmp_path, planner):
    config = tmp_path / "runtime.toml"
    config.write_text(f'planner = "{planner}"\nmax_speed = 1.5\n')
    recorded = adp_runtime.Sim(adp_runtime.Navigator(str(CONFIG)), 10, 1).observe()
    for vel in [(3.0, 0.0), (10.0, 0.0), (1e6, 0.0), (-1e6, 0.0), (0.5, 50.0), (1e6, -1e6)]:
        nav = adp_runtime.Navigator(str(config))
        for _ in range(6):
            v, w = nav.cycle(**dict(recorded, vel=vel)).command
            assert -1.5 <= v <= 1.5 and -4.0 <= w <= 4.0, (vel, v, w)


def test_a_panic_would_raise_an_exception_not_abort():
    # A defect inside the runtime raises InternalError, an ordinary RuntimeError that a
    # robot's `except Exception` catches (pyo3's own PanicException is a BaseException).
    assert issubclass(adp_runtime.InternalError, RuntimeError)
    assert "InternalError" in adp_runtime.__all__


def test_a_bad_configuration_names_the_file_and_key(tmp_path):
    bad = tmp_path / "runtime.toml"
    bad.write_text('planner = "dwa"\nmax_speed = 1.5\nspeed = 2\n')
    with pytest.raises(adp_runtime.ConfigError, match="unknown field `speed`") as e:
        adp_runtime.Navigator(str(bad))
    assert str(bad) in str(e.value)
    missing = tmp_path / "nowhere.toml"
    with pytest.raises(adp_runtime.ConfigError, match="cannot read"):
        adp_runtime.Navigator(str(missing))
    fast = tmp_path / "fast.toml"
    fast.write_text('planner = "dwa"\nmax_speed = 1e9\n')
    with pytest.raises(adp_runtime.ConfigError, match="max_speed = 1000000000 m/s exceeds the runtime's limit of 5 m/s"):
        adp_runtime.Navigator(str(fast))
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


def test_the_runtime_says_when_the_run_has_arrived(tmp_path):
    # goal_tolerance_m wider than BARN's 1 m success radius, so arrival comes first.
    config = tmp_path / "runtime.toml"
    config.write_text('planner = "dwa"\nmax_speed = 1.5\ngoal_tolerance_m = 2.5\n')
    nav = adp_runtime.Navigator(str(config))
    sim = adp_runtime.Sim(nav, 3, 5)
    out = nav.cycle(**sim.observe())
    assert not out.arrived and out.command != adp_runtime.STOP
    while not out.arrived:
        assert sim.step(out) == "running"
        out = nav.cycle(**sim.observe())
    assert out.command == adp_runtime.STOP and out.planned and out.schedule is None
    assert "arrived=true" in repr(out)
    # Latched until a new goal: the robot is left standing.
    for _ in range(20):
        assert sim.step(out) == "running"
        out = nav.cycle(**sim.observe())
        assert out.arrived and out.command == adp_runtime.STOP
    # A new goal 4 m from the robot, beyond the tolerance: a new run, planning again.
    inputs = sim.observe()
    x, y, _ = inputs["pose"]
    out = nav.cycle(**dict(inputs, goal=(x, y + 4.0)))
    assert not out.arrived and out.schedule is not None
