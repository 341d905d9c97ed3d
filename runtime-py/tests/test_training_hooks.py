"""What a training actor outside the project needs from the runtime: the planner runs on a
schedule given from outside (the learner's policy chose it), exactly as on the same schedule
fixed by the configuration, and the local goal a policy's observation reads."""

import pathlib

import pytest

import adp_runtime

ROOT = pathlib.Path(__file__).resolve().parents[2]


def navigator(tmp_path, fixed="ddp", policy=False):
    text = f'planner = "dwa"\nmax_speed = 1.5\nfixed = "{fixed}"\n'
    if policy:
        text += f'policy = "{ROOT / "runtime" / "examples" / "policy"}"\n'
    path = tmp_path / f"{fixed}-{policy}.toml"
    path.write_text(text)
    return adp_runtime.Navigator(str(path))


def drive(nav, world=3, seed=2, before=None):
    sim = adp_runtime.Sim(nav, world, seed)
    outs, status, k = [], "running", 0
    while status == "running":
        if before is not None:
            before(nav, k)
        out = nav.cycle(**sim.observe())
        outs.append(out)
        status = sim.step(out)
        k += 1
    return outs, status


VANILLA = ([0.05] * 20, [20] * 20)


def test_a_given_schedule_plans_as_the_same_fixed_one(tmp_path):
    fixed, status = drive(navigator(tmp_path, "vanilla"))
    nav = navigator(tmp_path, "ddp")
    nav.set_schedule(*VANILLA)
    given, status_given = drive(nav)
    assert status == status_given == "succeeded"
    assert given == fixed


def test_the_schedule_changes_at_an_agent_step(tmp_path):
    def ddp_then_vanilla(nav, k):
        if k == 10:
            nav.set_schedule(*VANILLA)

    outs, status = drive(navigator(tmp_path, "ddp"), before=ddp_then_vanilla)
    assert status == "succeeded"
    assert outs[0].schedule[0] == 20 and outs[0].schedule[1] == pytest.approx(2.0)
    assert [o.schedule[1] for o in outs[10:]] == pytest.approx([1.0] * len(outs[10:]))


def test_refusals(tmp_path):
    with pytest.raises(adp_runtime.ConfigError, match="the navigator's policy chooses the schedules"):
        navigator(tmp_path, policy=True).set_schedule(*VANILLA)
    nav = navigator(tmp_path)
    with pytest.raises(adp_runtime.ConfigError, match="65 steps: at most 64"):
        nav.set_schedule([0.01] * 65, [1] * 65)
    with pytest.raises(adp_runtime.ConfigError, match="horizon: at most 5 s"):
        nav.set_schedule([0.5] * 20, [1] * 20)
    with pytest.raises(ValueError, match="schedule"):
        nav.set_schedule([0.1, -0.1], [1, 1])
    with pytest.raises(ValueError, match="schedule"):
        nav.set_schedule([0.1, 0.1], [1])


def test_the_local_goal(tmp_path):
    nav = navigator(tmp_path)
    assert nav.local_goal is None
    sim = adp_runtime.Sim(nav, 3, 0)
    nav.cycle(**sim.observe())
    gx, gy = nav.local_goal
    assert gy > 3.0 and abs(gx + 2.25) < 5.0
