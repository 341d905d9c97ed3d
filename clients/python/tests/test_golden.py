"""The shared golden vectors in testdata/ (also read by actor/tests/golden.rs): the Python
ports of the action-to-schedule formula and of the observation layout must give the Rust
values."""

import json
import pathlib

import numpy as np
import pytest

from adp_client.action import ActionError, ActionMap, ActionSpace
from adp_client.observation import LaserResampler, LayoutError, layout_size, observation

TESTDATA = pathlib.Path(__file__).resolve().parents[3] / "testdata"


def _vectors(name):
    return json.loads((TESTDATA / name).read_text())["vectors"]


def test_action_vectors_match_the_rust_port():
    vectors = _vectors("action_vectors.json")
    assert len(vectors) >= 12
    for v in vectors:
        sp, m = ActionSpace(v["space"]), ActionMap(v["map"])
        got = sp.to_params(m.box_action(sp, v["output"]))
        np.testing.assert_allclose(got, v["params"], atol=1e-12, err_msg=str(v))
        if v["schedule"] is None:
            with pytest.raises(ActionError):
                m.schedule(sp, v["output"], 20)
            continue
        s = m.schedule(sp, v["output"], 20)
        assert s.checks == v["schedule"]["checks"], v
        np.testing.assert_allclose(s.dts, v["schedule"]["dts"], rtol=0, atol=1e-15, err_msg=str(v))


def test_observation_vectors_match_the_rust_port():
    vectors = _vectors("observation_vectors.json")
    assert len(vectors) >= 4
    for v in vectors:
        r = LaserResampler(v["layout"], v["angles_rad"])
        got = observation(
            r,
            v["ranges_m"],
            v["laser_clip_m"],
            v["previous_action"],
            v["velocity"],
            v["local_goal"],
            v["goal"],
            v["tracks"],
            v["track_slots"],
        )
        want = np.asarray(v["observation"], dtype=np.float32)
        assert got.dtype == np.float32 and got.shape == want.shape, v["name"]
        np.testing.assert_array_equal(got, want, err_msg=v["name"])


def test_layout_names_are_checked():
    assert layout_size("scan") == 720 and layout_size("sectors:25") == 25
    for bad in ("sectors:0", "sectors:721", "sectors:x", "beams"):
        with pytest.raises(LayoutError, match="is not a laser layout"):
            layout_size(bad)
