"""A tiny pure-Python environment for examples and tests: a point robot drives to a goal on
a plane with a few round obstacles; the observation is a fake laser scan plus goal and
velocity features padded to the run's observation length."""

import math

import numpy as np

from .actor import Environment, RunInfo


class PointWorld(Environment):
    """A point robot that moves toward its goal at a speed the action's first value scales;
    obstacles placed from the world index and seed. `max_steps` truncates an episode."""

    def __init__(self, max_steps: int = 40, step_delay: float = 0.0):
        self.max_steps = max_steps
        self.step_delay = step_delay
        self.obs_dim = 0

    def configure(self, info: RunInfo) -> None:
        """Takes the run's observation length."""
        self.obs_dim = info.obs_dim

    def _obs(self):
        o = np.zeros(self.obs_dim, dtype=np.float32)
        n = max(self.obs_dim - 4, 0)
        if n:
            ang = np.linspace(-math.pi, math.pi, n, endpoint=False)
            d = np.full(n, 3.0)
            for ox, oy, r in self.obstacles:
                dx, dy = ox - self.x, oy - self.y
                dist = math.hypot(dx, dy) - r
                bearing = math.atan2(dy, dx)
                hit = np.abs(np.angle(np.exp(1j * (ang - bearing)))) < 0.3
                d[hit] = np.minimum(d[hit], max(dist, 0.0))
            o[:n] = d / 3.0
        tail = [self.gx - self.x, self.gy - self.y, self.v, self.t / 10.0][: self.obs_dim]
        o[n : n + len(tail)] = tail
        return o

    def reset(self, world: int, seed: int):
        """Places the robot at the origin, the goal 5 m ahead, obstacles from (world, seed)."""
        rng = np.random.default_rng([world, seed])
        self.x = self.y = self.v = self.t = 0.0
        self.gx, self.gy = 5.0, float(rng.uniform(-1, 1))
        self.obstacles = [(float(rng.uniform(1, 4)), float(rng.uniform(-2, 2)), 0.3) for _ in range(3)]
        self.k = 0
        return self._obs()

    def step(self, action):
        """Moves 0.1 s toward the goal at a speed set by action[0]; ends on goal, collision
        or after max_steps."""
        if self.step_delay:
            import time

            time.sleep(self.step_delay)
        a = np.asarray(action, dtype=np.float64)
        self.v = 0.5 + 0.5 * (float(a[0]) + 1.0)
        dx, dy = self.gx - self.x, self.gy - self.y
        dist = math.hypot(dx, dy)
        step = min(self.v * 0.1, dist)
        self.x += step * dx / max(dist, 1e-9)
        self.y += step * dy / max(dist, 1e-9)
        self.t += 0.1
        self.k += 1
        new_dist = math.hypot(self.gx - self.x, self.gy - self.y)
        reward = dist - new_dist - 0.01
        collided = any(math.hypot(ox - self.x, oy - self.y) < r for ox, oy, r in self.obstacles)
        success = new_dist < 0.1
        terminal = collided or success
        truncated = not terminal and self.k >= self.max_steps
        info = {}
        if terminal or truncated:
            outcome = "success" if success else "collision" if collided else "timeout"
            info = {"outcome": outcome, "time_s": self.t, "score": (1.0 if success else 0.0)}
            reward += 10.0 if success else -10.0 if collided else 0.0
        return self._obs(), reward, terminal, truncated, info
