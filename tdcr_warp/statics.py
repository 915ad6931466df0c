"""Batched static shooting: ``solve_static(robot, tensions)`` for B rods at once.

Newton on the 6 base unknowns (n(0), m(0)) per rod, with a forward-difference Jacobian
built by parallel probe integrations, Broyden updates between rebuilds, backtracking on the
residual norm, a bounded step, and a per-rod convergence mask. On the CPU the batch is split
over threads (Warp releases the GIL while a CPU kernel runs).
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field, replace

import numpy as np
import warp as wp

from .kernels import layout
from .kernels.rod import MODELS
from .kernels.statics import INTEGRATORS, N_PROBES, make_static_kernels
from .robot import InputError, Robot

__all__ = ["StaticOptions", "StaticSolution", "solve_static"]

PRECISIONS = {"float64": (wp.float64, np.float64), "float32": (wp.float32, np.float32)}


@dataclass(frozen=True)
class StaticOptions:
    """What selects code and stopping rules (host only).

    nodes: integration intervals along s (N; shapes have N + 1 nodes). integrator: "rk4" or
    "euler". model: "coupled" (distributed tendon loads) or "point" (termination loads only).
    precision: "float64" or "float32". tol: Newton stops when the scaled residual, expressed
    as a tip-displacement-like error L |r| [m], is below it (None: 1e-10 m in float64,
    1e-6 m in float32). max_iter: Newton iterations per rod. max_step: bound on a Newton
    step in scaled unknowns. threads: CPU threads (None: all cores; CUDA uses one).
    """

    nodes: int = 50
    integrator: str = "rk4"
    model: str = "coupled"
    precision: str = "float64"
    tol: float | None = None
    max_iter: int = 50
    max_step: float = 10.0
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


def make_grid(length: np.ndarray, tendon_len: np.ndarray, point_s: np.ndarray, nodes: int):
    """Arc-length nodes holding every tendon termination and point load.

    Returns grid (Bg, N+1), term_node (Bg, K), point_node (Bg, P); Bg is 1 unless one of the
    inputs varies per rod. Intervals are shared out over the segments in proportion to
    their length (at least one each).
    """
    K, P = tendon_len.shape[1], point_s.shape[1]
    bg = max(length.shape[0], tendon_len.shape[0], point_s.shape[0])
    keys = np.concatenate([np.broadcast_to(length[:, None], (bg, 1)),
                           np.broadcast_to(tendon_len, (bg, K)),
                           np.broadcast_to(point_s, (bg, P))], axis=1)
    uniq, inverse = np.unique(keys, axis=0, return_inverse=True)
    rows = [_grid_row(row[0], row[1:], nodes) for row in uniq]
    grid = np.stack([r[0] for r in rows])[inverse.ravel()]
    marks = np.stack([r[1] for r in rows])[inverse.ravel()]
    return grid, marks[:, :K].astype(np.int32), marks[:, K:].astype(np.int32)


def _grid_row(L: float, breaks: np.ndarray, nodes: int):
    tol = 1e-12 * L
    pts = np.unique(np.concatenate([breaks, [L]]))
    pts = pts[np.concatenate([[True], np.diff(pts) > tol])]
    pts = pts[pts > tol]
    if len(pts) > nodes:
        raise InputError(f"solver nodes = {nodes} is fewer than the {len(pts)} segments set by "
                         "tendon terminations and point loads")
    seg = np.diff(np.concatenate([[0.0], pts]))
    ideal = nodes * seg / L
    count = np.maximum(1, np.floor(ideal)).astype(int)
    while count.sum() < nodes:
        count[np.argmax(ideal - count)] += 1
    while count.sum() > nodes:
        count[np.argmax(np.where(count > 1, count - ideal, -np.inf))] -= 1
    starts = np.concatenate([[0.0], pts[:-1]])
    grid = np.concatenate([np.linspace(a, b, c, endpoint=False) for a, b, c in zip(starts, pts, count)]
                          + [[L]])
    node_of = np.concatenate([[0], np.cumsum(count)])
    marks = np.array([node_of[np.argmin(np.abs(np.concatenate([[0.0], pts]) - b))] for b in breaks],
                     dtype=np.int64)
    return grid, marks


def straight_guess(robot: Robot, tensions: np.ndarray) -> np.ndarray:
    """n(0), m(0) (B, 6) of the straight rod under the same loads: the Newton start."""
    B = tensions.shape[0]
    e3 = np.array([0.0, 0.0, 1.0])
    L = np.broadcast_to(robot.length, (B,))
    sec = robot.section()
    fe = np.broadcast_to((robot.density * sec["area"])[:, None] * robot.gravity, (B, 3))
    n0 = np.broadcast_to(robot.tip_force, (B, 3)) + fe * L[:, None]
    m0 = (np.broadcast_to(robot.tip_moment, (B, 3))
          + np.cross(L[:, None] * e3, np.broadcast_to(robot.tip_force, (B, 3)))
          + np.cross(0.5 * (L**2)[:, None] * e3, fe))
    if robot.tendons:
        tl = np.broadcast_to(robot.tendon_lengths(), (B, robot.n_tendons))
        tendon = np.broadcast_to(robot.pack_tendons(), (B, robot.n_tendons, layout.TENDON_WIDTH))
        for k in range(robot.n_tendons):
            x0, y0, a, w, ph = (tendon[:, k, c] for c in range(layout.TENDON_WIDTH))
            ang = w * tl[:, k] + ph
            r = np.stack([x0 + a * np.cos(ang), y0 + a * np.sin(ang), 0 * ang], axis=-1)
            t = np.stack([-a * w * np.sin(ang), a * w * np.cos(ang), 1 + 0 * ang], axis=-1)
            F = -tensions[:, k, None] * t / np.linalg.norm(t, axis=-1, keepdims=True)
            n0 = n0 + F
            m0 = m0 + np.cross(tl[:, k, None] * e3 + r, F)
    if robot.point_forces:
        ps, pf = robot.pack_point_forces()
        ps = np.broadcast_to(ps, (B, ps.shape[1]))
        pf = np.broadcast_to(pf, (B,) + pf.shape[1:])
        n0 = n0 + pf.sum(axis=1)
        m0 = m0 + np.cross(ps[..., None] * e3, pf).sum(axis=1)
    return np.concatenate([n0, m0], axis=1)


def _scales(robot: Robot, B: int) -> np.ndarray:
    """Per-rod factors that turn [n(0), m(0)] into the kernels' scaled unknowns, (B, 6)."""
    L = np.broadcast_to(robot.length, (B,))
    EI = np.broadcast_to(robot.section()["kbt"][:, 0], (B,))
    return np.concatenate([np.repeat((L**2 / EI)[:, None], 3, 1), np.repeat((L / EI)[:, None], 3, 1)], 1)


