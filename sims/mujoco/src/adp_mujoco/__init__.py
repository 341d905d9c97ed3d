"""The Clearpath Jackal in MuJoCo on the project's BARN worlds, driven by the project's own
planners through `adp_runtime`.

    from adp_mujoco import run_episode, navigator
    nav = navigator("dwa", 1.5, fixed="ddp")     # the runtime's DWA under DDP's schedule
    result = run_episode(3, nav, seed=0)         # BARN world 3 in MuJoCo
    result["status"], result["time_s"], result["score"]

`JackalSim` is the simulator itself (observe / step, as `adp_runtime.Sim`); `SimError` and
its subclasses end one episode with a clear message and leave the caller free to run the
next.
"""

from .episode import decremental_schedule, navigator, run_episode, runtime_config
from .errors import LidarError, PhysicsError, SimError, WorldError
from .jackal import JackalParams, SkidSteer
from .lidar import Lidar
from .sim import DEFAULT_EPISODE, PHYSICS_DT, JackalSim, barn_score
from .world import check_world, load_world, scene_xml

__all__ = [
    "DEFAULT_EPISODE", "PHYSICS_DT", "JackalParams", "JackalSim", "Lidar", "LidarError",
    "PhysicsError", "SimError", "SkidSteer", "WorldError", "barn_score", "check_world",
    "decremental_schedule",
    "load_world", "navigator", "run_episode", "runtime_config", "scene_xml",
]
