"""Step and turn responses of the MuJoCo Jackal beside the project's simulator.

`mujoco_response(params, v, w)` drives the MuJoCo Jackal on flat open ground with the
constant command (v, w) from rest and records its true forward speed and yaw rate every
control period. `project_response(v, w)` does the same in the project's simulator through
the runtime's `adp_runtime.Sim` (a BARN world under the default `gazebo-jackal` dynamics
profile; its `observe()["vel"]` is the robot's true velocity). `steady_yaw` averages the yaw
rate over the last second of a 2 s command. `adp-mujoco calibrate` prints the tables and
draws the figure (matplotlib, only for the figure).

The project's simulator only runs BARN worlds, whose obstacles are close to the start: a
trial there runs in the first world of the catalog where it does not collide within its
duration (the dynamics do not depend on the world); a trial that collides in every world
is reported as missing, not guessed.
"""

import math
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from .jackal import JackalParams
from .sim import JackalSim

CONTROL_DT = 0.05
"""The planner cycle (s): both simulators take one command per 50 ms."""

TRIAL_S = 1.6
"""How long each constant command runs (s): long enough for both simulators to settle
(gazebo-jackal reaches 1.5 m/s in about 0.9 s), short enough that the project's simulator
finds a BARN world where the arc does not collide."""

STEADY_FROM_S = 1.0
"""The steady yaw rate is the mean over [STEADY_FROM_S, TRIAL_S]."""

PROJECT_LATENCY_S = 0.075
"""`gazebo-jackal`'s command latency (settings/src/dynamics.rs, `latency_s`), which the
project's `Sim.drive` applies in full; the MuJoCo trials use the same, so both curves start
at the same time."""

# The commands of the turn table: the planners' speeds (DWA and MPPI run at 1.0 to 2.0 m/s
# top speed and command anything from 0 up to it) and yaw rates up to 2 rad/s.
TURN_V = (0.0, 0.5, 1.0, 1.5)
TURN_W = (0.25, 0.5, 1.0, 1.5, 2.0)


def _open_world(heading: float = 0.0) -> Dict:
    return {"id": "calibration", "cylinders": [], "walls": [], "start": (0.0, 0.0, heading),
            "goal": (1.0e4, 1.0e4), "goal_radius": 0.1, "optimal_time_s": 1.0}


def mujoco_response(params: JackalParams, v: float, w: float, duration: float = TRIAL_S,
                    latency_s: float = PROJECT_LATENCY_S, seed: int = 0) -> Dict[str, np.ndarray]:
    """The MuJoCo Jackal's true forward speed and yaw rate every control period after the
    command (v, w) is issued from rest: arrays `t`, `v`, `w`."""
    sim = JackalSim(_open_world(), seed=seed, params=params, command_latency_s=latency_s)
    free = sim._free_v
    ts, vs, ws = [0.0], [0.0], [0.0]
    for k in range(int(round(duration / CONTROL_DT))):
        sim.step((v, w) if k == 0 else _Hold())
        q = sim.data.qpos[sim._free_q + 3:sim._free_q + 7]
        yaw = math.atan2(2 * (q[0] * q[3] + q[1] * q[2]), 1 - 2 * (q[2] ** 2 + q[3] ** 2))
        vx, vy = sim.data.qvel[free], sim.data.qvel[free + 1]
        ts.append((k + 1) * CONTROL_DT)
        vs.append(float(vx * math.cos(yaw) + vy * math.sin(yaw)))
        ws.append(float(sim.data.qvel[free + 5]))
    return {"t": np.array(ts), "v": np.array(vs), "w": np.array(ws)}


class _Hold:
    """A cycle that did not plan: the base keeps its command."""
    command = (0.0, 0.0)
    planned = False
    compute_s = None


def project_response(v: float, w: float, duration: float = TRIAL_S,
                     worlds: Sequence[int] = range(300)) -> Optional[Dict[str, np.ndarray]]:
    """The project's simulator (default `gazebo-jackal` profile) under the same command,
    through `adp_runtime.Sim.drive` (the command every control period, the profile's full
    latency); None if it collides within `duration` in every world tried."""
    import adp_runtime

    from .episode import navigator

    # The runtime's embedded evaluation settings (configs/eval.toml): profile "gazebo-jackal".
    nav = navigator("dwa", 1.5, fixed="ddp")
    for world in worlds:
        sim = adp_runtime.Sim(nav, world, 0)
        ts, vs, ws = [0.0], [0.0], [0.0]
        ok = True
        for k in range(int(round(duration / CONTROL_DT))):
            status = sim.drive((v, w))
            if status != "running":
                ok = False
                break
            vel = sim.observe()["vel"]
            ts.append((k + 1) * CONTROL_DT)
            vs.append(float(vel[0]))
            ws.append(float(vel[1]))
        if ok:
            return {"t": np.array(ts), "v": np.array(vs), "w": np.array(ws), "world": world}
    return None


