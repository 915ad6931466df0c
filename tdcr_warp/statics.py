"""Batched static shooting: ``solve_static(robot, tensions)`` for B rods at once.

Newton on the 6 base unknowns (n(0), m(0)) per rod, with a forward-difference Jacobian
built by parallel probe integrations, Broyden updates between rebuilds, backtracking on the
residual norm, a bounded step, and a per-rod convergence mask. On the CPU the batch is split
over threads (Warp releases the GIL while a CPU kernel runs).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace

import numpy as np
import warp as wp

from .kernels import layout
from .kernels.rod import MODELS
from .kernels.shooting import INTEGRATORS
from .robot import InputError, Robot
from .shooting import (PRECISIONS, ShootingBatch, check_tensions, host_tables, parallel, rows, split,
                       straight_guess, unknown_scales)

__all__ = ["StaticOptions", "StaticSolution", "solve_static"]


@dataclass(frozen=True)
class StaticOptions:
    """What selects code and stopping rules (host only).

    nodes: integration intervals along s (N; shapes have N + 1 nodes). integrator: "rk4" or
    "euler". model: "coupled" (distributed tendon loads) or "point" (termination loads only).
    precision: "float64" or "float32". tol: Newton stops when the scaled residual, expressed
    as a tip-displacement-like error L |r| [m], is below it (None: 1e-10 m in float64,
    1e-6 m in float32). max_iter: Newton iterations per rod. max_step: bound on a Newton
    step in scaled unknowns. jacobian: "broyden" (finite differences once, then rank-one
    updates; a rebuild when a step fails) or "newton" (finite differences at every
    iterate). threads: CPU threads (None: all cores; CUDA uses one).
    """

    nodes: int = 50
    integrator: str = "rk4"
    model: str = "coupled"
    precision: str = "float64"
    tol: float | None = None
    max_iter: int = 50
    max_step: float = 10.0
    jacobian: str = "broyden"
    threads: int | None = None

    def __post_init__(self):
        if not isinstance(self.nodes, int) or isinstance(self.nodes, bool) or self.nodes < 1:
            raise InputError(f"solver nodes must be a positive integer, got {self.nodes!r}")
        if self.integrator not in INTEGRATORS:
            raise InputError(f"solver integrator must be one of {INTEGRATORS}, got {self.integrator!r}")
        if self.model not in MODELS:
            raise InputError(f"solver model must be one of {MODELS}, got {self.model!r}")
        if self.precision not in PRECISIONS:
            raise InputError(f"solver precision must be one of {tuple(PRECISIONS)}, got {self.precision!r}")
        if self.tol is not None and not (self.tol > 0 and math.isfinite(self.tol)):
            raise InputError(f"solver tol must be a positive number, got {self.tol!r}")
        if not isinstance(self.max_iter, int) or self.max_iter < 1:
            raise InputError(f"solver max_iter must be a positive integer, got {self.max_iter!r}")
        if not (self.max_step > 0):
            raise InputError(f"solver max_step must be positive, got {self.max_step!r}")
        if self.jacobian not in ("broyden", "newton"):
            raise InputError(f"solver jacobian must be 'broyden' or 'newton', got {self.jacobian!r}")
        if self.threads is not None and (not isinstance(self.threads, int) or self.threads < 1):
            raise InputError(f"solver threads must be a positive integer, got {self.threads!r}")

    @property
    def tolerance(self) -> float:
        if self.tol is not None:
            return self.tol
        return 1e-10 if self.precision == "float64" else 1e-6


@dataclass
class StaticSolution:
    """Solved shapes and diagnostics of B rods (float64 NumPy arrays on the host).

    s: (B, N+1) arc length of the nodes [m]; positions: (B, N+1, 3) [m]; rotations:
    (B, N+1, 3, 3) body-to-world; n, m: (B, N+1, 3) internal force [N] and moment [N m]
    (world frame) just proximal of each node (so n[:, -1] = n(L-), before the tip loads);
    tip_position (B, 3), tip_rotation (B, 3, 3); base_wrench (B, 6) = [n(0), m(0)].
    converged (B,) bool; status (B,) bit flags (kernels/layout.py); iterations (B,);
    integrations (B,): base-to-tip integrations spent; residual (B,): L |r| [m];
    orthogonality_error (B,): max |R^T R - I| over the nodes; jacobian (B, 6, 6): the last
    scaled shooting Jacobian (reused by a warm start).
    """

    s: np.ndarray
    positions: np.ndarray
    rotations: np.ndarray
    n: np.ndarray
    m: np.ndarray
    base_wrench: np.ndarray
    converged: np.ndarray
    status: np.ndarray
    iterations: np.ndarray
    integrations: np.ndarray
    residual: np.ndarray
    orthogonality_error: np.ndarray
    jacobian: np.ndarray
    options: StaticOptions = field(repr=False)

    @property
    def tip_position(self) -> np.ndarray:
        return self.positions[:, -1]

    @property
    def tip_rotation(self) -> np.ndarray:
        return self.rotations[:, -1]

    def failure_reasons(self) -> list[str]:
        """One string per rod: "converged" or why it failed."""
        out = []
        for st in self.status:
            names = [v for k, v in layout.STATUS_NAMES.items() if int(st) & k]
            out.append(", ".join(names) if names else "not converged")
        return out

    def to_npz(self, path) -> None:
        arrays = {k: v for k, v in asdict(self).items() if isinstance(v, np.ndarray)}
        np.savez_compressed(path, **arrays)


def solve_static(robot: Robot, tensions, *, options: StaticOptions | None = None,
                 device: str | None = None, initial: StaticSolution | None = None,
                 **overrides) -> StaticSolution:
    """Solve the statics of a batch of rods.

    robot: the batch (shared or per-rod fields); tensions: (B, K) [N], each >= 0.
    options / overrides: :class:`StaticOptions` fields (nodes, integrator, model, ...).
    device: "cpu" or "cuda:0" (None: Warp's default). initial: an earlier solution of the
    same batch size to warm-start from (its base wrench and Jacobian).
    """
    opts = replace(options or StaticOptions(), **overrides)
    tau = check_tensions(robot, tensions)
    B = tau.shape[0]
    dev = wp.get_device(device)
    host = host_tables(robot, opts.nodes)
    scales = unknown_scales(robot, B)
    if initial is not None:
        if initial.base_wrench.shape[0] != B:
            raise InputError(f"initial: warm start has {initial.base_wrench.shape[0]} rods, batch has {B}")
        x0 = initial.base_wrench * scales
        J0 = initial.jacobian
    else:
        x0 = straight_guess(robot, tau) * scales
        J0 = None
    chunks = split(B, dev, opts.threads)
    batches = [ShootingBatch(host={k: rows(v, lo, hi) for k, v in host.items()}, tau=tau[lo:hi],
                             precision=opts.precision, integrator=opts.integrator, model=opts.model,
                             device=dev) for lo, hi in chunks]

    def run(i):
        lo, hi = chunks[i]
        batches[i].solve(x0[lo:hi], None if J0 is None else J0[lo:hi], tol=opts.tolerance,
                         max_iter=opts.max_iter, max_step=opts.max_step,
                         broyden=opts.jacobian == "broyden")
        return batches[i].results()

    parts = parallel(run, list(range(len(chunks))))
    out = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    out["base_wrench"] = out.pop("x") / scales
    grid = host["grid"]
    s = np.broadcast_to(grid, (B, grid.shape[1])).astype(np.float64)
    return StaticSolution(s=s, options=opts, **out)



