"""Action spaces: how a normalized action in [-1, 1]^k becomes a planner's rollout schedule,
its objective gain factors or a velocity command (a Python port of planner/src/action.rs and the
schedule constructors it uses), and the action map that turns a policy's output into that box
action.

A schedule is a list of step lengths `dts` (seconds) and, per step, how many footprint
boundary points are collision-checked (`checks`, at most `n`).

The objective-weight spaces are named with their planner (`weights:dwa`,
`decremental+weights:mppi`): each gain value is a factor in [0, 2] on the planner's configured
weight of that name (1, normalized 0, is the hand-tuned weight). `velocity` outputs the command:
`v_frac` in [0, 1] of the run's speed cap and `w` in [-2, 2] rad/s; it has no schedule.
The shared test vectors in testdata/action_vectors.json pin both ports.
"""

import math
from dataclasses import dataclass
from typing import List

FIXED_HORIZON = 2.0
UNCONSTRAINED_STEPS = 20
_DDP_P = 1.7

VELOCITY_MAX_W = 2.0
FACTOR_RANGE = (0.0, 2.0)
_DECREMENTAL = [("p", 1.0, 1.7), ("T", 1.6, 2.2), ("N", 15.0, 22.0), ("alpha", 0.0, 0.6)]
_DDP_PARAMS = [1.7, 2.0, 20.0, 0.0]

# The objective gains of each planner that has them (planner/src/gains.rs), in factor order.
GAINS = {
    "dwa": ["w_goal", "w_path", "w_obstacle", "w_speed"],
    "mppi": ["w_goal", "w_path", "w_obstacle", "w_heading", "w_smooth"],
    "system": ["goal", "obstacle", "heading", "space"],
}

_RANGES = {
    "decremental": _DECREMENTAL,
    "incremental": _DECREMENTAL,
    "unconstrained": [("dt", 0.02, 0.18)] * UNCONSTRAINED_STEPS,
    "fixed": [("dt", 0.05, 0.2), ("check_density", 0.0, 1.0)],
    "velocity": [("v_frac", 0.0, 1.0), ("w", -VELOCITY_MAX_W, VELOCITY_MAX_W)],
}
for _planner, _names in GAINS.items():
    _g = [(n, FACTOR_RANGE[0], FACTOR_RANGE[1]) for n in _names]
    _RANGES[f"weights:{_planner}"] = _g
    _RANGES[f"decremental+weights:{_planner}"] = _DECREMENTAL + _g


class ActionError(ValueError):
    """An action that cannot be turned into a schedule."""


def _round(x: float) -> float:
    # Rust's f64::round rounds halves away from zero (Python's round() goes to even).
    return math.floor(x + 0.5) if x >= 0 else -math.floor(-x + 0.5)


@dataclass
class Schedule:
    """Step lengths (s) and boundary points checked after each step (of `boundary_points`)."""

    dts: List[float]
    checks: List[int]
    boundary_points: int

    @property
    def horizon(self) -> float:
        """Rollout horizon: the sum of the steps (s)."""
        return sum(self.dts)


def _from_parts(dts, checks, n) -> Schedule:
    if not dts or len(dts) != len(checks):
        raise ActionError("schedule: need one check count per step")
    for d in dts:
        if not d > 0.0:
            raise ActionError(f"schedule: dt = {d} must be > 0")
    return Schedule(list(dts), [min(int(c), n) for c in checks], n)


def _decremental(p, total, steps, alpha, n) -> Schedule:
    if not p > 0 or not total > 0 or steps < 1 or not 0.0 <= alpha <= 1.0:
        raise ActionError(f"schedule: p = {p}, T = {total}, N = {steps}, alpha = {alpha} out of range")

    def t(i):
        f = i / steps
        return alpha * f * total + (1.0 - alpha) * f**p * total

    dts = [t(i) - t(i - 1) for i in range(1, steps + 1)]
    checks = [int(_round(n * (1.0 - (i / steps) ** p))) for i in range(1, steps + 1)]
    return Schedule(dts, checks, n)


