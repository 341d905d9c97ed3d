"""ADP on a robot: a local planner (DWA, MPPI, Log-MPPI or the standalone system) and its
trained schedule policy, driven by the robot's scans, odometry and goal, one control cycle
per call.

    nav = adp_runtime.Navigator("runtime.toml")
    try:
        out = nav.cycle(stamp_s, ranges, (x, y, yaw), (v, w), odom_stamp_s, (gx, gy))
        v, w = out.command        # a stop once out.arrived (within goal_tolerance_m)
    except adp_runtime.RefusedInput as e:
        message, kind = e.args
        v, w = adp_runtime.STOP
    except adp_runtime.InternalError:
        v, w = adp_runtime.STOP

Units are SI; poses, goals and paths are in one fixed frame (the one the robot's
localization reports), yaw counter-clockwise from its x axis; velocities are in the robot's
frame; ranges are in the configured lidar's beam order (increasing angle, centred on the
heading). The command is always inside the configured speed and turn limits. `Sim` runs a
BARN world in place of a robot; `world(id)` hands a world of the project's catalog (obstacles,
start, goal, reference path) to a simulator outside the project, `select_worlds(spec)` names
the worlds of a split, and `Navigator.episode` gives the episode rules and the robot.
"""

from adp_runtime._native import (
    STOP,
    ConfigError,
    CycleOutput,
    InternalError,
    Navigator,
    RefusedInput,
    Sim,
    select_worlds,
    world,
)

__all__ = ["STOP", "ConfigError", "CycleOutput", "InternalError", "Navigator", "RefusedInput", "Sim", "select_worlds", "world"]
