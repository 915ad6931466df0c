"""The Cosserat rod with tendons, statics and BDF-alpha dynamics: the right-hand side between
nodes and the jumps at a node, composed from the physics terms of kernels/strains.py,
tendons.py, friction.py and inertia.py (kernels/__init__.py lists which term lives where).

State along s: position p, orientation R (body to world), internal force n and moment m
(world frame); in dynamics also the body-frame velocities q (linear) and w (angular); with
tendon states the tendon states E (kernels/tendons.py).

  kirchhoff_solve / cosserat_solve  the coupled model's system for (v', u') with the tendon load
  coupled_rates        (v', u') of the coupled model and the tendon load moved into (n', m')
  point_rates          (v', u') of the point model (needed only for the tendon states)
  rhs                  d/ds of the state between nodes
  point_jumps          the jumps of n at a node where point forces act

kernels/nodes.py adds the jumps at the nodes and gathers one variant's functions
(``make_rod_funcs``).
Sources: [RW11] Rucker & Webster 2011 (statics), [T19] Till, Aloi & Rucker 2019 (dynamics).
"""

import functools
from types import SimpleNamespace

import warp as wp

from .backbone import make_backbone
from .friction import make_profiles, make_tensions
from .inertia import make_damping, make_inertia
from .strains import make_strains
from .structs import make_rows, make_structs, tendon_vectors
from .tendons import make_chord_rates, make_coupled_load, make_tendon_rates
from .variants import Features

__all__ = ["FRICTION_PASSES", "make_point_jumps", "make_rhs"]

FRICTION_PASSES = 2  # fixed-point passes of the friction load through the coupled 6x6 solve


@functools.cache
def make_coupled_solves(dtype, dynamic: bool, tendons: int, friction: bool, helix: bool, spline: bool):
    """The coupled model's solve for (v', u') once a tendon pulls. With friction the load sum
    tau' t depends on (v', u') through kappa = |t'|: a fixed point from the frictionless solve,
    contracting by ~ mu tau r^2 / EI; the tendon rates of its last pass (kappa one pass behind:
    ~1e-6 relative) are dE."""
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)
    kvec, evec = tendon_vectors(dtype, tendons)
    Model = make_structs(dtype, dynamic).Model
    tendon_rates = make_tendon_rates(dtype, dynamic, tendons, friction, helix, spline).tendon_rates

    @wp.func
    def kirchhoff_solve(md: Model, b: int, s: dtype, u: vec3, v: vec3, kbt: vec3, Hs: mat33, d: vec3, step: int,
                        tau: kvec, g: kvec, h: kvec):
        """v' = 0: u' from the lower block row (Kbt + H) u' = d. Returns u', the friction force
        on the backbone, dE and whether dE is set (friction)."""
        Sinv = wp.inverse(wp.diag(kbt) + Hs)
        du = Sinv * d
        fb = vec3()
        dE = evec()
        rated = int(0)
        if wp.static(friction):
            for _pass in range(FRICTION_PASSES + 0 * md.n_tendons):
                dE, fb, lb = tendon_rates(md, b, s, u, v, vec3(), du, step, tau, g, h)
                du = Sinv * (d - lb)
            rated = 1
        return du, fb, dE, rated

    @wp.func
    def cosserat_solve(md: Model, b: int, s: dtype, u: vec3, v: vec3, kse: vec3, kbt: vec3, As: mat33, Bs: mat33,
                       Hs: mat33, c: vec3, d: vec3, step: int, tau: kvec, g: kvec, h: kvec):
        """6x6 solve [[Kse + A, B^T], [B, Kbt + H]] [v'; u'] = [c; d] by the Schur complement of
        the upper-left block. Returns v', u', dE and whether dE is set (friction)."""
        Pinv = wp.inverse(wp.diag(kse) + As)
        BP = Bs * Pinv
        Sinv = wp.inverse(wp.diag(kbt) + Hs - BP * wp.transpose(Bs))
        du = Sinv * (d - BP * c)
        dv = Pinv * (c - wp.transpose(Bs) * du)
        dE = evec()
        rated = int(0)
        if wp.static(friction):
            for _pass in range(FRICTION_PASSES + 0 * md.n_tendons):
                dE, fb, lb = tendon_rates(md, b, s, u, v, dv, du, step, tau, g, h)
                du = Sinv * ((d - lb) - BP * (c - fb))
                dv = Pinv * ((c - fb) - wp.transpose(Bs) * du)
            rated = 1
        return dv, du, dE, rated

    return SimpleNamespace(kirchhoff_solve=kirchhoff_solve, cosserat_solve=cosserat_solve)


