"""Independent reference solver (plain NumPy/SciPy) for the static Cosserat rod with tendons.

Not part of the package and not a test file: a helper for the tests. Written only from the
model's equations (docs/physics.md, sections 1 and 2: the rod and the coupled tendon model) and
the equations of tendon friction and length control below; it shares no code with the Warp solver.

Conventions
-----------
* Base clamped at p(0) = 0, R(0) = I, rod leaves along +z.
* State y = [p (3), R (9, row-major), n (3), m (3)]; n, m internal force/moment, WORLD frame.
  With friction or length control the state grows by 4 T (T tendons, see "Extended state").
* Kse = diag(GA, GA, EA), Kbt = diag(EI, EI, GJ), v* = e3, u* constant (body frame).
* Tendon routing in the body frame r_i(s) = [x0 + a cos(w s + phi), y0 + a sin(w s + phi), 0],
  w = 2 pi turns / l_i; tendon i is present for s < l_i. pb_i = u x r_i + r_i' + v, world unit
  tangent t_i = R pb_i / |pb_i|; the motor side is s = 0.
* model="coupled": distributed tendon loads from the 6x6 system of [RW11];
  model="point": only the termination loads.
* Point loads: at s = l_i, F_i = -tau_i(l_i-) t_i(l_i-), L_i = (R r_i) x F_i from the state just
  before l_i; integrating base -> tip, n <- n - F_i, m <- m - L_i. Point force F at s: n <- n - F.
* Kinks (kink_loads=True, coupled model): where n, m jump at an interior s while tendon j goes
  on, t_j jumps from t- to t+ and the tendon pushes on the backbone with the point force
  P_j = tau_j+ t_j+ - tau_j- t_j- at R r_j (n <- n - P_j, m <- m - (R r_j) x P_j); the post-jump
  state is implicit (fixed-point iteration). kink_loads=False: no kink force ([RW11] as published).
* Shooting residual [n(L+) - tip_force, m(L+) - tip_moment]; unknowns n(0), m(0) (plus one base
  tension per length-controlled, taut tendon, see below).

Tendon friction (capstan), per tendon keys friction = mu >= 0 (default 0), slip = sigma = +-1
(default +1: the tendon slides toward the motor, tension falls from base to tip)
    tau_i' = -mu_i sigma_i kappa_i tau_i,     kappa_i = |t_i'|    (turning rate per unit s)
    tendon load on the backbone (world, per unit s):  f_i = (tau_i t_i)' = tau_i t_i' + tau_i' t_i,
                                                      l_i = (R r_i) x f_i
  tau_i(0) is the given tension. kappa_i depends on v', u' (t' contains pb' = v' + u' x r + u x r'
  + r''), so with mu > 0 the 6x6 system for (v', u') is nonlinear in them: it is solved exactly by
  a fixed-point iteration in the kappa_j (a contraction of rate ~ mu tau (1/EA + r^2/EI)), with a
  Newton fallback. At a kink (kink_loads=True) the tension jumps too:
  tau+ = tau- exp(-mu sigma angle(t-, t+)); with kink_loads=False it does not. Point model: tau_i
  follows the same law with kappa_i from the rod's own v', u' (no tendon terms), and the kink
  tension jump applies when kink_loads=True (there is never a kink force in the point model).

Length (displacement) control, per tendon keys control = "tension" (default) | "displacement",
displacement = q [m] (pull positive), compliance = c [1/N] (c = 1/(E_t A_t), 0 = inextensible),
pretension = tau_ref [N] (default 0), optional reference_length = ell0_ref [m] (else computed)
    ell0_i(state) = int_0^{l_i} |pb_i| / (1 + c_i tau_i) ds        (unstretched length in the robot)
    ell0_ref,i    = ell0_i at the reference state: every tendon in tension control at its
                    pretension, no friction, same rod, loads and model (one extra solve)
    taut:  ell0_i = ell0_ref,i - q_i with tau_i(0) > 0;  slack: tau_i(0) = 0, ell0_i <= ell0_ref,i - q_i
  The unknown is tau_i(0); the complementarity is solved by an active set (solve all taut; a
  tendon whose tension comes out negative is set slack; a slack one whose inequality fails is
  made taut again; repeat).

Extended state (friction or length control): y[18 + i] = tau_i, y[18 + T + i] = Theta_i (turning
int kappa ds plus kink angles), y[18 + 2T + i] = ell_i (int |pb| ds), y[18 + 3T + i] = ell0_i;
frozen for s >= l_i.

Sections (rod key "sections", optional): a backbone that varies along s. Each section is a dict with
end [m] (the first starts at the base, each next one at the previous end, the last ends at L) and
radius, inner_radius (default 0), youngs_modulus, shear_modulus or poisson_ratio, density: a number or
[at its start, at its end], linear in s in between. Tube: A = pi (ro^2 - ri^2), I = pi (ro^4 - ri^4) / 4,
J = 2 I, Kse = diag(G A, G A, E A), Kbt = diag(E I, E I, G J), fe = rho A g. Differentiating
R^T n = Kse (v - v*) and R^T m = Kbt (u - u*) adds -Kse' (v - v*) and -Kbt' (u - u*) to the right-hand
sides of the (v', u') system. The section ends are breakpoints: n, m continue across them, the strains
follow the new section's stiffness, and the tendons that go on kink there (kink_loads, as above).
Tension control without friction only.

A rod is a dict (SI units): length, youngs_modulus, poisson_ratio, radius, density (or sections),
precurvature (3,), gravity (3,), tip_force (3,), tip_moment (3,),
tendons: list of {offset (x, y), helix_radius, turns, phase, length, tension,
                  friction, slip, control, displacement, compliance, pretension, reference_length},
point_forces: list of {s, force (3,)}.
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import fsolve, root

__all__ = ["solve_reference", "solve_reference_user_style", "reference_lengths"]

_E3 = np.array([0.0, 0.0, 1.0])
_I3 = np.eye(3)
_EPS = np.finfo(float).eps


def _hat(x):
    return np.array([[0.0, -x[2], x[1]], [x[2], 0.0, -x[0]], [-x[1], x[0], 0.0]])


def _cross(a, b):
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _vec3(x, default=(0.0, 0.0, 0.0)):
    a = np.asarray(default if x is None else x, dtype=float).reshape(3)
    return a.copy()


def _angle(a, b):
    """Angle [rad] between unit vectors a and b (accurate for small angles)."""
    return float(np.arctan2(np.linalg.norm(_cross(a, b)), a @ b))


class _Section:
    """A section of a backbone that varies along s (module docstring, "Sections"): each field a number or
    [at its start, at its end], linear in between; the shear modulus given, or E / (2 (1 + nu))."""

    FIELDS = ("radius", "inner_radius", "youngs_modulus", "shear_modulus", "density")

    def __init__(self, d: dict):
        self.end = float(d["end"])
        self.start = 0.0
        pairs = {}
        for name in ("radius", "inner_radius", "youngs_modulus", "poisson_ratio", "shear_modulus", "density"):
            if d.get(name) is not None:
                pairs[name] = np.broadcast_to(np.asarray(d[name], float), (2,)).copy()
        pairs.setdefault("inner_radius", np.zeros(2))
        if "shear_modulus" not in pairs:
            pairs["shear_modulus"] = pairs["youngs_modulus"] / (2.0 * (1.0 + pairs["poisson_ratio"]))
        self.pairs = pairs

    def value(self, s, name):
        """(value, d/ds) of field ``name`` at s."""
        a, b = self.pairs[name]
        slope = (b - a) / (self.end - self.start)
        return a + slope * (s - self.start), slope


class _Tendon:
    __slots__ = ("idx", "x0", "y0", "a", "w", "phi", "l", "tau", "mu", "sigma", "control", "q", "c",
                 "pre", "ref_len")

    def __init__(self, d: dict, L: float, idx: int = 0):
        self.idx = idx
        off = d.get("offset", (0.0, 0.0))
        self.x0, self.y0 = float(off[0]), float(off[1])
        self.a = float(d.get("helix_radius", 0.0) or 0.0)
        self.l = float(d.get("length", L) if d.get("length", None) is not None else L)
        if not (0.0 < self.l <= L * (1 + 1e-12)):
            raise ValueError(f"tendon length {self.l} outside (0, L]")
        self.l = min(self.l, L)
        self.w = 2.0 * np.pi * float(d.get("turns", 0.0) or 0.0) / self.l
        self.phi = float(d.get("phase", 0.0) or 0.0)
        self.control = d.get("control", "tension") or "tension"
        if self.control not in ("tension", "displacement"):
            raise ValueError(f"tendon {idx}: control must be 'tension' or 'displacement', got {self.control!r}")
        if self.control == "tension":
            self.tau = float(d["tension"])
            if self.tau < 0:
                raise ValueError("tendon tension must be >= 0")
        else:
            self.tau = 0.0  # unknown; the model sets a guess
        self.mu = float(d.get("friction", 0.0) or 0.0)
        if self.mu < 0:
            raise ValueError(f"tendon {idx}: friction must be >= 0, got {self.mu}")
        self.sigma = float(d.get("slip", 1.0) if d.get("slip", None) is not None else 1.0)
        if self.sigma not in (1.0, -1.0):
            raise ValueError(f"tendon {idx}: slip must be +1 or -1, got {self.sigma}")
        self.q = float(d.get("displacement", 0.0) or 0.0)
        self.c = float(d.get("compliance", 0.0) or 0.0)
        if self.c < 0:
            raise ValueError(f"tendon {idx}: compliance must be >= 0, got {self.c} 1/N")
        self.pre = float(d.get("pretension", 0.0) or 0.0)
        if self.pre < 0:
            raise ValueError(f"tendon {idx}: pretension must be >= 0, got {self.pre} N")
        rl = d.get("reference_length", None)
        self.ref_len = None if rl is None else float(rl)

    def routing(self, s):
        """r, r', r'' (body frame) at arc length s."""
        ang = self.w * s + self.phi
        c, sn = np.cos(ang), np.sin(ang)
        a, w = self.a, self.w
        r = np.array([self.x0 + a * c, self.y0 + a * sn, 0.0])
        dr = np.array([-a * w * sn, a * w * c, 0.0])
        ddr = np.array([-a * w * w * c, -a * w * w * sn, 0.0])
        return r, dr, ddr


