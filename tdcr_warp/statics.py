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
from .kernels.rod import MODELS, RODS
from .kernels.shooting import INTEGRATORS
from .robot import InputError, Robot, require_memory
from .shooting import (PRECISIONS, ShootingBatch, check_tensions, host_tables, parallel, rows, scene_features,
                       split, straight_guess, unknown_scales)

__all__ = ["StaticOptions", "StaticSolution", "describe_status", "solve_static"]


PRESETS = {
    "fast": dict(integrator="rk4", nodes=10, rod="kirchhoff"),
    "balanced": dict(integrator="rk4", nodes=20, rod="cosserat"),
    "accurate": dict(integrator="rk4", nodes=50, rod="cosserat", tol=1e-12),
}


def describe_status(status: int) -> str:
    """The status bits of one rod in words."""
    names = [v for k, v in layout.STATUS_NAMES.items() if int(status) & k]
    return ", ".join(names) if names else "not converged"


@dataclass(frozen=True)
class StaticOptions:
    """What selects code and stopping rules (host only).

    nodes: integration intervals along s (N; shapes have N + 1 nodes). integrator: "rk4",
    "midpoint" or "euler". model: "coupled" (distributed tendon loads), "point" (termination
    loads only) or "constant_curvature" (closed form: straight tendons ending at the tip, no
    external load). rod: "cosserat" (shear, extension) or "kirchhoff" (inextensible,
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
    c = max(continuation, load, sqrt(axial load L^2 / EI)) steps (0: off). threads: CPU threads (None: all cores; CUDA uses one).
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
        ]
        for name, ok, what in checks:
            if not ok:
                raise InputError(f"solver {name} must be {what}, got {getattr(self, name)!r}")

    @classmethod
    def preset(cls, name: str, **overrides) -> "StaticOptions":
        """Named settings chosen from experiments/speed_accuracy.py (see README for the
        measured tip errors): "fast", "balanced" (the defaults at N = 20) or "accurate"."""
        if name not in PRESETS:
            raise InputError(f"solver preset must be one of {tuple(PRESETS)}, got {name!r}")
        return cls(**(PRESETS[name] | overrides))

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
    scaled shooting Jacobian (reused by a warm start). tip_error_estimate (B,) [m]: with
    ``error_estimate`` only.
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
    tip_error_estimate: np.ndarray | None = None

    @property
    def tip_position(self) -> np.ndarray:
        return self.positions[:, -1]

    @property
    def tip_rotation(self) -> np.ndarray:
        return self.rotations[:, -1]

    def failure_reasons(self) -> list[str]:
        """One string per rod: "converged" or why it failed."""
        return [describe_status(st) for st in self.status]

    def to_npz(self, path) -> None:
        arrays = {k: v for k, v in asdict(self).items() if isinstance(v, np.ndarray)}
        np.savez_compressed(path, **arrays)


LARGE_LOAD = 1.5  # scaled bending load of the straight-rod start: |m(0)| L / EI + |n_xy(0)| L^2 / EI
MAX_CONTINUATION = 64


def _continuation(bt: ShootingBatch, host: dict, tau: np.ndarray, x_full: np.ndarray, mask: np.ndarray,
                  steps: int, newton: dict) -> None:
    """Homotopy for the rods in ``mask``: tensions and external loads scaled by lam, from the
    straight-rod start scaled likewise (it is linear in the loads). Iterations and
    integrations add up over the path."""
    rod0, pf0 = host["rod"], host["pforce"]

    def set_load(lam):
        rod = rod0.copy()
        for c in (layout.FE, layout.TIP_F, layout.TIP_M):
            rod[:, c:c + 3] *= lam
        bt.put(bt.args.rod, rod)
        if pf0.shape[1]:
            bt.put(bt.args.pforce, pf0 * lam)
        bt.set_tensions(tau * lam)

    iters, shots = bt.homotopy(set_load, steps, mask, x_full * (1 / steps), newton)
    set_load(1.0)
    touched = shots > 0
    it, sh = bt.iters.numpy().copy(), bt.n_shoot.numpy().copy()
    it[touched], sh[touched] = iters[touched], shots[touched]
    bt.put(bt.iters, it)
    bt.put(bt.n_shoot, sh)


def _constant_curvature(robot: Robot, tau: np.ndarray, opts: StaticOptions) -> StaticSolution:
    """The cheapest rung: closed-form arcs. Straight tendons ending at the tip and no external
    load give the coupled model's exact solution without shear and extension: a constant
    curvature u = Kbt^-1 sum_i r_i x (-tau_i e3), compression n = -sum(tau) t."""
    L = robot.length
    problems = [name for name, bad in (
        ("gravity", np.any(robot.gravity != 0)), ("tip_force", np.any(robot.tip_force != 0)),
        ("tip_moment", np.any(robot.tip_moment != 0)), ("point_forces", bool(robot.point_forces)),
        ("precurvature", np.any(robot.precurvature != 0)),
        ("helical tendons", any(np.any(t.helix_radius != 0) for t in robot.tendons)),
        ("tendons ending before the tip", any(t.length is not None and np.any(t.length < L * (1 - 1e-12))
                                              for t in robot.tendons)))
        if bad]
    if problems:
        raise InputError(f"solver model 'constant_curvature' needs straight tendons ending at the tip and no "
                         f"external load; this scene has {', '.join(problems)}")
    B, N = tau.shape[0], opts.nodes
    e3 = np.array([0.0, 0.0, 1.0])
    kbt = np.broadcast_to(robot.section()["kbt"], (B, 3))
    moment = np.zeros((B, 3))
    for k, t in enumerate(robot.tendons):
        off = np.broadcast_to(t.offset, (B, 2))
        r = np.c_[off, np.zeros(B)]
        moment += np.cross(r, -tau[:, k:k + 1] * e3)
    u = moment / kbt
    kappa = np.linalg.norm(u, axis=1)
    axis = np.where(kappa[:, None] > 0, u / np.maximum(kappa, 1e-300)[:, None], 0.0)
    Lb = np.broadcast_to(L, (B,))
    s = Lb[:, None] * np.linspace(0.0, 1.0, N + 1)[None]
    A = np.zeros((B, 3, 3))
    A[:, 0, 1], A[:, 0, 2], A[:, 1, 2] = -axis[:, 2], axis[:, 1], -axis[:, 0]
    A = A - np.transpose(A, (0, 2, 1))
    ks = kappa[:, None] * s
    eye = np.eye(3)[None, None]
    R = eye + np.sin(ks)[..., None, None] * A[:, None] + (1 - np.cos(ks))[..., None, None] * (A @ A)[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        c1 = np.where(kappa[:, None] > 0, (1 - np.cos(ks)) / kappa[:, None], 0.0)
        c2 = np.where(kappa[:, None] > 0, s - np.sin(ks) / kappa[:, None], 0.0)
    p = (s[..., None] * e3 + c1[..., None] * (A @ e3)[:, None] + c2[..., None] * (A @ A @ e3)[:, None])
    total = tau.sum(axis=1)
    n = -total[:, None, None] * (R @ e3)
    m = np.einsum("bsij,bj->bsi", R, kbt * u)
    status = np.full(B, layout.CONVERGED, dtype=np.int32)
    zeros = np.zeros(B)
    return StaticSolution(s=s, positions=p, rotations=R, n=n, m=m, base_wrench=np.c_[n[:, 0], m[:, 0]],
                          converged=np.ones(B, bool), status=status, iterations=zeros.astype(np.int32),
                          integrations=zeros.astype(np.int32), residual=zeros, orthogonality_error=zeros,
                          jacobian=np.zeros((B, 6, 6)), options=opts,
                          tip_error_estimate=zeros if opts.error_estimate else None)


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
    if opts.model == "constant_curvature":
        return _constant_curvature(robot, tau, opts)
    B = tau.shape[0]
    dev = wp.get_device(device)
    require_memory(B * (opts.nodes + 1) * 400.0, f"nodes = {opts.nodes} for {B} rods: the shapes")
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
    features = scene_features(robot, opts.specialize)
    batches = [ShootingBatch(host={k: rows(v, lo, hi) for k, v in host.items()}, tau=tau[lo:hi],
                             precision=opts.precision, integrator=opts.integrator, model=opts.model,
                             device=dev, rod=opts.rod, features=features) for lo, hi in chunks]

    def run(i):
        lo, hi = chunks[i]
        newton = dict(tol=opts.tolerance, max_iter=opts.max_iter, max_step=opts.max_step,
                      broyden=opts.jacobian == "broyden")
        bt = batches[i]
        bt.solve(x0[lo:hi], None if J0 is None else J0[lo:hi], **newton)
        if opts.continuation and initial is None:
            # Beyond ~1.5 rad of linear bending, Newton from the straight rod may land on another
            # equilibrium (a looped cantilever under a large tip force): follow the load from zero.
            with np.errstate(all="ignore"):  # absurd inputs overflow: those rods are flagged anyway
                load = np.linalg.norm(x0[lo:hi, 3:], axis=1) + np.linalg.norm(x0[lo:hi, :2], axis=1)
                compression = np.sqrt(np.abs(x0[lo:hi, 2]))
            finite = np.isfinite(load) & np.isfinite(compression)
            redo = finite & (((bt.status.numpy() & layout.CONVERGED) == 0) | (load > LARGE_LOAD))
            if redo.any():
                # steps grow with the bending load and with the axial compression measured in
                # Euler loads (sqrt(P L^2 / EI)): slender rods under large tendon loads need more
                hard = np.maximum(load, compression)[redo].max()
                steps = int(np.clip(np.ceil(hard), opts.continuation, MAX_CONTINUATION))
                _continuation(bt, {k: rows(v, lo, hi) for k, v in host.items()}, tau[lo:hi], x0[lo:hi], redo,
                              steps, newton)
        return bt.results()

    parts = parallel(run, list(range(len(chunks))))
    out = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    out["base_wrench"] = out.pop("x") / scales
    grid = host["grid"]
    s = np.broadcast_to(grid, (B, grid.shape[1])).astype(np.float64)
    sol = StaticSolution(s=s, options=opts, **out)
    if opts.error_estimate:
        coarse = solve_static(robot, tau, options=replace(opts, nodes=max(1, opts.nodes // 2), error_estimate=False),
                              device=device, initial=sol)
        order = {"euler": 1, "midpoint": 2, "rk4": 4}[opts.integrator]
        est = 2.0 * np.linalg.norm(sol.tip_position - coarse.tip_position, axis=1) / (2**order - 1)
        sol.tip_error_estimate = np.where(coarse.converged, est, np.inf)
    return sol



