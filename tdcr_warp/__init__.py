"""tdcr-warp: batched simulation of tendon-driven continuum robots on NVIDIA Warp.

The names below load on first use (``tw.solve_static`` imports Warp and the solver), so that
``import tdcr_warp`` and the command line's argument parsing cost milliseconds.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys

# name -> the module defining it
_EXPORTS = {
    "describe_status": "tdcr_warp.model.options", "status_names": "tdcr_warp.model.options",  # the status bits
    "InputError": "tdcr_warp.model.robot", "PointForce": "tdcr_warp.model.robot", "Robot": "tdcr_warp.model.robot",
    "Tendon": "tdcr_warp.model.robot", "Section": "tdcr_warp.model.backbone", "Obstacle": "tdcr_warp.model.world", "TipConstraint": "tdcr_warp.model.world",
    "Simulator": "tdcr_warp.physics.dynamics", "StepResult": "tdcr_warp.physics.dynamics",
    "Trajectory": "tdcr_warp.physics.dynamics",
    "StaticOptions": "tdcr_warp.physics.statics", "StaticSolution": "tdcr_warp.physics.statics",
    "solve_static": "tdcr_warp.physics.statics",
}


def _quiet(warp) -> None:
    """No Warp start-up banner, no line per kernel module loaded (``-v`` shows them); warnings stay."""
    warp.config.log_level = max(warp.config.log_level, warp.LOG_WARNING)


class _QuietWarp:
    """Import hook (first on sys.meta_path until warp is imported): ``_quiet`` runs as soon as any
    module imports warp, so that the package is quiet without importing Warp itself."""

    @staticmethod
    def find_spec(name, path=None, target=None):
        if name != "warp":
            return None
        sys.meta_path.remove(_QuietWarp)
        spec = importlib.util.find_spec("warp")
        if spec is not None and spec.loader is not None:
            exec_module = spec.loader.exec_module

            def exec_quiet(module):
                exec_module(module)
                _quiet(module)
            spec.loader.exec_module = exec_quiet
        return spec


if "warp" in sys.modules:
    _quiet(sys.modules["warp"])
else:
    sys.meta_path.insert(0, _QuietWarp)


def __getattr__(name: str):
    if name == "__version__":
        value = _package_version()
    elif name in _EXPORTS:
        value = getattr(importlib.import_module(_EXPORTS[name]), name)
    else:
        raise AttributeError(f"module 'tdcr_warp' has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__) | {"__version__"})


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


__all__ = ["InputError", "Obstacle", "PointForce", "Robot", "Section", "Simulator", "StaticOptions", "StaticSolution",
           "StepResult", "Tendon", "TipConstraint", "Trajectory", "describe_status", "solve_static", "status_names"]