def _needs_reference(rod: dict) -> bool:
    return any((t.get("control", "tension") or "tension") == "displacement"
               and t.get("reference_length", None) is None for t in (rod.get("tendons") or []))


class _Model:
    """Parameters, RHS and shooting residual for one rod.

    scale: load factor on tensions and loads (continuation of tension-controlled rods).
    blend: homotopy from the reference state (length control): tensions pre + blend (tau - pre),
        friction blend mu, displacements blend q. ref_lengths: (T,) ell0_ref per tendon.
    slack: indices of length-controlled tendons held at zero tension (active set).
    augmented: carry the tendon states (tensions, turning, lengths); default: when needed.
    """

    def __init__(self, rod: dict, model: str, scale: float = 1.0, kink_loads: bool = False, *,
                 blend=None, ref_lengths=None, slack=(), augmented=None):
        self.kink_loads = bool(kink_loads)
        if model not in ("coupled", "point"):
            raise ValueError("model must be 'coupled' or 'point'")
        self.model = model
        self.L = L = float(rod["length"])
        self.vstar = _E3.copy()
        self.ustar = _vec3(rod.get("precurvature"))
        # loads, scaled by `scale` (continuation); precurvature is not a load
        self.g = scale * _vec3(rod.get("gravity"))
        self.sections = [_Section(d) for d in rod.get("sections") or []]
        if self.sections:
            starts = [0.0] + [sec.end for sec in self.sections[:-1]]
            for sec, s0 in zip(self.sections, starts):
                sec.start = s0
            if abs(self.sections[-1].end - L) > 1e-12 * L:
                raise ValueError("the last section must end at the rod length")
            self.sec = 0
            self._at(0.0)  # the base's stiffness: the scales and the guess
            self.fe = self.fe_s.copy()
        else:
            E = float(rod["youngs_modulus"])
            G = E / (2.0 * (1.0 + float(rod["poisson_ratio"])))
            r = float(rod["radius"])
            self._set_stiffness(np.pi * r**2, np.pi * r**4 / 4.0, E, G)
            self.fe = float(rod["density"]) * np.pi * r**2 * self.g
            self.fe_s = self.fe
        self.tip_force = scale * _vec3(rod.get("tip_force"))
        self.tip_moment = scale * _vec3(rod.get("tip_moment"))
        self.tendons = [_Tendon(t, L, i) for i, t in enumerate(rod.get("tendons") or [])]
        self.T = len(self.tendons)
        for t in self.tendons:
            t.tau *= scale
        if blend is not None:
            for t in self.tendons:
                if t.control == "tension":
                    t.tau = t.pre + blend * (t.tau - t.pre)
                t.mu *= blend
        # length control: targets ell0_ref - q, unknown base tensions of the taut tendons
        disp = [t for t in self.tendons if t.control == "displacement"]
        self.slack = set(int(i) for i in slack)
        self.free = [t for t in disp if t.idx not in self.slack]
        self.target = {}
        for t in disp:
            ref = t.ref_len if t.ref_len is not None else (
                None if ref_lengths is None else float(ref_lengths[t.idx]))
            if ref is None or not np.isfinite(ref):
                raise ValueError(f"tendon {t.idx}: length control needs its reference length")
            q = t.q * (1.0 if blend is None else blend)
            self.target[t.idx] = ref - q
            # guess: straight rod, tension changes the unstretched length at the rate kl [m/N]
            t.tau = 0.0 if t.idx in self.slack else max(t.pre + q / self.length_rate(t), 0.0)
        self.augmented = bool(augmented) if augmented is not None else (
            bool(disp) or any(t.mu > 0 for t in self.tendons))
        self.points = []
        for pf in rod.get("point_forces") or []:
            s = float(pf["s"])
            if not (0.0 < s <= L * (1 + 1e-12)):
                raise ValueError(f"point force at s={s} outside (0, L]")
            self.points.append((min(s, L), scale * _vec3(pf["force"])))
        if self.sections and (disp or any(t.mu > 0 for t in self.tendons)):
            raise ValueError("sections: tension control without friction only")
        # breakpoints (with the sections' ends): group values equal up to a relative 1e-12
        cand = sorted([t.l for t in self.tendons] + [s for s, _ in self.points] + [L]
                      + [sec.end for sec in self.sections[:-1]])
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
        self.kinks = []  # kink records of the last integration (augmented state only)
        self.stop_states = {}  # full states at the s_stops of the last integration

    def _set_stiffness(self, A, I, E, G):
        self.EI = E * I
        self.EA = E * A
        self.Kse = np.diag([G * A, G * A, E * A])
        self.Kbt = np.diag([E * I, E * I, G * 2.0 * I])
        self.Kse_inv = np.diag(1.0 / np.diag(self.Kse))
        self.Kbt_inv = np.diag(1.0 / np.diag(self.Kbt))

    def _section_of(self, s):
        """Index of the section holding s (a point inside it: no tie at an end)."""
        return next(j for j, sec in enumerate(self.sections) if s < sec.end or j == len(self.sections) - 1)

    def _at(self, s):
        """With sections: Kse, Kbt (and inverses), their s-derivatives dKse, dKbt and the weight per
        length fe_s at s, in the section self.sec (by its linear profiles, extended to its ends)."""
        if not self.sections:
            return
        sec = self.sections[self.sec]
        (ro, dro), (ri, dri), (E, dE), (G, dG), (rho, drho) = (sec.value(s, f) for f in _Section.FIELDS)
        A, dA = np.pi * (ro**2 - ri**2), 2.0 * np.pi * (ro * dro - ri * dri)
        I, dI = np.pi * (ro**4 - ri**4) / 4.0, np.pi * (ro**3 * dro - ri**3 * dri)
        self._set_stiffness(A, I, E, G)
        self.dKse = np.diag([dG * A + G * dA, dG * A + G * dA, dE * A + E * dA])
        self.dKbt = np.diag([dE * I + E * dI, dE * I + E * dI, 2.0 * (dG * I + G * dI)])
        self.fe_s = rho * A * self.g

    def length_rate(self, t):
        """Rough d ell0 / d tau [m/N] of tendon t on a straight rod (a scale, not a model)."""
        rr = np.hypot(t.x0, t.y0) + abs(t.a)
        return t.l * (1.0 / self.EA + rr * rr / self.EI + t.c)

    # ---- extended state: y[18 + i] tau_i, y[18 + T + i] Theta_i, y[18 + 2T + i] ell_i,
    # y[18 + 3T + i] ell0_i (module docstring)
    def i_len0(self, i):
        return 18 + 3 * self.T + i

    def tension(self, t, y):
        return y[18 + t.idx] if self.augmented else t.tau

    # ---- kinematics ---------------------------------------------------------------------
    def strains(self, R, n, m):
        v = self.Kse_inv @ (R.T @ n) + self.vstar
        u = self.Kbt_inv @ (R.T @ m) + self.ustar
        return v, u

    def _friction_solve(self, M, rhs6, fr):
        """Solve M x + sum_j kappa_j C_j = rhs6 with kappa_j = |g_j + W_j x| (friction tendons).

        fr: list of (C_j (6,), g_j (3,), W_j (3, 6)). x is affine in kappa, x = x0 - Y kappa, so
        this is a small fixed point kappa = |a - Z kappa| (contraction; Newton if it is not)."""
        nf = len(fr)
        Cm = np.array([c for c, _, _ in fr]).T  # (6, nf)
        sol = np.linalg.solve(M, np.column_stack([rhs6, Cm]))
        x0, Y = sol[:, 0], sol[:, 1:]
        WX = np.vstack([W for _, _, W in fr]) @ sol  # (3 nf, 1 + nf)
        a = np.concatenate([g for _, g, _ in fr]).reshape(nf, 3) + WX[:, 0].reshape(nf, 3)
        Z = WX[:, 1:].reshape(nf, 3, nf)

        def kmap(k):
            d = a - Z @ k
            return np.sqrt(np.einsum("ij,ij->i", d, d))

        k = np.linalg.norm(a, axis=1)
        for _ in range(200):
            k_new = kmap(k)
            delta = np.max(np.abs(k_new - k))
            k = k_new
            if delta <= 8 * _EPS * (1.0 + np.max(k)):
                break
        else:
            sol = root(lambda kk: kk - kmap(kk), k, method="hybr", options={"xtol": 1e-15})
            k = sol.x
            if not sol.success and np.max(np.abs(k - kmap(k))) > 1e-12 * (1.0 + np.max(np.abs(k))):
                raise RuntimeError("friction strain system did not converge")
        return x0 - Y @ k, k, Cm @ k

    def rhs(self, s, y, tendons):
        self.nfev += 1
        self._at(s)
        R = y[3:12].reshape(3, 3)
        n = y[12:15]
        m = y[15:18]
        v, u = self.strains(R, n, m)
        Kse, Kbt = self.Kse, self.Kbt
        dp = R @ v
        dR = R @ _hat(u)
        aug = self.augmented
        kappa = {}  # tendon index -> turning rate |t'| (augmented state only)
        geo = {}  # tendon index -> (r, P = (I - h h^T)/|pb|, e = u x pb + u x r' + r'', |pb|)
        if self.model == "coupled" and tendons:
            Asum = np.zeros((3, 3))
            Bsum = np.zeros((3, 3))
            Gsum = np.zeros((3, 3))
            Hsum = np.zeros((3, 3))
            asum = np.zeros(3)
            bsum = np.zeros(3)
            fr = []  # friction tendons: (idx, C_j, g_j, W_j)
            for t in tendons:
                tau = y[18 + t.idx] if aug else t.tau
                r, dr, ddr = t.routing(s)
                pb = _cross(u, r) + dr + v
                nb = np.sqrt(pb @ pb)
                hp2 = np.outer(pb, pb) - (pb @ pb) * _I3  # hat(pb)^2
                Ai = -tau * hp2 / nb**3
                hr = _hat(r)
                Bi = hr @ Ai
                Asum += Ai
                Bsum += Bi
                Gsum -= Ai @ hr
                Hsum -= Bi @ hr
                e = _cross(u, pb) + _cross(u, dr) + ddr
                ai = Ai @ e
                asum += ai
                bsum += _cross(r, ai)
                if aug:
                    P = -hp2 / nb**3  # (I - h h^T) / |pb|
                    geo[t.idx] = (r, P, e, nb)
                    if t.mu > 0:
                        # friction load tau' h = -mu sigma kappa tau h per unit kappa, and its moment
                        ch = -t.mu * t.sigma * tau * (pb / nb)
                        C = np.concatenate([ch, _cross(r, ch)])
                        W = np.hstack([P, -P @ hr])  # w = R^T t' = P (e + v' + u' x r)
                        fr.append((t.idx, C, P @ e, W))
            M = np.empty((6, 6))
            M[:3, :3] = Kse + Asum
            M[:3, 3:] = Gsum
            M[3:, :3] = Bsum
            M[3:, 3:] = Kbt + Hsum
            nv = Kse @ (v - self.vstar)
            rhs6 = np.concatenate([
                -_cross(u, nv) - R.T @ self.fe_s - asum,
                -_cross(u, Kbt @ (u - self.ustar)) - _cross(v, nv) - bsum,
            ])
            if self.sections:  # d/ds of Kse (v - v*) and Kbt (u - u*): the stiffness' slope
                rhs6 -= np.concatenate([self.dKse @ (v - self.vstar), self.dKbt @ (u - self.ustar)])
            if fr:
                x, kf, cf = self._friction_solve(M, rhs6, [(C, g, W) for _, C, g, W in fr])
                for (i, _, _, _), kk in zip(fr, kf):
                    kappa[i] = kk
            else:
                x = np.linalg.solve(M, rhs6)
            dv, du = x[:3], x[3:]
            ft = R @ (asum + Asum @ dv + Gsum @ du)
            lt = R @ (bsum + Bsum @ dv + Hsum @ du)
            if fr:
                ft = ft + R @ cf[:3]
                lt = lt + R @ cf[3:]
            dn = -(self.fe_s + ft)
            dm = -_cross(dp, n) - lt
        else:
            dn = -self.fe_s
            dm = -_cross(dp, n)
            if aug and tendons:
                # point model: the rod's own v', u' (no tendon terms) set the tendon turning
                nv = Kse @ (v - self.vstar)
                c, d = -_cross(u, nv) - R.T @ self.fe_s, -_cross(u, Kbt @ (u - self.ustar)) - _cross(v, nv)
                if self.sections:
                    c, d = c - self.dKse @ (v - self.vstar), d - self.dKbt @ (u - self.ustar)
                dv, du = self.Kse_inv @ c, self.Kbt_inv @ d
                for t in tendons:
                    r, dr, ddr = t.routing(s)
                    pb = _cross(u, r) + dr + v
                    nb = np.sqrt(pb @ pb)
                    P = ((pb @ pb) * _I3 - np.outer(pb, pb)) / nb**3
                    geo[t.idx] = (r, P, _cross(u, pb) + _cross(u, dr) + ddr, nb)
        out = np.concatenate([dp, dR.reshape(9), dn, dm])
        if not aug:
            return out
        ext = np.zeros(4 * self.T)
        T = self.T
        for t in tendons:
            i = t.idx
            r, P, e, nb = geo[i]
            k = kappa[i] if i in kappa else np.linalg.norm(P @ (e + dv + _cross(du, r)))
            tau = y[18 + i]
            ext[i] = -t.mu * t.sigma * k * tau
            ext[T + i] = k
            ext[2 * T + i] = nb
            ext[3 * T + i] = nb / (1.0 + t.c * tau)
        return np.concatenate([out, ext])

    def termination_load(self, t, y):
        """(F_i, L_i) of tendon t ending at s = t.l, from the state y just before l_i."""
        self._at(t.l)
        R = y[3:12].reshape(3, 3)
        v, u = self.strains(R, y[12:15], y[15:18])
        r, dr, _ = t.routing(t.l)
        pb = _cross(u, r) + dr + v
        F = -self.tension(t, y) * (R @ pb) / np.sqrt(pb @ pb)
        Lm = _cross(R @ r, F)
        return F, Lm

    def tangents(self, s, y, tendons):
        """World-frame unit tangents R pb/|pb| of `tendons` at s for state y (stiffness: section self.sec)."""
        self._at(s)
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
        cont = self.active[k + 1] if k + 1 < len(self.breakpoints) else []
        if self.augmented and cont:
            return self._apply_kinks_augmented(b, y_minus, y, cont)
        if self.kink_loads and self.model == "coupled" and cont:
            # tendons that continue through b kink where the strains jump; the kink applies
            # tau_j (t_j+ - t_j-) (and its moment) to the backbone. The post-jump state is
            # implicit in t_j+; fixed-point iteration (contraction ~ tau / stiffness).
            # With sections the strains after b follow the next section's stiffness.
            tm = self.tangents(b, y_minus, cont)
            if self.sections:
                self.sec = self._section_of(0.5 * (b + self.breakpoints[k + 1]))
                self._at(b)
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

    def _apply_kinks_augmented(self, b, y_minus, y, cont):
        """Kinks of the continuing tendons `cont` at b with tendon states: kink force
        tau+ t+ - tau- t- (coupled, kink_loads), tension jump tau+ = tau- exp(-mu sigma angle)
        (kink_loads), turning += angle (always: Theta is the geometric turning)."""
        tm = self.tangents(b, y_minus, cont)
        if self.sections:  # the strains after b: the next section's stiffness
            self.sec = self._section_of(0.5 * (b + self.breakpoints[self.breakpoints.index(b) + 1]))
            self._at(b)
        tau_m = [y_minus[18 + t.idx] for t in cont]
        y_expl = y.copy()
        push = self.kink_loads and self.model == "coupled"
        forces = [np.zeros(3) for _ in cont]
        for _ in range(100):
            tp = self.tangents(b, y, cont)
            y_new = y_expl.copy()
            for j, (t, (rw, t_m), (_, t_p), tau) in enumerate(zip(cont, tm, tp, tau_m)):
                tau_p = tau * np.exp(-t.mu * t.sigma * _angle(t_m, t_p)) if self.kink_loads else tau
                y_new[18 + t.idx] = tau_p
                if push:
                    P = tau * (t_p - t_m) + (tau_p - tau) * t_p
                    forces[j] = P
                    y_new[12:15] -= P
                    y_new[15:18] -= _cross(rw, P)
            delta = np.max(np.abs(y_new[12:18] - y[12:18]))
            y = y_new
            if not push or delta <= 1e-15 * (1.0 + np.max(np.abs(y[12:18]))):
                break
        else:
            raise RuntimeError("kink jump iteration did not converge")
        tp = self.tangents(b, y, cont)
        for t, (rw, t_m), (_, t_p), tau, P in zip(cont, tm, tp, tau_m, forces):
            ang = _angle(t_m, t_p)
            y[18 + self.T + t.idx] += ang
            self.kinks.append(dict(s=b, tendon=t.idx, angle=ang, t_minus=t_m, t_plus=t_p,
                                   tension_minus=float(tau), tension_plus=float(y[18 + t.idx]),
                                   point=y[0:3] + rw, force=P.copy()))
        return y

    def y0(self, n0, m0, tau0=None):
        base = np.concatenate([np.zeros(3), _I3.reshape(9), n0, m0])
        if not self.augmented:
            return base
        ext = np.zeros(4 * self.T)
        for t in self.tendons:
            ext[t.idx] = t.tau if t.control == "tension" else 0.0
        for j, t in enumerate(self.free):
            ext[t.idx] = float(tau0[j]) if tau0 is not None else t.tau
        return np.concatenate([base, ext])

    # ---- integration --------------------------------------------------------------------
    def integrate(self, n0, m0, method, rtol, atol, s_stops=None, first_step=None, tau0=None):
        """Integrate base -> tip; returns state at L+ (after jumps) and, if s_stops is
        given, positions at those arc lengths (integration stops exactly there; the full
        states there, left limits at breakpoints, go to self.stop_states).
        tau0: base tensions of the free (length-controlled, taut) tendons."""
        y = self.y0(np.asarray(n0, float), np.asarray(m0, float), tau0)
        s0 = 0.0
        pos = {}
        states = {0.0: y.copy()}
        self.kinks = []
        stops = np.unique(np.asarray(s_stops, float)) if s_stops is not None else np.zeros(0)
        for k, b in enumerate(self.breakpoints):
            act = self.active[k]
            fun = lambda s, yy, act=act: self.rhs(s, yy, act)  # noqa: E731
            inner = stops[(stops > s0) & (stops < b)]
            if self.sections:
                self.sec = self._section_of(0.5 * (s0 + b))
            for e in list(inner) + [b]:
                if e > s0:
                    sol = solve_ivp(fun, (s0, e), y, method=method, rtol=rtol, atol=atol,
                                    first_step=first_step)
                    if sol.status != 0:
                        raise RuntimeError(f"solve_ivp failed: {sol.message}")
                    y = sol.y[:, -1].copy()
                    s0 = e
                pos[e] = y[0:3].copy()
                states[e] = y.copy()
            y = self.apply_jumps(k, y)
        if s_stops is not None:
            pos[0.0] = np.zeros(3)
            s_list = [float(s) for s in np.asarray(s_stops, float)]
            self.stop_states = {s: states[s] for s in s_list}
            positions = np.array([pos[s] for s in s_list])
            return y, positions
        return y

    def residual(self, n0, m0, **kw):
        yL = self.integrate(n0, m0, **kw)
        return np.concatenate([yL[12:15] - self.tip_force, yL[15:18] - self.tip_moment]), yL

    def residual_x(self, x, **kw):
        """Residual for the unknowns x = [n0, m0, tau0 of the free tendons]: tip balance and
        ell0_i - (ell0_ref,i - q_i) [m] per free tendon."""
        if not self.free:
            return self.residual(x[:3], x[3:6], **kw)
        yL = self.integrate(x[:3], x[3:6], tau0=x[6:], **kw)
        lres = [yL[self.i_len0(t.idx)] - self.target[t.idx] for t in self.free]
        return np.concatenate([yL[12:15] - self.tip_force, yL[15:18] - self.tip_moment, lres]), yL

    def x_scale(self, Fc, Mc):
        return np.array([Fc] * 3 + [Mc] * 3 + [Fc] * len(self.free))

    def res_scale(self, Fc, Mc):
        return np.array([Fc] * 3 + [Mc] * 3 + [Fc * self.length_rate(t) for t in self.free])

    # solver settings: with free tendons the length residuals, scaled by Fc * d ell0/d tau, have
    # a rounding floor of about eps * l / (Fc * kl) (~1e-13 on a 0.5 m rod), so stop there
    def fd_step(self):
        return 1e-6 if self.free else 1e-7

    def xtol(self):
        return 1e-12 if self.free else 1e-14

    def res_floor(self):
        if not self.free:
            return 1e-14 if self.augmented else 1e-13
        Fc, _ = self.scales()
        return max(1e-13, max(8 * _EPS * t.l / (Fc * self.length_rate(t)) for t in self.free))

    def x_guess(self):
        n0, m0 = self.straight_guess()
        return np.concatenate([n0, m0, [t.tau for t in self.free]])

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


