"""One BARN episode of the Jackal in MuJoCo, by the project's episode rules
(`sim::episode`): the run clock starts once the robot is `clock_start_distance` from its
start; the run succeeds when the robot's centre is within the world's `goal_radius` of the
goal, collides when its footprint touches an obstacle, and times out when the run clock
reaches `timeout_s`; all three are checked after every physics step. Score: the BARN score,
success x OT / clip(AT, 2 OT, 8 OT).

The robot senses what a real one does: a lidar scan (`lidar.Lidar`) and odometry integrated
from its wheel encoders (so it drifts when the wheels slip), with the yaw rate from a gyro as
the Jackal's EKF takes it (`odometry="wheels+gyro"`, default) or from the wheels alone
(`odometry="wheels"`).
"""

import math
from collections import deque
from typing import Any, Dict, Optional, Tuple

import mujoco
import numpy as np

from .errors import PhysicsError, SimError, WorldError
from .jackal import WHEELS, JackalParams, SkidSteer
from .lidar import Lidar
from .world import load_world, scene_xml

DEFAULT_EPISODE: Dict[str, Any] = {
    "control_dt": 0.05,
    "timeout_s": 100.0,
    "clock_start_distance": 0.1,
    "lidar": {"beams": 720, "fov_deg": 270.0, "min_range": 0.1, "max_range": 30.0,
              "noise_sigma": 0.001, "noise_fraction": 0.0, "dropout": 0.0},
}
"""The project's episode defaults (configs/eval.toml's [episode]); `adp_runtime.Navigator`'s
`episode` gives the ones a navigator was configured with, and the driver uses those."""

PHYSICS_DT = 0.002
"""MuJoCo's step (s): 25 steps per 50 ms planner cycle."""

COMMAND_LATENCY_S = 0.05
"""Delay from the end of a planning cycle to the wheels taking its command (s), before the
cycle's modelled compute: the sense-to-act pipeline outside planning that the project's
gazebo-jackal profile also assumes (its 0.075 s latency less its 0.025 s planning share)."""

GYRO_NOISE = 0.005
"""Gaussian noise of the gyro's yaw rate (rad/s): the Jackal's Gazebo IMU plugin
(jackal_description/urdf/jackal.gazebo, rateGaussianNoise 0.005)."""

_DIVERGED = [int(w) for w in (mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL,
                                mujoco.mjtWarning.mjWARN_BADQACC)]
"""MuJoCo's warnings for a diverged state: it resets the state when it raises one."""


def barn_score(success: bool, optimal_time: float, actual_time: float) -> float:
    """BARN score: success x OT / clip(AT, 2 OT, 8 OT) (`sim::score::barn_score`)."""
    if not success:
        return 0.0
    return optimal_time / min(max(actual_time, 2.0 * optimal_time), 8.0 * optimal_time)


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


