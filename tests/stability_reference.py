"""An independent host version of the stability test, kept as the tests' reference for the
device verdict (kernels/jacobi.py): it builds the fields the other way round, from the tip's
plane (3 translations, 3 rotations of the whole rod with its dead loads rotated back, and the 6
base-wrench probes, combined so that the tip's momenta vanish) and tracks the eigenvalues of the
unitary W = (V + iU)(V - iU)^-1 from the tip to the clamp, counting their passes through 1.
Tension control only (the wires' correction of displacement control is shared code).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import warp as wp
from tdcr_warp.kernels import layout

import tdcr_warp as tw
from tdcr_warp.core.build import Tables, _cross, put_model
from tdcr_warp.model.robot import Robot
from tdcr_warp.physics.sensitivity import PROBE_REL, linearise, vee_rate
from tdcr_warp.physics.statics import StaticProblem

CROSS_TOL = 1e-7  # rad: an eigenphase within this of 1 at the clamp is neutral (a zero mode), not a crossing


def host_index(robot: Robot, tensions, **options) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(index, lagrangian check, margin [rad]) of every rod solved under ``options`` (tension
    control; index -1 where a rod did not converge)."""
    opts = tw.StaticOptions(**options).override(stability="off", threads=1)
    tau = np.asarray(tensions, dtype=float).reshape(-1, robot.n_tendons) if robot.n_tendons else np.zeros((1, 0))
    B = max(robot.batch_size, tau.shape[0])
    tau = np.broadcast_to(tau, (B, tau.shape[1])).copy()
    prob = StaticProblem(robot, B, opts, wp.get_device("cpu"))
    sol = prob.solve(tau, None)
    sh, tables = prob.solvers[0], prob.tables
    lin = linearise(sh, tau, tables, 0, B, opts.precision, shapes=True)
    index, lag, margin = jacobi_index(sh, lin, tables, node_routing(robot, tables.grid), 0, B, tau, opts.precision,
                                      opts.rod == "kirchhoff", opts.model == "coupled")
    return np.where(sol.converged, index, -1), lag, margin


