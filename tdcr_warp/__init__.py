"""tdcr-warp: batched simulation of tendon-driven continuum robots on NVIDIA Warp."""

import warp as _wp

_wp.config.log_level = max(_wp.config.log_level, _wp.LOG_WARNING)  # no banner or module-load lines

from .robot import InputError, PointForce, Robot, Tendon  # noqa: E402
from .statics import StaticOptions, StaticSolution, solve_static  # noqa: E402
from .dynamics import Simulator, StepResult, Trajectory  # noqa: E402

__all__ = ["InputError", "PointForce", "Robot", "Simulator", "StaticOptions", "StaticSolution", "StepResult",
           "Tendon", "Trajectory", "solve_static"]
__version__ = "0.1.0"
