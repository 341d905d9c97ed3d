"""Per-episode step checksums, bit-for-bit the learner's (proto/src/checksum.rs).

Each step record hashes with 64-bit FNV-1a over: episode id (u64 LE), step index (u32 LE),
policy version (u64 LE), the f32 little-endian bytes of obs, action and reward, one byte each
for terminal and truncated, then the f32 bytes of final_obs. An episode's checksum is the
wrapping (mod 2**64) sum of its records' checksums.
"""

import struct

import numpy as np

_OFFSET = 0xCBF29CE484222325
_PRIME = 0x100000001B3
_MASK = (1 << 64) - 1


def _fnv(h: int, data: bytes) -> int:
    for b in data:
        h = ((h ^ b) * _PRIME) & _MASK
    return h


def f32_bytes(values) -> bytes:
    """Little-endian f32 bytes of `values` (the wire encoding of obs, actions, final obs)."""
    return np.ascontiguousarray(values, dtype="<f4").tobytes()


def step_checksum(
    episode_id: int,
    step_index: int,
    policy_version: int,
    obs: bytes,
    action: bytes,
    reward: float,
    terminal: bool,
    truncated: bool,
    final_obs: bytes = b"",
) -> int:
    """Checksum of one step record; `obs`, `action`, `final_obs` are their wire bytes."""
    h = _fnv(_OFFSET, struct.pack("<Q", episode_id))
    h = _fnv(h, struct.pack("<I", step_index))
    h = _fnv(h, struct.pack("<Q", policy_version))
    h = _fnv(h, obs)
    h = _fnv(h, action)
    h = _fnv(h, struct.pack("<f", reward))
    h = _fnv(h, bytes((int(bool(terminal)), int(bool(truncated)))))
    return _fnv(h, final_obs)


def add(total: int, checksum: int) -> int:
    """Wrapping u64 sum, as the episode checksum accumulates."""
    return (total + checksum) & _MASK