@functools.cache
def make_strain_rates(dtype, dynamic: bool, kirchhoff: bool, tendons: int, friction: bool, helix: bool,
                      spline: bool, sections: bool = False):
    """(v', u'): the derivative of the constitutive law, in the coupled model with the tendon load
    (``sections``: with the stiffness' slope, docs/physics.md "A backbone that varies along s")."""
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)
    kvec, evec = tendon_vectors(dtype, tendons)
    st = make_structs(dtype, dynamic)
    Model, Control, Step = st.Model, st.Control, st.Step
    coupled_tendon_load = make_coupled_load(dtype, dynamic, tendons, friction, helix, spline).coupled_tendon_load
    solves = make_coupled_solves(dtype, dynamic, tendons, friction, helix, spline)
    kirchhoff_solve, cosserat_solve = solves.kirchhoff_solve, solves.cosserat_solve
    damped_system = make_damping(dtype).damped_system

    @wp.func
    def coupled_rates(md: Model, ct: Control, sp: Step, b: int, s: dtype, R: mat33, rtn: vec3, rtm: vec3, v: vec3,
                      u: vec3, kse: vec3, kbt: vec3, dkse: vec3, dkbt: vec3, lam_n: vec3, lam_m: vec3, dn: vec3,
                      dm: vec3, step: int, slot: int, tau: kvec, g: kvec, h: kvec):
        """The coupled model [RW11]: [[Kse + c0 Bse + A, B^T], [B, Kbt + c0 Bbt + H]] [v'; u'] =
        [c; d]. The tendon load follows from the solve: a + A v' + G u' = a + c - (Kse + c0 Bse) v',
        likewise for the moment; it moves into dn, dm. With sections the stiffness' slope dkse,
        dkbt moves to the right: Kse' (v - v*) = Kse' Kse^-1 R^T n, Kbt' (u - u*) = Kbt' Kbt^-1 R^T m
        (statics). Returns v', u', dn, dm, dE and whether dE is set (friction)."""
        As, Bs, Hs, a_sum, b_sum, pulls = coupled_tendon_load(md, ct, b, s, u, v, step, tau)
        c = lam_n - wp.cross(u, rtn) - a_sum
        d = lam_m - wp.cross(v, rtn) - wp.cross(u, rtm) - b_sum
        if wp.static(sections):
            d = d - wp.cw_mul(dkbt, wp.cw_div(rtm, kbt))
            if wp.static(not kirchhoff):
                c = c - wp.cw_mul(dkse, wp.cw_div(rtn, kse))
        if wp.static(dynamic):
            kse, kbt, c, d = damped_system(md, sp, b, slot, kse, kbt, c, d)
        dv = vec3()
        du = vec3()
        dE = evec()
        rated = int(0)
        if pulls == 0:  # no tendon pulls on this interval: a diagonal system, no tendon load
            du = wp.cw_div(d, kbt)
            if wp.static(not kirchhoff):
                dv = wp.cw_div(c, kse)
        else:
            if wp.static(kirchhoff):
                du, fb, dE, rated = kirchhoff_solve(md, b, s, u, v, kbt, Hs, d, step, tau, g, h)
                dn = dn - R * (a_sum + wp.transpose(Bs) * du + fb)
            else:
                dv, du, dE, rated = cosserat_solve(md, b, s, u, v, kse, kbt, As, Bs, Hs, c, d, step, tau, g, h)
                dn = dn - R * (a_sum + c - wp.cw_mul(kse, dv))
            dm = dm - R * (b_sum + d - wp.cw_mul(kbt, du))
        return dv, du, dn, dm, dE, rated

    @wp.func
    def point_rates(md: Model, b: int, rtn: vec3, rtm: vec3, v: vec3, u: vec3, kse: vec3, kbt: vec3, dkse: vec3,
                    dkbt: vec3, lam_n: vec3, lam_m: vec3):
        """The point model: the rod's own (v', u') (the tendon paths' turning follows from them)."""
        dv = vec3()
        c = lam_n - wp.cross(u, rtn)
        d = lam_m - wp.cross(v, rtn) - wp.cross(u, rtm)
        if wp.static(sections):
            c = c - wp.cw_mul(dkse, wp.cw_div(rtn, kse))
            d = d - wp.cw_mul(dkbt, wp.cw_div(rtm, kbt))
        du = wp.cw_div(d, kbt)
        if wp.static(not kirchhoff):
            dv = wp.cw_div(c, kse)
        return dv, du

    return SimpleNamespace(coupled_rates=coupled_rates, point_rates=point_rates)