def _check_tensions(robot: Robot, tensions) -> np.ndarray:
    try:
        tau = np.array(tensions, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"tensions: expected a B x K array of numbers, got {tensions!r}") from None
    K = robot.n_tendons
    if tau.ndim == 1 and tau.shape[0] == K:
        tau = tau[None]
    if tau.ndim != 2 or tau.shape[1] != K:
        raise InputError(f"tensions: expected shape (B, {K}) for {K} tendons, got {tau.shape}")
    if robot.batch_size > 1 and tau.shape[0] == 1:
        tau = np.repeat(tau, robot.batch_size, axis=0)
    if robot.batch_size > 1 and tau.shape[0] != robot.batch_size:
        raise InputError(f"tensions: {tau.shape[0]} rows for a robot batch of {robot.batch_size} rods")
    bad = ~np.isfinite(tau) | (tau < 0)
    if bad.any():
        b, k = np.argwhere(bad)[0]
        raise InputError(f"tensions[{b}][{k}] must be a finite number >= 0 (tendons only pull), got {float(tau[b, k])!r}")
    return tau


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
    tau = _check_tensions(robot, tensions)
    B = tau.shape[0]
    wdtype, ndtype = PRECISIONS[opts.precision]
    dev = wp.get_device(device)
    kern = make_static_kernels(wdtype, opts.integrator, opts.model)

    grid, term_node, point_node = make_grid(robot.length, robot.tendon_lengths() if robot.tendons
                                            else np.zeros((1, 0)), robot.pack_point_forces()[0],
                                            opts.nodes)
    scales = _scales(robot, B)
    if initial is not None:
        if initial.base_wrench.shape[0] != B:
            raise InputError(f"initial: warm start has {initial.base_wrench.shape[0]} rods, batch has {B}")
        x0 = initial.base_wrench * scales
        J0 = initial.jacobian
    else:
        x0 = straight_guess(robot, tau) * scales
        J0 = None
    host = {
        "rod": robot.pack_rod(), "tendon": robot.pack_tendons(), "grid": grid,
        "term_node": term_node, "pforce": robot.pack_point_forces()[1], "pnode": point_node,
    }
    n_threads = 1 if dev.is_cuda else (opts.threads or os.cpu_count() or 1)
    n_threads = max(1, min(n_threads, B // 32 if B >= 64 else 1))
    bounds = np.linspace(0, B, n_threads + 1).astype(int)
    chunks = list(zip(bounds[:-1], bounds[1:]))
    for k in (kern.shoot, kern.newton):  # compile before the threads race to it
        k.module.load(dev, 1 if dev.is_cpu else 256)

    def run(lo_hi):
        lo, hi = lo_hi
        part = {k: (v[lo:hi] if v.shape[0] > 1 else v) for k, v in host.items()}
        return _solve_chunk(kern, part, tau[lo:hi], x0[lo:hi], None if J0 is None else J0[lo:hi],
                            opts, wdtype, ndtype, dev)

    if len(chunks) == 1:
        parts = [run(chunks[0])]
    else:
        with ThreadPoolExecutor(len(chunks)) as pool:
            parts = list(pool.map(run, chunks))
    out = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    out["base_wrench"] = out.pop("x") / scales
    s = np.broadcast_to(grid, (B, grid.shape[1])).astype(np.float64)
    return StaticSolution(s=s, options=opts, **out)


def _pad(a: np.ndarray, shape_min: tuple) -> np.ndarray:
    """Kernels take at least one column; empty tendon/point tables become zero-filled."""
    if a.shape[1] > 0:
        return a
    return np.zeros((a.shape[0],) + shape_min, dtype=a.dtype)


def _solve_chunk(kern, host, tau, x0, J0, opts: StaticOptions, wdtype, ndtype, dev):
    b = tau.shape[0]
    N1 = host["grid"].shape[1]
    K, P = host["tendon"].shape[1], host["pforce"].shape[1]

    def arr(a, dtype=None):
        a = np.ascontiguousarray(a)
        if dtype is None:
            dtype = wp.dtype_from_numpy(a.dtype)
        return wp.array(a, dtype=dtype, device=dev)

    rod = arr(host["rod"].astype(ndtype))
    tendon = arr(_pad(host["tendon"], (1, layout.TENDON_WIDTH)).astype(ndtype))
    tau_w = arr(_pad(tau, (1,)).astype(ndtype))
    grid = arr(host["grid"].astype(ndtype))
    term_node = arr(_pad(host["term_node"], (1,)).astype(np.int32))
    pforce = arr(_pad(host["pforce"], (1, 3)).astype(ndtype))
    pnode = arr(_pad(host["pnode"], (1,)).astype(np.int32))

    x = wp.zeros(b, dtype=kern.vec6, device=dev)
    r = wp.zeros(b, dtype=kern.vec6, device=dev)
    xt = arr(x0.astype(ndtype), kern.vec6)
    if J0 is None:
        J = wp.zeros(b, dtype=kern.mat66, device=dev)
        need_jac = wp.ones(b, dtype=int, device=dev)
    else:
        J = arr(J0.astype(ndtype), kern.mat66)
        need_jac = wp.zeros(b, dtype=int, device=dev)
    active = wp.ones(b, dtype=int, device=dev)
    flags = wp.zeros(b, dtype=int, device=dev)
    lam = wp.ones(b, dtype=wdtype, device=dev)
    status = wp.zeros(b, dtype=int, device=dev)
    iters = wp.zeros(b, dtype=int, device=dev)
    n_shoot = wp.zeros(b, dtype=int, device=dev)
    resnorm = wp.full(b, np.inf, dtype=wdtype, device=dev)
    n_active = wp.zeros(1, dtype=int, device=dev)
    res = wp.zeros((b, N_PROBES), dtype=kern.vec6, device=dev)
    p_out = wp.zeros((b, N1), dtype=kern.vec3, device=dev)
    R_out = wp.zeros((b, N1), dtype=kern.mat33, device=dev)
    n_out = wp.zeros((b, N1), dtype=kern.vec3, device=dev)
    m_out = wp.zeros((b, N1), dtype=kern.vec3, device=dev)
    orth = wp.zeros(b, dtype=wdtype, device=dev)

    common = [rod, tendon, tau_w, grid, term_node, pforce, pnode, K, P]
    outs = [p_out, R_out, n_out, m_out, orth]
    for _ in range(opts.max_iter):
        wp.launch(kern.shoot, dim=b * N_PROBES, inputs=common + [xt, active, need_jac, 1, res] + outs,
                  device=dev)
        n_active.zero_()
        wp.launch(kern.newton, dim=b, device=dev,
                  inputs=[rod, res, wdtype(opts.tolerance), opts.max_iter, wdtype(opts.max_step),
                          x, r, J, xt, active, need_jac, flags, lam, status, iters, n_shoot,
                          resnorm, n_active])
        if int(n_active.numpy()[0]) == 0:
            break
    # Rods that stopped without converging: store the shape of their last accepted point.
    st = status.numpy()
    st[(active.numpy() != 0) & (st == 0)] |= layout.MAX_ITER
    fl = flags.numpy()
    redo = ((st & layout.CONVERGED) == 0) & ((fl & 1) != 0)
    if redo.any():
        need_jac.zero_()
        wp.launch(kern.shoot, dim=b * N_PROBES, device=dev,
                  inputs=common + [x, arr(redo.astype(np.int32)), need_jac, 1, res] + outs)
    f64 = np.float64
    return {
        "positions": p_out.numpy().astype(f64), "rotations": R_out.numpy().astype(f64),
        "n": n_out.numpy().astype(f64), "m": m_out.numpy().astype(f64),
        "x": x.numpy().astype(f64), "converged": (st & layout.CONVERGED) != 0, "status": st,
        "iterations": iters.numpy(), "integrations": n_shoot.numpy(),
        "residual": resnorm.numpy().astype(f64), "orthogonality_error": orth.numpy().astype(f64),
        "jacobian": J.numpy().astype(f64),
    }
