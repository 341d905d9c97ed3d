"""The Jackal in MuJoCo as an `adp_client.Environment`: a MuJoCo actor that joins an
`adp learner` run (`adp_client.Actor(address, MujocoEnvironment()).run()`).

Each agent step maps the learner's action through the run's action map and space to a
schedule (`RunInfo.schedule`, what the Rust actors run), gives it to the runtime
(`Navigator.set_schedule`) and runs the run's `agent_period_cycles` planner cycles in MuJoCo,
stopping when the episode ends. The observation is the project's (`adp_client.observation`:
laser segment, previous action, measured v and w, local goal and goal in the robot frame) from
the MuJoCo scan and odometry and the runtime's local goal. The reward follows
`actor::env::AdpEnv::step` with the run's `[env]` settings: progress towards the goal times
`progress_scale`, `step_penalty`, the obstacle penalty of the footprint's clearance to the
lidar returns, `collision_reward` alone on a collision, `success_reward` added on success,
`timeout_reward` added on a timeout or the agent step cap, all times `reward_scale`.

Differences from the Rust actors: the first observation of an episode needs the runtime's
local goal, so `reset` runs one planning cycle whose command is not issued; the stuck term
(`stuck_window`) and domain randomization (`[env.randomize]`) are not applied; schedule
spaces only (not the velocity or objective-weight spaces). A world the model cannot be built
from, a lidar failure or a diverged physics state end the episode as a timeout with the error
in `info["error"]`, so the actor keeps serving.
"""

import math
from typing import Any, Dict, Optional

import numpy as np

import adp_client
from adp_client.observation import LaserResampler, observation

from .episode import navigator
from .errors import SimError
from .jackal import JackalParams
from .sim import JackalSim

OBSTACLE_BEAMS = 10
"""How many of the smallest clearances the obstacle term averages (actor/src/reward.rs)."""

OUTCOMES = {"succeeded": "success", "collided": "collision", "timed_out": "timeout", "error": "timeout"}


def footprint_clearance(ranges: np.ndarray, angles: np.ndarray, max_range: float,
                        half_length: float, half_width: float) -> float:
    """The mean of the 10 smallest distances from the footprint's boundary to the lidar
    returns (0 for a return inside it; infinity without returns), as
    `actor::reward::footprint_clearance`."""
    hit = ranges < max_range
    if not hit.any():
        return math.inf
    x, y = ranges[hit] * np.cos(angles[hit]), ranges[hit] * np.sin(angles[hit])
    d = np.hypot(np.maximum(np.abs(x) - half_length, 0.0), np.maximum(np.abs(y) - half_width, 0.0))
    return float(np.sort(d)[:OBSTACLE_BEAMS].mean())


def obstacle_penalty(clearance: float, threshold: float, scale: float) -> float:
    """`scale * (1 - d / threshold)^2` below the threshold, else 0 (actor/src/reward.rs)."""
    return scale * (1.0 - clearance / threshold) ** 2 if clearance < threshold else 0.0


def _to_robot(p, pose):
    x, y, yaw = pose
    dx, dy = p[0] - x, p[1] - y
    c, s = math.cos(yaw), math.sin(yaw)
    return (c * dx + s * dy, -s * dx + c * dy)


