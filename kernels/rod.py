"""Warp functions of the Cosserat rod with tendons, statics and BDF-alpha dynamics.

State along s: position p, orientation R (body to world), internal force n and moment m
(world frame); in dynamics also the body-frame velocities q (linear) and w (angular).
``make_rod_funcs(dtype, model, dynamic, rod, features)`` returns the physics of one
precision, one tendon model ("coupled" or "point"), statics or dynamics, as named terms:

  strains              v, u from the constitutive law (with strain damping in dynamics)
  tendon_route         body-frame tendon path r(s) and its arc-length derivatives
  coupled_tendon_load  the distributed tendon load of the coupled model, as the blocks of
                       the 6x6 system for (v', u') and the known part of the load
  tendon_end_loads     the pull of the tendons that end at a node
  kink_loads           the push of the tendons that continue past a jump of n or m
  rhs                  d/ds of the state between nodes; node_jumps: the jumps at a node

Sources: [RW11] Rucker & Webster 2011 (statics), [T19] Till, Aloi & Rucker 2019 (dynamics).

Dynamics keeps a BDF-alpha history per *slot*: every place where the right-hand side is
evaluated (each RK stage of each interval) and both sides of every node (for the jumps).
A slot holds (v, u, q, w, v', u'); ``Step.hist`` is y_h of the step being solved, and the
evaluation at the trial point writes its values to ``Step.ycur`` when asked (``store``).
"""

import functools
from types import SimpleNamespace
from typing import NamedTuple

import warp as wp

from .layout import (
    BBT,
    BSE,
    DRAG,
    FE,
    FORCE_SCALE,
    KBT,
    KSE,
    LENGTH,
    RHOA,
    RHOJ,
    T_A,
    T_COMPLIANCE,
    T_DX,
    T_DY,
    T_MU,
    T_PHASE,
    T_SLACK_SLOPE,
    T_W,
    T_X0,
    T_Y0,
    USTAR,
)

MODELS = ("coupled", "point")
RODS = ("cosserat", "kirchhoff")


class Features(NamedTuple):
    """Physics a scene contains; a False field compiles its terms out (``ALL``: the general kernel)."""

    gravity: bool = True  # distributed external force rho A g
    point_loads: bool = True  # point forces along the rod
    helix: bool = True  # routing with a varying offset (helical, converging)
    drag: bool = True  # square-law drag (dynamics)
    kinks: bool = True  # coupled model: the push of tendons kinked at a jump of n or m
    friction: bool = False  # capstan friction: tensions vary along s
    tendons: int = 0  # K > 0: per-tendon states along s (turning, path length, unstretched length)
    displaced: int = 0  # displacement-controlled tendons: one shooting unknown and residual each
    spline: bool = False  # tendons routed through points (cubic segments in Model.route)


ALL = Features()
FRICTION_PASSES = 2  # fixed-point passes of the friction load through the coupled 6x6 solve
SLOT_V, SLOT_U, SLOT_Q, SLOT_W, SLOT_DV, SLOT_DU = 0, 1, 2, 3, 4, 5
SLOT_WIDTH = 6


@functools.cache
def make_structs(dtype, dynamic: bool):
    """The kernel-side Model, Control and Step of one precision (statics or dynamics)."""
    vec3 = wp.types.vector(3, dtype)

    @wp.struct
    class Model:
        """Per-rod parameters, read-only in kernels; arrays lead with 1 (shared) or B."""

        rod: wp.array2d(dtype=dtype)  # (1|B, ROD_WIDTH)
        dyn: wp.array2d(dtype=dtype)  # (1|B, DYN_WIDTH)
        tendon: wp.array3d(dtype=dtype)  # (1|B, K, TENDON_WIDTH)
        grid: wp.array2d(dtype=dtype)  # (1|B, N+1) node arc lengths [m]
        term_node: wp.array2d(dtype=int)  # (1|B, K) node where each tendon ends
        pforce: wp.array3d(dtype=dtype)  # (1|B, P, 3) point forces [N]
        pnode: wp.array2d(dtype=int)  # (1|B, P) node of each point force
        tmode: wp.array2d(dtype=int)  # (1|B, K) shooting unknown 6 + j of a displacement-controlled tendon, or -1
        route: wp.array4d(dtype=dtype)  # (1, K, S, 9) spline segments: s_i, then x and y cubic coefficients
        n_tendons: int
        n_points: int

    @wp.struct
    class Control:
        """What the user commands (tendon states: tensions of displacement-controlled tendons
        are unknowns; with friction, ``tau`` is the tension at the motor, s = 0)."""

        tau: wp.array2d(dtype=dtype)  # (B, K) tensions [N]
        avail: wp.array2d(dtype=dtype)  # (B, K) unstretched length given to a displaced tendon less its arc length [m]
        slip: wp.array2d(dtype=dtype)  # (B, K) slip direction sigma in [-1, 1] (+1: sliding toward the motor)
        stick: int  # 1: stick-slip from the previous tension profile (tau_old), every rod and tendon
        taut: wp.array2d(dtype=int)  # (B, K) displaced tendon: 1 taut (tension unknown), 0 slack (zero tension)
        tau_old: wp.array3d(dtype=dtype)  # (B, S, K) previous tension at every evaluation slot [N]
        dtau_old: wp.array3d(dtype=dtype)  # (B, S, K) its arc-length derivative [N/m]

    @wp.struct
    class Step:
        """The BDF-alpha time step being solved (statics: c0 only, never read)."""

        c0: dtype  # y_t = c0 y + y_h [1/s]
        tprof: wp.array3d(dtype=dtype)  # (B, S, 3K) friction, at every slot of the trial point: tension,
        # tau' and the slip state (+1 toward the motor, -1 away, 0 stuck)
        if dynamic:
            hist: wp.array3d(dtype=vec3)  # (B, S, SLOT_WIDTH) history y_h per slot
            ycur: wp.array3d(dtype=vec3)  # (B, S, SLOT_WIDTH) values at the trial point

    return SimpleNamespace(Model=Model, Control=Control, Step=Step)


