"""Independent reference solver (plain NumPy/SciPy) for the static Cosserat rod with tendons.

Not part of the package and not a test file: a helper for the tests. Written only from
/work/shared/PHYSICS.md ("Rod", "Tendons, coupled model"); it shares no code with the
Warp solver.

Conventions
-----------
* Base clamped at p(0) = 0, R(0) = I, rod leaves along +z.
* State y = [p (3), R (9, row-major), n (3), m (3)]; n, m internal force/moment, WORLD frame.
* Kse = diag(GA, GA, EA), Kbt = diag(EI, EI, GJ), v* = e3, u* constant (body frame).
* Tendon routing in the body frame r_i(s) = [x0 + a cos(w s + phi), y0 + a sin(w s + phi), 0],
  w = 2 pi turns / l_i; tendon i is present for s < l_i.
* model="coupled": distributed tendon loads from the 6x6 system of [RW11];
  model="point": only the termination loads.
* Point loads: at s = l_i, F_i = -tau_i R pb_i/|pb_i|, L_i = (R r_i) x F_i from the state just
  before l_i; integrating base -> tip, n <- n - F_i, m <- m - L_i. Point force F at s: n <- n - F.
* Shooting residual [n(L+) - tip_force, m(L+) - tip_moment]; unknowns n(0), m(0).

A rod is a dict (SI units): length, youngs_modulus, poisson_ratio, radius, density,
precurvature (3,), gravity (3,), tip_force (3,), tip_moment (3,),
tendons: list of {offset (x, y), helix_radius, turns, phase, length, tension},
point_forces: list of {s, force (3,)}.
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import fsolve, root

__all__ = ["solve_reference", "solve_reference_user_style"]

_E3 = np.array([0.0, 0.0, 1.0])
_I3 = np.eye(3)


def _hat(x):
    return np.array([[0.0, -x[2], x[1]], [x[2], 0.0, -x[0]], [-x[1], x[0], 0.0]])


def _cross(a, b):
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _vec3(x, default=(0.0, 0.0, 0.0)):
    a = np.asarray(default if x is None else x, dtype=float).reshape(3)
    return a.copy()


class _Tendon:
    __slots__ = ("x0", "y0", "a", "w", "phi", "l", "tau")

    def __init__(self, d: dict, L: float):
        off = d.get("offset", (0.0, 0.0))
        self.x0, self.y0 = float(off[0]), float(off[1])
        self.a = float(d.get("helix_radius", 0.0) or 0.0)
        self.l = float(d.get("length", L) if d.get("length", None) is not None else L)
        if not (0.0 < self.l <= L * (1 + 1e-12)):
            raise ValueError(f"tendon length {self.l} outside (0, L]")
        self.l = min(self.l, L)
        self.w = 2.0 * np.pi * float(d.get("turns", 0.0) or 0.0) / self.l
        self.phi = float(d.get("phase", 0.0) or 0.0)
        self.tau = float(d["tension"])
        if self.tau < 0:
            raise ValueError("tendon tension must be >= 0")

    def routing(self, s):
        """r, r', r'' (body frame) at arc length s."""
        ang = self.w * s + self.phi
        c, sn = np.cos(ang), np.sin(ang)
        a, w = self.a, self.w
        r = np.array([self.x0 + a * c, self.y0 + a * sn, 0.0])
        dr = np.array([-a * w * sn, a * w * c, 0.0])
        ddr = np.array([-a * w * w * c, -a * w * w * sn, 0.0])
        return r, dr, ddr


