"""Bounded allocation of a tip command into motor displacements, for B rods at once.

Under displacement control the motor sets how much tendon each wire has; the tension follows
from the rod's shape. Around a solved state (displacements q0, tensions tau0) the statics give
the tip Jacobian J = dp/dq, the tension Jacobian T = dtau/dq of the taut tendons and, for the
slack ones, G = d gap / dq, the rate at which their spare length changes
(tdcr_warp/physics/sensitivity.py): pulling one tendon also stretches its neighbours, so T is far from
diagonal, and it takes 0.96 mm of slack out of its antagonist per mm on the report's robot.
The command q for a desired input v = b_c q (b_c = w^2 J in the controller's model) solves, per
rod,

    min |b_c q - v|^2 + lam_t |tau0 + T (q - q0)|^2 + lam_g |gap0 + G (q - q0)|^2
    s.t. q_lo <= q <= q_hi                  (the motor's range)
         tau0 + T (q - q0) <= tau_max       (taut tendons: the tension limit at equilibrium)
         gap0 + G (q - q0) >= 0             (slack tendons stay slack)

A slack tendon pulls nothing, so its column of J and row of T are zero, and the plan knows it:
it never counts on a pull from it. As the other tendons bend the rod, its path lengthens or
shortens; the last constraint pays it out or takes it in so that it neither brakes the motion
(going taut under a linear model that has it slack) nor unwinds, and lam_g holds it just slack,
ready to pull at the next refresh of the model. A taut tendon may be released past zero
tension (then it is slack at the next refresh). The small regularisation (lam_t at 1e-6 and
lam_g at 1e-3 of |b_c|^2, relative to |T|^2 and |G|^2) picks, out of the null space of b_c
(pulling every tendon together bends nothing; it only raises the tensions), the least tensions
at equilibrium, as the tension allocation picks the least tensions. Every bound is widened to admit holding the last command, so the
problem is always feasible: where the plant has drifted past a bound, the command does not go
further.

The quadratic programmes are solved together by ADMM (the operator splitting of OSQP:
Stellato et al., Math. Prog. Comp. 2020), vectorised over rods, with a step size rho per rod
adapted to balance the primal and dual residuals.
"""

from __future__ import annotations

import numpy as np

__all__ = ["allocate_displacements", "solve_qp"]

LAM_T, LAM_G = 1e-6, 1e-3  # the regularisation of the equilibrium tensions and the slack, relative to |b_c|^2
ALPHA = 1.6  # over-relaxation
SIGMA = 1e-6  # proximal term on x


def _factor(H: np.ndarray, A: np.ndarray, rho: np.ndarray) -> np.ndarray:
    n = H.shape[1]
    return np.linalg.inv(H + SIGMA * np.eye(n) + rho[:, None, None] * np.einsum("bmi,bmj->bij", A, A))


def solve_qp(H: np.ndarray, c: np.ndarray, A: np.ndarray, lo: np.ndarray, hi: np.ndarray, *, x0=None, y0=None,
             tol: float = 1e-7, max_iter: int = 4000, check_every: int = 25):
    """Per rod b: min 1/2 x^T H x + c^T x subject to lo <= A x <= hi (rows with lo = -inf and
    hi = inf are free). H (B, n, n) positive semidefinite, c (B, n), A (B, m, n), lo, hi (B, m).
    x0 (B, n), y0 (B, m): a warm start (the last solution and its multipliers). A rod stops when
    its primal and dual residuals are below ``tol`` relative to its problem's size (checked every
    ``check_every`` iterations), or after ``max_iter`` iterations; a rod's iterations and step size
    are its own, so its answer does not depend on the other rods of the batch. Returns x (B, n),
    y (B, m) and the iterations the slowest rod spent."""
    B, n = c.shape
    hs = np.maximum(np.einsum("bii->b", H) / n, 1e-300)  # scale the objective to a unit diagonal
    H, c = H / hs[:, None, None], c / hs[:, None]
    rn = np.linalg.norm(A, axis=2)  # unit-norm rows; empty rows are free
    live = rn > 0
    A = A / np.where(live, rn, 1.0)[:, :, None]
    lo = np.where(live, lo / np.where(live, rn, 1.0), -np.inf)
    hi = np.where(live, hi / np.where(live, rn, 1.0), np.inf)
    rho = np.full(B, 0.1)
    M = _factor(H, A, rho)
    x = np.zeros((B, n)) if x0 is None else np.array(x0, dtype=np.float64)
    y = np.zeros(lo.shape) if y0 is None else np.array(y0, dtype=np.float64) / (hs[:, None] / np.where(live, rn, 1.0))
    z = np.clip(np.einsum("bmi,bi->bm", A, x), lo, hi)
    it = 0
    active = np.ones(B, dtype=bool)  # rods still iterating
    while it < max_iter:
        run = active[:, None]
        for _ in range(check_every):
            rhs = SIGMA * x - c + np.einsum("bmi,bm->bi", A, rho[:, None] * z - y)
            xt = np.einsum("bij,bj->bi", M, rhs)
            zt = np.einsum("bmi,bi->bm", A, xt)
            x = np.where(run, ALPHA * xt + (1 - ALPHA) * x, x)
            zr = ALPHA * zt + (1 - ALPHA) * z
            z_new = np.clip(zr + y / rho[:, None], lo, hi)
            y = np.where(run, y + rho[:, None] * (zr - z_new), y)
            z = np.where(run, z_new, z)
        it += check_every
        Ax = np.einsum("bmi,bi->bm", A, x)
        Hx = np.einsum("bij,bj->bi", H, x)
        Aty = np.einsum("bmi,bm->bi", A, y)
        r_p = np.abs(Ax - z).max(axis=1)
        r_d = np.abs(Hx + c + Aty).max(axis=1)
        s_p = np.maximum(np.abs(Ax).max(axis=1), np.abs(z).max(axis=1))
        s_d = np.maximum.reduce([np.abs(Hx).max(axis=1), np.abs(Aty).max(axis=1), np.abs(c).max(axis=1)])
        active &= ~((r_p <= tol * (1 + s_p)) & (r_d <= tol * (1 + s_d)))
        if not active.any():
            break
        # balance the residuals (OSQP's rule), within a factor of 5 per update
        ratio = np.sqrt((r_p / np.maximum(s_p, 1e-300)) / np.maximum(r_d / np.maximum(s_d, 1e-300), 1e-300))
        new = np.clip(rho * np.clip(ratio, 0.2, 5.0), 1e-6, 1e6)
        update = active & (np.abs(np.log(new / rho)) > np.log(2.0))
        if update.any():
            rho = np.where(update, new, rho)
            M = _factor(H, A, rho)
    return x, y * (hs[:, None] / np.where(live, rn, 1.0)), it


