"""Displacement control's tendons on the host: the length a motor gives each tendon, the linear
straight-rod model of their tensions (a solve's start), and the taut / slack complementarity
settled between smooth solves.

A tendon under displacement control has one shooting unknown: its tension where it is taut,
a measure of its spare length where it is slack (kernels/tendons.py length_residuals).
"""

from __future__ import annotations

import numpy as np

from tdcr_warp.core.build import Tables
from tdcr_warp.core.solver import Shooting
from tdcr_warp.kernels import layout
from tdcr_warp.model.robot import InputError, Robot

__all__ = ["SLACK_PASSES", "available_lengths", "linear_tensions", "settle_slack", "tendon_compliance"]

SLACK_PASSES = 8


def available_lengths(robot: Robot, reference: np.ndarray, tau: np.ndarray,
                      displacements: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Tensions with the displaced columns zeroed, and the unstretched length the motor gives
    each displaced tendon, reference - q (B, K) [m] (None: q = 0), or an InputError where that is
    not positive."""
    disp = list(robot.displaced)
    q = np.zeros_like(tau) if displacements is None else displacements
    avail = np.zeros_like(tau)
    avail[:, disp] = reference[:, disp] - q[:, disp]
    bad = avail[:, disp] <= 0
    if bad.any():
        b, j = np.argwhere(bad)[0]
        k = disp[j]
        raise InputError(f"displacements[{b}][{k}] = {float(q[b, k])!r} m needs a negative tendon length: tendon {k} "
                         f"holds {reference[b, k]:.6g} m of unstretched tendon at its reference")
    tau = tau.copy()
    tau[:, disp] = 0.0
    return tau, avail


def tendon_compliance(robot: Robot, B: int) -> np.ndarray:
    """(B, K, K) the linear model of a straight rod (``linear_tensions``): tendon k shortens by
    sum_j C_kj tau_j [m], C_kj = l_kj (r_k . r_j / EI + 1 / EA) + c_k l_k delta_kj (l_kj =
    min(l_k, l_j): the bending and the compression of tendon j act where it runs; r at the
    base). It depends on the robot alone."""
    K = robot.n_tendons
    r = np.broadcast_to(robot.tendon_routing(0.0)[0], (B, K, 3))
    lk = np.broadcast_to(robot.tendon_lengths(), (B, K))
    lkj = np.minimum(lk[:, :, None], lk[:, None, :])
    sec = robot.section()
    ei = np.broadcast_to(sec["kbt"][:, 0], (B,))[:, None, None]
    ea = np.broadcast_to(sec["kse"][:, 2], (B,))[:, None, None]
    C = lkj * (np.einsum("bki,bji->bkj", r, r) / ei + 1.0 / ea)
    return C + np.eye(K) * (np.broadcast_to(robot.tendon_columns("compliance"), (B, K)) * lk)[:, :, None]


def linear_tensions(robot: Robot, tables: Tables, C: np.ndarray, tau: np.ndarray,
                    avail: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tensions (B, K) [N] of the displaced tendons in the linear model of a straight rod
    (C: ``tendon_compliance``), and their scaled unknowns (B, Kd): the displaced set solves
    C_DD tau_D = free_D - avail_D - C_DT tau_T, with an active set for slack (a negative
    tension goes slack, the set solved again; pseudo-inverse: four tendons at 90 degrees
    have a co-contraction mode no length fixes)."""
    t = tables
    B, K = tau.shape
    disp = np.flatnonzero(t.tmode[0] >= 0)
    is_disp = np.zeros(K, dtype=bool)
    is_disp[disp] = True
    free = np.broadcast_to(t.straight.path, (B, K))
    known = np.where(is_disp, 0.0, tau)
    rhs = free - avail - np.einsum("bkj,bj->bk", C, known)
    active = np.broadcast_to(is_disp, (B, K)).copy()
    for _ in range(len(disp) + 1):
        both = active[:, :, None] & active[:, None, :]
        M = np.where(both, C, np.eye(K))
        sol = np.einsum("bkj,bj->bk", np.linalg.pinv(M), np.where(active, rhs, 0.0))
        neg = active & (sol < 0)
        if not neg.any():
            break
        active &= ~neg
    guess = np.where(is_disp, np.where(active, sol, 0.0), tau)
    scales = t.scale_rows(B)[:, 6:]
    L = np.broadcast_to(robot.length, (B,))[:, None]
    slope = np.broadcast_to(t.tendon[..., layout.T_SLACK_SLOPE], (B, K))[:, disp]
    needed = (free - np.einsum("bkj,bj->bk", C, guess))[:, disp]
    z = np.where(active[:, disp], guess[:, disp] / scales, (needed - avail[:, disp]) / (L * slope))
    return guess, z


def settle_slack(sh: Shooting, taut: np.ndarray, disp: np.ndarray, j_of: np.ndarray, newton: dict) -> None:
    """The complementarity of displacement control, per rod: a taut tendon solved to a negative
    tension goes slack (also where the solve failed: a wrong taut set can keep Newton from
    converging), a slack one whose path needs more tendon than it has goes taut, and the rod is
    solved again from where it stopped, until the set settles (``SLACK_PASSES``; then flagged
    UNSETTLED). Each solve is smooth in its unknowns; the unknown of a tendon that switches is
    near zero either way. Iterations and integrations add up over the passes."""
    iters, shots = sh.counts()
    for _ in range(SLACK_PASSES):
        z = sh.newton.x.numpy()[:, j_of]
        ok = sh.converged()
        flip = np.where(taut[:, disp], z < 0, ok[:, None] & (z > 0))
        rods = flip.any(axis=1)
        if not rods.any():
            break
        taut[:, disp] ^= flip
        sh.set_taut(taut)
        sh.solve(None, mask=rods.astype(np.int32), **newton)
        it, sn = sh.counts()
        iters[rods] += it[rods]
        shots[rods] += sn[rods]
    else:
        z = sh.newton.x.numpy()[:, j_of]
        bad = np.where(taut[:, disp], z < 0, z > 0).any(axis=1)
        if bad.any():
            st = sh.newton.status.numpy()
            st[bad] = (st[bad] & ~layout.CONVERGED) | layout.UNSETTLED
            sh.dev.put(sh.newton.status, st)
    sh.set_counts(iters, shots)