class _Model:
    """Parameters, RHS and shooting residual for one rod."""

    def __init__(self, rod: dict, model: str, scale: float = 1.0, kink_loads: bool = False):
        self.kink_loads = bool(kink_loads)
        if model not in ("coupled", "point"):
            raise ValueError("model must be 'coupled' or 'point'")
        self.model = model
        self.L = L = float(rod["length"])
        E = float(rod["youngs_modulus"])
        nu = float(rod["poisson_ratio"])
        r = float(rod["radius"])
        rho = float(rod["density"])
        G = E / (2.0 * (1.0 + nu))
        A = np.pi * r**2
        I = np.pi * r**4 / 4.0
        J = 2.0 * I
        self.EI = E * I
        self.Kse = np.diag([G * A, G * A, E * A])
        self.Kbt = np.diag([E * I, E * I, G * J])
        self.Kse_inv = np.diag(1.0 / np.diag(self.Kse))
        self.Kbt_inv = np.diag(1.0 / np.diag(self.Kbt))
        self.vstar = _E3.copy()
        self.ustar = _vec3(rod.get("precurvature"))
        # loads, scaled by `scale` (continuation); precurvature is not a load
        self.fe = scale * rho * A * _vec3(rod.get("gravity"))
        self.tip_force = scale * _vec3(rod.get("tip_force"))
        self.tip_moment = scale * _vec3(rod.get("tip_moment"))
        self.tendons = [_Tendon(t, L) for t in (rod.get("tendons") or [])]
        for t in self.tendons:
            t.tau *= scale
        self.points = []
        for pf in rod.get("point_forces") or []:
            s = float(pf["s"])
            if not (0.0 < s <= L * (1 + 1e-12)):
                raise ValueError(f"point force at s={s} outside (0, L]")
            self.points.append((min(s, L), scale * _vec3(pf["force"])))
        # breakpoints: group values equal up to a relative 1e-12
        cand = sorted([t.l for t in self.tendons] + [s for s, _ in self.points] + [L])
        bps = []
        for c in cand:
            if not bps or c - bps[-1] > 1e-12 * L:
                bps.append(c)
        bps[-1] = L if abs(bps[-1] - L) <= 1e-12 * L else bps[-1]
        self.breakpoints = bps
        tolb = 1e-12 * L
        self.ends_at = [[t for t in self.tendons if abs(t.l - b) <= tolb] for b in bps]
        self.points_at = [[F for s, F in self.points if abs(s - b) <= tolb] for b in bps]
        # tendons present on segment k = (bps[k-1], bps[k]): those with l_i >= bps[k]
        self.active = [[t for t in self.tendons if t.l >= b - tolb] for b in bps]
        self.nfev = 0

    # ---- kinematics ---------------------------------------------------------------------
    def strains(self, R, n, m):
        v = self.Kse_inv @ (R.T @ n) + self.vstar
        u = self.Kbt_inv @ (R.T @ m) + self.ustar
        return v, u

    def rhs(self, s, y, tendons):
        self.nfev += 1
        R = y[3:12].reshape(3, 3)
        n = y[12:15]
        m = y[15:18]
        v, u = self.strains(R, n, m)
        Kse, Kbt = self.Kse, self.Kbt
        dp = R @ v
        dR = R @ _hat(u)
        if self.model == "coupled" and tendons:
            Asum = np.zeros((3, 3))
            Bsum = np.zeros((3, 3))
            Gsum = np.zeros((3, 3))
            Hsum = np.zeros((3, 3))
            asum = np.zeros(3)
            bsum = np.zeros(3)
            for t in tendons:
                r, dr, ddr = t.routing(s)
                pb = _cross(u, r) + dr + v
                nb = np.sqrt(pb @ pb)
                hp2 = np.outer(pb, pb) - (pb @ pb) * _I3  # hat(pb)^2
                Ai = -t.tau * hp2 / nb**3
                hr = _hat(r)
                Bi = hr @ Ai
                Asum += Ai
                Bsum += Bi
                Gsum -= Ai @ hr
                Hsum -= Bi @ hr
                ai = Ai @ (_cross(u, pb) + _cross(u, dr) + ddr)
                asum += ai
                bsum += _cross(r, ai)
            M = np.empty((6, 6))
            M[:3, :3] = Kse + Asum
            M[:3, 3:] = Gsum
            M[3:, :3] = Bsum
            M[3:, 3:] = Kbt + Hsum
            nv = Kse @ (v - self.vstar)
            rhs6 = np.concatenate([
                -_cross(u, nv) - R.T @ self.fe - asum,
                -_cross(u, Kbt @ (u - self.ustar)) - _cross(v, nv) - bsum,
            ])
            x = np.linalg.solve(M, rhs6)
            dv, du = x[:3], x[3:]
            ft = R @ (asum + Asum @ dv + Gsum @ du)
            lt = R @ (bsum + Bsum @ dv + Hsum @ du)
            dn = -(self.fe + ft)
            dm = -_cross(dp, n) - lt
        else:
            dn = -self.fe
            dm = -_cross(dp, n)
        return np.concatenate([dp, dR.reshape(9), dn, dm])

    def termination_load(self, t, y):
        """(F_i, L_i) of tendon t ending at s = t.l, from the state y just before l_i."""
        R = y[3:12].reshape(3, 3)
        v, u = self.strains(R, y[12:15], y[15:18])
        r, dr, _ = t.routing(t.l)
        pb = _cross(u, r) + dr + v
        F = -t.tau * (R @ pb) / np.sqrt(pb @ pb)
        Lm = _cross(R @ r, F)
        return F, Lm

    def tangents(self, s, y, tendons):
        """World-frame unit tangents R pb/|pb| of `tendons` at s for state y."""
        R = y[3:12].reshape(3, 3)
        v, u = self.strains(R, y[12:15], y[15:18])
        out = []
        for t in tendons:
            r, dr, _ = t.routing(s)
            pb = _cross(u, r) + dr + v
            out.append((R @ r, R @ pb / np.sqrt(pb @ pb)))
        return out

    def apply_jumps(self, k, y):
        y_minus = y
        y = y.copy()
        loads = [self.termination_load(t, y_minus) for t in self.ends_at[k]]  # pre-jump state
        for F, Lm in loads:
            y[12:15] -= F
            y[15:18] -= Lm
        for F in self.points_at[k]:
            y[12:15] -= F
        b = self.breakpoints[k]
        if (self.kink_loads and self.model == "coupled" and k + 1 < len(self.breakpoints)
                and self.active[k + 1]):
            # tendons that continue through b kink where the strains jump; the kink applies
            # tau_j (t_j+ - t_j-) (and its moment) to the backbone. The post-jump state is
            # implicit in t_j+; fixed-point iteration (contraction ~ tau / stiffness).
            cont = self.active[k + 1]
            tm = self.tangents(b, y_minus, cont)
            y_expl = y.copy()
            for _ in range(100):
                tp = self.tangents(b, y, cont)
                y_new = y_expl.copy()
                for t, (rw, t_m), (_, t_p) in zip(cont, tm, tp):
                    P = t.tau * (t_p - t_m)
                    y_new[12:15] -= P
                    y_new[15:18] -= _cross(rw, P)
                delta = np.max(np.abs(y_new[12:18] - y[12:18]))
                y = y_new
                if delta <= 1e-15 * (1.0 + np.max(np.abs(y[12:18]))):
                    break
            else:
                raise RuntimeError("kink jump iteration did not converge")
        return y

    def y0(self, n0, m0):
        return np.concatenate([np.zeros(3), _I3.reshape(9), n0, m0])

    # ---- integration --------------------------------------------------------------------
    def integrate(self, n0, m0, method, rtol, atol, s_stops=None, first_step=None):
        """Integrate base -> tip; returns state at L+ (after jumps) and, if s_stops is
        given, positions at those arc lengths (integration stops exactly there)."""
        y = self.y0(np.asarray(n0, float), np.asarray(m0, float))
        s0 = 0.0
        pos = {}
        stops = np.unique(np.asarray(s_stops, float)) if s_stops is not None else np.zeros(0)
        for k, b in enumerate(self.breakpoints):
            act = self.active[k]
            fun = lambda s, yy, act=act: self.rhs(s, yy, act)  # noqa: E731
            inner = stops[(stops > s0) & (stops < b)]
            for e in list(inner) + [b]:
                if e > s0:
                    sol = solve_ivp(fun, (s0, e), y, method=method, rtol=rtol, atol=atol,
                                    first_step=first_step)
                    if sol.status != 0:
                        raise RuntimeError(f"solve_ivp failed: {sol.message}")
                    y = sol.y[:, -1].copy()
                    s0 = e
                pos[e] = y[0:3].copy()
            y = self.apply_jumps(k, y)
        if s_stops is not None:
            pos[0.0] = np.zeros(3)
            positions = np.array([pos[float(s)] for s in np.asarray(s_stops, float)])
            return y, positions
        return y

    def residual(self, n0, m0, **kw):
        yL = self.integrate(n0, m0, **kw)
        return np.concatenate([yL[12:15] - self.tip_force, yL[15:18] - self.tip_moment]), yL

    # ---- initial guess ------------------------------------------------------------------
    def straight_guess(self):
        L = self.L
        n0 = self.tip_force + self.fe * L
        m0 = self.tip_moment + _cross(L * _E3, self.tip_force) + 0.5 * L * L * _cross(_E3, self.fe)
        for t in self.tendons:
            r, dr, _ = t.routing(t.l)
            tang = dr + _E3
            F = -t.tau * tang / np.linalg.norm(tang)
            n0 = n0 + F
            m0 = m0 + _cross(t.l * _E3, F) + _cross(r, F)
        for s, F in self.points:
            n0 = n0 + F
            m0 = m0 + _cross(s * _E3, F)
        return n0, m0

    def scales(self):
        """Characteristic force Fc and moment Mc = Fc L for scaling the shooting problem."""
        n0, m0 = self.straight_guess()
        L = self.L
        Fc = max(np.linalg.norm(n0), np.linalg.norm(m0) / L, sum(t.tau for t in self.tendons),
                 np.linalg.norm(self.tip_force), np.linalg.norm(self.tip_moment) / L,
                 np.linalg.norm(self.fe) * L, 1e-6 * self.EI / L**2)
        return Fc, Fc * L