def _newton(F, J, z0, floor, max_iter=40):
    """Damped Newton on F(z) = 0 with the Jacobian reused while it converges fast.
    Returns (z, f) at the last accepted iterate."""
    z = np.array(z0, float)
    f = F(z)
    nf = float(np.linalg.norm(f))
    if nf < floor:
        return z, f
    Jm, f = J(z)
    fresh = True
    for _ in range(max_iter):
        if nf < floor:
            break
        dz = np.linalg.solve(Jm, -f)
        alpha, ok = 1.0, False
        while alpha >= 1.0 / 64:
            z_new = z + alpha * dz
            f_new = F(z_new)
            nn = float(np.linalg.norm(f_new))
            if np.isfinite(nn) and nn < (1.0 - 1e-4 * alpha) * nf:
                ok = True
                break
            alpha *= 0.5
        if not ok:
            if fresh or nf < 1e-11:  # no descent with a fresh Jacobian, or at the rounding floor
                break
            Jm, f = J(z)
            fresh = True
            continue
        slow = nn > 0.1 * nf
        z, f, nf = z_new, f_new, nn
        fresh = False
        if slow and nf > 1e-11:
            Jm, f = J(z)
            fresh = True
    return z, f


def _scaled_shoot(mdl: _Model, x_guess, ivp_kw, Fc, Mc, root_method):
    """Solve the shooting problem in scaled unknowns; returns (x, scaled residual norm, ok).
    Unknowns [n0, m0] (+ base tensions of free length-controlled tendons)."""
    sx = mdl.x_scale(Fc, Mc)
    sr = mdl.res_scale(Fc, Mc)
    nx = len(sx)

    def F(z):
        x = z * sx
        res, _ = mdl.residual_x(x, **ivp_kw)
        return res / sr

    def J(z):
        f0 = F(z)
        h = mdl.fd_step()
        Jm = np.empty((nx, nx))
        for j in range(nx):
            zp = z.copy()
            zp[j] += h
            zm = z.copy()
            zm[j] -= h
            Jm[:, j] = (F(zp) - F(zm)) / (2 * h)
        return Jm, f0

    z0 = np.asarray(x_guess, float) / sx

    def fun(z):
        return F(z)

    def jac(z):
        Jm, _ = J(z)
        return Jm

    if mdl.augmented and root_method == "hybr":
        # tendon states: damped Newton with Jacobian reuse first (hybr spends a Jacobian on its
        # shape check and more at the rounding floor of the length residuals); hybr if it stalls
        try:
            z, f = _newton(F, J, z0, mdl.res_floor())
            rn = float(np.linalg.norm(f))
            if np.isfinite(rn) and rn < 1e-10:
                return z * sx, rn, True
        except (RuntimeError, np.linalg.LinAlgError, FloatingPointError, ValueError):
            pass

    try:
        if root_method == "hybr":
            sol = root(fun, z0, jac=jac, method="hybr", options={"xtol": mdl.xtol()})
        else:
            sol = root(fun, z0, jac=jac, method=root_method, tol=1e-14)
        z = sol.x
        f = F(z)
        # Newton polish (cheap, guards against hybr stopping at a slightly larger residual)
        for _ in range(4):
            if np.linalg.norm(f) < mdl.res_floor():
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
    return z * sx, rn, bool(np.isfinite(rn) and rn < 1e-10)


