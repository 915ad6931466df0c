"""Independent reference solver (plain NumPy/SciPy) for the static Cosserat rod in penalty contact.

Not part of the package and not a test file: a helper for tests/test_scipy_contact.py. Written
only from the model's equations below; it shares no code with the Warp solver (nor with
tests/scipy_reference.py).

Model
-----
* Rod of length L clamped at p(0) = 0, R(0) = I, leaving along +z; no precurvature.
  State y = [p (3), R (9, row-major), n (3), m (3), P (3)]: n, m internal force and moment in
  the WORLD frame, P = int_0^s p ds (only for the moment balance of the self-checks).
* Kse = diag(GA, GA, EA), Kbt = diag(EI, EI, GJ); v = Kse^-1 R^T n + e3, u = Kbt^-1 R^T m.
  p' = R v, R' = R hat(u), n' = -rho A g, m' = -p' x n.
* Tip: n(L+) = tip_force, m(L+) = 0. Shooting unknowns n(0), m(0) (n(0) before the node-0 jump).
* Nodes s_i = i L / N. At every node (i = 0..N) n jumps: n(s_i+) = n(s_i-) - F_i, with
  F_i = sum_j k_j w_i phi(-g_ij) nrm_ij,  w_i = (s_min(i+1,N) - s_max(i-1,0)) / 2,
  g_ij = d_j(p_i) - r, phi the C1 quadratic-smoothed ramp of width eps_j = EI / (k_j L^3).
* Obstacles: dicts {"kind", fields..., "stiffness": k [N/m per m]}; kinds and fields as in the
  package: plane (point, normal), sphere (center, radius), capsule (start, end, radius),
  tube (start, end, radius; rod inside), bent_tube (start, direction, toward, bend_radius,
  angle, radius; rod inside).

Method: shooting, every interval integrated with solve_ivp (DOP853, rtol 1e-12, atol 1e-14);
the 7 trajectories of a forward-difference Jacobian (and the 4 of a batched backtracking line
search, steps 1 .. 1/64) are integrated together as one system so that they share the adaptive steps. Newton on
the scaled unknowns, inside a continuation in load (and optionally in stiffness).
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

__all__ = ["gaps_normals", "phi", "solve_contact"]

_E3 = np.array([0.0, 0.0, 1.0])
_NS = 21  # state size
DEBUG = False  # print the continuation's steps


def _unit(x):
    x = np.asarray(x, float).reshape(3)
    return x / np.linalg.norm(x)


def phi(delta, eps):
    """Penalty ramp: 0 below -eps/2, quadratic (delta + eps/2)^2 / (2 eps) inside, delta above."""
    delta = np.asarray(delta, float)
    quad = (delta + 0.5 * eps) ** 2 / (2.0 * eps)
    return np.where(delta <= -0.5 * eps, 0.0, np.where(delta >= 0.5 * eps, delta, quad))


def gaps_normals(ob: dict, p: np.ndarray, r: float):
    """Gap g = d(p) - r (B,) and unit free-side normal (B, 3) of one obstacle at points p (B, 3).

    Where the obstacle does not act (a tube outside its ends, a bent tube past its arc) g = +inf
    and the normal is 0."""
    p = np.atleast_2d(np.asarray(p, float))
    kind = ob["kind"]
    inf = np.full(len(p), np.inf)

    def radial(dvec):  # unit vector and length of dvec (B, 3), 0 where the length is 0
        d = np.linalg.norm(dvec, axis=1)
        safe = np.where(d > 0, d, 1.0)
        return dvec / safe[:, None] * (d > 0)[:, None], d

    if kind == "plane":
        nb = _unit(ob["normal"])
        d = (p - np.asarray(ob["point"], float)) @ nb
        return d - r, np.broadcast_to(nb, p.shape).copy()
    if kind == "sphere":
        nrm, d = radial(p - np.asarray(ob["center"], float))
        return d - float(ob["radius"]) - r, nrm
    if kind in ("capsule", "tube"):
        a, b = np.asarray(ob["start"], float), np.asarray(ob["end"], float)
        ab = b - a
        t = (p - a) @ ab / (ab @ ab)
        tq = np.clip(t, 0.0, 1.0)
        nrm, d = radial(p - (a + tq[:, None] * ab))
        if kind == "capsule":
            return d - float(ob["radius"]) - r, nrm
        inside = (t >= 0.0) & (t <= 1.0)
        g = np.where(inside, float(ob["radius"]) - d - r, inf)
        return g, -nrm * inside[:, None]
    if kind == "bent_tube":
        a, dv = np.asarray(ob["start"], float), _unit(ob["direction"])
        tv = np.asarray(ob["toward"], float)
        tv = _unit(tv - (tv @ dv) * dv)
        Rb, Phi = float(ob["bend_radius"]), float(ob["angle"])
        c = a + Rb * tv
        z = np.cross(dv, tv)
        w = (p - c) - np.outer((p - c) @ z, z)
        u, _ = radial(w)
        theta = np.mod(np.arctan2(u @ dv, -(u @ tv)), 2.0 * np.pi)
        nrm, d = radial(p - (c + Rb * u))
        inside = theta <= Phi
        g = np.where(inside, float(ob["radius"]) - d - r, inf)
        return g, -nrm * inside[:, None]
    raise ValueError(f"unknown obstacle kind {kind!r}")


class _Rod:
    """Parameters of one rod; `load` scales gravity and tip force, `kscale` every stiffness."""

    def __init__(self, rod: dict, nodes: int, load: float = 1.0, kscale: float = 1.0):
        self.L = L = float(rod["length"])
        E, nu, self.r = float(rod["youngs_modulus"]), float(rod["poisson_ratio"]), float(rod["radius"])
        G = E / (2.0 * (1.0 + nu))
        A = np.pi * self.r**2
        inertia = np.pi * self.r**4 / 4.0
        self.EI = E * inertia
        self.kse = np.array([G * A, G * A, E * A])
        self.kbt = np.array([E * inertia, E * inertia, G * 2.0 * inertia])
        self.fg = load * float(rod["density"]) * A * np.asarray(rod.get("gravity", (0, 0, 0)), float)
        self.tip = load * np.asarray(rod.get("tip_force", (0, 0, 0)), float)
        self.obstacles = list(rod.get("obstacles") or [])
        self.k = np.array([kscale * float(o["stiffness"]) for o in self.obstacles])
        self.eps = self.EI / (self.k * L**3)
        self.N = N = int(nodes)
        self.s = np.linspace(0.0, L, N + 1)
        self.w = (self.s[np.minimum(np.arange(N + 1) + 1, N)] - self.s[np.maximum(np.arange(N + 1) - 1, 0)]) / 2
        self.Fs = max(np.linalg.norm(self.tip) + np.linalg.norm(self.fg) * L, self.EI / L**2)  # force scale

    def contact(self, i: int, p: np.ndarray):
        """F_i (B, 3) and gaps (B, O) at node i for node positions p (B, 3)."""
        F = np.zeros_like(p)
        gaps = np.zeros((len(p), len(self.obstacles)))
        for j, ob in enumerate(self.obstacles):
            g, nrm = gaps_normals(ob, p, self.r)
            gaps[:, j] = g
            F += (self.k[j] * self.w[i] * phi(-g, self.eps[j]))[:, None] * nrm
        return F, gaps

    def rhs(self, s, yf):
        Y = yf.reshape(-1, _NS)
        R = Y[:, 3:12].reshape(-1, 3, 3)
        n, m = Y[:, 12:15], Y[:, 15:18]
        v = np.einsum("bji,bj->bi", R, n) / self.kse + _E3
        u = np.einsum("bji,bj->bi", R, m) / self.kbt
        H = np.zeros((len(Y), 3, 3))
        H[:, 0, 1], H[:, 0, 2], H[:, 1, 2] = -u[:, 2], u[:, 1], -u[:, 0]
        H[:, 1, 0], H[:, 2, 0], H[:, 2, 1] = u[:, 2], -u[:, 1], u[:, 0]
        dp = np.einsum("bij,bj->bi", R, v)
        out = np.empty_like(Y)
        out[:, 0:3] = dp
        out[:, 3:12] = (R @ H).reshape(-1, 9)
        out[:, 12:15] = -self.fg
        out[:, 15:18] = -np.cross(dp, n)
        out[:, 18:21] = Y[:, 0:3]
        return out.ravel()

    def unscale(self, X):
        X = np.atleast_2d(X)
        return np.concatenate([X[:, :3] * self.Fs, X[:, 3:] * self.Fs * self.L], axis=1)

    def shoot(self, X, record=False):
        """Integrate base -> tip for scaled unknowns X (B, 6); scaled residuals (B, 6) [, record]."""
        W = self.unscale(X)
        B = len(W)
        Y = np.zeros((B, _NS))
        Y[:, 3:12] = np.eye(3).ravel()
        Y[:, 12:18] = W
        rec = dict(positions=[], rotations=[], n=[], contact_force=[], gaps=[]) if record else None
        for i in range(self.N + 1):
            F, g = self.contact(i, Y[:, 0:3])
            if record:
                rec["positions"].append(Y[0, 0:3].copy())
                rec["rotations"].append(Y[0, 3:12].reshape(3, 3).copy())
                rec["n"].append(Y[0, 12:15].copy())
                rec["contact_force"].append(F[0].copy())
                rec["gaps"].append(g[0].copy())
            Y[:, 12:15] -= F
            if i < self.N:
                sol = solve_ivp(self.rhs, (self.s[i], self.s[i + 1]), Y.ravel(), method="DOP853",
                                rtol=1e-12, atol=1e-14, first_step=self.s[i + 1] - self.s[i])
                if not sol.success:
                    raise RuntimeError(sol.message)
                Y = sol.y[:, -1].reshape(B, _NS)
        res = np.concatenate([(Y[:, 12:15] - self.tip) / self.Fs, Y[:, 15:18] / (self.Fs * self.L)], axis=1)
        if record:
            rec = {k: np.array(v) for k, v in rec.items()}
            rec.update(tip_state=Y[0].copy())
        return res, rec

    def newton(self, X, tol=1e-13, maxit=15):
        """Newton with a forward-difference Jacobian; a full step is tried together with the
        Jacobian columns at its end point, else a batched backtracking line search."""
        X = np.asarray(X, float).copy()
        E = np.vstack([np.zeros(6), 1e-7 * np.eye(6)])
        res, _ = self.shoot(X + E)
        for it in range(maxit):
            r0 = res[0]
            if np.max(np.abs(r0)) < tol:
                return X, True, it
            try:
                dX = np.linalg.solve((res[1:] - r0).T / 1e-7, -r0)
            except np.linalg.LinAlgError:
                return X, False, it
            full, _ = self.shoot(X + dX + E)
            if np.linalg.norm(full[0]) < (1.0 - 1e-4) * np.linalg.norm(r0):
                X, res = X + dX, full
                continue
            alphas = 0.5 ** np.arange(1, 8)
            rs, _ = self.shoot(X + alphas[:, None] * dX)
            ok = np.nonzero(np.linalg.norm(rs, axis=1) < (1.0 - 1e-4 * alphas) * np.linalg.norm(r0))[0]
            if len(ok) == 0:  # converged to the integration's noise floor, or failed
                return X, bool(np.max(np.abs(r0)) < 1e2 * tol), it
            X = X + alphas[ok[0]] * dX
            res, _ = self.shoot(X + E)
        return X, False, maxit


def _continue(rod, nodes, X, path, tol, dt=1.0):
    """Follow `path(t)` -> (load, kscale) from t = 0 (solution X) to t = 1 with adaptive steps."""
    t, steps, prev = 0.0, 0, None
    while t < 1.0:
        t1 = min(1.0, t + dt)
        guess = X if prev is None else X + (X - prev[1]) * (t1 - t) / (t - prev[0])  # secant predictor
        Xn, ok, it = _Rod(rod, nodes, *path(t1)).newton(guess, tol=tol)
        steps += 1
        if DEBUG:
            print(f"continuation t {t1:.4g} ok {ok} iterations {it}")
        if ok:
            prev, t, X, dt = (t, X), t1, Xn, dt * 1.5
        else:
            dt /= 3.0
            if dt < 1e-4:
                raise RuntimeError(f"continuation stalled at t = {t}")
    return X, steps


def solve_contact(rod: dict, nodes: int = 200, *, k_start: float | None = None, guess=None, tol=1e-13) -> dict:
    """Solve the static rod of `rod` (dict: length, radius, youngs_modulus, poisson_ratio, density,
    gravity, tip_force, obstacles) on `nodes` intervals.

    Without a guess: continuation in load 0 -> 1; with k_start, at every stiffness scaled by
    k_start / (the first obstacle's k), followed by a geometric continuation of the stiffness
    back to its value (a decade a step). guess: the (6,) [n0, m0] of an earlier solution at full
    load: then only the stiffness continuation from k_start (if given), else a plain Newton.
    Returns n0, m0 (n0 before the node-0 jump), positions (N+1, 3), rotations (N+1, 3, 3),
    n (N+1, 3) just proximal of each node, contact_force (N+1, 3), gaps (N+1, O), n_tip (n(L+)),
    m_tip, int_p (int_0^L p ds), weight (rho A g L), residual (max scaled), steps (Newton solves).
    """
    kref = [float(o["stiffness"]) for o in rod.get("obstacles") or []]
    ks = 1.0 if k_start is None or not kref else k_start / kref[0]
    base = _Rod(rod, nodes)
    if guess is None:
        X, steps = _continue(rod, nodes, np.zeros(6), lambda t: (t, ks), tol)
    else:
        W = np.asarray(guess, float).reshape(6)
        X, steps = np.concatenate([W[:3] / base.Fs, W[3:] / (base.Fs * base.L)]), 0
        if ks == 1.0:
            X, ok, _ = base.newton(X, tol=tol)
            steps += 1
            if not ok:
                raise RuntimeError("Newton from the guess failed")
    if ks != 1.0:
        X, st = _continue(rod, nodes, X, lambda t: (1.0, ks ** (1.0 - t)), tol,
                          dt=1.0 / max(1.0, np.ceil(abs(np.log10(ks)))))  # a decade a step
        steps += st
    res, rec = base.shoot(X[None], record=True)
    W = base.unscale(X)[0]
    y = rec.pop("tip_state")
    return dict(n0=W[:3], m0=W[3:], **rec, n_tip=y[12:15], m_tip=y[15:18],
                tip_position=y[0:3], int_p=y[18:21], weight=base.fg * base.L, residual=float(np.max(np.abs(res))),
                steps=steps, s=base.s, EI=base.EI)
