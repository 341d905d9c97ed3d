"""adp_client: train with the adp learner from any simulator.

Implement an `Environment` (reset/step) and run `Actor(address, env, token_file=...).run()`.
"""

from .action import ActionError, ActionMap, ActionSpace, Schedule
from .actor import (
    Actor,
    AdpError,
    ConfigError,
    Connection,
    EnvironmentFault,
    Environment,
    LearnerUnreachable,
    RunInfo,
    Session,
    StepsRefused,
    read_token_file,
)
from .checksum import step_checksum
from .policy import MlpPolicy, PolicyError, param_count
from .spec import SpecError

__all__ = [
    "ActionError", "ActionMap", "ActionSpace", "Actor", "AdpError", "ConfigError", "Connection", "Environment",
    "EnvironmentFault", "LearnerUnreachable", "MlpPolicy", "PolicyError", "RunInfo", "Schedule",
    "Session", "SpecError", "StepsRefused", "param_count", "read_token_file", "step_checksum",
]
__version__ = "0.1.0"
