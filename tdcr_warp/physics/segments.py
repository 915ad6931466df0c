"""Multiple shooting of one chunk of rods (kernels/segments.py integrates the segments).

The rod is split at nodes into M segments. The unknowns of a rod, scaled to O(1) like single
shooting's, are the base wrench [n(0) L^2 / EI, m(0) L / EI] and, at the start of each later
segment j, its state: p / L, a rotation vector theta (R = Rref_j exp(theta^), Rref_j updated
after every Newton step so theta stays small), n L^2 / EI, m L / EI and in dynamics q / (L c0), w
/ c0. The residuals are the gaps between each segment's end and the next one's start, scaled the
same way (the rotation's as the rotation vector of R_start^T R_end), then the tip residual of
single shooting; L |r| < tol is convergence, the same measure as single shooting's.

Newton with a Jacobian of central differences at every iterate (2 integrations of a segment per
unknown: about 2 nu / M rod integrations; an unknown moves only the gaps into and out of its
segment, so only those blocks are formed: the Jacobian is banded), solved per rod on the device
by banded LU (kernels/banded.py: O(nz d^2) work, against the O(nz^3) of a dense solve, which
took 70% of a split rod's time at 80 segments), with a backtracking line search on |r|. A rod whose Newton
fails keeps its unknowns and reference rotations. As in single shooting, a step
from that Jacobian shorter than 1e-12 |z| (float32: 1e-5) means z is exact to working precision
and the residual at its round-off floor: converged, PRECISION_LIMITED, if L |r| < 100 tol; so is
a point within 100 tol from which no step along a fresh Newton direction lowers |r| (small dt puts the floor of L |r|
near 2e-10 m on the report's robot, where the axial forces at the segments' starts are fixed only
to ~1e-10 of their scale: 1 / EA is small).
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from tdcr_warp.core.solver import Shooting
from tdcr_warp.kernels import layout
from tdcr_warp.kernels.banded import band_solve, band_widths
from tdcr_warp.kernels.segments import STATE, make_segment_kernel

__all__ = ["Segments", "growth", "rodrigues", "segment_bounds", "segments_needed", "single_shooting_warning"]

PROBE = 1e-8  # the central differences' step, per scaled unknown (1e-6 straddles the contact law's band at rigid
# stiffness, ~1e-9 m wide: the climbs of a bent tube failed at 80 segments; 1e-8 passed them at 40)
FLOOR = {"float64": 1e-12, "float32": 1e-5}  # a Newton step this short (relative to z): round-off
STUCK = 100.0  # no decrease of |r| along a fresh Newton step within this many tol: round-off
HALVINGS = 12  # the line search's


SINGLE_REACH = {"float64": 1e6, "float32": 1e4}  # the amplification of a start error a precision resolves
SWITCH_REACH = {"float64": 1e3, "float32": 1e2}  # beyond it, segments (measured: the report's damped robot fails
# single shooting at an amplification of e^9.1 at dt = 4e-5 s, where its shear waves lead; e^7.2 converges)
SEGMENT_REACH = {"float64": 30.0, "float32": 10.0}  # what multiple shooting allows a segment (measured: fewer, larger segments stall at round-off)


def growth(robot, c_ratio: float, dt: float) -> np.ndarray:
    """(B,) ln of the amplification of a start error along each whole rod in a time step dt [s]
    (BDF-alpha's c0 = c_ratio / dt): the largest of the bending modes', L (rho A c0^2 / (E I + c0
    Bbt))^(1/4) / sqrt 2, and the shear and extension waves', L c0 (rho A / (K + c0 Bse))^(1/2)
    (K: G A, G A, E A); inf where the numbers overflow."""
    sec = robot.section()
    c0 = np.float64(c_ratio) / dt
    rho_a = robot.density * sec["area"]
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        bend = (rho_a[:, None] * c0**2 / (sec["kbt"][:, :2] + c0 * robot.damping_bending[:, :2])).max(axis=1) ** 0.25
        bend = bend / math.sqrt(2)
        wave = np.sqrt((rho_a[:, None] * c0**2 / (sec["kse"] + c0 * robot.damping_shear)).max(axis=1))
        g = robot.length * np.maximum(bend, wave)
    return np.where(np.isfinite(g), g, np.inf)


def segments_needed(robot, precision: str, dt: float, c_ratio: float) -> int:
    """The segments that bring every rod's growth per segment within SEGMENT_REACH (1: single
    shooting resolves dt, its growth within SWITCH_REACH)."""
    g = float(np.max(growth(robot, c_ratio, dt)))
    if g <= math.log(SWITCH_REACH[precision]):
        return 1
    return int(math.ceil(g / math.log(SEGMENT_REACH[precision]))) if math.isfinite(g) else 1 << 30


def single_shooting_warning(robot, precision: str, dt: float, c_ratio: float) -> str | None:
    """Why single shooting may fail at dt (a start error amplified beyond SINGLE_REACH, with the
    dt that stays inside), or None (docs/accuracy.md, robustness)."""
    limit = math.log(SINGLE_REACH[precision])
    g = growth(robot, c_ratio, dt)
    worst = int(np.argmax(g))
    if g[worst] <= limit:
        return None
    lo, hi = math.log(dt), max(math.log(dt), math.log(1e3))  # growth falls as dt grows
    for _ in range(100):  # bisect log dt
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if np.max(growth(robot, c_ratio, math.exp(mid))) > limit else (lo, mid)
    amp = f"1e{g[worst] / math.log(10):.0f}" if math.isfinite(g[worst]) else "beyond float64"
    return (f"dt = {dt:g} s is below the single-shooting limit of {int(np.sum(g > limit))} rod(s) (rod {worst}: "
            f"amplification {amp}; dt >= {math.exp(hi):.1e} s stays inside): steps may fail, and are then flagged "
            "(segments = None splits a rod into as many as it needs, where its variant allows)")


def segment_bounds(n_int: int, count: int) -> np.ndarray:
    """(count + 1,) the nodes that split a grid of n_int intervals into ``count`` segments: the
    first node of each, then n_int."""
    return np.round(np.linspace(0, n_int, count + 1)).astype(np.int32)


def rodrigues(theta: np.ndarray) -> np.ndarray:
    """(..., 3, 3) exp(theta^) of rotation vectors theta (..., 3)."""
    a = np.linalg.norm(theta, axis=-1)[..., None, None]
    k = np.zeros(theta.shape[:-1] + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -theta[..., 2], theta[..., 1], -theta[..., 0]
    k = k - np.swapaxes(k, -1, -2)
    small = a < 1e-8
    s = np.where(small, 1.0 - a**2 / 6, np.sin(a) / np.where(small, 1.0, a))
    c = np.where(small, 0.5 - a**2 / 24, (1 - np.cos(a)) / np.where(small, 1.0, a * a))
    return np.eye(3) + s * k + c * (k @ k)


def _vee(a: np.ndarray) -> np.ndarray:
    """The rotation vector of a near-identity rotation a (..., 3, 3) (its skew part's)."""
    return 0.5 * np.stack([a[..., 2, 1] - a[..., 1, 2], a[..., 0, 2] - a[..., 2, 0], a[..., 1, 0] - a[..., 0, 1]],
                          axis=-1)


def _orthogonality(R: np.ndarray) -> np.ndarray:
    """(b,) max |R^T R - I| over the nodes of rotations R (b, N+1, 3, 3)."""
    return np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max(axis=(1, 2, 3))


def _norm(a: np.ndarray) -> np.ndarray:
    """(b,) |a| of each row of a (b, n); inf where a trial overflowed (NaN or inf entries)."""
    with np.errstate(over="ignore", invalid="ignore"):
        return np.sqrt(np.sum(np.square(np.nan_to_num(a, nan=np.inf)), axis=1))


class BandSystems:
    """The Newton systems of b rods with nz unknowns, d per later segment start, on ``device``:
    assembled on the host by rows (``put``; kernels/banded.py's storage), solved on the device."""

    def __init__(self, b: int, nz: int, d: int, device):
        self.kl, ku = band_widths(d)
        shape = (b, nz, 2 * self.kl + ku + 1)
        self.a = np.zeros(shape)  # every Jacobian writes the same entries: the others stay 0
        self.a_dev = wp.zeros(shape, dtype=wp.float64, device=device)
        self.rhs, self.scale = (wp.zeros((b, nz), dtype=wp.float64, device=device) for _ in range(2))
        self.reach = wp.zeros((b, nz), dtype=int, device=device)
        self.active, self.ok = (wp.zeros(b, dtype=int, device=device) for _ in range(2))
        self.device = device

    def put(self, rows: np.ndarray, cols: np.ndarray, values: np.ndarray) -> None:
        """a[:, rows, cols] = values (rows and cols broadcast; values (b, ...) of their shape)."""
        self.a[:, rows, cols - rows + self.kl] = values

    def solve(self, rhs: np.ndarray, rods: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(b, nz) the solutions of the assembled systems of ``rods`` (b,) for rhs (b, nz) (0
        elsewhere), with (b,) whether each was solved (False: a zero or non-finite pivot)."""
        self.a_dev.assign(self.a)
        self.rhs.assign(rhs)
        self.active.assign(rods.astype(np.int32))
        wp.launch(band_solve, dim=len(rods), device=self.device,
                  inputs=[self.a_dev, self.rhs, self.scale, self.reach, self.kl, self.active, self.ok])
        solved = rods & (self.ok.numpy() != 0)
        return np.where(solved[:, None], self.rhs.numpy(), 0.0), solved


class SegmentUnknowns:
    """The unknowns of b rods in ``count`` segments split at the nodes ``bounds``: their scales,
    the reference rotations, the segments' start states from them and the residual of the gaps;
    rod (b, ROD_WIDTH) the rods' rows, ``c0`` [1/s]: BDF-alpha's (the velocities' scale)."""

    def __init__(self, rod: np.ndarray, bounds: np.ndarray, c0: float, dynamic: bool):
        self.b, self.M, self.bounds, self.dynamic = rod.shape[0], len(bounds) - 1, bounds, dynamic
        L, F, Mo = rod[:, layout.LENGTH], rod[:, layout.FORCE_SCALE], rod[:, layout.MOMENT_SCALE]
        self.L, ones = L, np.ones(self.b)
        self.d = 18 if dynamic else 12
        # the scale of each of a state's d unknowns: p, theta, n, m (, q, w)
        self.scale = np.stack([L] * 3 + [ones] * 3 + [F] * 3 + [Mo] * 3
                              + ([L * c0] * 3 + [ones * c0] * 3 if dynamic else []), axis=1)
        self.base_scale = np.stack([F] * 3 + [Mo] * 3, axis=1)
        self.nz = 6 + self.d * (self.M - 1)
        self.Rref = np.tile(np.eye(3), (self.b, self.M - 1, 1, 1))
        self.z = np.zeros((self.b, self.nz))

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """The unknowns and reference rotations of every rod (a copy, for ``restore``)."""
        return self.z.copy(), self.Rref.copy()

    def restore(self, state: tuple, rods: np.ndarray) -> None:
        """The unknowns and reference rotations of ``rods`` (b,) as a ``state`` held them."""
        self.z[rods], self.Rref[rods] = state[0][rods], state[1][rods]

    def from_nodes(self, out, rods: np.ndarray) -> None:
        """The unknowns of ``rods`` (b,) from a stored shape (a Shooting's ``nodes``): a start."""
        q, w = (out.q.numpy(), out.w.numpy()) if self.dynamic else (None, None)
        self.from_states(out.p.numpy(), out.R.numpy(), out.n.numpy(), out.m.numpy(), rods, q, w)

    def from_states(self, p, R, n, m, rods: np.ndarray, q=None, w=None) -> None:
        """The unknowns of ``rods`` (b,) from the states at every node (b, N+1, ...) (q, w: at rest
        where None)."""
        at = self.bounds[:-1]  # the segments' first nodes
        p, R, n, m = (np.asarray(a)[:, at].astype(np.float64) for a in (p, R, n, m))
        z = [n[:, 0] / self.base_scale[:, :3], m[:, 0] / self.base_scale[:, 3:]]
        if self.dynamic:
            q, w = (np.zeros_like(p) if a is None else np.asarray(a)[:, at].astype(np.float64) for a in (q, w))
        for j in range(1, self.M):
            parts = [p[:, j], np.zeros((self.b, 3)), n[:, j], m[:, j]] + ([q[:, j], w[:, j]] if self.dynamic else [])
            z.append(np.concatenate(parts, axis=1) / self.scale)
        self.z[rods] = np.concatenate(z, axis=1)[rods]
        self.Rref[rods] = R[rods, 1:]

    def _state(self, y: np.ndarray, Rref: np.ndarray) -> np.ndarray:
        """(b, ..., STATE) the start states of later segments from their scaled unknowns y
        (b, ..., d) and reference rotations Rref (b, ..., 3, 3)."""
        y = y * self.scale.reshape((self.b,) + (1,) * (y.ndim - 2) + (self.d,))
        st = np.zeros(y.shape[:-1] + (STATE,))
        st[..., 0:3] = y[..., 0:3]
        st[..., 3:12] = (Rref @ rodrigues(y[..., 3:6])).reshape(y.shape[:-1] + (9,))
        st[..., 12:12 + self.d - 6] = y[..., 6:]
        return st

    def starts(self, z: np.ndarray) -> np.ndarray:
        """(b, M, STATE) every segment's start state from unknowns z (b, nz)."""
        st = np.zeros((self.b, self.M, STATE))
        st[:, 0, 3:12] = np.eye(3).ravel()
        st[:, 0, 12:18] = z[:, :6] * self.base_scale
        st[:, 1:] = self._state(z[:, 6:].reshape(self.b, self.M - 1, self.d), self.Rref)
        return st

    def gap(self, e: np.ndarray, a: np.ndarray) -> np.ndarray:
        """(b, ..., d) the scaled gap from end states e to start states a (b, ..., STATE) each
        (the rotation's as the rotation vector of R_a^T R_e)."""
        Ra, Re = a[..., 3:12].reshape(a.shape[:-1] + (3, 3)), e[..., 3:12].reshape(e.shape[:-1] + (3, 3))
        g = np.concatenate([e[..., 0:3] - a[..., 0:3], _vee(np.swapaxes(Ra, -1, -2) @ Re),
                            e[..., 12:12 + self.d - 6] - a[..., 12:12 + self.d - 6]], axis=-1)
        return g / self.scale.reshape((self.b,) + (1,) * (g.ndim - 2) + (self.d,))

    def residual(self, st: np.ndarray, end: np.ndarray, tip: np.ndarray) -> np.ndarray:
        """(b, nz) the scaled gaps between segment ends ``end`` (b, M, STATE) and the next starts
        ``st``, then the tip residual ``tip`` (b, 6)."""
        return np.concatenate([self.gap(end[:, :-1], st[:, 1:]).reshape(self.b, -1), tip], axis=1)

    def _absorb(self, z: np.ndarray, rods: np.ndarray) -> None:
        """The rotation vectors of ``rods`` folded into their reference rotations (theta = 0)."""
        y = z[:, 6:].reshape(self.b, self.M - 1, self.d)
        theta = y[..., 3:6] * self.scale[:, None, 3:6]
        R = self.Rref @ rodrigues(theta)
        self.Rref[rods] = R[rods]
        y[rods, :, 3:6] = 0.0
        z[:, 6:] = y.reshape(self.b, -1)


class Segments(SegmentUnknowns):
    """Multiple shooting of the rods of one Shooting ``sh`` in ``count`` segments; ``c0`` [1/s]:
    BDF-alpha's (0 in statics)."""

    def __init__(self, sh: Shooting, rod: np.ndarray, count: int, c0: float):
        n_int = sh.n1 - 1
        if not 2 <= count <= n_int:
            raise ValueError(f"segments must be between 2 and the interval count {n_int}, got {count}")
        bounds = segment_bounds(n_int, count)
        super().__init__(np.broadcast_to(rod, (sh.b, rod.shape[1])), bounds, c0, sh.dynamic)
        self.sh, self.wdt = sh, sh.dev.wdtype
        self.kernel = make_segment_kernel(*sh.variant)
        self.bounds_d = wp.array(bounds, dtype=int, device=sh.device)
        self.rods = wp.ones(sh.b, dtype=int, device=sh.device)  # the rods a launch integrates
        self.mask = np.ones(sh.b, dtype=bool)  # its host copy
        self.spent = np.zeros(sh.b)  # rod integrations of the last solve
        self.band = BandSystems(sh.b, self.nz, self.d, sh.device)
        self._arrays = {}

    def _buffers(self, C: int):
        if C not in self._arrays:
            d, wdt = self.sh.device, self.wdt
            self._arrays[C] = (wp.zeros((self.b, C, STATE), dtype=wdt, device=d), wp.zeros(C, dtype=int, device=d),
                               wp.zeros((self.b, C, STATE), dtype=wdt, device=d),
                               wp.zeros((self.b, C, 6), dtype=wdt, device=d))
        return self._arrays[C]

    def ends(self, st: np.ndarray, seg: np.ndarray, store: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Integrate the columns: start states st (b, C, STATE) of segments seg (C,); their end
        states (b, C, STATE) and tip residuals (b, C, 6) (meaningful for the last segment)."""
        sh = self.sh
        start, segs, end, tip = self._buffers(len(seg))
        start.assign(st.astype(sh.dev.ndtype))
        segs.assign(seg.astype(np.int32))
        wp.launch(self.kernel, dim=(self.b, len(seg)), inputs=[sh.model, sh.control, sh.step, self.rods, start, segs,
                                                                 self.bounds_d, int(store), sh.nodes, end, tip],
                  device=sh.device)
        self.spent[self.mask] += len(seg) / self.M
        return end.numpy().astype(np.float64), tip.numpy().astype(np.float64)

    def evaluate(self, z: np.ndarray, store: bool = False) -> np.ndarray:
        """(b, nz) the residual at z (``store``: keep the shape and the slots; a trial that
        overflows gives non-finite entries, which the line search rejects)."""
        st = self.starts(z)
        end, tip = self.ends(st, np.arange(self.M), store)
        with np.errstate(over="ignore", invalid="ignore"):
            return self.residual(st, end, tip[:, -1])

    def jacobian(self, z: np.ndarray) -> None:
        """Central differences of the residual into self.band, block by block: unknown j moves
        the start of its segment s only, so only the gap into s and the gap out of s (or the tip
        residual) change; 2 integrations of segment s per unknown."""
        nz, d, M = self.nz, self.d, self.M
        seg_of = np.concatenate([np.zeros(6, dtype=int), 1 + np.arange(nz - 6) // d])
        base_st = self.starts(z)
        base_end, _tip = self.ends(base_st, np.arange(M))
        sign = np.tile([PROBE, -PROBE], nz)  # +h then -h per unknown
        seg, cols = np.repeat(seg_of, 2), np.repeat(np.arange(nz), 2)
        st = np.repeat(base_st[:, :1], 12, axis=1)  # the base wrench's columns
        st[:, np.arange(12), 12 + cols[:12]] += sign[:12] * self.base_scale[:, cols[:12]]
        later = np.arange(12, 2 * nz)
        block = 6 + d * (seg[later, None] - 1) + np.arange(d)  # (columns, d) each column's block of z
        y = z[:, block]
        y[:, np.arange(len(later)), (cols[later] - 6) % d] += sign[later]
        st = np.concatenate([st, self._state(y, self.Rref[:, seg[later] - 1])], axis=1)
        end, tip = self.ends(st, seg)  # (a column that overflows gives non-finite entries: no step)
        diff = lambda g: (g[:, 0::2] - g[:, 1::2]) / (2 * PROBE)  # noqa: E731
        put = self.band.put
        into = np.arange(6, nz)  # the gap into segment s >= 1 from its start
        rows = d * (seg_of[into, None] - 1) + np.arange(d)
        put(rows, into[:, None], diff(self.gap(base_end[:, seg[later] - 1], st[:, later])))
        out = np.flatnonzero(seg_of < M - 1)  # the gap out of segment s from its end
        pick = np.repeat(out, 2) * 2 + np.tile([0, 1], len(out))
        rows = d * seg_of[out, None] + np.arange(d)
        put(rows, out[:, None], diff(self.gap(end[:, pick], base_st[:, seg[pick] + 1])))
        last = np.flatnonzero(seg_of == M - 1)  # the tip residual, from the last segment's end
        pick = np.repeat(last, 2) * 2 + np.tile([0, 1], len(last))
        put(d * (M - 1) + np.arange(6)[None, :], last[:, None], diff(tip[:, pick]))

    def solve(self, mask: np.ndarray, tol: float, max_iter: int) -> tuple[np.ndarray, ...]:
        """Newton for the rods in ``mask`` (b,) from self.z; returns converged (b,) bool, of
        those the ones at the round-off floor (b,) bool, iterations (b,) and L |r| (b,); keeps the
        shape and slots of the last point."""
        self.rods.assign(mask.astype(np.int32))
        self.mask = mask.copy()
        self.spent[:] = 0.0
        z, Rref = self.z.copy(), self.Rref.copy()
        r = self.evaluate(z)
        size = self.L * _norm(r)
        ok = size < tol
        active = mask & ~ok & np.isfinite(size)
        iters = np.zeros(self.b, dtype=np.int32)
        limited = np.zeros(self.b, dtype=bool)
        floor = FLOOR["float64" if self.wdt == wp.float64 else "float32"]
        for _ in range(max_iter):
            if not active.any():
                break
            iters[active] += 1
            self.jacobian(z)
            dz, good = self.band.solve(-r, active & np.isfinite(self.band.a).all(axis=(1, 2)))
            tiny = good & (np.linalg.norm(dz, axis=1) < floor * np.maximum(1.0, np.linalg.norm(z, axis=1)))
            tiny &= size < STUCK * tol  # (far from tol a tiny step means a wrong Jacobian, not round-off)
            limited |= tiny
            ok |= tiny
            good &= ~tiny
            active &= ~tiny
            lam = np.ones(self.b)
            todo = good.copy()
            for _h in range(HALVINGS):
                trial = np.where(todo[:, None], z + lam[:, None] * dz, z)
                rt = self.evaluate(trial)
                st = self.L * _norm(rt)
                better = todo & np.isfinite(st) & (st < size)
                z[better], r[better], size[better] = trial[better], rt[better], st[better]
                todo &= ~better
                lam[todo] *= 0.5
                if not todo.any():
                    break
            self._absorb(z, better_mask := good & ~todo)
            stuck = todo & (size < STUCK * tol)  # no decrease from a fresh Jacobian, near tol: round-off
            limited |= stuck
            ok |= active & ((size < tol) | stuck)
            active &= better_mask & ~ok
        self.evaluate(z, store=True)
        keep = mask & ok  # a rod that failed keeps its unknowns and reference rotations
        self.z = np.where(keep[:, None], z, self.z)
        self.Rref = np.where(keep[:, None, None, None], self.Rref, Rref)
        return ok & mask, limited & mask, iters, size

    def solve_into(self, rods: np.ndarray, tol: float, max_iter: int) -> None:
        """``solve`` ``rods`` (b,); their status, base wrench, iterations, integrations, residual
        and orthogonality error put beside the other rods' in the Shooting's own arrays."""
        sh = self.sh
        ok, limited, iters, size = self.solve(rods, tol, max_iter)
        status = np.where(ok, layout.CONVERGED, np.where(np.isfinite(size), layout.MAX_ITER, layout.NONFINITE))
        status = np.where(limited, status | layout.PRECISION_LIMITED, status)
        orth = np.zeros(sh.b)  # (the segments' kernel keeps no orthogonality error)
        orth[rods] = _orthogonality(sh.host(sh.nodes.R).get(np.float64)[rods])
        for arr, values in ((sh.newton.status, status), (sh.newton.x, self.z[:, :6]), (sh.newton.iters, iters),
                            (sh.newton.n_shoot, np.ceil(self.spent)), (sh.newton.resnorm, size),
                            (sh.nodes.orth, orth)):
            mirror = sh.host(arr)
            merged = mirror.get(np.float64).copy()
            merged[rods] = values[rods]
            mirror.put(merged)
