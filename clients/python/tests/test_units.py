"""Unit tests: generated stubs are current, the checksum, the numpy MLP and the action-space
port (values from planner/src/action.rs's tests)."""

import json
import math
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from adp_client import ActionMap, ActionError, ActionSpace, MlpPolicy, PolicyError, param_count, step_checksum
from adp_client.checksum import f32_bytes

HERE = pathlib.Path(__file__).resolve().parent


def test_generated_stubs_are_current():
    r = subprocess.run([sys.executable, str(HERE.parent / "tools" / "gen_stubs.py"), "--check"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


def test_every_field_changes_the_checksum():
    obs = f32_bytes([0.5, -0.25])
    base = dict(episode_id=3, step_index=1, policy_version=2, obs=obs, action=f32_bytes([0.1]), reward=-0.5,
                terminal=False, truncated=False, final_obs=b"")
    c = step_checksum(**base)
    for change in [dict(episode_id=4), dict(step_index=2), dict(policy_version=3),
                   dict(obs=f32_bytes([0.5, -0.26])), dict(action=f32_bytes([0.2])), dict(reward=-0.4),
                   dict(terminal=True), dict(truncated=True, final_obs=obs)]:
        assert step_checksum(**{**base, **change}) != c, change
    assert step_checksum(**base) == c
    assert 0 <= c < 2**64


def test_fnv_reference_value():
    # FNV-1a 64 of the empty input is the offset basis; of b"a" the published value.
    from adp_client.checksum import _OFFSET, _fnv
    assert _fnv(_OFFSET, b"") == 0xCBF29CE484222325
    assert _fnv(_OFFSET, b"a") == 0xAF63DC4C8601EC8C


def naive(dims, flat, obs):
    x = np.asarray(obs, dtype=np.float64)
    off = 0
    for l, (n, m) in enumerate(zip(dims[:-1], dims[1:])):
        w = np.asarray(flat[off:off + n * m], dtype=np.float64)
        b = np.asarray(flat[off + n * m:off + n * m + m], dtype=np.float64)
        y = np.array([sum(x[i] * w[i * m + o] for i in range(n)) + b[o] for o in range(m)])
        x = np.tanh(y) if l == len(dims) - 2 else np.maximum(y, 0)
        off += n * m + m
    return x


def test_policy_matches_a_naive_forward_pass():
    rng = np.random.default_rng(5)
    for dims in ([5, 3], [7, 9, 2], [6, 4, 8, 5, 3]):
        flat = rng.uniform(-1, 1, param_count(dims)).astype(np.float32)
        p = MlpPolicy(dims, flat.tobytes())
        assert (p.obs_dim, p.act_dim) == (dims[0], dims[-1])
        for _ in range(5):
            obs = rng.uniform(-1, 1, dims[0]).astype(np.float32)
            np.testing.assert_allclose(p.act(obs), naive(dims, flat, obs), atol=1e-5)
        batch = rng.uniform(-1, 1, (4, dims[0])).astype(np.float32)
        np.testing.assert_allclose(p.act(batch), np.stack([p.act(o) for o in batch]), atol=1e-6)


def test_policy_refusals_name_the_problem():
    assert param_count([730, 512, 512, 4]) == 730 * 512 + 512 + 512 * 512 + 512 + 512 * 4 + 4
    with pytest.raises(PolicyError, match="need 8 parameters, got 7"):
        MlpPolicy([3, 2], np.zeros(7, np.float32))
    bad = np.zeros(8, np.float32)
    bad[5] = np.inf
    with pytest.raises(PolicyError, match="parameter 5 is inf"):
        MlpPolicy([3, 2], bad)
    with pytest.raises(PolicyError, match="layer sizes"):
        MlpPolicy([3], [])
    with pytest.raises(PolicyError, match="observation has 2 values"):
        MlpPolicy([3, 2], np.zeros(8, np.float32)).act([0.0, 1.0])


def test_decremental_matches_the_rust_values():
    sp = ActionSpace("decremental")
    np.testing.assert_allclose(sp.to_params([0.0, 0.0, -0.1, 0.0]), [1.35, 1.9, 18.0, 0.3], atol=1e-12)
    s = sp.schedule([0.0, 0.0, -0.1, 0.0], 20)
    assert len(s.dts) == 18

    def t(i):
        return 0.3 * (i / 18.0) * 1.9 + 0.7 * (i / 18.0) ** 1.35 * 1.9

    for i, d in enumerate(s.dts):
        assert abs(d - (t(i + 1) - t(i))) < 1e-12
    assert abs(s.horizon - 1.9) < 1e-12
    # The DDP action: p = 1.7, T = 2, N = 20, alpha = 0 gives DDP's check counts.
    a = sp.to_action([1.7, 2.0, 20.0, 0.0])
    assert a[0] == 1.0 and a[3] == -1.0
    ddp = sp.schedule(a, 20)
    assert ddp.checks == [int(math.floor(20 * (1 - (i / 20) ** 1.7) + 0.5)) for i in range(1, 21)]
    for a in ([-1.0] * 4, [1.0] * 4, [0.3, -0.7, 0.9, 0.2]):
        s = sp.schedule(a, 20)
        assert all(y >= x - 1e-12 for x, y in zip(s.dts, s.dts[1:]))
        assert 1.6 - 1e-9 < s.horizon < 2.2 + 1e-9 and 15 <= len(s.dts) <= 22
    np.testing.assert_allclose(sp.to_params([5.0, -9.0, 1.0, 1.0]), [1.7, 1.6, 22.0, 0.6], atol=1e-12)


def test_incremental_unconstrained_fixed():
    a = [0.5, -0.2, 0.1, -0.5]
    dec = ActionSpace("decremental").schedule(a, 20)
    inc = ActionSpace("incremental").schedule(a, 20)
    assert inc.dts == dec.dts[::-1] and inc.checks == dec.checks[::-1]
    un = ActionSpace("unconstrained")
    s = un.schedule([1.0] * 20, 20)
    assert abs(s.horizon - 2.0) < 1e-12 and all(abs(d - 0.1) < 1e-12 for d in s.dts)
    assert abs(un.schedule([-1.0] * 20, 20).horizon - 0.4) < 1e-12
    fx = ActionSpace("fixed").schedule([0.0, 0.0], 20)
    assert len(fx.dts) == 16 and all(c == 10 for c in fx.checks) and abs(fx.horizon - 2.0) < 1e-12
    for name in ("decremental", "unconstrained", "fixed"):
        sp = ActionSpace(name)
        a = [math.sin(i * 0.37) for i in range(sp.dim)]
        back = sp.to_action(sp.to_params(a))
        for i, (x, y) in enumerate(zip(a, back)):
            if sp.ranges()[i][0] != "N":
                assert abs(x - y) < 1e-12


def test_ddp_centred_map_matches_the_rust_values():
    # planner/src/action.rs ddp_centred_map_puts_ddp_at_zero_and_keeps_the_box.
    sp = ActionSpace("decremental")
    m = ActionMap("ddp-centred")
    ddp = sp.ddp_action()
    assert m.box_action(sp, [0.0] * 4) == ddp
    t = lambda u: sp.to_params([0.0, m.to_box(u, ddp[1]), 0.0, 0.0])[1]
    assert abs(t(0.5) - 2.1) < 1e-12 and abs(t(-0.5) - 1.8) < 1e-12
    p = lambda u: sp.to_params([m.to_box(u, ddp[0]), 0.0, 0.0, 0.0])[0]
    assert abs(p(0.7) - 1.7) < 1e-12 and abs(p(-0.5) - 1.35) < 1e-12 and abs(p(-1.0) - 1.0) < 1e-12
    assert m.schedule(sp, [0.0] * 4, 20).checks == sp.schedule(ddp, 20).checks
    assert ActionMap("affine").box_action(sp, [0.3, 0.1, -0.2, 0.9]) == [0.3, 0.1, -0.2, 0.9]
    with pytest.raises(ActionError, match="unknown action map"):
        ActionMap("bogus")


def test_action_errors():
    with pytest.raises(ActionError, match=r"\(T\) is nan"):
        ActionSpace("decremental").schedule([0.0, float("nan"), 0.0, 0.0], 20)
    with pytest.raises(ActionError, match="needs 20 values, got 4"):
        ActionSpace("unconstrained").schedule([0.0] * 4, 20)
    with pytest.raises(ActionError, match="unknown action space `bogus`"):
        ActionSpace("bogus")


def test_weight_and_velocity_spaces():
    for planner, n in (("dwa", 4), ("mppi", 5), ("system", 4)):
        for name, dim in ((f"weights:{planner}", n), (f"decremental+weights:{planner}", 4 + n)):
            sp = ActionSpace(name)
            assert sp.dim == dim and len(sp.gains) == n
            for m in ("ddp-centred", "affine"):
                # The policy output that selects DDP: 0 (ddp-centred) or the DDP box (affine).
                u = [0.0] * dim if m == "ddp-centred" else sp.ddp_action()
                q = sp.to_params(ActionMap(m).box_action(sp, u))
                assert sp.gain_factors(q) == [1.0] * n
    ddp = ActionSpace("weights:dwa").schedule([0.0] * 4, 20)
    assert ddp.checks == ActionSpace("decremental").schedule(ActionSpace("decremental").ddp_action(), 20).checks
    vel = ActionSpace("velocity")
    assert vel.velocity_command([0.5, 7.0], 1.0) == (0.75, 2.0)
    with pytest.raises(ActionError, match="no rollout schedule"):
        vel.schedule([0.0, 0.0], 20)
    with pytest.raises(ActionError, match="needs the planner: write `weights:dwa`"):
        ActionSpace("weights")
    with pytest.raises(ActionError, match="unknown action space `weights:log-mppi`"):
        ActionSpace("weights:log-mppi")


def test_run_spec_enums_decode_to_names_and_unknown_values_are_refused():
    from adp_client._proto import adp_pb2 as pb
    from adp_client import SpecError
    from adp_client.spec import action_map_name, action_space_name, laser_layout, planner_name

    assert planner_name(pb.PLANNER_LOG_MPPI) == "log-mppi"
    assert action_space_name(pb.ActionSpace(kind=pb.ACTION_SPACE_KIND_DECREMENTAL)) == "decremental"
    weights = pb.ActionSpace(kind=pb.ACTION_SPACE_KIND_DECREMENTAL_WEIGHTS, gains=pb.PLANNER_MPPI)
    assert action_space_name(weights) == "decremental+weights:mppi"
    assert ActionSpace(action_space_name(weights)).dim == 9
    env = pb.EnvConfig(action_map=pb.ACTION_MAP_AFFINE, laser_sectors=25)
    assert (action_map_name(env), laser_layout(env)) == ("affine", "sectors:25")
    assert laser_layout(pb.EnvConfig()) == "scan"
    with pytest.raises(SpecError, match="env.action_map is unspecified"):
        action_map_name(pb.EnvConfig())
    with pytest.raises(SpecError, match="spec.planner = 9 is not a known value"):
        planner_name(9)
    with pytest.raises(SpecError, match="spec.action_space.gains is unspecified"):
        action_space_name(pb.ActionSpace(kind=pb.ACTION_SPACE_KIND_WEIGHTS))
    with pytest.raises(SpecError, match="env.laser_sectors = 721"):
        laser_layout(pb.EnvConfig(laser_sectors=721))
