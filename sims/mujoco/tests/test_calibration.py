"""The calibrated base (issue 73 item 5): the Jackal controller plus a PI loop on the gyro's
yaw rate turns the MuJoCo robot at the commanded rate over the commands the planners use;
the published controller (multiplier 1.5, no loop) under-turns; the project's simulator is
measured, not assumed, through the runtime."""

import pytest

from adp_mujoco import JackalParams, SkidSteer
from adp_mujoco.calibrate import TURN_V, TURN_W, mujoco_response, project_response, steady_speed, steady_yaw
from adp_mujoco.cli import _params, main
from adp_mujoco.jackal import CALIBRATED_YAW_LOOP, base_params

# The stated tolerance: the steady yaw rate (mean over 1.0 to 1.6 s after the command) is
# within 8 % of the commanded one, or 0.02 rad/s for the slowest turns.
TOLERANCE = 0.08


def close(achieved, commanded):
    return abs(achieved - commanded) <= max(TOLERANCE * abs(commanded), 0.02)


@pytest.mark.parametrize("v", TURN_V)
def test_the_calibrated_base_turns_at_the_commanded_rate(v):
    p = JackalParams.calibrated()
    for w in TURN_W:
        got = steady_yaw(mujoco_response(p, v, w))
        assert close(got, w), f"command ({v}, {w}): yaw rate {got:.3f} rad/s"


def test_the_calibrated_base_turns_right_as_it_turns_left():
    p = JackalParams.calibrated()
    for v, w in ((1.0, -1.0), (1.5, -0.5), (0.0, -2.0)):
        got = steady_yaw(mujoco_response(p, v, w))
        assert close(got, w), f"command ({v}, {w}): yaw rate {got:.3f} rad/s"


def test_the_calibrated_base_keeps_the_commanded_speed_in_gentle_turns():
    # Where the tyres allow it (|v w| up to 0.5): the loop does not cost forward speed.
    p = JackalParams.calibrated()
    for v, w in ((1.0, 0.0), (1.5, 0.0), (1.0, 0.5), (1.5, 0.25)):
        assert steady_speed(mujoco_response(p, v, w)) == pytest.approx(v, rel=0.03)


def test_the_published_base_under_turns():
    # The finding the calibration corrects: well under half the commanded rate at 1 rad/s.
    p = JackalParams.published()
    for v in (0.0, 1.0, 1.5):
        assert steady_yaw(mujoco_response(p, v, 1.0)) < 0.5


def test_the_default_is_the_calibrated_base_and_the_published_one_is_named():
    assert JackalParams() == JackalParams.calibrated()
    assert {k: getattr(JackalParams(), k) for k in CALIBRATED_YAW_LOOP} == CALIBRATED_YAW_LOOP
    pub = base_params("published")
    assert (pub.track_multiplier, pub.yaw_kp, pub.yaw_ki) == (1.5, 0.0, 0.0)
    with pytest.raises(ValueError):
        base_params("gazebo")
    assert base_params("calibrated-slip").yaw_slip == (0.08, 0.06, 0.4)
    assert JackalParams().yaw_slip == (0.0, 0.0, 0.0)


def test_the_cli_names_the_base():
    class Args:
        base, track_multiplier = "published", None
    assert _params(Args()) == JackalParams.published()
    Args.base, Args.track_multiplier = "calibrated", 3.0
    assert _params(Args()) == JackalParams.calibrated(track_multiplier=3.0)
    with pytest.raises(SystemExit):
        main(["eval", "--base", "neither"])


def test_the_yaw_loop_acts_on_the_gyro_and_only_with_gains():
    # Open loop (no reading, or zero gains): the published mapping. With a reading short of
    # the command, the proportional and integral terms widen the wheels' difference.
    for p, reading in ((JackalParams.calibrated(), None), (JackalParams.published(), 0.0)):
        c = SkidSteer(p)
        c.command(0.0, 1.0)
        left, _, right, _ = c.step(1.0, reading)
        assert right == pytest.approx(p.effective_track / 2 / p.wheel_radius)
    p = JackalParams.calibrated()
    c = SkidSteer(p)
    c.command(0.0, 1.0)
    _, _, right, _ = c.step(1.0, 0.5)
    turn = 1.0 + p.yaw_kp * 0.5 + min(p.yaw_ki * 0.5 * 1.0, p.yaw_i_max)
    assert right == pytest.approx(turn * p.effective_track / 2 / p.wheel_radius)


def test_the_project_simulator_is_measured_through_the_runtime():
    pytest.importorskip("adp_runtime")
    # gazebo-jackal (settings/src/dynamics.rs): the yaw rate is the wheels' times
    # 1 - min(0.08 |v| + 0.06 |w|, 0.4) once the lag and the accelerations have settled.
    for v, w in ((0.0, 1.0), (1.0, 1.0), (1.5, 0.5)):
        r = project_response(v, w)
        assert r is not None
        assert steady_yaw(r) == pytest.approx(w * (1 - min(0.08 * v + 0.06 * w, 0.4)), rel=1e-3)
        assert steady_speed(r) == pytest.approx(v, abs=1e-3)


def test_the_slip_base_turns_as_the_project_simulator_does():
    # `calibrated-slip` (an experiment): the loop's reference is gazebo-jackal's slipped yaw
    # rate, w (1 - min(0.08 |v| + 0.06 |w|, 0.4)); same tolerance.
    p = base_params("calibrated-slip")
    for v, w in ((0.0, 1.0), (1.0, 1.0), (1.5, 0.5), (1.5, 1.0)):
        want = w * (1 - min(0.08 * v + 0.06 * w, 0.4))
        got = steady_yaw(mujoco_response(p, v, w))
        assert close(got, want), f"command ({v}, {w}): yaw rate {got:.3f}, profile {want:.3f}"
