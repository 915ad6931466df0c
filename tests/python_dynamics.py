"""A straightforward per-rod Python implementation of the report's dynamic method, written
from the model's equations (docs/physics.md; not part of the package): explicit Euler along s
with N intervals, BDF-alpha history per node, ``scipy.optimize.fsolve`` on the 6 base unknowns
every step. The report's bugs are not ported (tendon loads in the ODE, v' and u' from the 6x6 solve, the
true tip, R re-orthonormalised). Straight tendons ending at the tip only; no point forces.

It is the per-rod peer of ``experiments/bench_dynamics.py`` and, run at the same settings as
the Warp solver (Euler, same N), an independent check of its dynamics.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import fsolve

E3 = np.array([0.0, 0.0, 1.0])


def hat(x):
    return np.array([[0, -x[2], x[1]], [x[2], 0, -x[0]], [-x[1], x[0], 0]])


class PythonRod:
    """rod: dict with length, youngs_modulus, poisson_ratio, radius, density, gravity (3,),
    offsets (K x 2), damping_shear, damping_bending, drag (3,) each; dt [s], alpha."""

    def __init__(self, rod: dict, tensions0, *, dt: float, alpha: float, nodes: int = 20):
        self.L = rod["length"]
        E, nu, r, rho = rod["youngs_modulus"], rod["poisson_ratio"], rod["radius"], rod["density"]
        G = E / (2 * (1 + nu))
        A, I = np.pi * r**2, np.pi * r**4 / 4
        self.Kse, self.Kbt = np.array([G * A, G * A, E * A]), np.array([E * I, E * I, 2 * G * I])
        self.rhoA, self.rhoJ = rho * A, rho * I * np.array([1.0, 1.0, 2.0])
        self.fe = rho * A * np.asarray(rod.get("gravity", np.zeros(3)))
        self.Bse = np.asarray(rod.get("damping_shear", np.zeros(3)), float)
        self.Bbt = np.asarray(rod.get("damping_bending", np.zeros(3)), float)
        self.C = np.asarray(rod.get("drag", np.zeros(3)), float)
        self.offsets = [np.array([o[0], o[1], 0.0]) for o in rod["offsets"]]
        self.N, self.h = nodes, self.L / nodes
        self.c0 = (1.5 + alpha) / (dt * (1 + alpha))
        self.c1, self.c2, self.d1 = -2 / dt, (0.5 + alpha) / (dt * (1 + alpha)), alpha / (1 + alpha)
        self.EI = E * I
        # history per node (N intervals + the tip before its loads): v, u, q, w, v', u'
        self.hist = np.zeros((nodes + 1, 6, 3))
        self.tau = np.asarray(tensions0, float)
        self.nfev = 0
        c0 = self.c0
        self.c0 = 0.0  # the static start: no rates
        self.x = fsolve(self.residual, self.guess(), xtol=1e-13)
        y = self.integrate(self.x)[1]
        self.c0 = c0
        self.hist = (self.c1 + self.c2) * y  # at rest: y_t = c0 y + y_h = 0
        self.yprev = y

    def guess(self):
        n0 = self.fe * self.L - self.tau.sum() * E3
        m0 = np.cross(0.5 * self.L**2 * E3, self.fe) + sum(np.cross(r, -t * E3) for r, t in zip(self.offsets, self.tau))
        return np.concatenate([n0, m0])

    def strains(self, R, n, m, hist):
        v = (R.T @ n + self.Kse * E3 - self.Bse * hist[0]) / (self.Kse + self.c0 * self.Bse)
        u = (R.T @ m - self.Bbt * hist[1]) / (self.Kbt + self.c0 * self.Bbt)
        return v, u

    def rhs(self, R, n, m, q, w, hist):
        v, u = self.strains(R, n, m, hist)
        vt, ut = self.c0 * v + hist[0], self.c0 * u + hist[1]
        qt, wt = self.c0 * q + hist[2], self.c0 * w + hist[3]
        A, B, G, H = (np.zeros((3, 3)) for _ in range(4))
        a, b = np.zeros(3), np.zeros(3)
        for r, t in zip(self.offsets, self.tau):
            if t > 0:
                pb = np.cross(u, r) + v
                Ai = -t * hat(pb) @ hat(pb) / np.linalg.norm(pb) ** 3
                Bi = hat(r) @ Ai
                A, B, G, H = A + Ai, B + Bi, G - Ai @ hat(r), H - Bi @ hat(r)
                ai = Ai @ np.cross(u, pb)
                a, b = a + ai, b + np.cross(r, ai)
        sn = self.Kse * (v - E3) + self.Bse * vt
        sm = self.Kbt * u + self.Bbt * ut
        lam_n = self.rhoA * (np.cross(w, q) + qt) + self.C * q * np.abs(q) - R.T @ self.fe - a
        lam_m = np.cross(w, self.rhoJ * w) + self.rhoJ * wt - np.cross(v, sn) - b
        gam_v = np.cross(u, sn) + self.Bse * hist[4]
        gam_u = np.cross(u, sm) + self.Bbt * hist[5]
        M = np.block([[np.diag(self.Kse + self.c0 * self.Bse) + A, G], [B, np.diag(self.Kbt + self.c0 * self.Bbt) + H]])
        dvu = np.linalg.solve(M, np.concatenate([lam_n - gam_v, lam_m - gam_u]))
        dv, du = dvu[:3], dvu[3:]
        dp = R @ v
        dn = R @ (self.rhoA * (np.cross(w, q) + qt) + self.C * q * np.abs(q)) - self.fe - R @ (a + A @ dv + G @ du)
        dm = R @ (np.cross(w, self.rhoJ * w) + self.rhoJ * wt) - np.cross(dp, n) - R @ (b + B @ dv + H @ du)
        dq = vt - np.cross(u, q) + np.cross(w, v)
        dw = ut - np.cross(u, w)
        return (dp, R @ hat(u), dn, dm, dq, dw), np.array([v, u, q, w, dv, du])

    def integrate(self, x):
        self.nfev += 1
        p, R, n, m, q, w = np.zeros(3), np.eye(3), x[:3].copy(), x[3:].copy(), np.zeros(3), np.zeros(3)
        ys = np.zeros((self.N + 1, 6, 3))
        for k in range(self.N):
            d, ys[k] = self.rhs(R, n, m, q, w, self.hist[k])
            p, R, n, m, q, w = (z + self.h * dz for z, dz in zip((p, R, n, m, q, w), d))
            R = 1.5 * R - 0.5 * R @ R.T @ R
        v, u = self.strains(R, n, m, self.hist[self.N])
        ys[self.N] = [v, u, q, w, np.zeros(3), np.zeros(3)]
        for r, t in zip(self.offsets, self.tau):
            pb = np.cross(u, r) + v
            F = -t * R @ pb / np.linalg.norm(pb)
            n, m = n - F, m - np.cross(R @ r, F)
        res = np.concatenate([n * self.L**2 / self.EI, m * self.L / self.EI])
        return res, ys, p, R @ q

    def residual(self, x):
        return self.integrate(x)[0]

    def step(self, tensions):
        """One time step; returns the tip position and velocity (world frame)."""
        self.tau = np.asarray(tensions, float)
        self.x = fsolve(self.residual, self.x, xtol=1e-12)
        _, y, tip, vel = self.integrate(self.x)
        yt = self.c0 * y + self.hist
        self.hist = self.c1 * y + self.c2 * self.yprev + self.d1 * yt
        self.yprev = y
        return tip, vel