def _follow(make_model, xc, ivp_kw, Fc, Mc, root_method, what):
    """Continuation in a factor lam from 0 to 1: ``make_model(lam)`` is the problem at lam, each
    step solved from the last (adaptive steps). Returns (x at lam = 1, nfev)."""
    lam, dlam, nfev = 0.0, 0.1, 0
    while lam < 1.0:
        lam_try = min(1.0, lam + dlam)
        m_l = make_model(lam_try)
        xs, rns, oks = _scaled_shoot(m_l, xc, ivp_kw, Fc, Mc, root_method)
        nfev += m_l.nfev
        if oks:
            lam, xc = lam_try, xs
            dlam = min(0.25, dlam * 1.5)
        else:
            dlam *= 0.5
            if dlam < 1e-4:
                raise RuntimeError(f"solve_reference: {what} failed at {lam}")
    return xc, nfev


def _solve_tension_controlled(rod, model, kink_loads, x0, ivp_kw, root_method):
    """Direct shooting, then load continuation if it fails. Returns (x, ok, nfev, model)."""
    mdl = _Model(rod, model, kink_loads=kink_loads)
    Fc, Mc = mdl.scales()
    if x0 is None:
        n0g, m0g = mdl.straight_guess()
        x0 = np.concatenate([n0g, m0g])
    nfev = 0
    x, rn, ok = _scaled_shoot(mdl, x0, ivp_kw, Fc, Mc, root_method)
    nfev += mdl.nfev
    if not ok:
        # continuation in the load factor lam: tensions, tip loads, gravity, point forces
        x, n = _follow(lambda lam: _Model(rod, model, scale=lam, kink_loads=kink_loads), np.zeros(6), ivp_kw,
                       Fc, Mc, root_method, "continuation at load factor")
        nfev += n
        ok = True
    return x, ok, nfev, mdl


