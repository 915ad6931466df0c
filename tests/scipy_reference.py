"""An independent per-rod reference solver in NumPy/SciPy (not part of the package).

Written from shared PHYSICS.md with other numerics than the Warp solver: adaptive
``solve_ivp`` between breakpoints, a dense 6x6 ``np.linalg.solve`` for the coupled tendon
system, and the post-jump state at interior terminations found by a root solve (the package
uses a fixed-point iteration). The shooting unknowns are found by ``scipy.optimize.root``.

A rod is a dict (SI units): length, youngs_modulus, poisson_ratio, radius, density,
precurvature (3,), gravity (3,), tip_force (3,), tip_moment (3,), tendons: list of
{offset (2,), helix_radius, turns, phase, length, tension}, point_forces: list of {s, force}.
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import fsolve, root

E3 = np.array([0.0, 0.0, 1.0])


def hat(x):
    return np.array([[0, -x[2], x[1]], [x[2], 0, -x[0]], [-x[1], x[0], 0]])


class Rod:
    def __init__(self, d: dict, model: str):
        self.model = model
        self.L = float(d["length"])
        E, nu, r = d["youngs_modulus"], d["poisson_ratio"], d["radius"]
        G = E / (2 * (1 + nu))
        A, I = np.pi * r**2, np.pi * r**4 / 4
        self.Kse = np.diag([G * A, G * A, E * A])
        self.Kbt = np.diag([E * I, E * I, 2 * G * I])
        self.EI = E * I
        self.ustar = np.asarray(d.get("precurvature", np.zeros(3)), float)
        self.fe = d["density"] * A * np.asarray(d.get("gravity", np.zeros(3)), float)
        self.tip_f = np.asarray(d.get("tip_force", np.zeros(3)), float)
        self.tip_m = np.asarray(d.get("tip_moment", np.zeros(3)), float)
        self.tendons = []
        for t in d.get("tendons", []):
            li = float(t.get("length", self.L))
            self.tendons.append(dict(x0=t.get("offset", (0, 0))[0], y0=t.get("offset", (0, 0))[1],
                                     a=t.get("helix_radius", 0.0), w=2 * np.pi * t.get("turns", 0.0) / li,
                                     ph=t.get("phase", 0.0), l=li, tau=float(t["tension"])))
        self.points = [(float(p["s"]), np.asarray(p["force"], float)) for p in d.get("point_forces", [])]
        self.nfev = 0

    def route(self, t, s):
        ang = t["w"] * s + t["ph"]
        a, w = t["a"], t["w"]
        r = np.array([t["x0"] + a * np.cos(ang), t["y0"] + a * np.sin(ang), 0.0])
        dr = np.array([-a * w * np.sin(ang), a * w * np.cos(ang), 0.0])
        ddr = np.array([-a * w * w * np.cos(ang), -a * w * w * np.sin(ang), 0.0])
        return r, dr, ddr

    def strains(self, R, n, m):
        return np.linalg.solve(self.Kse, R.T @ n) + E3, np.linalg.solve(self.Kbt, R.T @ m) + self.ustar

    def rhs(self, s, y, present):
        self.nfev += 1
        R, n, m = y[3:12].reshape(3, 3), y[12:15], y[15:18]
        v, u = self.strains(R, n, m)
        dp = R @ v
        dR = R @ hat(u)
        dn = -self.fe.copy()
        dm = -np.cross(dp, n)
        if self.model == "coupled" and present:
            A, B, G, H = (np.zeros((3, 3)) for _ in range(4))
            a, b = np.zeros(3), np.zeros(3)
            for t in present:
                r, dr, ddr = self.route(t, s)
                pb = np.cross(u, r) + dr + v
                Ai = -t["tau"] * hat(pb) @ hat(pb) / np.linalg.norm(pb) ** 3
                Bi = hat(r) @ Ai
                A += Ai
                B += Bi
                G -= Ai @ hat(r)
                H -= Bi @ hat(r)
                ai = Ai @ (np.cross(u, pb) + np.cross(u, dr) + ddr)
                a += ai
                b += np.cross(r, ai)
            sv = self.Kse @ (v - E3)
            su = self.Kbt @ (u - self.ustar)
            lhs = np.block([[self.Kse + A, G], [B, self.Kbt + H]])
            rhs = np.concatenate([-np.cross(u, sv) - R.T @ self.fe - a,
                                  -np.cross(u, su) - np.cross(v, sv) - b])
            vs_us = np.linalg.solve(lhs, rhs)
            dn = dn - R @ (a + A @ vs_us[:3] + G @ vs_us[3:])
            dm = dm - R @ (b + B @ vs_us[:3] + H @ vs_us[3:])
        return np.concatenate([dp, dR.ravel(), dn, dm])

    def tangent(self, t, s, R, n, m):
        v, u = self.strains(R, n, m)
        r, dr, _ = self.route(t, s)
        pb = np.cross(u, r) + dr + v
        return R @ pb / np.linalg.norm(pb), R @ r

    def jump(self, s, y):
        """Loads at arc length s: terminations, point forces and (coupled) tendon kinks."""
        R, n, m = y[3:12].reshape(3, 3), y[12:15].copy(), y[15:18].copy()
        n1, m1 = n.copy(), m.copy()
        any_jump = False
        for t in self.tendons:
            if abs(t["l"] - s) < 1e-12:
                tg, rw = self.tangent(t, s, R, n, m)
                F = -t["tau"] * tg
                n1 -= F
                m1 -= np.cross(rw, F)
                any_jump = True
        for sp, F in self.points:
            if abs(sp - s) < 1e-12:
                n1 -= F
                any_jump = True
        going_on = [t for t in self.tendons if t["l"] > s + 1e-12 and t["tau"] > 0]
        if self.model == "coupled" and any_jump and going_on and s < self.L - 1e-12:
            before = [self.tangent(t, s, R, n, m)[0] for t in going_on]

            def eq(z):
                n2, m2 = z[:3], z[3:]
                fk, lk = np.zeros(3), np.zeros(3)
                for t, t0 in zip(going_on, before):
                    t1, rw = self.tangent(t, s, R, n2, m2)
                    F = t["tau"] * (t1 - t0)
                    fk += F
                    lk += np.cross(rw, F)
                return np.concatenate([n2 - (n1 - fk), m2 - (m1 - lk)])

            z = fsolve(eq, np.concatenate([n1, m1]), xtol=1e-14)
            n1, m1 = z[:3], z[3:]
        out = y.copy()
        out[12:15], out[15:18] = n1, m1
        return out

    def breakpoints(self):
        pts = {self.L} | {t["l"] for t in self.tendons} | {s for s, _ in self.points}
        return sorted(pts)

    def integrate(self, x, method, rtol, atol, s_eval=None):
        n0 = x[:3] * self.EI / self.L**2
        m0 = x[3:] * self.EI / self.L
        y = np.concatenate([np.zeros(3), np.eye(3).ravel(), n0, m0])
        s0 = 0.0
        samples = []
        for sb in self.breakpoints():
            present = [t for t in self.tendons if t["l"] > s0 + 1e-12 and t["tau"] > 0]
            te = None if s_eval is None else [s for s in s_eval if s0 <= s <= sb]
            sol = solve_ivp(self.rhs, (s0, sb), y, method=method, rtol=rtol, atol=atol, args=(present,),
                            t_eval=te)
            if not sol.success:
                raise RuntimeError(sol.message)
            if te:
                samples.extend(sol.y[:3].T)
            y = self.jump(sb, sol.y[:, -1])
            s0 = sb
        res_n = (y[12:15] - self.tip_f) * self.L**2 / self.EI
        res_m = (y[15:18] - self.tip_m) * self.L / self.EI
        return np.concatenate([res_n, res_m]), y, samples

    def straight_guess(self):
        n0 = self.tip_f + self.fe * self.L
        m0 = self.tip_m + np.cross(self.L * E3, self.tip_f) + np.cross(0.5 * self.L**2 * E3, self.fe)
        for t in self.tendons:
            r, dr, _ = self.route(t, t["l"])
            tg = (dr + E3) / np.linalg.norm(dr + E3)
            F = -t["tau"] * tg
            n0 = n0 + F
            m0 = m0 + np.cross(t["l"] * E3 + r, F)
        for s, F in self.points:
            n0 = n0 + F
            m0 = m0 + np.cross(s * E3, F)
        return np.concatenate([n0 * self.L**2 / self.EI, m0 * self.L / self.EI])


def solve_reference(rod: dict, *, model="coupled", rtol=1e-11, atol=1e-13, method="DOP853", s_eval=None) -> dict:
    """Tip pose and base wrench of one rod, solved to tight tolerances."""
    r = Rod(rod, model)
    sol = root(lambda x: r.integrate(x, method, rtol, atol)[0], r.straight_guess(), method="hybr",
               options={"xtol": 1e-14})
    res, y, samples = r.integrate(sol.x, method, rtol, atol, s_eval)
    if not sol.success and np.linalg.norm(res) > 1e-10:  # "no further improvement" at round-off is fine
        raise RuntimeError(f"reference root finder failed: {sol.message} (|r| = {np.linalg.norm(res):.1e})")
    out = {"tip_position": y[:3], "tip_rotation": y[3:12].reshape(3, 3),
           "n0": sol.x[:3] * r.EI / r.L**2, "m0": sol.x[3:] * r.EI / r.L,
           "residual_norm": float(np.linalg.norm(res)), "nfev": r.nfev}
    if s_eval is not None:
        out["positions"] = np.array(samples)
    return out


def solve_reference_user_style(rod: dict, model="coupled") -> dict:
    """What a Python user would write: solve_ivp RK45 at rtol 1e-8 inside fsolve."""
    r = Rod(rod, model)
    x = fsolve(lambda x: r.integrate(x, "RK45", 1e-8, 1e-10)[0], r.straight_guess())
    _, y, _ = r.integrate(x, "RK45", 1e-8, 1e-10)
    return {"tip_position": y[:3], "nfev": r.nfev}