def node_routing(robot: Robot, grid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """r(s) and r'(s) (1|B, N+1, K, 3) of every tendon at the nodes ``grid`` (1|B, N+1)."""
    rs, drs = [], []
    for j in range(grid.shape[1]):
        s = np.broadcast_to(grid[:, j:j + 1], (grid.shape[0], max(robot.n_tendons, 1)))[:, :robot.n_tendons]
        r, dr, _ = robot.tendon_routing(s)
        rs.append(r)
        drs.append(dr)
    return np.stack(rs, axis=1), np.stack(drs, axis=1)


def totals(st: dict, rod: np.ndarray, tension: np.ndarray, route, present: np.ndarray, kirchhoff: bool):
    """The total internal force n + sum_k tau_k t_k and moment m + sum_k tau_k (R r_k) x t_k at
    every node (b, N+1, 3) of a shape ``st`` (P, Rn, n, m), with the tendons that run there
    (present (1|b, N+1, K)); t_k the unit tangent of tendon k's path, from the strains."""
    R, n, m = st["Rn"], st["n"], st["m"]
    if route is None:
        return n, m
    r, dr = route
    Rt = np.swapaxes(R, -1, -2)
    rtn = (Rt @ n[..., None])[..., 0]
    rtm = (Rt @ m[..., None])[..., 0]
    kse, kbt = rod[:, None, layout.KSE:layout.KSE + 3], rod[:, None, layout.KBT:layout.KBT + 3]
    ustar = rod[:, None, layout.USTAR:layout.USTAR + 3]
    e3 = np.array([0.0, 0.0, 1.0])
    v = np.broadcast_to(e3, rtn.shape) if kirchhoff else rtn / kse + e3
    u = rtm / kbt + ustar
    pb = _cross(u[:, :, None], r) + dr + v[:, :, None]
    w = (tension[:, None, :] * present)[..., None] / np.linalg.norm(pb, axis=-1, keepdims=True)
    # in the body frame: sum tau pb / |pb| and sum tau r x pb / |pb|, then to the world
    fb = (w * pb).sum(axis=2)
    lb = (w * _cross(np.broadcast_to(r, pb.shape), pb)).sum(axis=2)
    return n + (R @ fb[..., None])[..., 0], m + (R @ lb[..., None])[..., 0]


def _field(st0: dict, st1: dict, tot0, tot1, h) -> np.ndarray:
    """(b, N+1, 12) a Jacobi field from two shapes h apart: [zeta, eta, P_zeta, P_eta]."""
    h = h[:, None, None]
    eta = vee_rate(st0["Rn"], st1["Rn"], h[..., None])
    dn = (tot1[0] - tot0[0]) / h
    dm = (tot1[1] - tot0[1]) / h
    return np.concatenate([(st1["P"] - st0["P"]) / h, eta, dn, dm - 0.5 * _cross(eta, tot0[1])], axis=-1)


def _rotated_loads(tables: Tables, axis: int, eps: float) -> Tables:
    """The tables with gravity and the point forces rotated by -eps about world axis ``axis``."""
    e = np.zeros(3)
    e[axis] = 1.0
    rod = np.array(tables.rod)
    fe = rod[:, layout.FE:layout.FE + 3]
    rod[:, layout.FE:layout.FE + 3] = fe - eps * _cross(np.broadcast_to(e, fe.shape), fe)
    pf = np.array(tables.pforce)
    if pf.size:
        pf = pf - eps * _cross(np.broadcast_to(e, pf.shape), pf)
    return replace(tables, rod=rod, pforce=pf)


def jacobi_index(sh, lin: dict, tables: Tables, route, lo: int, hi: int, tension: np.ndarray,
                 precision: str, kirchhoff: bool, coupled: bool):
    """Per rod of the chunk: the index of the second variation (0: stable), the Lagrangian
    check max |U^T V - V^T U| / max(|U|, |V|)^2 over the nodes (Frobenius norms of the
    symplectically scaled fields), and the eigenphases' smallest
    distance from a crossing at the clamp (a margin [rad]). ``lin``: linearise(..., shapes=True);
    route: ``node_routing`` of the whole batch; tension (b, K) the tendons' tensions [N]."""
    base, fields, hx = lin["base"], lin["fields"], lin["field_steps"]
    b, N1 = base["P"].shape[:2]
    rod = np.broadcast_to(tables.rows("rod", lo, hi), (b, layout.ROD_WIDTH))
    K = tension.shape[1]
    route = tuple(a[lo:hi] if a.shape[0] > 1 else a for a in route) if K and coupled else None
    term = np.broadcast_to(tables.rows("term_node", lo, hi), (b, K))
    present = (np.arange(N1)[None, :, None] <= term[:, None, :]).astype(np.float64)

    def tot(st):
        return totals(st, rod, tension, route, present, kirchhoff)

    t0 = tot(base)
    cols = []
    for i in range(3):  # translations
        f = np.zeros((b, N1, 12))
        f[:, :, i] = 1.0
        cols.append(f)
    loads = bool(np.any(tables.rod[:, layout.FE:layout.FE + 3] != 0) or np.any(tables.pforce != 0))
    x = sh.newton.x.numpy().astype(np.float64)
    eps = PROBE_REL[precision]
    for i in range(3):  # rotations of the rod, its tendons and its base wrench; dead loads rotated back
        e = np.zeros(3)
        e[i] = 1.0
        eb = np.broadcast_to(e, base["P"].shape)
        f = np.concatenate([_cross(eb, base["P"]), eb, _cross(eb, t0[0]),
                            _cross(eb, t0[1]) - 0.5 * _cross(eb, t0[1])], axis=-1)
        if loads:
            pr = sh.probe(x, put_model(sh.kern, sh.dev, _rotated_loads(tables, i, eps), lo, hi), shapes=True)
            f = f + _field(base, pr, t0, tot(pr), np.full(b, eps))
            lin["integrations"] = lin["integrations"] + 1
        cols.append(f)
    for j in range(6):  # the base wrench (a probe above x*, and below it for central differences)
        up, down = fields[j]
        f = _field(base, up, t0, tot(up), hx[:, j])
        if down is not None:
            f = 0.5 * (f + _field(base, down, t0, tot(down), -hx[:, j]))
        cols.append(f)
    Y = np.stack(cols, axis=-1)  # (b, N+1, 12, 12)
    L = rod[:, layout.LENGTH]
    a = np.sqrt(rod[:, layout.KBT] / L)  # symplectic scaling: [zeta a / L, eta a, P_zeta L / a, P_eta / a]
    sc = np.concatenate([np.repeat((a / L)[:, None], 3, 1), np.repeat(a[:, None], 3, 1),
                         np.repeat((L / a)[:, None], 3, 1), np.repeat((1 / a)[:, None], 3, 1)], axis=1)
    Y = Y * sc[:, None, :, None]
    Y = Y / np.linalg.norm(Y[:, :1], axis=2, keepdims=True).clip(1e-300)  # columns of unit size at the base
    _, _, vh = np.linalg.svd(Y[:, -1, 6:, :])  # the tip: momenta zero
    c = np.swapaxes(vh[:, 6:, :], 1, 2)  # (b, 12, 6) its null space
    Z = np.einsum("bsij,bjk->bsik", Y, c)
    U, V = Z[:, :, :6], Z[:, :, 6:]
    UV = np.einsum("bsji,bsjk->bsik", U, V)
    size = np.maximum(np.linalg.norm(U, axis=(2, 3)), np.linalg.norm(V, axis=(2, 3))).max(axis=1) ** 2
    lag = np.linalg.norm(UV - np.swapaxes(UV, 2, 3), axis=(2, 3)).max(axis=1) / size.clip(1e-300)
    W = np.linalg.solve(np.swapaxes(V - 1j * U, 2, 3), np.swapaxes(V + 1j * U, 2, 3))
    lam = np.linalg.eigvals(np.swapaxes(W, 2, 3))  # (b, N+1, 6)
    index, margin = _count_crossings(lam[:, ::-1])
    return index, lag, margin


def _count_crossings(lam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (b, S, 6) of W from the tip (s = L) to the clamp: the number of times one
    passes 1 (tracked by nearest matching from node to node, phases unwrapped), and the smallest
    distance of a phase from 1 at the clamp [rad]."""
    b, S, n = lam.shape
    cur = lam[:, 0]
    psi = np.angle(cur)
    count = np.zeros(b, dtype=np.int64)
    rows = np.arange(b)
    for k in range(1, S):
        new = lam[:, k]
        d = np.abs(np.angle(new[:, None, :] / cur[:, :, None]))  # (b, old, new)
        order = np.empty((b, n), dtype=np.int64)
        for _ in range(n):  # greedy nearest pairs
            flat = d.reshape(b, -1).argmin(axis=1)
            i, j = flat // n, flat % n
            order[rows, i] = j
            d[rows, i, :] = np.inf
            d[rows, :, j] = np.inf
        nxt = np.take_along_axis(new, order, axis=1)
        step = np.angle(nxt / cur)
        before = np.floor((psi + CROSS_TOL) / (2 * np.pi))
        psi = psi + step
        count += np.abs(np.floor((psi + CROSS_TOL) / (2 * np.pi)) - before).astype(np.int64).sum(axis=1)
        cur = nxt
    margin = np.abs(np.angle(lam[:, -1])).min(axis=1)
    return count, margin