def steady_yaw(r: Optional[Dict[str, np.ndarray]]) -> float:
    if r is None:
        return float("nan")
    sel = r["t"] > STEADY_FROM_S + 1e-9
    return float(np.mean(r["w"][sel]))


def steady_speed(r: Optional[Dict[str, np.ndarray]]) -> float:
    """The mean forward speed over the same window as `steady_yaw`."""
    if r is None:
        return float("nan")
    sel = r["t"] > STEADY_FROM_S + 1e-9
    return float(np.mean(r["v"][sel]))


def turn_table(params: JackalParams, vs=TURN_V, ws=TURN_W, speeds: Optional[list] = None
               ) -> List[Tuple[float, float, float]]:
    """(v, w, steady yaw rate) of the MuJoCo Jackal for every command of the grid; with
    `speeds` a list, (v, w, steady forward speed) are appended to it."""
    rows = []
    for v in vs:
        for w in ws:
            r = mujoco_response(params, v, w)
            rows.append((v, w, steady_yaw(r)))
            if speeds is not None:
                speeds.append((v, w, steady_speed(r)))
    return rows


def project_turn_table(vs=TURN_V, ws=TURN_W, speeds: Optional[list] = None
                       ) -> List[Tuple[float, float, float]]:
    rows = []
    for v in vs:
        for w in ws:
            r = project_response(v, w)
            rows.append((v, w, steady_yaw(r)))
            if speeds is not None:
                speeds.append((v, w, steady_speed(r)))
    return rows


def _print_table(title: str, rows) -> None:
    print(title)
    ws = sorted({w for _, w, _ in rows})
    print("  v \\ w  " + " ".join(f"{w:>6.2f}" for w in ws))
    for v in sorted({v for v, _, _ in rows}):
        cells = {w: y for vv, w, y in rows if vv == v}
        print(f"  {v:5.2f}  " + " ".join(f"{cells[w]:6.3f}" for w in ws))


def _t90(r: Optional[Dict[str, np.ndarray]], v: float) -> float:
    """The first sample time at which the forward speed reaches 90 % of `v`."""
    if r is None or not np.any(r["v"] >= 0.9 * v):
        return float("nan")
    return float(r["t"][np.argmax(r["v"] >= 0.9 * v)])


def run(out: Optional[str] = None) -> Dict[str, List]:
    """Prints the steady yaw rates of the published and calibrated MuJoCo bases and of the
    project's simulator over the grid, and draws the figure into `out` (a PNG)."""
    bases = {"MuJoCo, published (multiplier 1.5)": JackalParams.published(),
             "MuJoCo, calibrated (gyro PI loop)": JackalParams.calibrated()}
    speeds = {name: [] for name in bases}
    tables = {name: turn_table(p, speeds=speeds[name]) for name, p in bases.items()}
    name = "project's simulator (gazebo-jackal)"
    speeds[name] = []
    tables[name] = project_turn_table(speeds=speeds[name])
    for name, rows in tables.items():
        _print_table(f"steady yaw rate (rad/s), {name}", rows)
    for name, rows in speeds.items():
        _print_table(f"steady forward speed (m/s), {name}", rows)
    for name, p in bases.items():
        r = mujoco_response(p, 1.0, 0.0)
        print(f"step to 1.0 m/s, {name}: 90 % at {_t90(r, 1.0):.2f} s after the command")
    r = project_response(1.0, 0.0)
    print(f"step to 1.0 m/s, project's simulator (gazebo-jackal): 90 % at {_t90(r, 1.0):.2f} s "
          f"after the command (world {r['world'] if r else None})")
    if out:
        _figure(bases, tables, out)
    return tables