class ActionSpace:
    """One of the run's action spaces by name: decremental, incremental, unconstrained, fixed,
    weights:<planner>, decremental+weights:<planner> (planner dwa, mppi or system), velocity."""

    def __init__(self, name: str):
        if name in ("weights", "decremental+weights"):
            raise ActionError(
                f"action space `{name}` sets a planner's objective gains and needs the planner: "
                f"write `{name}:dwa`, `{name}:mppi` or `{name}:system`"
            )
        if name not in _RANGES:
            raise ActionError(
                f"unknown action space `{name}` (expected decremental, incremental, unconstrained, fixed, "
                "weights:<planner>, decremental+weights:<planner> or velocity)"
            )
        self.name = name

    @property
    def gains(self):
        """The names of the planner gains the space sets (empty for the other spaces)."""
        return GAINS[self.name.split(":")[1]] if ":" in self.name else []

    def gain_factors(self, params) -> List[float]:
        """The gain factors among an action's physical parameters (after the schedule's)."""
        return list(params[len(params) - len(self.gains):]) if self.gains else []

    def velocity_command(self, action, max_speed: float):
        """(v, w) of a velocity-space action: v = v_frac * max_speed (m/s), w (rad/s)."""
        if self.name != "velocity":
            raise ActionError(f"velocity action needs 2 values, got {len(action)}")
        q = self.to_params(action)
        return q[0] * max_speed, q[1]

    @property
    def dim(self) -> int:
        """Dimension of the action vector."""
        return len(_RANGES[self.name])

    def ranges(self):
        """Name and physical range (low, high) of each action dimension."""
        return list(_RANGES[self.name])

    def to_params(self, action) -> List[float]:
        """Physical parameters of a normalized action (clamped to [-1, 1] first; N rounded)."""
        ranges = _RANGES[self.name]
        action = [float(a) for a in action]
        if len(action) != len(ranges):
            raise ActionError(f"{self.name} action needs {len(ranges)} values, got {len(action)}")
        out = []
        for i, (a, (name, lo, hi)) in enumerate(zip(action, ranges)):
            if not math.isfinite(a):
                raise ActionError(f"action value {i} ({name}) is {a}: must be finite")
            v = lo + (min(max(a, -1.0), 1.0) + 1.0) * 0.5 * (hi - lo)
            out.append(float(_round(v)) if name == "N" else v)
        return out

    def to_action(self, params) -> List[float]:
        """The normalized action of physical parameters (clamped to their ranges)."""
        return [2.0 * (min(max(v, lo), hi) - lo) / (hi - lo) - 1.0 for v, (_, lo, hi) in zip(params, _RANGES[self.name])]

    def ddp_action(self) -> List[float]:
        """The box action closest to the DDP schedule (p = 1.7, T = 2 s, N = 20, alpha = 0) with
        the hand-tuned gains (factor 1); the box centre for velocity, which has no DDP."""
        if self.name in ("decremental", "incremental"):
            return self.to_action(_DDP_PARAMS)
        if self.name.startswith("weights:"):
            return self.to_action([1.0] * len(self.gains))
        if self.name.startswith("decremental+weights:"):
            return self.to_action(_DDP_PARAMS + [1.0] * len(self.gains))
        if self.name == "velocity":
            return [0.0, 0.0]
        if self.name == "unconstrained":
            ddp = _decremental(1.7, 2.0, 20, 0.0, 20)
            return self.to_action(ddp.dts)
        return self.to_action([0.1, 1.0])

    def schedule(self, action, n: int) -> Schedule:
        """The schedule an action selects, with up to `n` footprint boundary points per check."""
        q = self.to_params(action)
        if self.name == "velocity":
            raise ActionError("the velocity action space outputs the command itself and has no rollout schedule")
        if self.name.startswith("weights:"):
            return _decremental(_DDP_P, FIXED_HORIZON, 20, 0.0, n)
        if self.name == "decremental" or self.name.startswith("decremental+weights:"):
            return _decremental(q[0], q[1], int(q[2]), q[3], n)
        if self.name == "incremental":
            s = _decremental(q[0], q[1], int(q[2]), q[3], n)
            return Schedule(s.dts[::-1], s.checks[::-1], n)
        if self.name == "unconstrained":
            total = sum(q)
            scale = FIXED_HORIZON / total if total > FIXED_HORIZON else 1.0
            dts = [d * scale for d in q]
            horizon = sum(dts)
            t = 0.0
            checks = []
            for d in dts:
                t += d
                checks.append(int(_round(n * (1.0 - (t / horizon) ** _DDP_P))))
            return _from_parts(dts, checks, n)
        steps = int(max(_round(FIXED_HORIZON / q[0]), 1.0))
        c = int(_round(q[1] * n))
        return _from_parts([q[0]] * steps, [c] * steps, n)


ACTION_MAPS = ("ddp-centred", "affine")


class ActionMap:
    """How a policy's output u in [-1, 1]^k becomes the box action that `ActionSpace.schedule`
    reads (planner/src/action.rs `ActionMap`): "affine" is the identity; "ddp-centred" (the
    learner's default) is piecewise affine about DDP, per dimension with d its DDP box value,
    a = d + u (1 - d) for u >= 0 and a = d + u (1 + d) for u < 0, so output 0 is DDP."""

    def __init__(self, name: str = "ddp-centred"):
        if name not in ACTION_MAPS:
            raise ActionError(f"unknown action map `{name}` (expected ddp-centred or affine)")
        self.name = name

    def to_box(self, u: float, ddp: float) -> float:
        """The box value of one output `u` (clamped to [-1, 1]) whose DDP box value is `ddp`."""
        u = float(u)
        if not math.isfinite(u):
            return u
        u = min(max(u, -1.0), 1.0)
        if self.name == "affine":
            return u
        return ddp + u * (1.0 - ddp) if u >= 0.0 else ddp + u * (1.0 + ddp)

    def box_action(self, space: ActionSpace, output) -> List[float]:
        """The box action of a policy output in `space`."""
        output = [float(u) for u in output]
        if len(output) != space.dim:
            raise ActionError(f"{space.name} action needs {space.dim} values, got {len(output)}")
        return [self.to_box(u, d) for u, d in zip(output, space.ddp_action())]

    def schedule(self, space: ActionSpace, output, n: int) -> Schedule:
        """The schedule a policy output selects in `space` (what the Rust environment runs)."""
        return space.schedule(self.box_action(space, output), n)
