"""The observation a policy reads, built from a robot's own scan and state (a Python port of
policy/src/observation.rs, for wrappers around real robots and other simulators).

One observation is, in this order: the laser segment (`scan`: 720 values, beam k at
-135 + 270 k / 719 degrees, each the sensor beam nearest that angle; `sectors:N`: the least
range in each of N equal sectors of the 270-degree field from -135 degrees, beams outside the
field unused, a sector without a beam taking the beam nearest its centre), each range encoded
as `2 min(r, clip) / clip - 1`; the previous normalized action; v and w; the local goal's and
the goal's bearing (rad) and distance (m) in the robot frame; then, with k track slots, the k
nearest moving tracks (x, y, vx, vy in the robot frame; empty slots zeros). Values are float32.
The shared test vectors in testdata/observation_vectors.json pin both ports.
"""

import math
from typing import List, Sequence, Tuple

import numpy as np

LASER_BEAMS = 720
LASER_FIELD_DEG = 270.0
MAX_SECTORS = LASER_BEAMS
_ANGLE_EPS = 1e-9


class LayoutError(ValueError):
    """A laser layout name that is neither `scan` nor `sectors:N` (N in 1..720)."""


def layout_size(layout: str) -> int:
    """Values of the laser segment of `layout` (`scan` or `sectors:N`)."""
    if layout == "scan":
        return LASER_BEAMS
    if layout.startswith("sectors:"):
        try:
            n = int(layout[len("sectors:"):])
        except ValueError:
            n = 0
        if 1 <= n <= MAX_SECTORS:
            return n
    raise LayoutError(f'observation = "{layout}" is not a laser layout: "scan" or "sectors:N" with N in 1..={MAX_SECTORS}')


def _nearest(angles: Sequence[float], a: float) -> int:
    """Index of the angle nearest `a` in increasing `angles`; ties go to the lower index."""
    lo, hi = 0, len(angles)
    while lo < hi:
        mid = (lo + hi) // 2
        if angles[mid] < a:
            lo = mid + 1
        else:
            hi = mid
    i = lo
    if i == 0:
        return 0
    if i == len(angles) or a - angles[i - 1] <= angles[i] - a:
        return i - 1
    return i


class LaserResampler:
    """Builds the laser segment of `layout` from scans of a lidar whose beams point at `angles`
    (rad from the heading, counter-clockwise, increasing)."""

    def __init__(self, layout: str, angles: Sequence[float]):
        angles = [float(a) for a in angles]
        if not angles or any(b <= a for a, b in zip(angles, angles[1:])):
            raise ValueError("beam angles must be increasing")
        self.layout = layout
        self.beams = len(angles)
        n = layout_size(layout)
        field = math.radians(LASER_FIELD_DEG)
        if layout == "scan":
            self.spans: List[Tuple[int, int]] = []
            for k in range(LASER_BEAMS):
                j = _nearest(angles, -field / 2.0 + field * k / (LASER_BEAMS - 1))
                self.spans.append((j, j + 1))
            return
        half, width = field / 2.0, field / n
        spans = [None] * n
        for j, a in enumerate(angles):
            if a < -half - _ANGLE_EPS or a > half + _ANGLE_EPS:
                continue
            i = min(int(max(math.floor((a + half) / width), 0.0)), n - 1)
            spans[i] = (j, j + 1) if spans[i] is None else (spans[i][0], j + 1)
        for i, s in enumerate(spans):
            if s is None:
                j = _nearest(angles, -half + (i + 0.5) * width)
                spans[i] = (j, j + 1)
        self.spans = spans

    def encode(self, ranges: Sequence[float], clip: float) -> np.ndarray:
        """The laser segment (float32) of one scan: one range per beam, in metres."""
        if len(ranges) != self.beams:
            raise ValueError(f"the resampler reads scans of {self.beams} beams, the scan has {len(ranges)}")
        r = np.asarray(ranges, dtype=np.float64)
        least = np.array([r[a:b].min() for a, b in self.spans], dtype=np.float64)
        return (2.0 * np.minimum(least, clip) / clip - 1.0).astype(np.float32)


def _bearing_distance(p) -> Tuple[float, float]:
    x, y = float(p[0]), float(p[1])
    return math.atan2(y, x), math.hypot(x, y)


def observation(
    resampler: LaserResampler,
    ranges: Sequence[float],
    laser_clip_m: float,
    previous_action: Sequence[float],
    velocity: Tuple[float, float],
    local_goal: Tuple[float, float],
    goal: Tuple[float, float],
    tracks: Sequence[Tuple[float, float, float, float]] = (),
    track_slots: int = 0,
) -> np.ndarray:
    """The observation (float32) of one scan and the robot's state: goals and tracks in the
    robot frame (m, m/s), `velocity` = (v, w) measured, `previous_action` normalized."""
    laser = resampler.encode(ranges, laser_clip_m)
    lb, ld = _bearing_distance(local_goal)
    gb, gd = _bearing_distance(goal)
    tail = [float(velocity[0]), float(velocity[1]), lb, ld, gb, gd]
    # Nearest first by distance; ties keep the list order.
    order = sorted(range(len(tracks)), key=lambda i: (math.hypot(tracks[i][0], tracks[i][1]), i))
    slots = []
    for k in range(track_slots):
        slots.extend([float(x) for x in tracks[order[k]][:4]] if k < len(order) else [0.0] * 4)
    rest = np.asarray(list(previous_action) + tail + slots, dtype=np.float64).astype(np.float32)
    return np.concatenate([laser, rest])
