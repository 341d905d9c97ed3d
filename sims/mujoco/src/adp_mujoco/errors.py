"""The package's exceptions. Each ends one episode with a clear message; the caller (an
evaluation loop, a training actor) catches `SimError` and goes on with the next episode."""


class SimError(Exception):
    """Base class: something ended an episode that is not a navigation outcome."""


class WorldError(SimError):
    """A world the MuJoCo model cannot be built from (missing or non-finite fields, an
    obstacle with radius <= 0, a start inside an obstacle, MuJoCo refusing the model)."""


class LidarError(SimError):
    """The lidar failed: ray casting raised, or returned a scan with the wrong beam count or
    a value that is not a range."""


class PhysicsError(SimError):
    """The physics diverged: a NaN or infinite state, or MuJoCo's instability warning (it
    would otherwise reset the state silently)."""
