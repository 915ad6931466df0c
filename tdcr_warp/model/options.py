"""Solver options and the status bits of a rod's solve (host side).

``StaticOptions`` holds everything that selects code or stopping rules; its fields become
kernel-factory keys. Nothing here touches Warp: the scene reader imports it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np

from tdcr_warp.kernels import layout
from tdcr_warp.kernels.variants import INTEGRATORS, MODELS, RODS
from tdcr_warp.model.robot import InputError, Robot

__all__ = ["COMMANDS", "DRIVERS", "PRECISIONS", "PRESETS", "StaticOptions", "check_model_support", "describe_status",
           "failure_reasons", "status_names"]

PRECISIONS = ("float64", "float32")
COMMANDS = ("tension", "displacement")  # what the tip controller commands: tendon tensions or motor displacements
DRIVERS = ("fused", "probes")
STABILITY = ("off", "check", "stable")
ENERGY_TOLERANCE = 0.01  # the energy monitor's default (experiments/bdf_alpha_energy.py, docs/accuracy.md)


def status_names(status: int) -> list[str]:
    """The status bits of one rod (kernels/layout.py) as words."""
    return [v for k, v in layout.STATUS_NAMES.items() if int(status) & k]


def describe_status(status: int) -> str:
    """The status bits of one rod in words."""
    names = status_names(status)
    return ", ".join(names) if names else "not converged"


def failure_reasons(status, ok, counts: dict[str, int] | None = None) -> dict[str, int]:
    """The failed rods (``ok`` false) counted per reason in words, added to ``counts``."""
    counts = {} if counts is None else counts
    for st in status[~ok]:
        key = describe_status(st)
        counts[key] = counts.get(key, 0) + 1
    return counts


PRESETS = {
    "fast": dict(integrator="rk4", nodes=10, rod="kirchhoff"),
    "balanced": dict(integrator="rk4", nodes=20, rod="cosserat"),
    "accurate": dict(integrator="rk4", nodes=50, rod="cosserat", tol=1e-12),
}


@dataclass(frozen=True)
class StaticOptions:
    """What selects code and stopping rules (host only).

    nodes: integration intervals along s (N; shapes have N + 1 nodes). integrator: "rk4",
    "midpoint" or "euler". model: "coupled" (distributed tendon loads), "point" (termination
    loads only), "disks" (tendons straight between the robot's spacer disks, loading the
    backbone there; statics, frictionless) or "constant_curvature" (closed form: straight
    tendons ending at the tip, no external load). rod: "cosserat" (shear, extension) or "kirchhoff" (inextensible,
    unshearable). specialize: compile out the physics the batch does not contain (gravity,
    point loads, helical routing, drag). error_estimate: also solve with N/2 nodes and report
    per rod ``tip_error_estimate`` = 2 |tip(N) - tip(N/2)| / (2^p - 1) [m] (p: the integrator's
    order; a Richardson estimate of the discretisation error with a safety factor 2; it does
    not measure model error such as Kirchhoff vs Cosserat).
    precision: "float64" or "float32". tol: Newton stops when the scaled residual, expressed
    as a tip-displacement-like error L |r| [m], is below it (None: 1e-10 m in float64,
    1e-6 m in float32). max_iter: Newton iterations per rod. max_step: bound on a Newton
    step in scaled unknowns. jacobian: "broyden" (finite differences once, then rank-one
    updates; a rebuild when a step fails) or "newton" (finite differences at every
    iterate). continuation: rods that fail from the straight-rod start, or whose load would
    bend a straight rod by more than ~1.5 rad (where other equilibria exist), are solved by a
    homotopy in tensions and loads, scaled by 1/c, ..., 1, each step from the last, with
    c = max(continuation, load, sqrt(axial load L^2 / EI)) steps per rod (0: off). threads:
    CPU threads (None: all cores; CUDA uses one). driver: how the Newton loop runs: "fused"
    (all iterations of a rod in one thread, one launch per solve: the CPU default),
    "probes" (a thread per rod and probe, one launch per iteration: the CUDA default), None:
    the device's default. kink_loads: in the coupled model, the point loads of tendons kinked
    where n or m jumps (a tendon ends or a point force acts before the tip): on, global force
    and moment balance is exact; off, the published coupled model of Rucker & Webster (2011),
    which omits them (about 0.5 mm apart on a two-segment robot under a large tip load).
    tendon_states: integrate every tendon's path length and unstretched length (and report
    them) also where no tendon is under displacement control or has friction (there they are
    integrated anyway).
    sensitivities: also return the tip Jacobian of the commands and the tip compliance per rod
    (tdcr_warp/physics/sensitivity.py; one probe integration per unknown and per tension-controlled
    tendon). stability: "check" (the default: the Jacobi test of every converged rod on the
    device, tdcr_warp/physics/stability.py, about 1 + nu integrations more; an unstable one is
    flagged UNSTABLE and is not a success), "stable" (check, and where an equilibrium is unstable
    search for a stable one by restarts, reporting which branch was returned) or "off" (the bare
    solve, no verdict). contact_tolerance: the penetration of a rigid obstacle allowed, as a
    fraction of the rod's radius (rigid obstacles are stiffened until it holds; beyond it a rod
    is flagged PENETRATION). contact_steps: the most stiffenings per solve
    (tdcr_warp/physics/contact.py). segments: multiple shooting (tdcr_warp/physics/segments.py),
    for robots without tendon states, a constrained tip or disks: None (the default) splits only
    the rods single shooting cannot resolve (statics: a contact left unresolved; dynamics: a step
    that fails where dt is beyond single shooting's reach) into as many segments as they need; M
    solves every rod in M segments (statics: from single shooting's answer); 1: never.
    energy_tolerance (dynamics): the energy monitor. Where nothing does work on a rod but its
    conservative loads (gravity, dead point forces, held tensions in the coupled model; damping,
    drag only take energy away), a step whose mechanical energy rises above its value at the last
    change of command by more than energy_tolerance times the rod's kinetic plus elastic energy is
    flagged ENERGY and fails (tdcr_warp/physics/dynamics.py; docs/solver.md); 0: off.
    """

    nodes: int = 50
    integrator: str = "rk4"
    model: str = "coupled"
    precision: str = "float64"
    tol: float | None = None
    max_iter: int = 50
    max_step: float = 10.0
    jacobian: str = "broyden"
    continuation: int = 8
    rod: str = "cosserat"
    specialize: bool = True
    error_estimate: bool = False
    threads: int | None = None
    driver: str | None = None
    kink_loads: bool = True
    tendon_states: bool = False
    sensitivities: bool = False
    stability: str = "check"
    contact_tolerance: float = 0.01
    contact_steps: int = 8
    segments: int | None = None
    energy_tolerance: float = ENERGY_TOLERANCE

    def __post_init__(self):
        def integer(v, low, high=10**9):
            return isinstance(v, int) and not isinstance(v, bool) and low <= v <= high

        def one_of(v, options):
            return isinstance(v, str) and v in options

        def positive(v):
            return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0

        checks = [
            ("nodes", integer(self.nodes, 1, 100_000), "an integer in [1, 100000]"),
            ("integrator", one_of(self.integrator, INTEGRATORS), f"one of {INTEGRATORS}"),
            ("model", one_of(self.model, MODELS + ("constant_curvature",)), f"one of {MODELS + ('constant_curvature',)}"),
            ("rod", one_of(self.rod, RODS), f"one of {RODS}"),
            ("specialize", isinstance(self.specialize, bool), "true or false"),
            ("error_estimate", isinstance(self.error_estimate, bool), "true or false"),
            ("precision", one_of(self.precision, PRECISIONS), f"one of {tuple(PRECISIONS)}"),
            ("tol", self.tol is None or positive(self.tol), "a positive number"),
            ("max_iter", integer(self.max_iter, 1, 10_000), "an integer in [1, 10000]"),
            ("max_step", positive(self.max_step), "a positive number"),
            ("jacobian", one_of(self.jacobian, ("broyden", "newton")), "'broyden' or 'newton'"),
            ("continuation", integer(self.continuation, 0, 10_000), "an integer in [0, 10000]"),
            ("threads", self.threads is None or integer(self.threads, 1), "a positive integer"),
            ("driver", self.driver is None or one_of(self.driver, DRIVERS), f"one of {DRIVERS}"),
            ("kink_loads", isinstance(self.kink_loads, bool), "true or false"),
            ("tendon_states", isinstance(self.tendon_states, bool), "true or false"),
            ("sensitivities", isinstance(self.sensitivities, bool), "true or false"),
            ("stability", one_of(self.stability, STABILITY), f"one of {STABILITY}"),
            ("contact_tolerance", positive(self.contact_tolerance), "a positive number"),
            ("contact_steps", integer(self.contact_steps, 0, 100), "an integer in [0, 100]"),
            ("segments", self.segments is None or integer(self.segments, 1), "a positive integer or None"),
            ("energy_tolerance", positive(self.energy_tolerance) or (isinstance(self.energy_tolerance, (int, float))
                                                                      and not isinstance(self.energy_tolerance, bool)
                                                                      and self.energy_tolerance == 0),
             "a number >= 0 (0: no energy monitor)"),
        ]
        for name, ok, what in checks:
            if not ok:
                raise InputError(f"solver {name} must be {what}, got {getattr(self, name)!r}")

    @classmethod
    def preset(cls, name: str, **overrides) -> "StaticOptions":
        """Named settings chosen from experiments/speed_accuracy.py (see docs/accuracy.md for the
        measured tip errors): "fast", "balanced" (the defaults at N = 20) or "accurate"."""
        if name not in PRESETS:
            raise InputError(f"solver preset must be one of {tuple(PRESETS)}, got {name!r}")
        _known_options(overrides)
        return cls(**(PRESETS[name] | overrides))

    def override(self, **changes) -> "StaticOptions":
        """A copy with ``changes`` (fields, e.g. nodes=20): the ``**overrides`` of the solvers; an
        unknown name is an InputError naming it and listing the fields."""
        _known_options(changes)
        return replace(self, **changes)

    @property
    def tolerance(self) -> float:
        if self.tol is not None:
            return self.tol
        return 1e-10 if self.precision == "float64" else 1e-6


def _known_options(names) -> None:
    known = [f.name for f in fields(StaticOptions)]
    unknown = [n for n in names if n not in known]
    if unknown:
        raise InputError(f"unknown solver option {unknown[0]!r} (the StaticOptions fields: {', '.join(known)})")


def _shown(values: np.ndarray) -> str:
    """A per-rod field as the scene gives it: one number, or the list of the rods' values."""
    return repr(float(values.flat[0])) if values.size == 1 else repr(values.tolist())


def check_model_support(robot: Robot, model: str, dynamic: bool = False) -> None:
    """An InputError naming everything in ``robot`` (and, with ``dynamic``, the time stepping)
    that the solver model ``model`` does not solve: the disk model ("disks") is static,
    frictionless and without contact; the closed form ("constant_curvature") is static too, and
    has no friction, contact, displacement control or held tip. Checked where a scene is read,
    after the command line's --model, and where the solvers start. A backbone with sections is
    solved by the static coupled and point models only (``_check_sections``)."""
    _check_sections(robot, model, dynamic)
    if model not in ("disks", "constant_curvature"):
        return
    found = [f"friction (tendons[{k}].friction = {_shown(t.friction)})" for k, t in enumerate(robot.tendons)
             if np.any(t.friction > 0)]
    if robot.obstacles:
        found.append(f"obstacles ({len(robot.obstacles)} [[obstacles]])")
    if model == "constant_curvature":
        found += [f"displacement control (tendons[{k}].control = \"displacement\")"
                  for k, t in enumerate(robot.tendons) if t.control == "displacement"]
        found += ["a held tip ([tip])"] if robot.tip_constraint is not None else []
    if dynamic:
        found.append("dynamics (time stepping: simulate, control, search, gain-grid)")
    if found:
        static = "static, frictionless and without contact" if model == "disks" else "a static closed form"
        raise InputError(f"solver model = \"{model}\" ({static}) does not support {'; '.join(found)}: use model = "
                         "\"coupled\" or \"point\"")


def _check_sections(robot: Robot, model: str, dynamic: bool) -> None:
    """An InputError naming what a backbone with sections is not solved with yet: the solver models
    "disks" and "constant_curvature", dynamics, friction, displacement control, obstacles, a held tip."""
    if not robot.sections:
        return
    found = [f"solver model = \"{model}\""] if model in ("disks", "constant_curvature") else []
    found += [f"friction (tendons[{k}].friction = {_shown(t.friction)})" for k, t in enumerate(robot.tendons)
              if np.any(t.friction > 0)]
    found += [f"displacement control (tendons[{k}].control = \"displacement\")"
              for k, t in enumerate(robot.tendons) if t.control == "displacement"]
    found += [f"obstacles ({len(robot.obstacles)} [[obstacles]])"] if robot.obstacles else []
    found += ["a held tip ([tip])"] if robot.tip_constraint is not None else []
    found += ["dynamics (time stepping: simulate, control, search, gain-grid)"] if dynamic else []
    if found:
        raise InputError(f"a backbone with sections ([[sections]]) is solved by the static \"coupled\" and \"point\" "
                         f"models without friction, displacement control, obstacles or a held tip; not with "
                         f"{'; '.join(found)}")