def _scaled_shoot(mdl: _Model, x_guess, ivp_kw, Fc, Mc, root_method):
    """Solve the shooting problem in scaled unknowns; returns (x, scaled residual norm, ok)."""
    sc = np.array([Fc] * 3 + [Mc] * 3)

    def F(z):
        x = z * sc
        res, _ = mdl.residual(x[:3], x[3:], **ivp_kw)
        return res / sc

    def J(z):
        f0 = F(z)
        h = 1e-7
        Jm = np.empty((6, 6))
        for j in range(6):
            zp = z.copy()
            zp[j] += h
            zm = z.copy()
            zm[j] -= h
            Jm[:, j] = (F(zp) - F(zm)) / (2 * h)
        return Jm, f0

    z0 = np.asarray(x_guess, float) / sc

    def fun(z):
        return F(z)

    def jac(z):
        Jm, _ = J(z)
        return Jm

    try:
        if root_method == "hybr":
            sol = root(fun, z0, jac=jac, method="hybr", options={"xtol": 1e-14})
        else:
            sol = root(fun, z0, jac=jac, method=root_method, tol=1e-14)
        z = sol.x
        f = F(z)
        # Newton polish (cheap, guards against hybr stopping at a slightly larger residual)
        for _ in range(4):
            if np.linalg.norm(f) < 1e-13:
                break
            Jm, f = J(z)
            dz = np.linalg.solve(Jm, -f)
            z_new = z + dz
            f_new = F(z_new)
            if np.linalg.norm(f_new) < np.linalg.norm(f):
                z, f = z_new, f_new
            else:
                break
    except (RuntimeError, np.linalg.LinAlgError, FloatingPointError, ValueError):
        return None, np.inf, False
    rn = float(np.linalg.norm(f))
    return z * sc, rn, bool(np.isfinite(rn) and rn < 1e-10)


