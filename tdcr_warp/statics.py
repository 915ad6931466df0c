"""Batched static shooting: ``solve_static(robot, tensions)`` for B rods at once.

Newton on the 6 base unknowns (n(0), m(0)) per rod (kernels/newton.py), with a
forward-difference Jacobian, Broyden updates between rebuilds, backtracking on the residual
norm, a bounded step and a per-rod verdict; a per-rod load continuation where the start is
far from the answer (tdcr_warp/homotopy.py). On the CPU the batch is split over threads
(Warp releases the GIL while a CPU kernel runs). Repeated solves of the same robot object and
batch shape reuse its device arrays (``StaticProblem``).
"""

from __future__ import annotations

import threading
import weakref
from collections import OrderedDict
from dataclasses import asdict, dataclass, field, replace

import numpy as np
import warp as wp

from .build import Tables
from .homotopy import continuation_steps, load_continuation
from .kernels import layout
from .parallel import parallel, split
from .robot import InputError, Robot, check_tensions, require_memory
from .solver import Shooting
from .types import StaticOptions, describe_status

__all__ = ["StaticOptions", "StaticProblem", "StaticSolution", "solve_static"]


@dataclass
class StaticSolution:
    """Solved shapes and diagnostics of B rods (float64 NumPy arrays on the host).

    s: (B, N+1) arc length of the nodes [m]; positions: (B, N+1, 3) [m]; rotations:
    (B, N+1, 3, 3) body-to-world; n, m: (B, N+1, 3) internal force [N] and moment [N m]
    (world frame) just proximal of each node (so n[:, -1] = n(L-), before the tip loads);
    tip_position (B, 3), tip_rotation (B, 3, 3); base_wrench (B, 6) = [n(0), m(0)].
    converged (B,) bool; status (B,) bit flags (kernels/layout.py); iterations (B,);
    integrations (B,): base-to-tip integrations spent (the 7 of a first Jacobian in a Broyden RK4 solve with
    N >= 16 run over double steps, at about half the cost); residual (B,): L |r| [m];
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


class StaticProblem:
    """The device arrays of one robot batch at one shape (B rods, options, device), built
    once and reused by every solve of that shape: the tables, and per CPU thread the
    Model / Control / State / Work of its rods (tdcr_warp.solver.Shooting)."""

    def __init__(self, robot: Robot, B: int, opts: StaticOptions, device):
        self.robot, self.B, self.opts, self.device = robot, B, opts, device
        self.tables = Tables.of(robot, opts.nodes, opts.specialize)
        self.chunks = split(B, device, opts.threads)
        K = robot.n_tendons
        self.solvers = [Shooting(self.tables, lo, hi, np.zeros((hi - lo, K)), precision=opts.precision,
                                 integrator=opts.integrator, model=opts.model, device=device, rod=opts.rod,
                                 driver=opts.driver)
                        for lo, hi in self.chunks]
        self.lock = threading.Lock()

    def solve(self, tau: np.ndarray, initial: StaticSolution | None) -> StaticSolution:
        opts, tables, B = self.opts, self.tables, self.B
        scales = tables.scale_rows(B)
        if initial is not None:
            if initial.base_wrench.shape[0] != B:
                raise InputError(f"initial: warm start has {initial.base_wrench.shape[0]} rods, batch has {B}")
            x0, J0 = initial.base_wrench / scales, initial.jacobian
        else:
            x0, J0 = tables.straight.guess(tau) / scales, None
        newton = dict(tol=opts.tolerance, max_iter=opts.max_iter, max_step=opts.max_step,
                      broyden=opts.jacobian == "broyden")

        def run(i):
            lo, hi = self.chunks[i]
            sh = self.solvers[i]
            sh.set_tensions(tau[lo:hi])
            if J0 is not None:
                sh.dev.put(sh.newton.J, J0[lo:hi])
            sh.solve(x0[lo:hi], fresh_jacobian=J0 is None, **newton)
            if opts.continuation and initial is None:
                finite, large, steps = continuation_steps(x0[lo:hi], opts.continuation)
                redo = finite & (~sh.converged() | large)
                if redo.any():
                    load_continuation(sh, tables.rows("rod", lo, hi), tables.rows("pforce", lo, hi), tau[lo:hi],
                                      x0[lo:hi], redo, steps, newton)
            return sh.results()

        parts = parallel(run, list(range(len(self.chunks))))
        out = parts[0] if len(parts) == 1 else {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
        out["base_wrench"] = out.pop("x") * scales
        grid = tables.grid
        s = np.broadcast_to(grid, (B, grid.shape[1])).astype(np.float64)
        return StaticSolution(s=s, options=opts, **out)


CACHE_SIZE = 8
CACHE_NODE_RODS = 1 << 17  # cache problems up to B (N + 1) of this (~20 MB of device arrays each)
_cache: OrderedDict = OrderedDict()
_cache_lock = threading.Lock()


def _problem(robot: Robot, B: int, opts: StaticOptions, device) -> tuple[StaticProblem, bool]:
    """A cached problem of this robot object and shape (locked for the caller), or a new one.
    Returns (problem, cached)."""
    if B * (opts.nodes + 1) > CACHE_NODE_RODS:
        return StaticProblem(robot, B, opts, device), False
    key = (id(robot), B, opts if not opts.error_estimate else replace(opts, error_estimate=False), device.alias)
    with _cache_lock:
        hit = _cache.get(key)
        if hit is not None and hit[0]() is robot and hit[1].lock.acquire(blocking=False):
            _cache.move_to_end(key)
            return hit[1], True
    problem = StaticProblem(robot, B, opts, device)
    problem.lock.acquire()
    with _cache_lock:
        _cache[key] = (weakref.ref(robot), problem)
        while len(_cache) > CACHE_SIZE:
            _cache.popitem(last=False)
    return problem, True


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
    problem, locked = _problem(robot, B, opts, dev)
    try:
        sol = problem.solve(tau, initial)
    finally:
        if locked:
            problem.lock.release()
    if opts.error_estimate:
        coarse = solve_static(robot, tau, options=replace(opts, nodes=max(1, opts.nodes // 2), error_estimate=False),
                              device=device, initial=sol)
        order = {"euler": 1, "midpoint": 2, "rk4": 4}[opts.integrator]
        est = 2.0 * np.linalg.norm(sol.tip_position - coarse.tip_position, axis=1) / (2**order - 1)
        sol.tip_error_estimate = np.where(coarse.converged, est, np.inf)
    return sol
