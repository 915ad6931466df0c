"""Host side of batched shooting, shared by statics and dynamics.

``ShootingBatch`` owns the device arrays of one chunk of rods (allocated once) and runs the
per-rod Newton loop of ``kernels/shooting.py``; ``split`` and ``parallel`` share a batch out
over CPU threads (Warp releases the GIL while a CPU kernel runs).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import warp as wp

from .kernels import layout
from .kernels.rod import ALL, SLOT_WIDTH, Features
from .kernels.shooting import make_shooting_kernels
from .robot import InputError, Robot

PRECISIONS = {"float64": (wp.float64, np.float64), "float32": (wp.float32, np.float32)}


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
    ends = np.concatenate([[0.0], pts])
    marks = np.array([node_of[np.argmin(np.abs(ends - b))] for b in breaks], dtype=np.int64)
    return grid, marks


def straight_guess(robot: Robot, tensions: np.ndarray) -> np.ndarray:
    """n(0), m(0) (B, 6) of the straight rod under the same loads: the Newton start."""
    B = tensions.shape[0]
    e3 = np.array([0.0, 0.0, 1.0])
    L = np.broadcast_to(robot.length, (B,))
    sec = robot.section()
    fe = np.broadcast_to((robot.density * sec["area"])[:, None] * robot.gravity, (B, 3))
    tip_f = np.broadcast_to(robot.tip_force, (B, 3))
    n0 = tip_f + fe * L[:, None]
    m0 = (np.broadcast_to(robot.tip_moment, (B, 3)) + np.cross(L[:, None] * e3, tip_f)
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


def unknown_scales(robot: Robot, B: int) -> np.ndarray:
    """Per-rod factors that turn [n(0), m(0)] into the kernels' scaled unknowns, (B, 6)."""
    L = np.broadcast_to(robot.length, (B,))
    EI = np.broadcast_to(robot.section()["kbt"][:, 0], (B,))
    return np.concatenate([np.repeat((L**2 / EI)[:, None], 3, 1), np.repeat((L / EI)[:, None], 3, 1)], 1)