class JackalSim:
    """A Jackal in a BARN world, one control period per `step`.

    `world`: a world id (through `adp_runtime.world`), a JSON file or a world dict
    (`world.load_world`). `episode`: the rules and the lidar (`DEFAULT_EPISODE`'s keys, e.g.
    `Navigator.episode`). Raises WorldError when the world cannot be built, LidarError and
    PhysicsError from `step` when the sensor or the physics fail; after either the episode has
    status "error" and the next episode is a new JackalSim.
    """

    def __init__(self, world, episode: Optional[Dict[str, Any]] = None, seed: int = 0,
                 params: JackalParams = JackalParams(), physics_dt: float = PHYSICS_DT,
                 odometry: str = "wheels+gyro", command_latency_s: float = COMMAND_LATENCY_S):
        self.world = load_world(world)
        ep = dict(DEFAULT_EPISODE)
        ep.update(episode or {})
        self.control_dt = float(ep["control_dt"])
        self.timeout_s = float(ep["timeout_s"])
        self.clock_start_distance = float(ep["clock_start_distance"])
        if not (0 < physics_dt <= PHYSICS_DT):
            raise SimError(f"physics_dt = {physics_dt}: must be in (0, {PHYSICS_DT}] s")
        self.substeps = max(1, round(self.control_dt / physics_dt))
        if odometry not in ("wheels+gyro", "wheels"):
            raise SimError(f"odometry = {odometry!r}: expected 'wheels+gyro' or 'wheels'")
        self.odometry = odometry
        self.params = params
        self.command_latency_s = float(command_latency_s)
        xml = scene_xml(self.world, params, self.control_dt / self.substeps)
        try:
            self.model = mujoco.MjModel.from_xml_string(xml)
        except ValueError as e:
            raise WorldError(f"world {self.world['id']}: MuJoCo cannot build the model: {e}") from None
        self.data = mujoco.MjData(self.model)
        m = self.model
        self._footprint = m.geom("footprint").id
        self._free_q = m.jnt_qposadr[m.joint("jackal").id]
        self._free_v = m.jnt_dofadr[m.joint("jackal").id]
        self._wheel_v = np.array([m.jnt_dofadr[m.joint(f"{w}_wheel").id] for w in WHEELS])
        self._act = np.array([m.actuator(w).id for w in WHEELS])
        self.controller = SkidSteer(params)
        self.lidar = Lidar(m, ep["lidar"], seed)
        self._gyro_rng = np.random.default_rng(seed ^ 0x6779_726F)
        self._gyro = 0.0
        mujoco.mj_forward(m, self.data)
        if self._touching():
            raise WorldError(f"world {self.world['id']}: the robot's start {self.world['start']} is inside an obstacle")
        self._diverged = [self.data.warning[w].number for w in _DIVERGED]
        x, y, yaw = self.world["start"]
        self.start = (x, y)
        self.odom_pose = [x, y, yaw]
        self.odom_vel = (0.0, 0.0)
        self.status = "running"
        self.error: Optional[str] = None
        self.clock_start: Optional[float] = None
        self.end_time = 0.0
        self.distance = 0.0
        self.cycles = 0
        self._pending: deque = deque()
        self.ranges = self.lidar.scan(self.data)

    # -- state -----------------------------------------------------------------------
    @property
    def time(self) -> float:
        """Simulated time since the start (s)."""
        return float(self.data.time)

    def true_pose(self) -> Tuple[float, float, float]:
        """The chassis' true (x, y, yaw) in the world frame."""
        q = self.data.qpos[self._free_q:self._free_q + 7]
        w, qx, qy, qz = q[3:7]
        yaw = math.atan2(2 * (w * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz))
        return float(q[0]), float(q[1]), yaw

    def true_velocity(self) -> Tuple[float, float]:
        """The chassis' true forward speed (m/s) and yaw rate (rad/s)."""
        v = self.data.qvel[self._free_v:self._free_v + 6]
        _, _, yaw = self.true_pose()
        return float(v[0] * math.cos(yaw) + v[1] * math.sin(yaw)), float(v[5])

    def run_time(self) -> float:
        """The run clock (s): since the robot first moved clock_start_distance from its start."""
        return self.time - (self.clock_start if self.clock_start is not None else 0.0)

    # -- the robot's inputs ------------------------------------------------------------
    def observe(self) -> Dict[str, Any]:
        """The robot's inputs now, as keyword arguments of `adp_runtime.Navigator.cycle`:
        the scan, the odometry (its believed pose and measured velocity) and the goal."""
        t = self.time
        return {
            "stamp_s": t,
            "ranges": self.ranges.tolist(),
            "pose": tuple(self.odom_pose),
            "vel": self.odom_vel,
            "odom_stamp_s": t,
            "goal": tuple(self.world["goal"]),
        }

    # -- stepping -----------------------------------------------------------------------
    def step(self, out) -> str:
        """Simulates one control period with a cycle's decision: an `adp_runtime.CycleOutput`
        (a cycle that did not plan keeps the last command; a planned one takes effect after
        the command latency plus its modelled compute) or a (v, w) command. Returns the
        status: "running", "succeeded", "collided" or "timed_out". Raises LidarError or
        PhysicsError (the status is then "error")."""
        if self.status != "running":
            return self.status
        if isinstance(out, (tuple, list)):
            command, planned, compute_s = out, True, None
        else:
            command, planned, compute_s = out.command, out.planned, out.compute_s
        if planned:
            v, w = float(command[0]), float(command[1])
            if not (math.isfinite(v) and math.isfinite(w)):
                return self._fail(SimError(f"command ({v}, {w}) is not finite"))
            due = self.time + self.command_latency_s + (compute_s or 0.0)
            self._pending.append((due - 1e-9, (v, w)))
        try:
            self._advance()
            if self.status == "running":
                self.ranges = self.lidar.scan(self.data)
        except SimError as e:
            return self._fail(e)
        self.cycles += 1
        return self.status

    def _fail(self, e: SimError):
        self.status = "error"
        self.error = str(e)
        self.end_time = self.run_time()
        raise e

    def _touching(self) -> bool:
        n = self.data.ncon
        if n == 0:
            return False
        c = self.data.contact
        return bool(np.any(c.geom1[:n] == self._footprint) or np.any(c.geom2[:n] == self._footprint))

    def _advance(self) -> None:
        m, d = self.model, self.data
        dt = m.opt.timestep
        goal = self.world["goal"]
        for _ in range(self.substeps):
            while self._pending and self._pending[0][0] <= d.time:
                self.controller.command(*self._pending.popleft()[1])
            d.ctrl[self._act] = self.controller.step(dt, self._gyro)
            before = d.qpos[self._free_q:self._free_q + 2].copy()
            mujoco.mj_step(m, d)
            self._check_physics()
            self._integrate_odometry(dt)
            pos = d.qpos[self._free_q:self._free_q + 2]
            self.distance += float(np.hypot(*(pos - before)))
            if self.clock_start is None and math.hypot(pos[0] - self.start[0], pos[1] - self.start[1]) >= self.clock_start_distance:
                self.clock_start = float(d.time)
            if self._touching():
                return self._finish("collided")
            if math.hypot(pos[0] - goal[0], pos[1] - goal[1]) <= self.world["goal_radius"]:
                return self._finish("succeeded")
            if self.run_time() >= self.timeout_s:
                return self._finish("timed_out")

    def _check_physics(self) -> None:
        d = self.data
        for k, w in enumerate(_DIVERGED):
            if d.warning[w].number != self._diverged[k]:
                what = ("position", "velocity", "acceleration")[k]
                raise PhysicsError(
                    f"world {self.world['id']}: MuJoCo reports an unstable simulation (NaN, inf or "
                    f"huge {what} at dof {d.warning[w].lastinfo}) near t = {d.time:.3f} s")
        if not (np.all(np.isfinite(d.qpos)) and np.all(np.isfinite(d.qvel))):
            raise PhysicsError(f"world {self.world['id']}: NaN or infinite state at t = {d.time:.3f} s")

    def _integrate_odometry(self, dt: float) -> None:
        p = self.params
        wheel = self.data.qvel[self._wheel_v]
        left, right = (wheel[0] + wheel[1]) / 2, (wheel[2] + wheel[3]) / 2
        v = p.wheel_radius * (left + right) / 2
        # The gyro (yaw rate with noise) feeds the base's yaw-rate loop in every mode.
        self._gyro = float(self.data.qvel[self._free_v + 5]) + self._gyro_rng.normal(0.0, GYRO_NOISE)
        if self.odometry == "wheels":
            w = p.wheel_radius * (right - left) / p.effective_track
        else:
            w = self._gyro
        x, y, yaw = self.odom_pose
        mid = yaw + 0.5 * w * dt
        self.odom_pose = [x + v * math.cos(mid) * dt, y + v * math.sin(mid) * dt, _wrap(yaw + w * dt)]
        self.odom_vel = (float(v), float(w))

    def _finish(self, status: str) -> None:
        self.status = status
        self.end_time = self.run_time()

    # -- outcome --------------------------------------------------------------------------
    def result(self) -> Dict[str, Any]:
        """The run so far (final once the status is not "running"): world, status, time_s
        (run clock), sim_time_s, score, distance_m, cycles, and error (a message or None)."""
        time_s = self.run_time() if self.status == "running" else self.end_time
        return {
            "world": self.world["id"],
            "status": self.status,
            "time_s": time_s,
            "sim_time_s": self.time,
            "score": barn_score(self.status == "succeeded", self.world["optimal_time_s"], time_s),
            "distance_m": self.distance,
            "cycles": self.cycles,
            "error": self.error,
        }
