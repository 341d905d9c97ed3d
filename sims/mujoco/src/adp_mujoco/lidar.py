"""A 2-D scanning lidar by MuJoCo ray casting, with the project's noise model.

Beams spread evenly from -fov/2 to +fov/2 inclusive, centred on the sensor's heading (the
project's `sim::fan::Fan`), cast from the robot's `lidar` site along its orientation (a
pitching chassis tilts the scan plane, as a real one does). The rays see obstacle geoms only
(geom group `world.OBSTACLE_GROUP`) and never the robot's own body.

Noise follows `sim::lidar::Lidar::scan`: a beam without a return reads `max_range`; every
beam adds Gaussian noise of `noise_sigma` (m), or of `noise_fraction` x the scan's mean range
over its returns; a beam drops out (reads `max_range`) with probability `dropout`; the range
is clamped to [min_range, max_range] last. The draws come from NumPy generators seeded by the
episode's seed (not the project's PCG streams, so the noise values differ draw by draw, not
in distribution).
"""

from typing import Any, Dict

import mujoco
import numpy as np

from .errors import LidarError
from .world import OBSTACLE_GROUP

DROPOUT_STREAM = 0x6C69_6461_725F_6470
"""Seed offset of the dropout stream, apart from the noise stream."""


class Lidar:
    """The robot's laser scanner in one MuJoCo model."""

    def __init__(self, model: mujoco.MjModel, cfg: Dict[str, Any], seed: int):
        try:
            self.beams = int(cfg["beams"])
            self.fov = np.deg2rad(float(cfg["fov_deg"]))
            self.min_range = float(cfg["min_range"])
            self.max_range = float(cfg["max_range"])
            self.noise_sigma = float(cfg.get("noise_sigma", 0.0))
            self.noise_fraction = float(cfg.get("noise_fraction", 0.0))
            self.dropout = float(cfg.get("dropout", 0.0))
        except (KeyError, TypeError, ValueError) as e:
            raise LidarError(f"lidar configuration {cfg!r}: {e}") from None
        if not (self.beams >= 2 and 0 < self.min_range < self.max_range and np.isfinite(self.max_range)):
            raise LidarError(f"lidar configuration {cfg!r}: needs beams >= 2 and 0 < min_range < max_range")
        self.model = model
        self.site = model.site("lidar").id
        self.body = model.body("jackal").id
        self.angles = np.linspace(-self.fov / 2, self.fov / 2, self.beams)
        self._local = np.stack([np.cos(self.angles), np.sin(self.angles), np.zeros(self.beams)], axis=1)
        self._groups = np.zeros(6, dtype=np.uint8)
        self._groups[OBSTACLE_GROUP] = 1
        self._geomid = np.zeros(self.beams, dtype=np.int32)
        self._dist = np.zeros(self.beams, dtype=np.float64)
        self._noise = np.random.default_rng(seed)
        self._drop = np.random.default_rng(seed ^ DROPOUT_STREAM)

    def cast(self, data: mujoco.MjData) -> np.ndarray:
        """The true ranges (m) of every beam, -1 where a beam hits nothing within max_range."""
        origin = data.site_xpos[self.site].copy()
        rot = data.site_xmat[self.site].reshape(3, 3)
        dirs = np.ascontiguousarray((self._local @ rot.T).ravel())
        mujoco.mj_multiRay(self.model, data, origin, dirs, self._groups, 1, self.body,
                           self._geomid, self._dist, self.beams, self.max_range)
        return self._dist.copy()

    def scan(self, data: mujoco.MjData) -> np.ndarray:
        """One noisy scan (m), `beams` ranges in [min_range, max_range]. Raises LidarError if
        the ray casting fails or returns something that is not a scan."""
        try:
            raw = np.asarray(self.cast(data), dtype=np.float64)
        except LidarError:
            raise
        except Exception as e:  # MuJoCo's bindings raise ValueError/RuntimeError/TypeError
            raise LidarError(f"ray casting failed: {e}") from e
        if raw.shape != (self.beams,):
            raise LidarError(f"ray casting returned {raw.shape} ranges, expected ({self.beams},)")
        bad = ~np.isfinite(raw)
        if bad.any():
            raise LidarError(f"ray casting returned {int(bad.sum())} non-finite ranges (first at beam {int(np.argmax(bad))})")
        hit = raw >= 0.0
        ranges = np.where(hit, raw, self.max_range)
        if self.noise_sigma > 0:
            ranges = ranges + self._noise.normal(0.0, self.noise_sigma, self.beams)
        if self.noise_fraction > 0 and hit.any():
            sigma = self.noise_fraction * float(raw[hit].mean())
            ranges = ranges + sigma * self._noise.standard_normal(self.beams)
        if self.dropout > 0:
            ranges = np.where(self._drop.random(self.beams) < self.dropout, self.max_range, ranges)
        return np.clip(ranges, self.min_range, self.max_range)