class MujocoEnvironment(adp_client.Environment):
    """A MuJoCo Jackal for a training run (see the module docs). `params` and `sim_options`
    go to `JackalSim` (e.g. `JackalParams(track_multiplier=3.0)`)."""

    def __init__(self, params: JackalParams = JackalParams(), **sim_options):
        self.params = params
        self.sim_options = sim_options
        self.info = None
        self.sim: Optional[JackalSim] = None
        self.errors = 0

    def configure(self, info) -> None:
        if info.action_space.gains or info.action_space.name == "velocity":
            raise adp_client.ConfigError(
                f"action space {info.action_space.name}: the MuJoCo actor runs schedule spaces only")
        if info.env.observe_tracks:
            raise adp_client.ConfigError("the MuJoCo worlds have no moving obstacles to track")
        self.info = info
        self.env = info.env
        self.period = max(1, int(info.env.agent_period_cycles))

    def reset(self, world: int, seed: int):
        info = self.info
        self.nav = navigator(info.planner, info.max_speed, fixed="ddp", seed=seed & 0xFFFF_FFFF)
        self.previous = np.zeros(info.act_dim, dtype=np.float32)
        self.steps = 0
        self.error = None
        ep = self.nav.episode
        self.footprint = (ep["footprint"]["half_length"], ep["footprint"]["half_width"])
        try:
            self.sim = JackalSim(world, episode=ep, seed=seed & 0xFFFF_FFFF, params=self.params, **self.sim_options)
        except SimError as e:
            # An episode that cannot start (a world the model cannot be built from, a lidar
            # that fails at once): an observation of zeros, and the first step ends it.
            self.sim, self.error = None, str(e)
            self.errors += 1
            return np.zeros(info.obs_dim, dtype=np.float32)
        self.laser = LaserResampler(info.laser_layout, self.sim.lidar.angles)
        try:
            self.nav.cycle(**self.sim.observe())  # the local goal of the first observation
        except ValueError:
            pass  # refused: the observation takes the goal for the local goal
        self.distance = self._goal_distance()
        return self._observation()

    def _goal_distance(self) -> float:
        x, y, _ = self.sim.true_pose()
        gx, gy = self.sim.world["goal"]
        return math.hypot(gx - x, gy - y)

    def _observation(self) -> np.ndarray:
        sim = self.sim
        pose = tuple(sim.odom_pose)
        local = self.nav.local_goal or tuple(sim.world["goal"])
        return observation(self.laser, sim.ranges, self.env.laser_clip_m, self.previous, sim.odom_vel,
                           _to_robot(local, pose), _to_robot(sim.world["goal"], pose))

    def step(self, action):
        import adp_runtime

        info, env = self.info, self.env
        action = np.clip(np.asarray(action, dtype=np.float32), -1.0, 1.0)
        if self.sim is None:
            return (np.zeros(info.obs_dim, dtype=np.float32), 0.0, False, True,
                    {"outcome": "timeout", "time_s": 0.0, "score": 0.0, "error": self.error})
        schedule = info.schedule(action.tolist(), 20)
        self.nav.set_schedule(schedule.dts, schedule.checks, schedule.boundary_points)
        status = self.sim.status
        try:
            for _ in range(self.period):
                try:
                    out = self.nav.cycle(**self.sim.observe())
                except (adp_runtime.RefusedInput, adp_runtime.InternalError):
                    out = adp_runtime.STOP
                status = self.sim.step(out)
                if status != "running":
                    break
        except SimError as e:
            status, self.error = "error", str(e)
            self.errors += 1
        self.previous = action
        self.steps += 1
        distance = self._goal_distance()
        progress, self.distance = self.distance - distance, distance

        def shaping():
            lidar = self.sim.lidar
            clearance = footprint_clearance(self.sim.ranges, lidar.angles, lidar.max_range, *self.footprint)
            return (env.progress_scale * progress + env.step_penalty
                    + obstacle_penalty(clearance, env.obstacle_threshold_m, env.obstacle_scale))

        terminal = truncated = False
        if status == "collided":
            reward, terminal = env.collision_reward, True
        elif status == "succeeded":
            reward, terminal = shaping() + env.success_reward, True
        elif status in ("timed_out", "error") or 0 < env.max_agent_steps <= self.steps:
            reward, truncated = (shaping() if status != "error" else 0.0) + env.timeout_reward, True
            if status == "running":
                self.sim._finish("timed_out")
        else:
            reward = shaping()
        reward *= env.reward_scale
        infos: Dict[str, Any] = {}
        if terminal or truncated:
            r = self.sim.result()
            infos = {"outcome": OUTCOMES[r["status"]], "time_s": r["time_s"], "score": r["score"]}
            if self.error:
                infos["error"] = self.error
        obs = self._observation() if status != "error" else np.zeros(info.obs_dim, dtype=np.float32)
        return obs, float(reward), terminal, truncated, infos