def check_tensions(robot: Robot, tensions, name: str = "tensions") -> np.ndarray:
    """Tensions as a (B, K) float64 array, each finite and >= 0, or an InputError."""
    try:
        tau = np.array(tensions, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{name}: expected a B x K array of numbers, got {tensions!r}") from None
    K = robot.n_tendons
    if tau.ndim == 1 and tau.shape[0] == K:
        tau = tau[None]
    if tau.ndim != 2 or tau.shape[1] != K:
        raise InputError(f"{name}: expected shape (B, {K}) for {K} tendons, got {tau.shape}")
    if robot.batch_size > 1 and tau.shape[0] == 1:
        tau = np.repeat(tau, robot.batch_size, axis=0)
    if robot.batch_size > 1 and tau.shape[0] != robot.batch_size:
        raise InputError(f"{name}: {tau.shape[0]} rows for a robot batch of {robot.batch_size} rods")
    bad = ~np.isfinite(tau) | (tau < 0)
    if bad.any():
        b, k = np.argwhere(bad)[0]
        raise InputError(f"{name}[{b}][{k}] must be a finite number >= 0 (tendons only pull), "
                         f"got {float(tau[b, k])!r}")
    return tau


def host_tables(robot: Robot, nodes: int) -> dict[str, np.ndarray]:
    """The packed per-rod tables the kernels read (leading dimension 1 or B)."""
    tendon_len = robot.tendon_lengths() if robot.tendons else np.zeros((1, 0))
    point_s, point_f = robot.pack_point_forces()
    grid, term_node, point_node = make_grid(robot.length, tendon_len, point_s, nodes)
    return {"rod": robot.pack_rod(), "tendon": robot.pack_tendons(), "grid": grid,
            "term_node": term_node, "pforce": point_f, "pnode": point_node}


def scene_features(robot: Robot, specialize: bool) -> Features:
    """The physics this batch contains (all of it when ``specialize`` is off)."""
    if not specialize:
        return ALL
    tendon = robot.pack_tendons()
    return Features(gravity=bool(np.any(robot.gravity != 0) and np.any(robot.density > 0)),
                    point_loads=len(robot.point_forces) > 0,
                    helix=bool(np.any(tendon[..., layout.T_A] != 0)),
                    drag=bool(np.any(robot.drag != 0)))


def split(B: int, device, threads: int | None) -> list[tuple[int, int]]:
    """Rod ranges, one per CPU thread (one range on CUDA or for small batches)."""
    n = 1 if device.is_cuda else (threads or os.cpu_count() or 1)
    n = max(1, min(n, B // 32 if B >= 64 else 1))
    bounds = np.linspace(0, B, n + 1).astype(int)
    return list(zip(bounds[:-1], bounds[1:]))


def parallel(fn, items: list):
    """Run fn over items, on threads when there is more than one."""
    if len(items) == 1:
        return [fn(items[0])]
    with ThreadPoolExecutor(len(items)) as pool:
        return list(pool.map(fn, items))


def rows(table: np.ndarray, lo: int, hi: int) -> np.ndarray:
    """Rows lo:hi of a per-rod table; a shared table (leading 1) stays as it is."""
    return table[lo:hi] if table.shape[0] > 1 else table


def _pad(a: np.ndarray, shape_min: tuple) -> np.ndarray:
    """Kernels take at least one column; empty tendon/point tables become zero-filled."""
    if a.shape[1] > 0:
        return a
    return np.zeros((a.shape[0],) + shape_min, dtype=a.dtype)


class ShootingBatch:
    """Device arrays and the Newton loop for one chunk of b rods (allocated once).

    host: packed tables (``host_tables``, already restricted to the chunk); tau: (b, K);
    dyn: (1|b, DYN_WIDTH) dynamics table or None for statics.
    """

    def __init__(self, *, host: dict, tau: np.ndarray, precision: str, integrator: str, model: str,
                 device, dyn: np.ndarray | None = None, rod: str = "cosserat", features: Features = ALL):
        self.dev = device
        self.wdtype, self.ndtype = PRECISIONS[precision]
        self.dynamic = dyn is not None
        self.kern = make_shooting_kernels(self.wdtype, integrator, model, self.dynamic, rod, features)
        k = self.kern
        b = tau.shape[0]
        self.b = b
        n1 = host["grid"].shape[1]
        a = k.RodArgs()
        a.rod = self.array(host["rod"])
        a.tendon = self.array(_pad(host["tendon"], (1, layout.TENDON_WIDTH)))
        a.tau = self.array(_pad(tau, (1,)))
        a.grid = self.array(host["grid"])
        a.term_node = self.array(_pad(host["term_node"], (1,)), np.int32)
        a.pforce = self.array(_pad(host["pforce"], (1, 3)))
        a.pnode = self.array(_pad(host["pnode"], (1,)), np.int32)
        a.n_tendons = host["tendon"].shape[1]
        a.n_points = host["pforce"].shape[1]
        self.n_slots = (n1 - 1) * k.stages + 2 * n1 if self.dynamic else 1
        a.dyn = self.array(dyn if self.dynamic else np.zeros((1, layout.DYN_WIDTH)))
        hist_rows = b if self.dynamic else 1
        a.hist = wp.zeros((hist_rows, self.n_slots, SLOT_WIDTH), dtype=k.vec3, device=device)
        a.ycur = wp.zeros((hist_rows, self.n_slots, SLOT_WIDTH), dtype=k.vec3, device=device)
        a.c0 = self.wdtype(0.0)
        self.args = a
        out = k.Shapes()
        out.p = wp.zeros((b, n1), dtype=k.vec3, device=device)
        out.R = wp.zeros((b, n1), dtype=k.mat33, device=device)
        out.n = wp.zeros((b, n1), dtype=k.vec3, device=device)
        out.m = wp.zeros((b, n1), dtype=k.vec3, device=device)
        qw_rows = b if self.dynamic else 1
        out.q = wp.zeros((qw_rows, n1 if self.dynamic else 1), dtype=k.vec3, device=device)
        out.w = wp.zeros((qw_rows, n1 if self.dynamic else 1), dtype=k.vec3, device=device)
        out.orth = wp.zeros(b, dtype=self.wdtype, device=device)
        self.out = out
        self.x = wp.zeros(b, dtype=k.vec6, device=device)
        self.r = wp.zeros(b, dtype=k.vec6, device=device)
        self.xt = wp.zeros(b, dtype=k.vec6, device=device)
        self.J = wp.zeros(b, dtype=k.mat66, device=device)
        self.need_jac = wp.zeros(b, dtype=int, device=device)
        self.active = wp.zeros(b, dtype=int, device=device)
        self.flags = wp.zeros(b, dtype=int, device=device)
        self.lam = wp.zeros(b, dtype=self.wdtype, device=device)
        self.status = wp.zeros(b, dtype=int, device=device)
        self.iters = wp.zeros(b, dtype=int, device=device)
        self.n_shoot = wp.zeros(b, dtype=int, device=device)
        self.resnorm = wp.zeros(b, dtype=self.wdtype, device=device)
        self.n_active = wp.zeros(1, dtype=int, device=device)
        self.res = wp.zeros((b, k.n_probes), dtype=k.vec6, device=device)
        for kernel in (k.shoot, k.newton):  # compile (or load) before threads race to it
            kernel.module.load(device, 1 if device.is_cpu else 256)

    def array(self, a: np.ndarray, ndtype=None) -> wp.array:
        a = np.ascontiguousarray(a, dtype=ndtype or self.ndtype)
        return wp.array(a, dtype=wp.dtype_from_numpy(a.dtype), device=self.dev)

    def put(self, dest: wp.array, values: np.ndarray) -> None:
        """Copy host values into an existing device array (of any vector/matrix dtype)."""
        scalar = np.int32 if dest.dtype in (wp.int32, int) else self.ndtype
        dest.assign(np.ascontiguousarray(values, dtype=scalar))

    def set_tensions(self, tau: np.ndarray) -> None:
        self.put(self.args.tau, _pad(tau, (1,)))

    def evaluate(self, x: np.ndarray) -> None:
        """One integration per rod from scaled unknowns x (b, 6), storing shapes and slots."""
        self.put(self.xt, x)
        self.active.fill_(1)
        self.need_jac.zero_()
        wp.launch(self.kern.shoot, dim=self.b * self.kern.n_probes, device=self.dev,
                  inputs=[self.args, self.xt, self.active, self.need_jac, self.res, self.out])

    def solve(self, x0: np.ndarray | None, J0: np.ndarray | None, *, tol: float, max_iter: int,
              max_step: float, broyden: bool, mask: np.ndarray | None = None,
              keep_jacobian: bool = False) -> None:
        """Newton from scaled unknowns x0 (b, 6) (None: the last solution) and Jacobian J0
        (b, 6, 6) (None: finite differences first, unless ``keep_jacobian`` reuses the last
        one) for the rods in ``mask`` (default all); the others keep their last results."""
        k, dev = self.kern, self.dev
        if x0 is None:
            wp.copy(self.xt, self.x)
        else:
            self.put(self.xt, x0)
        if J0 is not None:
            self.put(self.J, J0)
        self.need_jac.fill_(0 if (J0 is not None or keep_jacobian) else 1)
        if mask is None or np.all(mask):
            self.put(self.active, np.ones(self.b))
            for arr in (self.flags, self.status, self.iters, self.n_shoot):
                arr.zero_()
            self.lam.fill_(1.0)
            self.resnorm.fill_(np.inf)
        else:  # reset only the rods being solved; the others keep their results
            m = np.asarray(mask).astype(bool)
            self.put(self.active, m)
            for arr, value in ((self.flags, 0), (self.status, 0), (self.iters, 0), (self.n_shoot, 0),
                               (self.lam, 1.0), (self.resnorm, np.inf)):
                a = arr.numpy().copy()
                a[m] = value
                self.put(arr, a)
        for _ in range(max_iter):
            wp.launch(k.shoot, dim=self.b * self.kern.n_probes, device=dev,
                      inputs=[self.args, self.xt, self.active, self.need_jac, self.res, self.out])
            self.n_active.zero_()
            wp.launch(k.newton, dim=self.b, device=dev,
                      inputs=[self.args.rod, self.res, self.wdtype(tol), max_iter, self.wdtype(max_step),
                              int(broyden), self.x, self.r, self.J, self.xt, self.active, self.need_jac,
                              self.flags, self.lam, self.status, self.iters, self.n_shoot, self.resnorm,
                              self.n_active])
            if int(self.n_active.numpy()[0]) == 0:
                break
        status = self.status.numpy()
        status[(self.active.numpy() != 0) & (status == 0)] |= layout.MAX_ITER
        self.put(self.status, status)
        # Rods that stopped without converging: store the shape of their last accepted point
        # (the converged ones stored theirs at their last, accepted, evaluation).
        redo = ((status & layout.CONVERGED) == 0) & ((self.flags.numpy() & 1) != 0)
        if mask is not None:
            redo &= mask.astype(bool)
        if redo.any():
            self.need_jac.zero_()
            wp.launch(k.shoot, dim=self.b * self.kern.n_probes, device=dev,
                      inputs=[self.args, self.x, self.array(redo, np.int32), self.need_jac, self.res,
                              self.out])

    def homotopy(self, set_load, steps: int, mask: np.ndarray, x0: np.ndarray, newton: dict):
        """Follow a load path for the rods in ``mask``: ``set_load(lam)`` sets the problem at
        lam = 1/steps, ..., 1, each solved from the last solution (the first from ``x0``). Rods
        that fail on the way stop there, flagged. Returns the iterations and integrations each
        rod spent, summed over the path."""
        on_path = mask.copy()
        iters = np.zeros(self.b, dtype=np.int64)
        shots = np.zeros(self.b, dtype=np.int64)
        for j in range(1, steps + 1):
            set_load(j / steps)
            self.solve(x0 if j == 1 else None, None, mask=on_path, keep_jacobian=j > 1, **newton)
            iters[on_path] += self.iters.numpy()[on_path]
            shots[on_path] += self.n_shoot.numpy()[on_path]
            on_path &= (self.status.numpy() & layout.CONVERGED) != 0
            if not on_path.any():
                break
        return iters, shots

    def results(self) -> dict[str, np.ndarray]:
        f64 = np.float64
        status = self.status.numpy()
        return {
            "positions": self.out.p.numpy().astype(f64), "rotations": self.out.R.numpy().astype(f64),
            "n": self.out.n.numpy().astype(f64), "m": self.out.m.numpy().astype(f64),
            "x": self.x.numpy().astype(f64), "converged": (status & layout.CONVERGED) != 0,
            "status": status, "iterations": self.iters.numpy(), "integrations": self.n_shoot.numpy(),
            "residual": self.resnorm.numpy().astype(f64),
            "orthogonality_error": self.out.orth.numpy().astype(f64),
            "jacobian": self.J.numpy().astype(f64),
        }