@functools.cache
def make_rod_funcs(dtype, model: str, dynamic: bool, rod: str = "cosserat", features: Features = ALL):
    """``rod``: "cosserat" (shear and extension) or "kirchhoff" (inextensible, unshearable:
    v = v*, so v' = 0 and the coupled tendon system shrinks to 3x3 for u').

    With ``features.tendons`` = K > 0 the state along s gains E = (Theta_k, ell_k - s, ell0_k - s),
    k < K: the turning of each tendon's path, its length and its unstretched length, less the arc
    length run (tendons that have ended stop accumulating), and the tension of tendon k at s is
    ``tensions(t0, E)``: t0 the tension at the motor (commanded, or a shooting unknown under
    displacement control), times the capstan factor exp(-sigma mu Theta) (``friction``).
    Loops over the tendons run to the runtime count md.n_tendons (= K), not to the constant K:
    Warp unrolls constant-bound loops, which multiplied the code of every call site."""
    if model not in MODELS:
        raise ValueError(f"model must be one of {MODELS}, got {model!r}")
    if rod not in RODS:
        raise ValueError(f"rod must be one of {RODS}, got {rod!r}")
    kirchhoff = rod == "kirchhoff"
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)
    zero = dtype(0.0)
    one = dtype(1.0)
    coupled = model == "coupled"
    K = features.tendons
    tstate = K > 0
    friction = features.friction
    kvec = wp.types.vector(max(K, 1), dtype)  # per-tendon values (a placeholder without tendon states)
    evec = wp.types.vector(max(3 * K, 1), dtype)  # E = (Theta, ell, ell0)
    uvec = wp.types.vector(6 + features.displaced, dtype)  # the shooting unknowns
    st = make_structs(dtype, dynamic)
    Model, Control, Step = st.Model, st.Control, st.Step

    @wp.func
    def row(b: int, table: wp.array2d(dtype=dtype)):
        """The row of rod b in a table shared by the batch (1 row) or per rod (B rows): a
        compare, not an integer division (which cost ~1/3 of a coupled right-hand side)."""
        return wp.min(b, table.shape[0] - 1)

    @wp.func
    def row(b: int, table: wp.array3d(dtype=dtype)):
        return wp.min(b, table.shape[0] - 1)

    @wp.func
    def row(b: int, table: wp.array2d(dtype=int)):
        return wp.min(b, table.shape[0] - 1)

    @wp.func
    def rvec(md: Model, b: int, c: int):
        i = row(b, md.rod)
        return vec3(md.rod[i, c], md.rod[i, c + 1], md.rod[i, c + 2])

    @wp.func
    def dvec(md: Model, b: int, c: int):
        i = row(b, md.dyn)
        return vec3(md.dyn[i, c], md.dyn[i, c + 1], md.dyn[i, c + 2])

    @wp.func
    def tendon_route(md: Model, b: int, k: int, s: dtype):
        """Body-frame routing r(s) of tendon k and its first two arc-length derivatives."""
        it = row(b, md.tendon)
        if wp.static(not features.helix):
            return vec3(md.tendon[it, k, T_X0], md.tendon[it, k, T_Y0], zero), vec3(), vec3()
        ra = md.tendon[it, k, T_A]
        w = md.tendon[it, k, T_W]
        ang = w * s + md.tendon[it, k, T_PHASE]
        c = wp.cos(ang)
        sn = wp.sin(ang)
        dx = md.tendon[it, k, T_DX]
        dy = md.tendon[it, k, T_DY]
        r = vec3(md.tendon[it, k, T_X0] + dx * s + ra * c, md.tendon[it, k, T_Y0] + dy * s + ra * sn, zero)
        dr = vec3(dx - ra * w * sn, dy + ra * w * c, zero)
        ddr = vec3(-ra * w * w * c, -ra * w * w * sn, zero)
        if wp.static(features.spline):  # a tendon through points: its cubic segment at s (others add zeros)
            seg = int(0)
            for j in range(md.route.shape[2]):
                if s >= md.route[0, k, j, 0]:
                    seg = j
            t = s - md.route[0, k, seg, 0]
            for ax in range(2):
                c0 = 1 + 4 * ax
                a0 = md.route[0, k, seg, c0]
                a1 = md.route[0, k, seg, c0 + 1]
                a2 = md.route[0, k, seg, c0 + 2]
                a3 = md.route[0, k, seg, c0 + 3]
                r[ax] = r[ax] + a0 + t * (a1 + t * (a2 + t * a3))
                dr[ax] = dr[ax] + a1 + t * (dtype(2.0) * a2 + dtype(3.0) * t * a3)
                ddr[ax] = ddr[ax] + dtype(2.0) * a2 + dtype(6.0) * t * a3
        return r, dr, ddr

    @wp.func
    def term_node(md: Model, b: int, k: int):
        return md.term_node[row(b, md.term_node), k]

    @wp.func
    def body_strains(md: Model, sp: Step, b: int, rtn: vec3, rtm: vec3, slot: int):
        """v, u (body frame) from the body-frame internal force R^T n and moment R^T m by the
        constitutive law; with strain damping in dynamics: R^T n = Kse (v - v*) + Bse v_t with
        v_t = c0 v + v_h (likewise u)."""
        kse = rvec(md, b, KSE)
        kbt = rvec(md, b, KBT)
        ustar = rvec(md, b, USTAR)
        v = vec3(zero, zero, one)
        if wp.static(dynamic):
            bse = dvec(md, b, BSE)
            bbt = dvec(md, b, BBT)
            if wp.static(not kirchhoff):
                v = wp.cw_div(rtn + kse[2] * vec3(zero, zero, one) - wp.cw_mul(bse, sp.hist[b, slot, SLOT_V]),
                              kse + sp.c0 * bse)
            u = wp.cw_div(rtm + wp.cw_mul(kbt, ustar) - wp.cw_mul(bbt, sp.hist[b, slot, SLOT_U]),
                          kbt + sp.c0 * bbt)
            return v, u
        if wp.static(not kirchhoff):
            v = wp.cw_div(rtn, kse) + v
        return v, wp.cw_div(rtm, kbt) + ustar

    @wp.func
    def strains(md: Model, sp: Step, b: int, R: mat33, n: vec3, m: vec3, slot: int):
        """v, u from the world-frame n, m (see ``body_strains``)."""
        return body_strains(md, sp, b, wp.transpose(R) * n, wp.transpose(R) * m, slot)

    @wp.func
    def store_slot(sp: Step, b: int, slot: int, v: vec3, u: vec3, q: vec3, w: vec3, dv: vec3, du: vec3):
        if wp.static(dynamic):
            sp.ycur[b, slot, SLOT_V] = v
            sp.ycur[b, slot, SLOT_U] = u
            sp.ycur[b, slot, SLOT_Q] = q
            sp.ycur[b, slot, SLOT_W] = w
            sp.ycur[b, slot, SLOT_DV] = dv
            sp.ycur[b, slot, SLOT_DU] = du

    @wp.func
    def base_tensions(md: Model, ct: Control, b: int, x: uvec):
        """Tension of every tendon at the motor (s = 0): commanded, or under displacement control
        the unknown x[6 + j] (scaled like n(0)) if the tendon is taut, 0 if it is slack (then
        x[6 + j] measures its slack, ``length_residuals``; the host settles which, per rod)."""
        t0 = kvec()
        if wp.static(tstate):
            fs = md.rod[row(b, md.rod), FORCE_SCALE]
            im = row(b, md.tmode)
            for k in range(md.n_tendons):
                j = md.tmode[im, k]
                if j >= 0:
                    t0[k] = wp.where(ct.taut[b, k] != 0, fs * x[6 + j], zero)
                else:
                    t0[k] = ct.tau[b, k]
        return t0

    @wp.func
    def blend(z: dtype, width: dtype):
        """0 for z <= 0, 1 above width, a C1 smoothstep between (a step at 0 when width = 0)."""
        if width <= zero:
            return wp.where(z > zero, one, zero)
        c = wp.clamp(z / width, zero, one)
        return c * c * (dtype(3.0) - dtype(2.0) * c)

    @wp.func
    def tensions(md: Model, ct: Control, b: int, t0: kvec, E: evec, slot: int, h_step: dtype, curv: dtype):
        """Tension of every tendon at the point of state E, and its arc-length derivative as
        tau' = g kappa + h (kappa: the turning rate of the tendon path). Capstan friction: the
        tension at s is t0 exp(-sigma mu Theta(s)); with ``stick`` it is the previous profile
        tau_old clamped to the band t0 exp(-mu Theta) .. t0 exp(+mu Theta) that friction can
        hold (outside it the tendon slips: toward the motor at the lower edge, away at the
        upper one). tau' jumps where the slip front lies; so that the shooting residual stays
        continuous as the front crosses an evaluation point, the derivative (the friction load,
        not the tension) switches from stick to slip over about one interval h_step beyond the
        band's edge: a C1 blend in ln(tau_old / edge) over the width 2 h_step (|tau_old'| /
        tau_old + mu curv), curv: the rod's curvature |u| (h_step = 0: a sharp switch). Inside
        the band the tendon sticks exactly: a quasi-static step starts where the last one left
        its profile, on the band's edge, with a smooth residual."""
        tau = t0
        g = kvec()
        h = kvec()
        if wp.static(friction):
            it = row(b, md.tendon)
            for k in range(md.n_tendons):
                mu = md.tendon[it, k, T_MU]
                th = E[k]
                if ct.stick != 0:
                    lo = t0[k] * wp.exp(-mu * th)
                    hi = t0[k] * wp.exp(mu * th)
                    old = ct.tau_old[b, slot, k]
                    dold = ct.dtau_old[b, slot, k]
                    tau[k] = wp.clamp(old, lo, hi)
                    wu = wp.where(old >= hi, one, zero)
                    wl = wp.where(old <= lo, one, zero)
                    if old > zero and lo > zero:
                        width = dtype(2.0) * h_step * (wp.abs(dold) / old + mu * curv)
                        wu = blend(wp.log(old / hi), width)
                        wl = blend(wp.log(lo / old), width)
                        tot = wu + wl
                        if tot > one:
                            wu = wu / tot
                            wl = wl / tot
                    g[k] = mu * tau[k] * (wu - wl)
                    h[k] = (one - wu - wl) * dold * (tau[k] / wp.max(old, dtype(1e-30)))
                else:
                    sg = ct.slip[b, k]
                    tau[k] = t0[k] * wp.exp(-sg * mu * th)
                    g[k] = -sg * mu * tau[k]
        return tau, g, h

    @wp.func
    def slip_state(md: Model, b: int, k: int, g: dtype, tau: dtype):
        """+1 sliding toward the motor (tau' = -mu kappa tau), -1 away from it, 0 stuck (the
        friction load more than half of the way to the slip branch's)."""
        ratio = g / wp.max(md.tendon[row(b, md.tendon), k, T_MU] * tau, dtype(1e-30))
        if ratio < dtype(-0.5):
            return one
        if ratio > dtype(0.5):
            return -one
        return zero

    @wp.func
    def tension_of(ct: Control, b: int, k: int, tau: kvec):
        if wp.static(tstate):
            return tau[k]
        return ct.tau[b, k]

    @wp.func
    def tendon_rates(md: Model, b: int, s: dtype, u: vec3, v: vec3, dv: vec3, du: vec3, step: int, tau: kvec,
                     g: kvec, h: kvec):
        """Per tendon present on this interval: d/ds of E (turning rate kappa = |t'| of the unit
        tangent t = R pb / |pb|, path rate |pb| - 1, unstretched rate |pb| / (1 + c tau) - 1: E
        holds the lengths less the arc length run, small numbers that float32 keeps to its
        relative precision), and with friction the friction load on the backbone, sum tau' t
        (body frame), with its moment."""
        dE = evec()
        fb = vec3()
        lb = vec3()
        it = row(b, md.tendon)
        for k in range(md.n_tendons):
            if step < term_node(md, b, k):
                r, dr, ddr = tendon_route(md, b, k, s)
                pb = wp.cross(u, r) + dr + v
                npb = wp.length(pb)
                dE[K + k] = npb - one  # lengths less the arc length: no cancellation in float32
                dE[2 * K + k] = npb / (one + md.tendon[it, k, T_COMPLIANCE] * tau[k]) - one
                if wp.static(friction):
                    tb = pb / npb
                    dpb = dv + wp.cross(du, r) + wp.cross(u, dr) + ddr
                    wv = wp.cross(u, tb) + (dpb - wp.dot(tb, dpb) * tb) / npb
                    kap = wp.length(wv)
                    dE[k] = kap
                    F = (g[k] * kap + h[k]) * tb
                    fb += F
                    lb += wp.cross(r, F)
        return dE, fb, lb

    @wp.func
    def coupled_tendon_load(md: Model, ct: Control, b: int, s: dtype, u: vec3, v: vec3, step: int, tau: kvec):
        """The coupled model's distributed tendon load [RW11], f_t = a + A v' + G u' and
        l_t = b + B v' + H u' (body frame), summed over the tendons that pull on this interval.

        Per tendon the path tangent is pb = u x r + r' + v, so d pb = v' + u' x r = J [v'; u']
        with J = [I, hat(r)^T], and with e = tau / |pb|^3 the tendon's block is
        [[A, G], [B, H]]_i = J^T A_i J, A_i = e (|pb|^2 I - pb pb^T) (symmetric, PSD):
          A = sum w I - e pb pb^T,  B = G^T = hat(sum w r) - e q pb^T,
          H = sum w (|r|^2 I - r r^T) - e q q^T,  with w = e |pb|^2 and q = r x pb,
        where r = (x, y, 0) in the cross-section. The known part: a_i = A_i y with
        y = u x (pb + r') + r'', b_i = r x a_i. Returns A, B, H, a, b and whether a tendon
        pulls here.
        """
        Am = mat33()  # sum e pb pb^T
        Bm = mat33()  # sum e q pb^T
        Hm = mat33()  # sum e q q^T
        W = zero
        Wr = vec3()
        wxx = zero
        wxy = zero
        wyy = zero
        a_sum = vec3()
        b_sum = vec3()
        pulls = int(0)
        for k in range(md.n_tendons):
            t = tension_of(ct, b, k, tau)
            if t != zero and step < term_node(md, b, k):  # (a taut displaced tendon's tension may cross 0)
                r, dr, ddr = tendon_route(md, b, k, s)
                pb = wp.cross(u, r) + dr + v
                pp = wp.dot(pb, pb)
                e = t / (pp * wp.sqrt(pp))
                w = e * pp
                q = wp.cross(r, pb)
                epb = e * pb
                eq = e * q
                Am += wp.outer(epb, pb)
                Bm += wp.outer(eq, pb)
                Hm += wp.outer(eq, q)
                W += w
                pulls = 1
                Wr += w * r
                wx = w * r[0]
                wy = w * r[1]
                wxx += wx * r[0]
                wxy += wx * r[1]
                wyy += wy * r[1]
                y = wp.cross(u, pb + dr) + ddr
                ai = w * y - wp.dot(pb, y) * epb
                a_sum += ai
                b_sum += wp.cross(r, ai)
        As = wp.diag(vec3(W, W, W)) - Am
        Bs = wp.skew(Wr) - Bm
        Hs = mat33(wyy, -wxy, zero, -wxy, wxx, zero, zero, zero, wxx + wyy) - Hm
        return As, Bs, Hs, a_sum, b_sum, pulls

    @wp.func
    def rhs(md: Model, ct: Control, sp: Step, b: int, s: dtype, p: vec3, R: mat33, n: vec3, m: vec3, q: vec3,
            w: vec3, t0: kvec, E: evec, step: int, slot: int, store: int):
        """d/ds of (p, R, n, m, q, w, E) on the interval after node ``step`` (t0: tensions at
        the motor)."""
        Rt = wp.transpose(R)
        rtn = Rt * n  # Kse (v - v*) + Bse v_t
        rtm = Rt * m  # Kbt (u - u*) + Bbt u_t
        v, u = body_strains(md, sp, b, rtn, rtm, slot)
        h_step = zero  # the interval and the curvature set the stick-slip blend (friction only)
        curv = zero
        if wp.static(friction):
            ig = row(b, md.grid)
            h_step = md.grid[ig, step + 1] - md.grid[ig, step]
            curv = wp.length(u)
        tau, g, h = tensions(md, ct, b, t0, E, slot, h_step, curv)
        dp = R * v
        dR = R * wp.skew(u)
        dq = vec3()
        dw = vec3()
        lam_n = vec3()  # body-frame distributed load terms, moved to the left
        if wp.static(features.gravity):
            lam_n = -(Rt * rvec(md, b, FE))
        lam_m = vec3()
        if wp.static(dynamic):
            rho_a = md.dyn[row(b, md.dyn), RHOA]
            rho_j = dvec(md, b, RHOJ)
            vt = sp.c0 * v + sp.hist[b, slot, SLOT_V]
            ut = sp.c0 * u + sp.hist[b, slot, SLOT_U]
            qt = sp.c0 * q + sp.hist[b, slot, SLOT_Q]
            wt = sp.c0 * w + sp.hist[b, slot, SLOT_W]
            dq = vt - wp.cross(u, q) + wp.cross(w, v)
            dw = ut - wp.cross(u, w)
            lam_n = lam_n + rho_a * (wp.cross(w, q) + qt)
            if wp.static(features.drag):
                lam_n = lam_n + wp.cw_mul(dvec(md, b, DRAG), wp.cw_mul(q, vec3(wp.abs(q[0]), wp.abs(q[1]),
                                                                              wp.abs(q[2]))))
            lam_m = wp.cross(w, wp.cw_mul(rho_j, w)) + wp.cw_mul(rho_j, wt)
        dn = R * lam_n
        dm = R * lam_m - wp.cross(dp, n)
        dv = vec3()
        du = vec3()
        dE = evec()
        rated = int(0)  # dE already from the friction passes
        if wp.static(coupled):
            As, Bs, Hs, a_sum, b_sum, pulls = coupled_tendon_load(md, ct, b, s, u, v, step, tau)
            kse = rvec(md, b, KSE)
            kbt = rvec(md, b, KBT)
            c = lam_n - wp.cross(u, rtn) - a_sum
            d = lam_m - wp.cross(v, rtn) - wp.cross(u, rtm) - b_sum
            if wp.static(dynamic):
                kse = kse + sp.c0 * dvec(md, b, BSE)
                kbt = kbt + sp.c0 * dvec(md, b, BBT)
                c = c - wp.cw_mul(dvec(md, b, BSE), sp.hist[b, slot, SLOT_DV])
                d = d - wp.cw_mul(dvec(md, b, BBT), sp.hist[b, slot, SLOT_DU])
            # 6x6 solve [[Kse + c0 Bse + A, B^T], [B, Kbt + c0 Bbt + H]] [v'; u'] = [c; d]
            # by the Schur complement of the upper-left block. The tendon load follows from the
            # solve: a + A v' + G u' = a + c - (Kse + c0 Bse) v', likewise for the moment.
            if pulls == 0:  # no tendon pulls on this interval: a diagonal system, no tendon load
                du = wp.cw_div(d, kbt)
                if wp.static(not kirchhoff):
                    dv = wp.cw_div(c, kse)
            else:
                # With friction the load sum tau' t depends on (v', u') through kappa = |t'|: a
                # fixed point from the frictionless solve, contracting by ~ mu tau r^2 / EI; the
                # tendon rates of its last pass (kappa one pass behind: ~1e-6 relative) are dE.
                if wp.static(kirchhoff):  # v' = 0: the lower block row alone
                    Sinv = wp.inverse(wp.diag(kbt) + Hs)
                    du = Sinv * d
                    fb = vec3()
                    if wp.static(friction):
                        for _pass in range(FRICTION_PASSES + 0 * md.n_tendons):
                            dE, fb, lb = tendon_rates(md, b, s, u, v, dv, du, step, tau, g, h)
                            du = Sinv * (d - lb)
                        rated = 1
                    dn = dn - R * (a_sum + wp.transpose(Bs) * du + fb)
                else:
                    Pinv = wp.inverse(wp.diag(kse) + As)
                    BP = Bs * Pinv
                    Sinv = wp.inverse(wp.diag(kbt) + Hs - BP * wp.transpose(Bs))
                    du = Sinv * (d - BP * c)
                    dv = Pinv * (c - wp.transpose(Bs) * du)
                    if wp.static(friction):
                        for _pass in range(FRICTION_PASSES + 0 * md.n_tendons):
                            dE, fb, lb = tendon_rates(md, b, s, u, v, dv, du, step, tau, g, h)
                            du = Sinv * ((d - lb) - BP * (c - fb))
                            dv = Pinv * ((c - fb) - wp.transpose(Bs) * du)
                        rated = 1
                    dn = dn - R * (a_sum + c - wp.cw_mul(kse, dv))
                dm = dm - R * (b_sum + d - wp.cw_mul(kbt, du))
        elif wp.static(friction):  # point model: the rod's own strain rates give the tendon paths' turning
            kse = rvec(md, b, KSE)
            kbt = rvec(md, b, KBT)
            du = wp.cw_div(lam_m - wp.cross(v, rtn) - wp.cross(u, rtm), kbt)
            if wp.static(not kirchhoff):
                dv = wp.cw_div(lam_n - wp.cross(u, rtn), kse)
        if wp.static(tstate):
            if rated == 0:
                dE, fb2, lb2 = tendon_rates(md, b, s, u, v, dv, du, step, tau, g, h)
            if wp.static(friction):
                if store != 0:
                    for k in range(md.n_tendons):
                        sp.tprof[b, slot, k] = tau[k]
                        sp.tprof[b, slot, K + k] = g[k] * dE[k] + h[k]
                        sp.tprof[b, slot, 2 * K + k] = slip_state(md, b, k, g[k], tau[k])
        if wp.static(dynamic):
            if store != 0:
                store_slot(sp, b, slot, v, u, q, w, dv, du)
        return dp, dR, dn, dm, dq, dw, dE

    @wp.func
    def tendon_tangent(R: mat33, v: vec3, u: vec3, r: vec3, dr: vec3):
        """World-frame unit tangent of a tendon path p + R r."""
        return wp.normalize(R * (wp.cross(u, r) + dr + v))

    @wp.func
    def tendon_end_loads(md: Model, ct: Control, b: int, s: dtype, R: mat33, n: vec3, m: vec3, v: vec3, u: vec3,
                         node: int, tau: kvec):
        """n, m after the tendons ending at ``node``: each pulls with F = -tau t(s-).
        Returns n, m and whether any tendon ends here."""
        jump = int(0)
        for k in range(md.n_tendons):
            if term_node(md, b, k) == node:
                r, dr, ddr = tendon_route(md, b, k, s)
                F = -tension_of(ct, b, k, tau) * tendon_tangent(R, v, u, r, dr)
                n = n - F
                m = m - wp.cross(R * r, F)
                jump = 1
        return n, m, jump

    @wp.func
    def kink_loads(md: Model, ct: Control, sp: Step, b: int, s: dtype, R: mat33, n1: vec3, m1: vec3, v: vec3,
                   u: vec3, node: int, slot_pre: int, slot_post: int, t0: kvec, E: evec, tau: kvec):
        """n, m (and E) after a jump at ``node`` in the coupled model: a jump of n or m kinks
        the tendons that go on (their tangent t depends on v, u), and each pushes on the
        backbone with tau+ t(s+) - tau- t(s-), the delta part of the distributed tendon load
        (with friction the kink angle adds to the turning Theta, and tau+ follows from it). It
        depends on the state after the jump, so it is found by fixed-point iteration from n1, m1
        (the state after the other point loads; contraction ~ tau r^2 / EI, far below 1)."""
        n = n1
        m = m1
        E2 = E
        for _sweep in range(4):
            v2, u2 = strains(md, sp, b, R, n, m, slot_post)
            tau2 = tau
            if wp.static(friction):
                for k in range(md.n_tendons):
                    if term_node(md, b, k) > node:
                        r, dr, ddr = tendon_route(md, b, k, s)
                        ta = tendon_tangent(R, v, u, r, dr)
                        tb = tendon_tangent(R, v2, u2, r, dr)
                        E2[k] = E[k] + wp.atan2(wp.length(wp.cross(ta, tb)), wp.dot(ta, tb))
                tau2, g2, h2 = tensions(md, ct, b, t0, E2, slot_post, zero, zero)
            fk = vec3()
            lk = vec3()
            for k in range(md.n_tendons):
                t = tension_of(ct, b, k, tau)
                if t != zero and term_node(md, b, k) > node:
                    r, dr, ddr = tendon_route(md, b, k, s)
                    F = vec3()
                    if wp.static(friction):
                        F = tau2[k] * tendon_tangent(R, v2, u2, r, dr) - t * tendon_tangent(R, v, u, r, dr)
                    else:
                        F = t * (tendon_tangent(R, v2, u2, r, dr) - tendon_tangent(R, v, u, r, dr))
                    fk += F
                    lk += wp.cross(R * r, F)
            n = n1 - fk
            m = m1 - lk
        return n, m, E2

    @wp.func
    def node_busy(md: Model, b: int, node: int):
        """1 if a tendon ends or a point force acts at ``node``."""
        busy = int(0)
        for k in range(md.n_tendons):
            if term_node(md, b, k) == node:
                busy = 1
        if wp.static(features.point_loads):
            for j in range(md.n_points):
                if md.pnode[row(b, md.pnode), j] == node:
                    busy = 1
        return busy

    @wp.func
    def node_jumps(md: Model, ct: Control, sp: Step, b: int, s: dtype, R: mat33, n: vec3, m: vec3, q: vec3,
                   w: vec3, t0: kvec, E: evec, node: int, slot_pre: int, slot_post: int, store: int):
        """Point loads at ``node``: n(s+) = n(s-) - F, m(s+) = m(s-) - L (tendon ends, point
        forces, and in the coupled model the kinks of the tendons that continue). A node
        without any of them (most nodes) returns at once, unless dynamics stores its slots.
        Returns n, m and E after the node."""
        busy = node_busy(md, b, node)
        if wp.static(dynamic):
            busy = busy | store
        if busy == 0:
            return n, m, E
        tau, g, h = tensions(md, ct, b, t0, E, slot_pre, zero, zero)
        v, u = strains(md, sp, b, R, n, m, slot_pre)
        n, m, jump = tendon_end_loads(md, ct, b, s, R, n, m, v, u, node, tau)
        if wp.static(features.point_loads):
            ig = row(b, md.pnode)
            ipf = row(b, md.pforce)
            for j in range(md.n_points):
                if md.pnode[ig, j] == node:
                    n = n - vec3(md.pforce[ipf, j, 0], md.pforce[ipf, j, 1], md.pforce[ipf, j, 2])
                    jump = 1
        E2 = E
        if wp.static(coupled and features.kinks):
            if jump != 0:
                n, m, E2 = kink_loads(md, ct, sp, b, s, R, n, m, v, u, node, slot_pre, slot_post, t0, E, tau)
        if wp.static(friction):
            if store != 0:
                tau2, g2, h2 = tensions(md, ct, b, t0, E2, slot_post, zero, zero)
                for k in range(md.n_tendons):
                    sp.tprof[b, slot_pre, k] = tau[k]
                    sp.tprof[b, slot_pre, K + k] = zero
                    sp.tprof[b, slot_pre, 2 * K + k] = slip_state(md, b, k, g[k], tau[k])
                    sp.tprof[b, slot_post, k] = tau2[k]
                    sp.tprof[b, slot_post, K + k] = zero
                    sp.tprof[b, slot_post, 2 * K + k] = slip_state(md, b, k, g2[k], tau2[k])
        if wp.static(dynamic):
            if store != 0:
                v3, u3 = strains(md, sp, b, R, n, m, slot_post)
                store_slot(sp, b, slot_pre, v, u, q, w, vec3(), vec3())
                store_slot(sp, b, slot_post, v3, u3, q, w, vec3(), vec3())
        return n, m, E2

    @wp.func
    def length_residuals(md: Model, ct: Control, b: int, x: uvec, E: evec, res: uvec):
        """The residual of each displacement-controlled tendon j (tendon k): (ell0 - avail) / L,
        the unstretched length its path needs minus what the motor gives it (both less the
        tendon's arc length l: E holds ell0 - l, Control.avail holds avail - l), scaled like the rod
        residual (L |r| is a length error [m]). A taut tendon's unknown is its tension; a slack
        one carries none and its residual is minus slope x more, so that -x slope L is its
        slack (the slope of the taut branch at zero tension on a straight rod): a consistent
        solution has x >= 0 taut and x <= 0 slack, and x is continuous where a tendon switches."""
        if wp.static(features.displaced > 0):
            L = md.rod[row(b, md.rod), LENGTH]
            im = row(b, md.tmode)
            it = row(b, md.tendon)
            for k in range(md.n_tendons):
                j = md.tmode[im, k]
                if j >= 0:
                    z = x[6 + j]
                    res[6 + j] = (E[2 * K + k] - ct.avail[b, k]) / L - wp.where(
                        ct.taut[b, k] != 0, zero, z * md.tendon[it, k, T_SLACK_SLOPE])
        return res

    @wp.func
    def orthonormalize(R: mat33):
        """One Newton-Schulz step towards the nearest rotation: squares the drift."""
        return dtype(1.5) * R - dtype(0.5) * (R * (wp.transpose(R) * R))

    return SimpleNamespace(
        vec3=vec3, mat33=mat33, kvec=kvec, evec=evec, uvec=uvec, Model=Model, Control=Control, Step=Step, row=row,
        rvec=rvec, rhs=rhs, node_jumps=node_jumps, node_busy=node_busy, orthonormalize=orthonormalize,
        base_tensions=base_tensions, tensions=tensions, term_node=term_node, length_residuals=length_residuals,
        tendon_route=tendon_route,
        tstate=tstate, K=K,
    )