@functools.cache
def make_rhs(dtype, model: str, dynamic: bool, rod: str, features: Features):
    """``rhs``: d/ds of (p, R, n, m, q, w, E)."""
    vec3, mat33 = wp.types.vector(3, dtype), wp.types.matrix((3, 3), dtype)
    zero = dtype(0.0)
    K, friction, kirchhoff = features.tendons, features.friction, rod == "kirchhoff"
    route = (features.helix, features.spline)
    kvec, evec = tendon_vectors(dtype, K)
    st = make_structs(dtype, dynamic)
    Model, Control, Step = st.Model, st.Control, st.Step
    row = make_rows(dtype, dynamic).row
    law = make_strains(dtype, dynamic, kirchhoff)
    tensions = make_tensions(dtype, dynamic, K, friction).tensions
    store_profile = make_profiles(dtype, dynamic, K).store_profile
    tendon_rates = make_tendon_rates(dtype, dynamic, K, friction, *route).tendon_rates
    chord_rates = make_chord_rates(dtype, K).chord_rates if model == "disks" else None
    inertia_loads = make_inertia(dtype, features.drag).inertia_loads
    rates = make_strain_rates(dtype, dynamic, kirchhoff, K, friction, *route, features.sections)
    along = make_backbone(dtype, dynamic, features.sections).along

    @wp.func
    def rhs(md: Model, ct: Control, sp: Step, b: int, s: dtype, p: vec3, R: mat33, n: vec3, m: vec3, q: vec3,
            w: vec3, t0: kvec, E: evec, step: int, slot: int, store: int):
        """d/ds of (p, R, n, m, q, w, E) on the interval after node ``step`` (t0: tensions at
        the motor); ``store``: write the slot's values (dynamics history, friction profile)."""
        Rt = wp.transpose(R)
        rtn = Rt * n  # Kse (v - v*) + Bse v_t
        rtm = Rt * m  # Kbt (u - u*) + Bbt u_t
        kse, kbt, dkse, dkbt, fe = along(md, b, s, step)
        v, u = law.body_strains(md, sp, b, kse, kbt, rtn, rtm, slot)
        h_step = zero  # the interval and the curvature set the stick-slip blend (friction only)
        curv = zero
        if wp.static(friction):
            ig = row(b, md.grid)
            h_step = md.grid[ig, step + 1] - md.grid[ig, step]
            curv = wp.length(u)
        tau, g, h = tensions(md, ct, b, t0, E, slot, h_step, curv)
        dp = R * v
        dR = mat33(  # R skew(u): row i is (row i of R) x u, without multiplying skew's zeros
            R[0, 1] * u[2] - R[0, 2] * u[1], R[0, 2] * u[0] - R[0, 0] * u[2], R[0, 0] * u[1] - R[0, 1] * u[0],
            R[1, 1] * u[2] - R[1, 2] * u[1], R[1, 2] * u[0] - R[1, 0] * u[2], R[1, 0] * u[1] - R[1, 1] * u[0],
            R[2, 1] * u[2] - R[2, 2] * u[1], R[2, 2] * u[0] - R[2, 0] * u[2], R[2, 0] * u[1] - R[2, 1] * u[0])
        dq = vec3()
        dw = vec3()
        lam_n = vec3()  # body-frame distributed load terms, moved to the left
        if wp.static(features.gravity):
            lam_n = -(Rt * fe)
        lam_m = vec3()
        if wp.static(dynamic):
            dq, dw, lam_n, lam_m = inertia_loads(md, sp, b, slot, v, u, q, w, lam_n)
        if wp.static(dynamic):
            dn = R * lam_n
            dm = R * lam_m - wp.cross(dp, n)
        else:  # statics: no distributed moment, a force only with gravity
            dn = vec3()
            if wp.static(features.gravity):
                dn = R * lam_n
            dm = -wp.cross(dp, n)
        dv = vec3()
        du = vec3()
        dE = evec()
        rated = int(0)  # dE already from the friction passes
        if wp.static(model == "coupled"):
            dv, du, dn, dm, dE, rated = rates.coupled_rates(md, ct, sp, b, s, R, rtn, rtm, v, u, kse, kbt, dkse, dkbt,
                                                            lam_n, lam_m, dn, dm, step, slot, tau, g, h)
        elif wp.static(friction):
            dv, du = rates.point_rates(md, b, rtn, rtm, v, u, kse, kbt, dkse, dkbt, lam_n, lam_m)
        if wp.static(model == "disks"):
            dE = chord_rates(md, b, step)
        elif wp.static(K > 0):
            if rated == 0:
                dE, fb2, lb2 = tendon_rates(md, b, s, u, v, dv, du, step, tau, g, h)
            if wp.static(friction):
                if store != 0:
                    store_profile(md, sp, b, slot, tau, g, h, dE)
        if wp.static(dynamic):
            if store != 0:
                law.store_slot(sp, b, slot, v, u, q, w, dv, du)
        return dp, dR, dn, dm, dq, dw, dE

    return SimpleNamespace(rhs=rhs)


@functools.cache
def make_point_jumps(dtype, dynamic: bool, point_loads: bool):
    """``point_jumps``: n after the point forces at a node."""
    vec3 = wp.types.vector(3, dtype)
    Model = make_structs(dtype, dynamic).Model
    row = make_rows(dtype, dynamic).row

    @wp.func
    def point_jumps(md: Model, b: int, node: int, n: vec3):
        """n(s+) = n(s-) - F for every point force F at ``node``; returns n and whether any acts."""
        jump = int(0)
        if wp.static(point_loads):
            ig = row(b, md.pnode)
            ipf = row(b, md.pforce)
            for j in range(md.n_points):
                if md.pnode[ig, j] == node:
                    n = n - vec3(md.pforce[ipf, j, 0], md.pforce[ipf, j, 1], md.pforce[ipf, j, 2])
                    jump = 1
        return n, jump

    return SimpleNamespace(point_jumps=point_jumps)
