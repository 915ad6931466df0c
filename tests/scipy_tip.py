"""Independent reference solver (plain NumPy/SciPy) for the static Cosserat rod with a constrained tip.

Not part of the package and not a test file: a helper for tests/test_scipy_tip.py. Written only
from the model's equations below; it shares no code with the Warp solver (nor with the other
reference modules in tests/).

Model
-----
* Rod of length L clamped at p(0) = 0, R(0) = I, leaving along +z; no precurvature, no tendons.
  State y = [p (3), R (9, row-major), n (3), m (3), P (3)]: n, m internal force and moment in
  the WORLD frame, P = int_0^s p ds (only for the global moment balance of the self-checks).
* Circular section: A = pi r^2, I = pi r^4 / 4, J = 2 I, G = E / (2 (1 + nu));
  Kse = diag(GA, GA, EA), Kbt = diag(EI, EI, GJ); v = Kse^-1 R^T n + e3, u = Kbt^-1 R^T m.
  p' = R v, R' = R hat(u), n' = -rho A g, m' = -p' x n, P' = p.
* Tip: n(L) = F_tip + F_c, m(L) = M_tip (the tip is pinned: free to rotate, no reaction moment).
* Constraint {"kind", "point", "normal" | "direction"} with target point c; its reaction is
  F_c = B lam and its equations B^T (p(L) - c) = 0 with an orthonormal basis B:
    point: B = I (3 x 3);  plane (unit normal nb): B = nb (3 x 1);
    line (unit direction d): B = two unit vectors across d (3 x 2).
  constraint=None: the free rod (F_c = 0).
* Unknowns x = [n(0), m(0), lam]; residuals [n(L) - F_tip - B lam, m(L) - M_tip, B^T (p(L) - c)],
  scaled by EI/L^2, EI/L, L (and the unknowns likewise).

Method: shooting; solve_ivp (DOP853, rtol 1e-12, atol 1e-14 at the end). The Jacobian is a
forward difference whose 7 trajectories (base + 6 perturbed n(0), m(0)) are integrated together
as one system so that they share the adaptive steps; its lam columns are exact. Newton with
backtracking, inside a continuation (looser tolerances on the way; see solve_tip): the free rod
under growing loads, then a spring pulling the tip toward the constraint, stiffened until the
exact constraint takes over. (Moving the target straight from the straight rod's tip instead
finds axially crushed, non-physical branches when the target is closer to the base than L.)

A rod is a dict (SI units): length, radius, youngs_modulus, poisson_ratio, density, gravity (3,),
tip_force (3,), tip_moment (3,); the constraint is passed separately.
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

__all__ = ["constraint_basis", "solve_tip"]

_E3 = np.array([0.0, 0.0, 1.0])
_NS = 21  # state size


def _unit(x):
    x = np.asarray(x, float).reshape(3)
    return x / np.linalg.norm(x)


def constraint_basis(constraint) -> np.ndarray:
    """B (3 x k): reaction F_c = B lam, constraint equations B^T (p(L) - c) = 0."""
    if constraint is None:
        return np.zeros((3, 0))
    kind = constraint["kind"]
    if kind == "point":
        return np.eye(3)
    if kind == "plane":
        return _unit(constraint["normal"])[:, None]
    if kind == "line":
        d = _unit(constraint["direction"])
        a = np.eye(3)[np.argmin(np.abs(d))]  # the axis least aligned with d
        e1 = _unit(a - (a @ d) * d)
        return np.stack([e1, np.cross(d, e1)], axis=1)
    raise ValueError(f"unknown constraint kind {kind!r}")


class _Rod:
    def __init__(self, rod: dict, constraint):
        self.L = L = float(rod["length"])
        E, nu, r = float(rod["youngs_modulus"]), float(rod["poisson_ratio"]), float(rod["radius"])
        G = E / (2.0 * (1.0 + nu))
        A, I = np.pi * r**2, np.pi * r**4 / 4.0
        self.EI = E * I
        self.kse_inv = 1.0 / np.array([G * A, G * A, E * A])
        self.kbt_inv = 1.0 / np.array([E * I, E * I, G * 2.0 * I])
        self.f = float(rod["density"]) * A * np.asarray(rod.get("gravity", (0, 0, 0)), float).reshape(3)
        self.F = np.asarray(rod.get("tip_force", (0, 0, 0)), float).reshape(3)
        self.M = np.asarray(rod.get("tip_moment", (0, 0, 0)), float).reshape(3)
        self.B = constraint_basis(constraint)
        self.k = self.B.shape[1]
        self.c = np.zeros(3) if constraint is None else np.asarray(constraint["point"], float).reshape(3)
        self.c0 = np.array([0.0, 0.0, L])  # tip of the straight rod: start of the continuation
        self.Fs, self.Ms = self.EI / L**2, self.EI / L  # force and moment scales
        self.xs = np.r_[np.full(3, self.Fs), np.full(3, self.Ms), np.full(self.k, self.Fs)]
        self.rs = np.r_[np.full(3, self.Fs), np.full(3, self.Ms), np.full(self.k, L)]

    def rhs(self, s, y, f):
        Y = y.reshape(-1, _NS)
        p, R, n, m = Y[:, 0:3], Y[:, 3:12].reshape(-1, 3, 3), Y[:, 12:15], Y[:, 15:18]
        v = np.einsum("kji,kj->ki", R, n) * self.kse_inv + _E3  # Kse^-1 R^T n + e3
        u = np.einsum("kji,kj->ki", R, m) * self.kbt_inv
        dp = np.einsum("kij,kj->ki", R, v)
        dR = np.empty_like(R)  # R hat(u): column j = R[:, :, j+1] u_{j+2} - R[:, :, j+2] u_{j+1}
        dR[:, :, 0] = R[:, :, 1] * u[:, 2:3] - R[:, :, 2] * u[:, 1:2]
        dR[:, :, 1] = R[:, :, 2] * u[:, 0:1] - R[:, :, 0] * u[:, 2:3]
        dR[:, :, 2] = R[:, :, 0] * u[:, 1:2] - R[:, :, 1] * u[:, 0:1]
        out = np.empty_like(Y)
        out[:, 0:3], out[:, 3:12], out[:, 12:15] = dp, dR.reshape(-1, 9), -f
        out[:, 15:18], out[:, 18:21] = -np.cross(dp, n), p
        return out.ravel()

    def integrate(self, W0, t, rtol, s_eval=None):
        """Trajectories from base wrenches W0 (K, 6) at load factor t; returns the solve_ivp result."""
        K = len(W0)
        y0 = np.zeros((K, _NS))
        y0[:, 3:12] = np.eye(3).ravel()
        y0[:, 12:18] = W0
        sol = solve_ivp(self.rhs, (0.0, self.L), y0.ravel(), method="DOP853", rtol=rtol,
                        atol=rtol * 1e-2, t_eval=s_eval, args=(t * self.f,))
        if sol.status != 0:
            raise RuntimeError(f"integration failed: {sol.message}")
        return sol

    def _res(self, x, yL, t, k=None):
        """Scaled residual at load factor t; k: spring stiffness [N/m] in place of the constraint."""
        if k is None:
            lam = x[6:] * self.Fs
            return np.r_[(yL[12:15] - t * self.F - self.B @ lam) / self.Fs, (yL[15:18] - t * self.M) / self.Ms,
                         self.B.T @ (yL[0:3] - self.c) / self.L]
        lam = k * self.B.T @ (self.c - yL[0:3])  # the spring pulls the tip toward the constraint
        return np.r_[(yL[12:15] - t * self.F - self.B @ lam) / self.Fs, (yL[15:18] - t * self.M) / self.Ms]

    def residual(self, x, t, rtol, k=None):
        W = x[:6] * self.xs[:6]
        return self._res(x, self.integrate(W[None], t, rtol).y[:, -1], t, k)

    def jacobian(self, x, t, rtol, k=None, h=1e-7):
        W = x[:6] * self.xs[:6]
        W0 = np.repeat(W[None], 7, axis=0)
        W0[1:] += h * np.diag(self.xs[:6])
        Y = self.integrate(W0, t, rtol).y[:, -1].reshape(7, _NS)
        r0 = self._res(x, Y[0], t, k)
        J = np.zeros((len(r0), len(x)))
        for j in range(6):
            J[:, j] = (self._res(x, Y[j + 1], t, k) - r0) / h
        if k is None:
            J[0:3, 6:] = -self.B  # d/d lam of (n(L) - F - B lam) / Fs, lam scaled by Fs
        return J

    def newton(self, x, t, rtol, tol, k=None, maxit=25):
        r = self.residual(x, t, rtol, k)
        for _ in range(maxit):
            nr = np.linalg.norm(r)
            if nr < tol:
                return x, nr, True
            dx = -np.linalg.solve(self.jacobian(x, t, rtol, k), r)
            a = 1.0
            while a >= 1.0 / 64:
                xn = x + a * dx
                try:
                    rn = self.residual(xn, t, rtol, k)
                except RuntimeError:
                    rn = np.full_like(r, np.inf)
                if np.linalg.norm(rn) < (1.0 - 1e-4 * a) * nr:
                    break
                a *= 0.5
            else:  # no decrease: converged to the integration's noise level, or failed
                return x, nr, nr < 1e3 * tol
            x, r = xn, rn
        nr = np.linalg.norm(r)
        return x, nr, nr < tol


def _track(m, x, path, n_min):
    """Follow the solution from path(0) to path(1) (path(a) -> dict(t=..., k=...)): adaptive steps
    in a, secant predictor, loose tolerances. Returns x and the number of steps."""
    a, da, x_prev, a_prev, steps = 0.0, 1.0 / n_min, None, None, 0
    while a < 1.0:
        an = min(1.0, a + da)
        guess = x if x_prev is None else x + (x - x_prev) * (an - a) / (a - a_prev)
        xn, nr, ok = m.newton(guess, rtol=1e-9, tol=1e-7, maxit=10, **path(an))
        steps += 1
        if ok:
            x_prev, a_prev, x, a = x, a, xn, an
            da = min(2.0 / n_min, 1.5 * da)
        else:
            da *= 0.5
            if da < 1e-5:
                raise RuntimeError(f"continuation stalled at a = {a} of {path(a)} (residual {nr:.2e})")
    return x, steps


def solve_tip(rod: dict, constraint=None, nodes: int = 200, *, rtol: float = 1e-12, tol: float = 1e-12,
              x0=None):
    """Static rod with the tip constrained (constraint: None or {"kind", "point", ...}).

    Continuation: (1) the free rod, loads t * (g, F_tip, M_tip), t: 0 -> 1; (2) a spring
    F_c = k B B^T (c - p(L)) pulls the tip toward the constraint, k: 1e-2 .. 1e5 EI/L^3
    (geometric); (3) Newton on the exact constraint from there (lam = k B^T (c - p(L))).
    x0: scaled unknowns of an earlier solution (warm start, no continuation).

    Returns a dict: s (N+1,), positions, n, m (N+1, 3), rotations (N+1, 3, 3), n0, m0,
    reaction F_c (3,), lam (k,), tip_position, int_p (int_0^L p ds), weight (rho A g L),
    residual (scaled max-norm), success, steps (continuation steps), x (scaled unknowns)."""
    m = _Rod(rod, constraint)
    steps, ok = 0, False
    if x0 is not None:
        x, _, ok = m.newton(np.asarray(x0, float), 1.0, rtol, tol)
    if not ok:
        x, steps = _track(m, np.zeros(6), lambda a: dict(t=a, k=0.0), 8)
        if m.k:
            ks = m.EI / m.L**3
            x, n2 = _track(m, x, lambda a: dict(t=1.0, k=ks * 10.0 ** (-2.0 + 7.0 * a)), 14)
            steps += n2
            k = ks * 1e5
            yL = m.integrate((x * m.xs[:6])[None], 1.0, 1e-9).y[:, -1]
            x = np.r_[x, k * m.B.T @ (m.c - yL[0:3]) / m.Fs]
        x, _, ok = m.newton(x, 1.0, rtol, tol)
    s = np.linspace(0.0, m.L, nodes + 1)
    W = x[:6] * m.xs[:6]
    sol = m.integrate(W[None], 1.0, rtol, s_eval=s)
    Y = sol.y.T  # (N+1, 21)
    res = m._res(x, Y[-1], 1.0)  # residual of the same integration
    lam = x[6:] * m.Fs
    return dict(s=s, positions=Y[:, 0:3], rotations=Y[:, 3:12].reshape(-1, 3, 3), n=Y[:, 12:15],
                m=Y[:, 15:18], n0=W[:3], m0=W[3:], reaction=m.B @ lam, lam=lam, tip_position=Y[-1, 0:3],
                int_p=Y[-1, 18:21], weight=m.f * m.L, residual=float(np.abs(res).max()),
                success=bool(ok and np.abs(res).max() < 1e3 * tol), steps=steps, x=x)
