"""Shared worlds for the tests: small hand-made worlds in the world-dict format, so physics
and sensing are checked against geometry worked out by hand."""

import os

import mujoco
import pytest

# MuJoCo's default warning handler prints and appends to MUJOCO_LOG.TXT in the working
# directory (the repository root under CI); the package reports what matters as PhysicsError.
WARNINGS = []
mujoco.set_mju_user_warning(WARNINGS.append)

if os.environ.get("ADP_REQUIRE_RUNTIME") == "1":
    # CI: the tests that drive episodes with the runtime must run, not skip.
    import adp_runtime  # noqa: F401


def open_world(goal=(6.0, 0.0), cylinders=(), walls=(), start=(0.0, 0.0, 0.0)):
    return {
        "id": "test",
        "cylinders": list(cylinders),
        "walls": list(walls),
        "start": start,
        "goal": goal,
        "goal_radius": 1.0,
        "optimal_time_s": 3.0,
    }


@pytest.fixture
def empty():
    return open_world()
