"""The actor MLP in numpy, from the flat weights of a policy snapshot.

Layout (as policy/src/mlp.rs): for each linear layer in order, with `n = dims[l]` inputs
and `m = dims[l + 1]` outputs, the weight matrix `[n][m]` row-major (y = x W + b), then the
bias `[m]`. Hidden layers use ReLU, the output layer tanh, so actions lie in [-1, 1].
"""

import numpy as np


class PolicyError(ValueError):
    """Layer sizes and flat weights that make no policy network."""


def param_count(dims) -> int:
    """Number of parameters of an MLP with layer sizes `dims`: the sum of n * m + m."""
    return sum(n * m + m for n, m in zip(dims[:-1], dims[1:]))


class MlpPolicy:
    """A deterministic policy network; `act` maps an observation to an action in [-1, 1]."""

    def __init__(self, dims, flat):
        """Builds the network from layer sizes (input first) and the flat f32 weights
        (a numpy array, or the snapshot's little-endian bytes)."""
        dims = [int(d) for d in dims]
        if len(dims) < 2 or any(d <= 0 for d in dims):
            raise PolicyError(f"layer sizes {dims}: need at least an input and an output size, all > 0")
        if isinstance(flat, (bytes, bytearray, memoryview)):
            if len(flat) % 4:
                raise PolicyError(f"policy weights: {len(flat)} bytes is not a whole number of f32 values")
            flat = np.frombuffer(flat, dtype="<f4")
        flat = np.asarray(flat, dtype=np.float32).ravel()
        expected = param_count(dims)
        if flat.size != expected:
            raise PolicyError(f"layer sizes {dims} need {expected} parameters, got {flat.size}")
        bad = np.flatnonzero(~np.isfinite(flat))
        if bad.size:
            raise PolicyError(f"parameter {bad[0]} is {flat[bad[0]]}: weights must be finite")
        self.dims = dims
        self.layers = []
        off = 0
        for n, m in zip(dims[:-1], dims[1:]):
            w = flat[off : off + n * m].reshape(n, m)
            b = flat[off + n * m : off + n * m + m]
            self.layers.append((w.copy(), b.copy()))
            off += n * m + m

    @property
    def obs_dim(self) -> int:
        """Observation length."""
        return self.dims[0]

    @property
    def act_dim(self) -> int:
        """Action length."""
        return self.dims[-1]

    def act(self, obs) -> np.ndarray:
        """The deterministic action(s) of `obs`: one observation `[obs_dim]` or a batch
        `[k, obs_dim]`; returns float32 of the matching shape with `act_dim` columns."""
        x = np.asarray(obs, dtype=np.float32)
        if x.shape[-1] != self.obs_dim:
            raise PolicyError(f"observation has {x.shape[-1]} values, the policy takes {self.obs_dim}")
        last = len(self.layers) - 1
        for i, (w, b) in enumerate(self.layers):
            x = x @ w + b
            x = np.tanh(x) if i == last else np.maximum(x, 0.0)
        return x.astype(np.float32, copy=False)