def allocate_displacements(bc: np.ndarray, v: np.ndarray, q_prev: np.ndarray, lin: dict, q_lo: np.ndarray,
                           q_hi: np.ndarray, tau_max: np.ndarray, warm: tuple | None = None):
    """Motor displacements (B, K) [m] for the desired input v (B, 3) on the model
    X2_t = a_c + bc q (bc (B, 3, K)), within the module's constraints. lin: the linearisation
    (``q`` (B, K) [m], ``tension`` (B, K) [N], ``tension_jacobian`` (B, K, K) [N/m], ``gap``
    (B, K) [m] and ``slack_jacobian`` (B, K, K) [1]); q_prev: the last command; q_lo, q_hi,
    tau_max (B, K). warm: (x, y) of the last call. Returns q and (x, y) for the next call."""
    q0, T, G = lin["q"], lin["tension_jacobian"], lin["slack_jacobian"]
    B, K = q0.shape
    Q = np.einsum("bik,bil->bkl", bc, bc)
    TT, GG = (np.einsum("bjk,bjl->bkl", M, M) for M in (T, G))

    def weight(w, M):  # w |b_c|^2 / |M|^2 (0 where M is empty: no taut, or no slack, tendon)
        tr = np.einsum("bkk->b", M)
        return np.where(tr > 0, w * np.einsum("bkk->b", Q) / np.where(tr > 0, tr, 1.0), 0.0)

    lam_t, lam_g = weight(LAM_T, TT), weight(LAM_G, GG)
    tau_free = lin["tension"] - np.einsum("bkl,bl->bk", T, q0)  # tau0 + T (q - q0) = tau_free + T q
    gap_free = lin["gap"] - np.einsum("bkl,bl->bk", G, q0)  # gap0 + G (q - q0) = gap_free + G q
    H = 2 * (Q + lam_t[:, None, None] * TT + lam_g[:, None, None] * GG)
    c = -2 * (np.einsum("bik,bi->bk", bc, v) - lam_t[:, None] * np.einsum("bjk,bj->bk", T, tau_free)
              - lam_g[:, None] * np.einsum("bjk,bj->bk", G, gap_free))
    inf = np.full((B, K), np.inf)
    A = np.concatenate([np.broadcast_to(np.eye(K), (B, K, K)), T, G], axis=1)
    lo = np.concatenate([q_lo, -inf, -gap_free], axis=1)
    hi = np.concatenate([q_hi, tau_max - tau_free, inf], axis=1)
    Aq = np.einsum("bmk,bk->bm", A, np.clip(q_prev, q_lo, q_hi))  # holding the last command is feasible
    lo, hi = np.minimum(lo, Aq), np.maximum(hi, Aq)
    D = 0.5 * (q_hi - q_lo)  # solved for q / D, of order 1
    x0, y0 = warm if warm is not None else (q_prev / D, None)
    x, y, _ = solve_qp(H * D[:, :, None] * D[:, None, :], c * D, A * D[:, None, :], lo, hi, x0=x0, y0=y0)
    return np.clip(x * D, q_lo, q_hi), (x, y)