def solve_reference(rod: dict, *, model="coupled", rtol=1e-12, atol=1e-14, method="DOP853",
                    guess=None, s_eval=None, root_method="hybr", kink_loads=True) -> dict:
    """Solve the static BVP by shooting. See the module docstring for conventions.

    kink_loads (coupled model only; default True, the project's model, see README 'Model notes';
    False = the bare jump rule of the module docstring):
    where n, m jump at an interior s (a tendon termination or a point force) while other
    tendons continue, the strains jump and so do the continuing tendons' tangents; with
    kink_loads=True the resulting point load tau_j (t_j+ - t_j-) at R r_j is applied too
    (post-jump state solved implicitly), which makes rod + tendons exactly balanced.

    guess: optional (6,) [n0, m0] or dict with keys n0, m0.
    Returns tip_position, tip_rotation, n0, m0, residual_norm, success, nfev, and positions
    (len(s_eval), 3) when s_eval is given.
    """
    ivp_kw = dict(method=method, rtol=rtol, atol=atol)
    mdl = _Model(rod, model, kink_loads=kink_loads)
    Fc, Mc = mdl.scales()
    if guess is None:
        n0g, m0g = mdl.straight_guess()
        x0 = np.concatenate([n0g, m0g])
    elif isinstance(guess, dict):
        x0 = np.concatenate([_vec3(guess["n0"]), _vec3(guess["m0"])])
    else:
        x0 = np.asarray(guess, float).reshape(6)

    nfev = 0
    x, rn, ok = _scaled_shoot(mdl, x0, ivp_kw, Fc, Mc, root_method)
    nfev += mdl.nfev
    if not ok:
        # continuation in the load factor lam: tensions, tip loads, gravity, point forces
        lam, dlam = 0.0, 0.1
        xc = np.zeros(6)
        while lam < 1.0:
            lam_try = min(1.0, lam + dlam)
            m_l = _Model(rod, model, scale=lam_try, kink_loads=kink_loads)
            xs, rns, oks = _scaled_shoot(m_l, xc, ivp_kw, Fc, Mc, root_method)
            nfev += m_l.nfev
            if oks:
                lam, xc = lam_try, xs
                dlam = min(0.25, dlam * 1.5)
            else:
                dlam *= 0.5
                if dlam < 1e-4:
                    raise RuntimeError(f"solve_reference: continuation failed at load factor {lam}")
        x, ok = xc, True
    mdl.nfev = 0
    res, yL = mdl.residual(x[:3], x[3:], **ivp_kw)
    nfev += mdl.nfev
    out = dict(
        tip_position=yL[0:3].copy(),
        tip_rotation=yL[3:12].reshape(3, 3).copy(),
        n0=x[:3].copy(),
        m0=x[3:].copy(),
        residual_norm=float(np.linalg.norm(res)),
        success=bool(ok),
        nfev=int(nfev),
    )
    if s_eval is not None:
        s_eval = np.asarray(s_eval, float).reshape(-1)
        if np.any(s_eval < 0) or np.any(s_eval > mdl.L * (1 + 1e-12)):
            raise ValueError("s_eval outside [0, L]")
        mdl.nfev = 0
        _, positions = mdl.integrate(x[:3], x[3:], s_stops=np.minimum(s_eval, mdl.L), **ivp_kw)
        out["nfev"] += mdl.nfev
        out["positions"] = positions
    return out


def solve_reference_user_style(rod: dict, model="coupled") -> dict:
    """How a typical Python user would do it (for benchmarking): solve_ivp RK45 at rtol=1e-8
    (default atol) inside scipy.optimize.fsolve from the straight-rod guess; piecewise only
    over the breakpoints that correctness needs. Returns tip_position, nfev, n0, m0."""
    mdl = _Model(rod, model)
    n0g, m0g = mdl.straight_guess()
    kw = dict(method="RK45", rtol=1e-8, atol=1e-6)

    def F(x):
        res, _ = mdl.residual(x[:3], x[3:], **kw)
        return res

    x = fsolve(F, np.concatenate([n0g, m0g]))
    _, yL = mdl.residual(x[:3], x[3:], **kw)
    return dict(tip_position=yL[0:3].copy(), nfev=int(mdl.nfev), n0=x[:3].copy(), m0=x[3:].copy())
