"""The episode driver: every planner cycle the MuJoCo world hands its scan, odometry and goal
to the project's runtime (`adp_runtime.Navigator`), whose planner (and policy, if it has one)
returns the (v, w) the wheels then take. No planning happens in Python."""

import math
import os
import tempfile
import time
from typing import Any, Callable, Dict, List, Optional, Tuple

from .errors import SimError
from .sim import JackalSim

PLANNERS = ("dwa", "mppi", "log-mppi", "system")


def runtime_config(planner: str = "dwa", max_speed: float = 1.5, fixed: str = "ddp",
                   policy: Optional[str] = None, seed: int = 0,
                   allow_policy_mismatch: bool = False) -> str:
    """The text of an `adp_runtime` configuration file (runtime/src/config.rs): `planner`
    at `max_speed` under the fixed schedule `fixed` ("ddp" or "vanilla"), or the trained
    `policy` (an `adp export` directory), the evaluation settings embedded in the runtime
    (configs/eval.toml)."""
    if planner not in PLANNERS:
        raise ValueError(f"planner {planner!r}: expected one of {', '.join(PLANNERS)}")
    if fixed not in ("ddp", "vanilla"):
        raise ValueError(f"fixed {fixed!r}: expected 'ddp' or 'vanilla'")
    lines = [f'planner = "{planner}"', f"max_speed = {float(max_speed)!r}", f'fixed = "{fixed}"',
             f"seed = {int(seed)}"]
    if policy is not None:
        lines.append(f"policy = {os.path.abspath(policy)!r}".replace("'", '"'))
    if allow_policy_mismatch:
        lines.append("allow_policy_mismatch = true")
    return "\n".join(lines) + "\n"


def navigator(planner: str = "dwa", max_speed: float = 1.5, fixed: str = "ddp",
              policy: Optional[str] = None, seed: int = 0, allow_policy_mismatch: bool = False):
    """An `adp_runtime.Navigator` for `runtime_config`'s arguments."""
    import adp_runtime

    text = runtime_config(planner, max_speed, fixed, policy, seed, allow_policy_mismatch)
    with tempfile.TemporaryDirectory(prefix="adp-mujoco-") as d:
        path = os.path.join(d, "runtime.toml")
        with open(path, "w", encoding="utf-8") as f:
            f.write(text)
        return adp_runtime.Navigator(path)


def decremental_schedule(p: float = 1.7, horizon: float = 2.0, steps: int = 20, alpha: float = 0.0,
                         boundary_points: int = 20):
    """The ADP decremental family's schedule as (dts, checks): t_i = alpha (i/N) T +
    (1 - alpha) (i/N)^p T, the state after step i checked with round(n (1 - (i/N)^p))
    boundary points (settings/src/schedule.rs `Schedule::decremental`); p = 1.7, T = 2 s,
    N = 20, alpha = 0 is DDP's."""
    t = [alpha * (i / steps) * horizon + (1 - alpha) * (i / steps) ** p * horizon for i in range(steps + 1)]
    dts = [t[i] - t[i - 1] for i in range(1, steps + 1)]
    checks = [int(math.floor(boundary_points * (1 - (i / steps) ** p) + 0.5)) for i in range(1, steps + 1)]
    return dts, checks


def run_episode(world, nav=None, seed: int = 0, max_cycles: Optional[int] = None,
                schedule: Optional[Callable[[JackalSim, int], Tuple[List[float], List[int]]]] = None,
                agent_period: int = 5, **sim_options) -> Dict[str, Any]:
    """Runs one episode of `world` (an id, a JSON file or a world dict) driven by `nav` (a
    fresh `navigator()` per episode when None: DWA with DDP at 1.5 m/s). Returns
    `JackalSim.result()` plus `refused` (cycles whose input the runtime refused: the robot
    stopped), `wall_s` and `physics_steps_per_s`. An episode that cannot be built or fails
    (a SimError) returns status "error" with the message in `error`, so a caller's loop goes
    on with the next one. `max_cycles` abandons the run as a timeout after that many cycles.
    `schedule(sim, agent_step)`, when given, is called every `agent_period` cycles from the
    first and returns the (dts, checks) the planner runs on until the next agent step (a
    training actor's hook: its learner's policy chooses it; `nav` must have no policy of
    its own). `sim_options` go to `JackalSim`."""
    import adp_runtime

    t0 = time.perf_counter()
    try:
        if nav is None:
            nav = navigator()
        sim = JackalSim(world, episode=nav.episode, seed=seed, **sim_options)
    except SimError as e:
        wid = world if isinstance(world, int) else (world.get("id", "?") if isinstance(world, dict) else str(world))
        return {"world": wid, "status": "error", "time_s": 0.0, "sim_time_s": 0.0, "score": 0.0,
                "distance_m": 0.0, "cycles": 0, "error": str(e), "refused": 0,
                "wall_s": time.perf_counter() - t0, "physics_steps_per_s": 0.0}
    refused = 0
    status = sim.status
    try:
        while status == "running":
            if max_cycles is not None and sim.cycles >= max_cycles:
                sim._finish("timed_out")
                break
            if schedule is not None and sim.cycles % agent_period == 0:
                nav.set_schedule(*schedule(sim, sim.cycles // agent_period))
            try:
                out = nav.cycle(**sim.observe())
            except (adp_runtime.RefusedInput, adp_runtime.InternalError):
                refused += 1
                out = adp_runtime.STOP
            status = sim.step(out)
    except SimError:
        pass  # the status is "error", the message in result()["error"]
    wall = time.perf_counter() - t0
    r = sim.result()
    r["refused"] = refused
    r["wall_s"] = wall
    r["physics_steps_per_s"] = sim.cycles * sim.substeps / wall if wall > 0 else 0.0
    return r
