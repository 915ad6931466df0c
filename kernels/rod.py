"""Warp functions of the Cosserat rod with tendons, statics and BDF-alpha dynamics.

State along s: position p, orientation R (body to world), internal force n and moment m
(world frame); in dynamics also the body-frame velocities q (linear) and w (angular).
``make_rod_funcs(dtype, model, dynamic)`` returns the right-hand side and the point-load
jumps for one precision, one tendon model ("coupled" or "point") and statics or dynamics.
Equations: shared PHYSICS.md ([RW11] statics, [T19] dynamics).

Dynamics keeps a BDF-alpha history per *slot*: every place where the right-hand side is
evaluated (each RK stage of each interval) and both sides of every node (for the jumps).
A slot holds (v, u, q, w, v', u'); ``hist`` is y_h of the step being solved, and the
evaluation at the trial point writes its values to ``ycur`` when asked (``store``).
"""

import functools
from types import SimpleNamespace
from typing import NamedTuple

import warp as wp

from .layout import BBT, BSE, DRAG, FE, KBT, KSE, RHOA, RHOJ, T_A, T_PHASE, T_W, T_X0, T_Y0, USTAR

MODELS = ("coupled", "point")
RODS = ("cosserat", "kirchhoff")


class Features(NamedTuple):
    """Physics a scene contains; a False field compiles its terms out (``ALL``: the general kernel)."""

    gravity: bool = True  # distributed external force rho A g
    point_loads: bool = True  # point forces along the rod
    helix: bool = True  # helical (non-straight) tendon routing
    drag: bool = True  # square-law drag (dynamics)


ALL = Features()
SLOT_V, SLOT_U, SLOT_Q, SLOT_W, SLOT_DV, SLOT_DU = 0, 1, 2, 3, 4, 5
SLOT_WIDTH = 6