def _solve_length_controlled(rod, model, kink_loads, guess_x, ivp_kw, root_method, ref, ref_x):
    """Active-set solve of the length-controlled rod. Returns (x, ok, nfev, model, slack set)."""
    probe = _Model(rod, model, kink_loads=kink_loads, ref_lengths=ref)
    disp = [t.idx for t in probe.tendons if t.control == "displacement"]
    slack = set()
    seen = set()
    nfev = 0
    tol_gap = 1e-11 * probe.L
    for _ in range(2 + 2 * len(disp)):
        mdl = _Model(rod, model, kink_loads=kink_loads, ref_lengths=ref, slack=slack)
        Fc, Mc = mdl.scales()
        x0 = mdl.x_guess()
        if guess_x is not None:
            x0[:6] = guess_x
        x, rn, ok = _scaled_shoot(mdl, x0, ivp_kw, Fc, Mc, root_method)
        nfev += mdl.nfev
        if not ok:
            # homotopy from the reference state (blend 0: all tendons at pretension, no friction)
            m_l = _Model(rod, model, kink_loads=kink_loads, ref_lengths=ref, slack=slack, blend=0.0)
            xc = np.concatenate([ref_x, [t.pre for t in m_l.free]])
            xc, _, ok0 = _scaled_shoot(m_l, xc, ivp_kw, Fc, Mc, root_method)
            nfev += m_l.nfev
            if not ok0:
                raise RuntimeError("solve_reference: length-control homotopy failed at its start")
            x, n = _follow(lambda lam: _Model(rod, model, kink_loads=kink_loads, ref_lengths=ref, slack=slack,
                                              blend=lam), xc, ivp_kw, Fc, Mc, root_method,
                           "length-control homotopy")
            nfev += n
            ok = True
        # complementarity: taut tendons need tau0 >= 0, slack ones ell0 <= ell0_ref - q
        neg = {t.idx for t, tau in zip(mdl.free, x[6:]) if tau < 0.0}
        _, yL = mdl.residual_x(x, **ivp_kw)
        nfev += mdl.nfev
        viol = {i for i in slack if yL[mdl.i_len0(i)] - mdl.target[i] > tol_gap}
        if not neg and not viol:
            return x, ok, nfev, mdl, slack
        seen.add(frozenset(slack))
        slack = (slack - viol) | neg
        if frozenset(slack) in seen:
            break
    raise RuntimeError("solve_reference: tendon slack active set did not settle")


