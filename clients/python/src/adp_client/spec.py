"""The run spec's typed settings as the names the rest of the client uses (the Python twin of
actor/src/spec.rs): the planner, the action space, the action map and the laser layout of the
`RunSpec` the learner sends at registration. A value this client does not know is refused with
a `SpecError` naming the field."""

from ._proto import adp_pb2 as pb

MAX_SECTORS = 720

_PLANNERS = {
    pb.PLANNER_DWA: "dwa",
    pb.PLANNER_MPPI: "mppi",
    pb.PLANNER_LOG_MPPI: "log-mppi",
    pb.PLANNER_SYSTEM: "system",
}
_SPACES = {
    pb.ACTION_SPACE_KIND_DECREMENTAL: "decremental",
    pb.ACTION_SPACE_KIND_INCREMENTAL: "incremental",
    pb.ACTION_SPACE_KIND_UNCONSTRAINED: "unconstrained",
    pb.ACTION_SPACE_KIND_FIXED: "fixed",
    pb.ACTION_SPACE_KIND_WEIGHTS: "weights",
    pb.ACTION_SPACE_KIND_DECREMENTAL_WEIGHTS: "decremental+weights",
    pb.ACTION_SPACE_KIND_VELOCITY: "velocity",
}
_MAPS = {pb.ACTION_MAP_DDP_CENTRED: "ddp-centred", pb.ACTION_MAP_AFFINE: "affine"}


class SpecError(ValueError):
    """The learner's run spec holds a value this client does not know (an older client?)."""


def _name(table, field, value):
    if value == 0:
        raise SpecError(f"{field} is unspecified")
    if value not in table:
        raise SpecError(f"{field} = {value} is not a known value")
    return table[value]


def planner_name(value: int, field: str = "spec.planner") -> str:
    """The planner name (dwa, mppi, log-mppi, system) of a `Planner` value."""
    return _name(_PLANNERS, field, value)


def action_space_name(space) -> str:
    """The action space name (`decremental`, `weights:dwa`, ...) of an `ActionSpace` message."""
    kind = _name(_SPACES, "spec.action_space.kind", space.kind)
    if kind in ("weights", "decremental+weights"):
        return f"{kind}:{planner_name(space.gains, 'spec.action_space.gains')}"
    return kind


def action_map_name(env) -> str:
    """The action map name (ddp-centred, affine) of an `EnvConfig` message."""
    return _name(_MAPS, "env.action_map", env.action_map)


def laser_layout(env) -> str:
    """The laser layout (`scan` or `sectors:N`) of an `EnvConfig` message."""
    n = env.laser_sectors
    if n == 0:
        return "scan"
    if n > MAX_SECTORS:
        raise SpecError(f"env.laser_sectors = {n} is out of range: 0 (the scan) or 1..={MAX_SECTORS}")
    return f"sectors:{n}"
