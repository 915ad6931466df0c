"""Warp functions of the static Cosserat rod with tendons (see shared PHYSICS.md).

State along s: position p, orientation R (body to world), internal force n and moment m
(world frame). ``make_rod_funcs(dtype, model)`` returns the right-hand side and the
termination jumps for one precision and one tendon model ("coupled" or "point").
"""

import functools
from types import SimpleNamespace

import warp as wp

from .layout import FE, KBT, KSE, T_A, T_PHASE, T_W, T_X0, T_Y0, USTAR

MODELS = ("coupled", "point")


@functools.cache
def make_rod_funcs(dtype, model: str):
    if model not in MODELS:
        raise ValueError(f"model must be one of {MODELS}, got {model!r}")
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)
    zero = dtype(0.0)
    one = dtype(1.0)
    coupled = model == "coupled"

    @wp.func
    def rod_vec(rod: wp.array2d(dtype=dtype), i: int, c: int):
        return vec3(rod[i, c], rod[i, c + 1], rod[i, c + 2])

    @wp.func
    def tendon_route(tendon: wp.array3d(dtype=dtype), it: int, k: int, s: dtype):
        """Body-frame routing r(s) and its first two arc-length derivatives."""
        a = tendon[it, k, T_A]
        w = tendon[it, k, T_W]
        ang = w * s + tendon[it, k, T_PHASE]
        c = wp.cos(ang)
        sn = wp.sin(ang)
        r = vec3(tendon[it, k, T_X0] + a * c, tendon[it, k, T_Y0] + a * sn, zero)
        dr = vec3(-a * w * sn, a * w * c, zero)
        ddr = vec3(-a * w * w * c, -a * w * w * sn, zero)
        return r, dr, ddr

    @wp.func
    def strains(rod: wp.array2d(dtype=dtype), ir: int, R: mat33, n: vec3, m: vec3):
        """v, u from the linear constitutive law (body frame)."""
        v = wp.cw_div(wp.transpose(R) * n, rod_vec(rod, ir, KSE)) + vec3(zero, zero, one)
        u = wp.cw_div(wp.transpose(R) * m, rod_vec(rod, ir, KBT)) + rod_vec(rod, ir, USTAR)
        return v, u

    @wp.func
    def rhs(
        s: dtype,
        p: vec3,
        R: mat33,
        n: vec3,
        m: vec3,
        rod: wp.array2d(dtype=dtype),
        ir: int,
        tendon: wp.array3d(dtype=dtype),
        it: int,
        tau: wp.array2d(dtype=dtype),
        rod_id: int,
        term_node: wp.array2d(dtype=int),
        ig: int,
        n_tendons: int,
        step: int,
    ):
        """d/ds of (p, R, n, m) on the interval after node ``step``."""
        Rt = wp.transpose(R)
        kse = rod_vec(rod, ir, KSE)
        kbt = rod_vec(rod, ir, KBT)
        fe = rod_vec(rod, ir, FE)
        rtn = Rt * n  # Kse (v - v*)
        rtm = Rt * m  # Kbt (u - u*)
        v = wp.cw_div(rtn, kse) + vec3(zero, zero, one)
        u = wp.cw_div(rtm, kbt) + rod_vec(rod, ir, USTAR)
        dp = R * v
        dR = R * wp.skew(u)
        dn = -fe
        dm = -wp.cross(dp, n)
        if wp.static(coupled):
            As = mat33()
            Bs = mat33()
            Gs = mat33()
            Hs = mat33()
            a_sum = vec3()
            b_sum = vec3()
            for k in range(n_tendons):
                t = tau[rod_id, k]
                if t > zero and step < term_node[ig, k]:
                    r, dr, ddr = tendon_route(tendon, it, k, s)
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
            c = -wp.cross(u, rtn) - Rt * fe - a_sum
            d = -wp.cross(u, rtm) - wp.cross(v, rtn) - b_sum
            # 6x6 solve [[Kse + A, G], [B, Kbt + H]] [v'; u'] = [c; d] by Schur complement.
            Pinv = wp.inverse(wp.diag(kse) + As)
            S = wp.diag(kbt) + Hs - Bs * Pinv * Gs
            du = wp.inverse(S) * (d - Bs * (Pinv * c))
            dv = Pinv * (c - Gs * du)
            dn = dn - R * (a_sum + As * dv + Gs * du)
            dm = dm - R * (b_sum + Bs * dv + Hs * du)
        return dp, dR, dn, dm

    @wp.func
    def tendon_tangent(R: mat33, v: vec3, u: vec3, r: vec3, dr: vec3):
        """World-frame unit tangent of a tendon path p + R r."""
        return wp.normalize(R * (wp.cross(u, r) + dr + v))

    @wp.func
    def node_jumps(
        s: dtype,
        R: mat33,
        n: vec3,
        m: vec3,
        rod: wp.array2d(dtype=dtype),
        ir: int,
        tendon: wp.array3d(dtype=dtype),
        it: int,
        tau: wp.array2d(dtype=dtype),
        rod_id: int,
        term_node: wp.array2d(dtype=int),
        ig: int,
        n_tendons: int,
        pforce: wp.array3d(dtype=dtype),
        ipf: int,
        pnode: wp.array2d(dtype=int),
        n_points: int,
        node: int,
    ):
        """Point loads at ``node``: n(s+) = n(s-) - F, m(s+) = m(s-) - L.

        A tendon ending here pulls with F = -tau t(s-). In the coupled model a jump of n or m
        also kinks the tendons that go on (their tangent t depends on v, u): each pushes on
        the backbone with tau (t(s+) - t(s-)), the delta part of the distributed tendon load.
        It depends on the state after the jump, so it is found by fixed-point iteration
        (contraction ~ tau r^2 / EI, far below 1 for real robots).
        """
        v, u = strains(rod, ir, R, n, m)
        jump = int(0)
        for k in range(n_tendons):
            if term_node[ig, k] == node:
                r, dr, ddr = tendon_route(tendon, it, k, s)
                F = -tau[rod_id, k] * tendon_tangent(R, v, u, r, dr)
                n = n - F
                m = m - wp.cross(R * r, F)
                jump = 1
        for j in range(n_points):
            if pnode[ig, j] == node:
                n = n - vec3(pforce[ipf, j, 0], pforce[ipf, j, 1], pforce[ipf, j, 2])
                jump = 1
        if wp.static(coupled):
            if jump != 0:
                n1 = n
                m1 = m
                for _sweep in range(4):
                    v2, u2 = strains(rod, ir, R, n, m)
                    fk = vec3()
                    lk = vec3()
                    for k in range(n_tendons):
                        t = tau[rod_id, k]
                        if t > zero and term_node[ig, k] > node:
                            r, dr, ddr = tendon_route(tendon, it, k, s)
                            F = t * (tendon_tangent(R, v2, u2, r, dr) - tendon_tangent(R, v, u, r, dr))
                            fk += F
                            lk += wp.cross(R * r, F)
                    n = n1 - fk
                    m = m1 - lk
        return n, m

    @wp.func
    def orthonormalize(R: mat33):
        """One Newton-Schulz step towards the nearest rotation: squares the drift."""
        return dtype(1.5) * R - dtype(0.5) * (R * (wp.transpose(R) * R))

    return SimpleNamespace(
        vec3=vec3, mat33=mat33, rod_vec=rod_vec, rhs=rhs, node_jumps=node_jumps,
        orthonormalize=orthonormalize, strains=strains,
    )
