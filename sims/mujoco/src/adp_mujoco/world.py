"""A BARN world as a MuJoCo scene: the project's world data (from `adp_runtime.world(id)`,
or a dict or JSON file of the same shape) checked, then written as MJCF with the obstacles
as static geoms and the Jackal at the world's start.

A world dict has `cylinders` [(x, y, r)], `start` (x, y, yaw), `goal` (x, y),
`goal_radius` and `optimal_time_s`; optionally `id`, `walls` [(min_x, min_y, max_x,
max_y)], `moving` (a count; worlds with moving obstacles are refused for now),
`path_length_m` and `reference_path`.
"""

import json
import math
import os
from typing import Any, Dict, Union

from .errors import WorldError
from .jackal import JackalParams, actuators_xml, robot_xml

OBSTACLE_HEIGHT = 1.0
"""Height of every obstacle (m): well above the lidar's plane and the robot."""

OBSTACLE_GROUP = 1
"""MJCF geom group of obstacles: the lidar sees this group only (not the ground, not the
robot)."""


def _finite(name: str, values, n: int):
    try:
        vals = [float(v) for v in values]
    except (TypeError, ValueError):
        raise WorldError(f"field `{name}` = {values!r}: expected {n} numbers") from None
    if len(vals) != n or not all(math.isfinite(v) for v in vals):
        raise WorldError(f"field `{name}` = {values!r}: expected {n} finite numbers")
    return vals


def load_world(source: Union[int, str, os.PathLike, Dict[str, Any]]) -> Dict[str, Any]:
    """A checked world dict from a world id (through `adp_runtime.world`), a JSON file path
    or a dict. Raises WorldError naming the field at fault."""
    if isinstance(source, bool):
        raise WorldError(f"world {source!r}: not a world id, file or dict")
    if isinstance(source, int):
        try:
            import adp_runtime
        except ImportError as e:
            raise WorldError(f"world {source}: adp_runtime is not installed ({e})") from None
        try:
            world = adp_runtime.world(source)
        except ValueError as e:
            raise WorldError(str(e)) from None
    elif isinstance(source, (str, os.PathLike)):
        try:
            with open(source, encoding="utf-8") as f:
                world = json.load(f)
        except OSError as e:
            raise WorldError(f"world file {os.fspath(source)}: {e.strerror or e}") from None
        except json.JSONDecodeError as e:
            raise WorldError(f"world file {os.fspath(source)}: not JSON ({e})") from None
    elif isinstance(source, dict):
        world = source
    else:
        raise WorldError(f"world {source!r}: not a world id, file or dict")
    return check_world(world)


def check_world(world: Any) -> Dict[str, Any]:
    """The world with its fields checked and normalised (floats, tuples)."""
    if not isinstance(world, dict):
        raise WorldError(f"a world is a dict, not {type(world).__name__}")
    for key in ("cylinders", "start", "goal", "goal_radius", "optimal_time_s"):
        if key not in world:
            raise WorldError(f"world {world.get('id', '?')}: missing field `{key}`")
    wid = world.get("id", "?")
    out = dict(world)
    cyl = world["cylinders"]
    if not isinstance(cyl, (list, tuple)):
        raise WorldError(f"world {wid}: field `cylinders` must be a list of (x, y, r)")
    cylinders = []
    for i, c in enumerate(cyl):
        x, y, r = _finite(f"cylinders[{i}]", c, 3)
        if r <= 0:
            raise WorldError(f"world {wid}: field `cylinders[{i}]` has radius {r} <= 0")
        cylinders.append((x, y, r))
    walls = []
    for i, b in enumerate(world.get("walls", [])):
        x0, y0, x1, y1 = _finite(f"walls[{i}]", b, 4)
        if not (x1 > x0 and y1 > y0):
            raise WorldError(f"world {wid}: field `walls[{i}]` = {b!r} is empty (min >= max)")
        walls.append((x0, y0, x1, y1))
    if int(world.get("moving", 0) or 0) > 0:
        raise WorldError(
            f"world {wid}: {world['moving']} moving obstacles; the MuJoCo worlds are static so far")
    out["cylinders"], out["walls"] = cylinders, walls
    out["start"] = tuple(_finite("start", world["start"], 3))
    out["goal"] = tuple(_finite("goal", world["goal"], 2))
    (out["goal_radius"],) = _finite("goal_radius", [world["goal_radius"]], 1)
    (out["optimal_time_s"],) = _finite("optimal_time_s", [world["optimal_time_s"]], 1)
    if out["goal_radius"] <= 0 or out["optimal_time_s"] <= 0:
        raise WorldError(f"world {wid}: `goal_radius` and `optimal_time_s` must be > 0")
    out.setdefault("id", wid)
    return out


def scene_xml(world: Dict[str, Any], params: JackalParams, timestep: float) -> str:
    """The MJCF of `world` (checked) with the Jackal at its start."""
    geoms = []
    h = OBSTACLE_HEIGHT / 2
    common = f'contype="2" conaffinity="2" group="{OBSTACLE_GROUP}" rgba="0.55 0.35 0.2 1"'
    for i, (x, y, r) in enumerate(world["cylinders"]):
        geoms.append(f'    <geom name="cyl{i}" type="cylinder" size="{r!r} {h!r}" pos="{x!r} {y!r} {h!r}" {common}/>')
    for i, (x0, y0, x1, y1) in enumerate(world["walls"]):
        geoms.append(
            f'    <geom name="wall{i}" type="box" size="{(x1 - x0) / 2!r} {(y1 - y0) / 2!r} {h!r}" '
            f'pos="{(x0 + x1) / 2!r} {(y0 + y1) / 2!r} {h!r}" {common}/>')
    f = params.wheel_friction
    return f"""<mujoco model="jackal-barn-{world['id']}">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{timestep!r}" integrator="implicitfast"/>
  <worldbody>
    <geom name="ground" type="plane" size="0 0 0.05" contype="1" conaffinity="1" condim="3"
          friction="{f!r} 0.005 0.0001" group="2" rgba="0.8 0.8 0.8 1"/>
{chr(10).join(geoms)}
{robot_xml(params, world["start"])}
  </worldbody>
  <actuator>
{actuators_xml(params)}
  </actuator>
</mujoco>
"""