@functools.cache
def make_rod_funcs(dtype, model: str, dynamic: bool, rod: str = "cosserat", features: Features = ALL):
    """``rod``: "cosserat" (shear and extension) or "kirchhoff" (inextensible, unshearable:
    v = v*, so v' = 0 and the coupled tendon system shrinks to 3x3 for u')."""
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

    @wp.struct
    class RodArgs:
        """Everything a rod evaluation reads; per-rod arrays lead with 1 (shared) or B."""

        rod: wp.array2d(dtype=dtype)  # (1|B, ROD_WIDTH)
        dyn: wp.array2d(dtype=dtype)  # (1|B, DYN_WIDTH), dynamics only
        tendon: wp.array3d(dtype=dtype)  # (1|B, K, TENDON_WIDTH)
        tau: wp.array2d(dtype=dtype)  # (B, K) tensions [N]
        grid: wp.array2d(dtype=dtype)  # (1|B, N+1) node arc lengths [m]
        term_node: wp.array2d(dtype=int)  # (1|B, K) node where each tendon ends
        pforce: wp.array3d(dtype=dtype)  # (1|B, P, 3) point forces [N]
        pnode: wp.array2d(dtype=int)  # (1|B, P) node of each point force
        n_tendons: int
        n_points: int
        c0: dtype  # BDF-alpha c0 [1/s] (dynamics)
        hist: wp.array3d(dtype=vec3)  # (B, S, SLOT_WIDTH) history y_h per slot (dynamics)
        ycur: wp.array3d(dtype=vec3)  # (B, S, SLOT_WIDTH) values at the trial point (dynamics)

    @wp.func
    def rvec(a: RodArgs, b: int, c: int):
        i = b % a.rod.shape[0]
        return vec3(a.rod[i, c], a.rod[i, c + 1], a.rod[i, c + 2])

    @wp.func
    def dvec(a: RodArgs, b: int, c: int):
        i = b % a.dyn.shape[0]
        return vec3(a.dyn[i, c], a.dyn[i, c + 1], a.dyn[i, c + 2])

    @wp.func
    def tendon_route(a: RodArgs, b: int, k: int, s: dtype):
        """Body-frame routing r(s) of tendon k and its first two arc-length derivatives."""
        it = b % a.tendon.shape[0]
        if wp.static(not features.helix):
            return vec3(a.tendon[it, k, T_X0], a.tendon[it, k, T_Y0], zero), vec3(), vec3()
        ra = a.tendon[it, k, T_A]
        w = a.tendon[it, k, T_W]
        ang = w * s + a.tendon[it, k, T_PHASE]
        c = wp.cos(ang)
        sn = wp.sin(ang)
        r = vec3(a.tendon[it, k, T_X0] + ra * c, a.tendon[it, k, T_Y0] + ra * sn, zero)
        dr = vec3(-ra * w * sn, ra * w * c, zero)
        ddr = vec3(-ra * w * w * c, -ra * w * w * sn, zero)
        return r, dr, ddr

    @wp.func
    def term_node(a: RodArgs, b: int, k: int):
        return a.term_node[b % a.term_node.shape[0], k]

    @wp.func
    def strains(a: RodArgs, b: int, R: mat33, n: vec3, m: vec3, slot: int):
        """v, u (body frame) from the constitutive law; with strain damping in dynamics:
        R^T n = Kse (v - v*) + Bse v_t with v_t = c0 v + v_h (likewise u)."""
        kse = rvec(a, b, KSE)
        kbt = rvec(a, b, KBT)
        rtn = wp.transpose(R) * n
        rtm = wp.transpose(R) * m
        ustar = rvec(a, b, USTAR)
        v = vec3(zero, zero, one)
        if wp.static(dynamic):
            bse = dvec(a, b, BSE)
            bbt = dvec(a, b, BBT)
            if wp.static(not kirchhoff):
                v = wp.cw_div(rtn + kse[2] * vec3(zero, zero, one) - wp.cw_mul(bse, a.hist[b, slot, SLOT_V]),
                              kse + a.c0 * bse)
            u = wp.cw_div(rtm + wp.cw_mul(kbt, ustar) - wp.cw_mul(bbt, a.hist[b, slot, SLOT_U]),
                          kbt + a.c0 * bbt)
            return v, u
        if wp.static(not kirchhoff):
            v = wp.cw_div(rtn, kse) + v
        return v, wp.cw_div(rtm, kbt) + ustar

    @wp.func
    def store_slot(a: RodArgs, b: int, slot: int, v: vec3, u: vec3, q: vec3, w: vec3, dv: vec3, du: vec3):
        a.ycur[b, slot, SLOT_V] = v
        a.ycur[b, slot, SLOT_U] = u
        a.ycur[b, slot, SLOT_Q] = q
        a.ycur[b, slot, SLOT_W] = w
        a.ycur[b, slot, SLOT_DV] = dv
        a.ycur[b, slot, SLOT_DU] = du

    @wp.func
    def rhs(a: RodArgs, b: int, s: dtype, p: vec3, R: mat33, n: vec3, m: vec3, q: vec3, w: vec3,
            step: int, slot: int, store: int):
        """d/ds of (p, R, n, m, q, w) on the interval after node ``step``."""
        Rt = wp.transpose(R)
        rtn = Rt * n  # Kse (v - v*) + Bse v_t
        rtm = Rt * m  # Kbt (u - u*) + Bbt u_t
        v, u = strains(a, b, R, n, m, slot)
        dp = R * v
        dR = R * wp.skew(u)
        dq = vec3()
        dw = vec3()
        lam_n = vec3()  # body-frame distributed load terms, moved to the left
        if wp.static(features.gravity):
            lam_n = -(Rt * rvec(a, b, FE))
        lam_m = vec3()
        if wp.static(dynamic):
            rho_a = a.dyn[b % a.dyn.shape[0], RHOA]
            rho_j = dvec(a, b, RHOJ)
            vt = a.c0 * v + a.hist[b, slot, SLOT_V]
            ut = a.c0 * u + a.hist[b, slot, SLOT_U]
            qt = a.c0 * q + a.hist[b, slot, SLOT_Q]
            wt = a.c0 * w + a.hist[b, slot, SLOT_W]
            dq = vt - wp.cross(u, q) + wp.cross(w, v)
            dw = ut - wp.cross(u, w)
            lam_n = lam_n + rho_a * (wp.cross(w, q) + qt)
            if wp.static(features.drag):
                lam_n = lam_n + wp.cw_mul(dvec(a, b, DRAG), wp.cw_mul(q, vec3(wp.abs(q[0]), wp.abs(q[1]),
                                                                             wp.abs(q[2]))))
            lam_m = wp.cross(w, wp.cw_mul(rho_j, w)) + wp.cw_mul(rho_j, wt)
        dn = R * lam_n
        dm = R * lam_m - wp.cross(dp, n)
        dv = vec3()
        du = vec3()
        if wp.static(coupled):
            As = mat33()
            Bs = mat33()
            Gs = mat33()
            Hs = mat33()
            a_sum = vec3()
            b_sum = vec3()
            for k in range(a.n_tendons):
                t = a.tau[b, k]
                if t > zero and step < term_node(a, b, k):
                    r, dr, ddr = tendon_route(a, b, k, s)
                    pb = wp.cross(u, r) + dr + v
                    npb = wp.length(pb)
                    P = wp.skew(pb)
                    Ai = (-t / (npb * npb * npb)) * (P * P)
                    Rh = wp.skew(r)
                    Bi = Rh * Ai
                    As += Ai
                    Bs += Bi
                    Gs -= Ai * Rh
                    Hs -= Bi * Rh
                    ai = Ai * (wp.cross(u, pb) + wp.cross(u, dr) + ddr)
                    a_sum += ai
                    b_sum += wp.cross(r, ai)
            kse = rvec(a, b, KSE)
            kbt = rvec(a, b, KBT)
            c = lam_n - wp.cross(u, rtn) - a_sum
            d = lam_m - wp.cross(v, rtn) - wp.cross(u, rtm) - b_sum
            if wp.static(dynamic):
                kse = kse + a.c0 * dvec(a, b, BSE)
                kbt = kbt + a.c0 * dvec(a, b, BBT)
                c = c - wp.cw_mul(dvec(a, b, BSE), a.hist[b, slot, SLOT_DV])
                d = d - wp.cw_mul(dvec(a, b, BBT), a.hist[b, slot, SLOT_DU])
            # 6x6 solve [[Kse + c0 Bse + A, G], [B, Kbt + c0 Bbt + H]] [v'; u'] = [c; d]
            # by the Schur complement of the upper-left block.
            if wp.static(kirchhoff):  # v' = 0: the lower block row alone
                du = wp.inverse(wp.diag(kbt) + Hs) * d
            else:
                Pinv = wp.inverse(wp.diag(kse) + As)
                S = wp.diag(kbt) + Hs - Bs * Pinv * Gs
                du = wp.inverse(S) * (d - Bs * (Pinv * c))
                dv = Pinv * (c - Gs * du)
            dn = dn - R * (a_sum + As * dv + Gs * du)
            dm = dm - R * (b_sum + Bs * dv + Hs * du)
        if wp.static(dynamic):
            if store != 0:
                store_slot(a, b, slot, v, u, q, w, dv, du)
        return dp, dR, dn, dm, dq, dw

    @wp.func
    def tendon_tangent(R: mat33, v: vec3, u: vec3, r: vec3, dr: vec3):
        """World-frame unit tangent of a tendon path p + R r."""
        return wp.normalize(R * (wp.cross(u, r) + dr + v))

    @wp.func
    def node_jumps(a: RodArgs, b: int, s: dtype, R: mat33, n: vec3, m: vec3, q: vec3, w: vec3,
                   node: int, slot_pre: int, slot_post: int, store: int):
        """Point loads at ``node``: n(s+) = n(s-) - F, m(s+) = m(s-) - L.

        A tendon ending here pulls with F = -tau t(s-). In the coupled model a jump of n or m
        also kinks the tendons that go on (their tangent t depends on v, u): each pushes on
        the backbone with tau (t(s+) - t(s-)), the delta part of the distributed tendon load.
        It depends on the state after the jump, so it is found by fixed-point iteration
        (contraction ~ tau r^2 / EI, far below 1 for real robots).
        """
        v, u = strains(a, b, R, n, m, slot_pre)
        jump = int(0)
        for k in range(a.n_tendons):
            if term_node(a, b, k) == node:
                r, dr, ddr = tendon_route(a, b, k, s)
                F = -a.tau[b, k] * tendon_tangent(R, v, u, r, dr)
                n = n - F
                m = m - wp.cross(R * r, F)
                jump = 1
        if wp.static(features.point_loads):
            ig = b % a.pnode.shape[0]
            ipf = b % a.pforce.shape[0]
            for j in range(a.n_points):
                if a.pnode[ig, j] == node:
                    n = n - vec3(a.pforce[ipf, j, 0], a.pforce[ipf, j, 1], a.pforce[ipf, j, 2])
                    jump = 1
        if wp.static(coupled):
            if jump != 0:
                n1 = n
                m1 = m
                for _sweep in range(4):
                    v2, u2 = strains(a, b, R, n, m, slot_post)
                    fk = vec3()
                    lk = vec3()
                    for k in range(a.n_tendons):
                        t = a.tau[b, k]
                        if t > zero and term_node(a, b, k) > node:
                            r, dr, ddr = tendon_route(a, b, k, s)
                            F = t * (tendon_tangent(R, v2, u2, r, dr) - tendon_tangent(R, v, u, r, dr))
                            fk += F
                            lk += wp.cross(R * r, F)
                    n = n1 - fk
                    m = m1 - lk
        if wp.static(dynamic):
            if store != 0:
                v3, u3 = strains(a, b, R, n, m, slot_post)
                store_slot(a, b, slot_pre, v, u, q, w, vec3(), vec3())
                store_slot(a, b, slot_post, v3, u3, q, w, vec3(), vec3())
        return n, m

    @wp.func
    def orthonormalize(R: mat33):
        """One Newton-Schulz step towards the nearest rotation: squares the drift."""
        return dtype(1.5) * R - dtype(0.5) * (R * (wp.transpose(R) * R))

    return SimpleNamespace(
        vec3=vec3, mat33=mat33, RodArgs=RodArgs, rvec=rvec, rhs=rhs, node_jumps=node_jumps,
        orthonormalize=orthonormalize,
    )