def _reference_rod(rod: dict) -> dict:
    """The reference state of length control: every tendon in tension control at its
    pretension, frictionless; same rod and loads."""
    d = dict(rod)
    tendons = []
    for t in rod.get("tendons") or []:
        t2 = {k: v for k, v in t.items() if k not in ("control", "displacement", "reference_length")}
        t2["tension"] = float(t.get("pretension", 0.0) or 0.0)
        t2["friction"] = 0.0
        tendons.append(t2)
    d["tendons"] = tendons
    return d


def reference_lengths(rod: dict, **solver_kw) -> np.ndarray:
    """ell0_ref [m], shape (T,): each tendon's unstretched length int |pb| / (1 + c tau) ds in
    the reference state (all tendons in tension control at their pretension, no friction, same
    rod, loads and model). solver_kw: solve_reference keywords (model, rtol, kink_loads, ...)."""
    solver_kw = {k: v for k, v in solver_kw.items() if k not in ("s_eval", "guess")}
    return solve_reference(_reference_rod(rod), **solver_kw)["tendon_unstretched_length"].copy()


def solve_reference(rod: dict, *, model="coupled", rtol=1e-12, atol=1e-14, method="DOP853",
                    guess=None, s_eval=None, root_method="hybr", kink_loads=True) -> dict:
    """Solve the static BVP by shooting. See the module docstring for conventions.

    kink_loads (coupled model only; default True, the project's model, see README 'Model notes';
    False = the bare jump rule of the module docstring):
    where n, m jump at an interior s (a tendon termination or a point force) while other
    tendons continue, the strains jump and so do the continuing tendons' tangents; with
    kink_loads=True the resulting point load tau_j+ t_j+ - tau_j- t_j- at R r_j is applied too
    (post-jump state solved implicitly), which makes rod + tendons exactly balanced; with
    friction the tension jumps there too (module docstring). In the point model kink_loads
    only switches the friction tension jump (there is no kink force).

    guess: optional (6,) [n0, m0] or dict with keys n0, m0.
    Returns tip_position (3,) [m], tip_rotation (3, 3), n0 (3,) [N], m0 (3,) [N m],
    residual_norm (of [tip force N, tip moment N m, ell0 - (ell0_ref - q) m per taut
    length-controlled tendon]), success, nfev (rhs calls of the solve; nfev_report: of the extra
    tendon-report pass that frictionless tension-controlled rods need),
    and per tendon i (arrays of shape (T,)):
      tendon_tension_base [N]        tau_i(0) (given, or solved under length control)
      tendon_tension_end [N]         tau_i(l_i-), just before the termination
      tendon_turning [rad]           Theta_i = int_0^l_i kappa_i ds + kink angles (geometric)
      tendon_kink_angle [rad]        the kink-angle part of Theta_i
      tendon_length [m]              ell_i = int_0^l_i |pb_i| ds (stretched path length)
      tendon_unstretched_length [m]  ell0_i = int_0^l_i |pb_i| / (1 + c_i tau_i) ds
      tendon_reference_length [m]    ell0_ref,i (NaN unless some tendon is length-controlled)
      tendon_slack (bool)            length-controlled tendon slack (tau = 0)
    kinks: list of dicts {s, tendon, angle, t_minus, t_plus, tension_minus, tension_plus,
    point (3,) world, force (3,) kink force applied to the backbone (zeros if none)}.
    With s_eval (k,): positions (k, 3), rotations (k, 3, 3), tendon_tensions (k, T) [N]
    (NaN where s > l_i); at breakpoints the left limits (s-).
    """
    ivp_kw = dict(method=method, rtol=rtol, atol=atol)
    if guess is None:
        x0 = None
    elif isinstance(guess, dict):
        x0 = np.concatenate([_vec3(guess["n0"]), _vec3(guess["m0"])])
    else:
        x0 = np.asarray(guess, float).reshape(6)

    T = len(rod.get("tendons") or [])
    ref = np.full(T, np.nan)
    has_disp = any((t.get("control", "tension") or "tension") == "displacement"
                   for t in (rod.get("tendons") or []))
    slack = set()
    if not has_disp:
        x, ok, nfev, mdl = _solve_tension_controlled(rod, model, kink_loads, x0, ivp_kw, root_method)
    else:
        ref_x = np.zeros(6)
        if _needs_reference(rod):
            rres = solve_reference(_reference_rod(rod), model=model, rtol=rtol, atol=atol, method=method,
                                   root_method=root_method, kink_loads=kink_loads)
            ref = rres["tendon_unstretched_length"].copy()
            ref_x = np.concatenate([rres["n0"], rres["m0"]])
        for i, t in enumerate(rod["tendons"]):
            if t.get("reference_length", None) is not None:
                ref[i] = float(t["reference_length"])
        x, ok, nfev, mdl, slack = _solve_length_controlled(rod, model, kink_loads, x0, ivp_kw,
                                                           root_method, ref, ref_x)
    mdl.nfev = 0
    res, yL = mdl.residual_x(x, **ivp_kw)
    kinks = mdl.kinks
    nfev += mdl.nfev
    out = dict(
        tip_position=yL[0:3].copy(),
        tip_rotation=yL[3:12].reshape(3, 3).copy(),
        n0=x[:3].copy(),
        m0=x[3:6].copy(),
        residual_norm=float(np.linalg.norm(res)),
        success=bool(ok),
        nfev=int(nfev),
    )
    base = np.array([t.tau if t.control == "tension" else 0.0 for t in mdl.tendons])
    for j, t in enumerate(mdl.free):
        base[t.idx] = x[6 + j]
    if s_eval is not None:
        s_eval = np.asarray(s_eval, float).reshape(-1)
        if np.any(s_eval < 0) or np.any(s_eval > mdl.L * (1 + 1e-12)):
            raise ValueError("s_eval outside [0, L]")
        mdl.nfev = 0
        s_c = np.minimum(s_eval, mdl.L)
        _, positions = mdl.integrate(x[:3], x[3:6], s_stops=s_c, tau0=x[6:], **ivp_kw)
        out["nfev"] += mdl.nfev
        out["positions"] = positions
        st = [mdl.stop_states[float(s)] for s in s_c]
        out["rotations"] = np.array([y[3:12].reshape(3, 3) for y in st])
        tens = np.full((len(s_c), T), np.nan)
        for k, (s, y) in enumerate(zip(s_c, st)):
            for t in mdl.tendons:
                if s <= t.l:
                    tens[k, t.idx] = y[18 + t.idx] if mdl.augmented else t.tau
        out["tendon_tensions"] = tens
    # tendon report (tension-controlled frictionless rods: one extra pass with tendon states)
    if mdl.augmented:
        yA, nrep = yL, 0
    else:
        rep = _Model(rod, model, kink_loads=kink_loads, augmented=True)
        yA = rep.integrate(x[:3], x[3:6], **ivp_kw)
        kinks, nrep = rep.kinks, rep.nfev
    kink_angle = np.zeros(T)
    for kk in kinks:
        kink_angle[kk["tendon"]] += kk["angle"]
    out.update(
        nfev_report=int(nrep),
        tendon_tension_base=base,
        tendon_tension_end=yA[18:18 + T].copy(),
        tendon_turning=yA[18 + T:18 + 2 * T].copy(),
        tendon_kink_angle=kink_angle,
        tendon_length=yA[18 + 2 * T:18 + 3 * T].copy(),
        tendon_unstretched_length=yA[18 + 3 * T:18 + 4 * T].copy(),
        tendon_reference_length=ref,
        tendon_slack=np.array([i in slack for i in range(T)], dtype=bool),
        kinks=kinks,
    )
    return out


def solve_reference_user_style(rod: dict, model="coupled") -> dict:
    """How a typical Python user would do it (for benchmarking): solve_ivp RK45 at rtol=1e-8
    (default atol) inside scipy.optimize.fsolve from the straight-rod guess; piecewise only
    over the breakpoints that correctness needs. Returns tip_position, nfev, n0, m0.
    Tension-controlled, frictionless tendons only."""
    mdl = _Model(rod, model)
    if mdl.augmented:
        raise NotImplementedError("solve_reference_user_style: no friction or length control")
    n0g, m0g = mdl.straight_guess()
    kw = dict(method="RK45", rtol=1e-8, atol=1e-6)

    def F(x):
        res, _ = mdl.residual(x[:3], x[3:], **kw)
        return res

    x = fsolve(F, np.concatenate([n0g, m0g]))
    _, yL = mdl.residual(x[:3], x[3:], **kw)
    return dict(tip_position=yL[0:3].copy(), nfev=int(mdl.nfev), n0=x[:3].copy(), m0=x[3:].copy())