def _figure(bases, tables, out: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 2, figsize=(11, 8))
    styles = {"MuJoCo, published (multiplier 1.5)": ("tab:red", "--"),
              "MuJoCo, calibrated (gyro PI loop)": ("tab:blue", "-"),
              "project's simulator (gazebo-jackal)": ("black", ":")}
    # (a) step response in v.
    a = ax[0][0]
    for cmd in (1.0, 1.5):
        for name, p in bases.items():
            r = mujoco_response(p, cmd, 0.0)
            c, ls = styles[name]
            a.plot(r["t"], r["v"], color=c, ls=ls, label=name if cmd == 1.0 else None)
        r = project_response(cmd, 0.0)
        if r is not None:
            c, ls = styles["project's simulator (gazebo-jackal)"]
            a.plot(r["t"], r["v"], color=c, ls=ls, label="project's simulator (gazebo-jackal)" if cmd == 1.0 else None)
        a.axhline(cmd, color="grey", lw=0.5)
    a.set_xlabel("time after the command (s)")
    a.set_ylabel("forward speed (m/s)")
    a.set_title("(a) step in v to 1.0 and 1.5 m/s (w = 0)")
    a.legend(fontsize=8)
    # (b) yaw rate over time for (1.5, 1.0).
    a = ax[0][1]
    for name, p in bases.items():
        r = mujoco_response(p, 1.5, 1.0)
        c, ls = styles[name]
        a.plot(r["t"], r["w"], color=c, ls=ls, label=name)
    r = project_response(1.5, 1.0)
    if r is not None:
        c, ls = styles["project's simulator (gazebo-jackal)"]
        a.plot(r["t"], r["w"], color=c, ls=ls, label="project's simulator (gazebo-jackal)")
    a.axhline(1.0, color="grey", lw=0.5)
    a.set_xlabel("time after the command (s)")
    a.set_ylabel("yaw rate (rad/s)")
    a.set_title("(b) yaw rate after the command (1.5 m/s, 1.0 rad/s)")
    a.legend(fontsize=8)
    # (c), (d) steady yaw rate against the commanded one at v = 1.0 and 1.5 m/s.
    for a, v in ((ax[1][0], 1.0), (ax[1][1], 1.5)):
        for name, rows in tables.items():
            pts = sorted((w, y) for vv, w, y in rows if vv == v)
            c, ls = styles[name]
            a.plot([w for w, _ in pts], [y for _, y in pts], color=c, ls=ls, marker="o", label=name)
        a.plot([0, 2], [0, 2], color="grey", lw=0.5, label="commanded (unicycle)")
        a.set_xlabel("commanded yaw rate (rad/s)")
        a.set_ylabel("steady yaw rate (rad/s)")
        a.set_title(f"({'c' if v == 1.0 else 'd'}) turn response at v = {v} m/s")
        a.legend(fontsize=8)
    fig.suptitle("The MuJoCo Jackal's step and turn responses beside the project's gazebo-jackal profile")
    fig.tight_layout()
    fig.savefig(out, dpi=110)


def command_usage(planners=("dwa", "mppi"), stride: int = 15, max_speed: float = 1.5) -> None:
    """Prints which (v, w) the planners command: the runtime's planners under DDP's schedule
    on every `stride`-th test world with the calibrated base, the quantiles of |w|, v and
    v |w| over the planned commands (the range the calibration has to cover)."""
    import adp_runtime

    from .episode import navigator, run_episode

    ids = adp_runtime.select_worlds("test")[::stride]
    for planner in planners:
        nav = navigator(planner, max_speed, fixed="ddp")
        cmds = []

        class Recorder:
            episode = nav.episode

            def __getattr__(self, name):
                return getattr(nav, name)

            def cycle(self, **kw):
                out = nav.cycle(**kw)
                if out.planned:
                    cmds.append(out.command)
                return out

        for world in ids:
            run_episode(world, Recorder(), seed=0, params=JackalParams.calibrated())
        c = np.array(cmds)
        v, w = c[:, 0], np.abs(c[:, 1])
        print(f"{planner} at {max_speed} m/s, DDP, {len(c)} planned commands on {len(ids)} test worlds "
              f"(every {stride}th)")
        print(f"  |w| quantiles 50/90/99 %: {np.round(np.quantile(w, [.5, .9, .99]), 2)}, "
              f"share |w| > 1: {np.mean(w > 1):.3f}, > 2: {np.mean(w > 2):.3f}")
        print(f"  v quantiles 10/50/90 %: {np.round(np.quantile(v, [.1, .5, .9]), 2)}")
        print(f"  v |w| quantiles 50/90/99 %: {np.round(np.quantile(v * w, [.5, .9, .99]), 2)}, "
              f"share v |w| > 1: {np.mean(v * w > 1):.3f}")
