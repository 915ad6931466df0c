"""tdcr-warp: batched simulation of tendon-driven continuum robots on NVIDIA Warp."""

import warp as _wp

_wp.config.log_level = max(_wp.config.log_level, _wp.LOG_WARNING)  # no banner or module-load lines

from tdcr_warp.model.options import describe_status, status_names  # noqa: E402  (the status bits: docs/outputs.md)
from tdcr_warp.model.robot import InputError, PointForce, Robot, Tendon  # noqa: E402
from tdcr_warp.physics.dynamics import Simulator, StepResult, Trajectory  # noqa: E402
from tdcr_warp.physics.statics import StaticOptions, StaticSolution, solve_static  # noqa: E402


def _package_version() -> str:
    """The installed distribution's version, else the version in the source tree's pyproject.toml."""
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version("tdcr-warp")
    except PackageNotFoundError:
        import tomllib
        from pathlib import Path
        try:
            with open(Path(__file__).resolve().parents[1] / "pyproject.toml", "rb") as f:
                return str(tomllib.load(f)["project"]["version"])
        except (OSError, KeyError, tomllib.TOMLDecodeError):
            return "unknown"


__all__ = ["InputError", "PointForce", "Robot", "Simulator", "StaticOptions", "StaticSolution", "StepResult",
           "Tendon", "Trajectory", "describe_status", "solve_static", "status_names"]
__version__ = _package_version()
