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
  node_busy            whether anything acts at a node
  span_end             the end of a step over several intervals (to the next busy node)
  node_jumps           the jumps of n, m (and E) at a node: tendon ends, point forces, kinks

``make_rod_funcs(dtype, model, dynamic, rod, features)`` returns them for one precision, one
tendon model ("coupled" or "point"), statics or dynamics, one rod model and feature set.
Sources: [RW11] Rucker & Webster 2011 (statics), [T19] Till, Aloi & Rucker 2019 (dynamics).
"""

import functools
from types import SimpleNamespace

import warp as wp

from .friction import make_profiles, make_tensions
from .inertia import make_damping, make_inertia
from .layout import FE, KBT, KSE
from .strains import make_strains
from .structs import make_rows, make_structs, tendon_vectors
from .tendons import (
    make_coupled_load,
    make_displacement,
    make_node_loads,
    make_tendon_rates,
)
from .variants import ALL, MODELS, RODS, Features

__all__ = ["FRICTION_PASSES", "make_rod_funcs"]

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
                      spline: bool):
    """(v', u'): the derivative of the constitutive law, in the coupled model with the tendon load."""
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)
    kvec, evec = tendon_vectors(dtype, tendons)
    st = make_structs(dtype, dynamic)
    Model, Control, Step = st.Model, st.Control, st.Step
    rvec = make_rows(dtype, dynamic).rvec
    coupled_tendon_load = make_coupled_load(dtype, dynamic, tendons, friction, helix, spline).coupled_tendon_load
    solves = make_coupled_solves(dtype, dynamic, tendons, friction, helix, spline)
    kirchhoff_solve, cosserat_solve = solves.kirchhoff_solve, solves.cosserat_solve
    damped_system = make_damping(dtype).damped_system

    @wp.func
    def coupled_rates(md: Model, ct: Control, sp: Step, b: int, s: dtype, R: mat33, rtn: vec3, rtm: vec3, v: vec3,
                      u: vec3, lam_n: vec3, lam_m: vec3, dn: vec3, dm: vec3, step: int, slot: int, tau: kvec,
                      g: kvec, h: kvec):
        """The coupled model [RW11]: [[Kse + c0 Bse + A, B^T], [B, Kbt + c0 Bbt + H]] [v'; u'] =
        [c; d]. The tendon load follows from the solve: a + A v' + G u' = a + c - (Kse + c0 Bse) v',
        likewise for the moment; it moves into dn, dm. Returns v', u', dn, dm, dE and whether dE is
        set (friction)."""
        As, Bs, Hs, a_sum, b_sum, pulls = coupled_tendon_load(md, ct, b, s, u, v, step, tau)
        kse = rvec(md, b, KSE)
        kbt = rvec(md, b, KBT)
        c = lam_n - wp.cross(u, rtn) - a_sum
        d = lam_m - wp.cross(v, rtn) - wp.cross(u, rtm) - b_sum
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
    def point_rates(md: Model, b: int, rtn: vec3, rtm: vec3, v: vec3, u: vec3, lam_n: vec3, lam_m: vec3):
        """The point model: the rod's own (v', u') (the tendon paths' turning follows from them)."""
        dv = vec3()
        kse = rvec(md, b, KSE)
        kbt = rvec(md, b, KBT)
        du = wp.cw_div(lam_m - wp.cross(v, rtn) - wp.cross(u, rtm), kbt)
        if wp.static(not kirchhoff):
            dv = wp.cw_div(lam_n - wp.cross(u, rtn), kse)
        return dv, du

    return SimpleNamespace(coupled_rates=coupled_rates, point_rates=point_rates)


@functools.cache
def make_rhs(dtype, model: str, dynamic: bool, rod: str, features: Features):
    """``rhs``: d/ds of (p, R, n, m, q, w, E)."""
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)
    zero = dtype(0.0)
    K, friction, kirchhoff = features.tendons, features.friction, rod == "kirchhoff"
    route = (features.helix, features.spline)
    kvec, evec = tendon_vectors(dtype, K)
    st = make_structs(dtype, dynamic)
    Model, Control, Step = st.Model, st.Control, st.Step
    rows = make_rows(dtype, dynamic)
    row, rvec = rows.row, rows.rvec
    law = make_strains(dtype, dynamic, kirchhoff)
    tensions = make_tensions(dtype, dynamic, K, friction).tensions
    store_profile = make_profiles(dtype, dynamic, K).store_profile
    tendon_rates = make_tendon_rates(dtype, dynamic, K, friction, *route).tendon_rates
    inertia_loads = make_inertia(dtype, features.drag).inertia_loads
    rates = make_strain_rates(dtype, dynamic, kirchhoff, K, friction, *route)

    @wp.func
    def rhs(md: Model, ct: Control, sp: Step, b: int, s: dtype, p: vec3, R: mat33, n: vec3, m: vec3, q: vec3,
            w: vec3, t0: kvec, E: evec, step: int, slot: int, store: int):
        """d/ds of (p, R, n, m, q, w, E) on the interval after node ``step`` (t0: tensions at
        the motor); ``store``: write the slot's values (dynamics history, friction profile)."""
        Rt = wp.transpose(R)
        rtn = Rt * n  # Kse (v - v*) + Bse v_t
        rtm = Rt * m  # Kbt (u - u*) + Bbt u_t
        v, u = law.body_strains(md, sp, b, rtn, rtm, slot)
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
            lam_n = -(Rt * rvec(md, b, FE))
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
            dv, du, dn, dm, dE, rated = rates.coupled_rates(md, ct, sp, b, s, R, rtn, rtm, v, u, lam_n, lam_m, dn, dm,
                                                            step, slot, tau, g, h)
        elif wp.static(friction):
            dv, du = rates.point_rates(md, b, rtn, rtm, v, u, lam_n, lam_m)
        if wp.static(K > 0):
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
def make_node_jumps(dtype, model: str, dynamic: bool, rod: str, features: Features):
    """``node_jumps``: n, m (and E) across a node; ``node_busy``: whether anything acts there."""
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)
    zero = dtype(0.0)
    K, friction, kirchhoff = features.tendons, features.friction, rod == "kirchhoff"
    kvec, evec = tendon_vectors(dtype, K)
    st = make_structs(dtype, dynamic)
    Model, Control, Step = st.Model, st.Control, st.Step
    rows = make_rows(dtype, dynamic)
    row, term_node = rows.row, rows.term_node
    law = make_strains(dtype, dynamic, kirchhoff)
    tensions = make_tensions(dtype, dynamic, K, friction).tensions
    store_node_profile = make_profiles(dtype, dynamic, K).store_node_profile
    loads = make_node_loads(dtype, dynamic, kirchhoff, K, friction, features.helix, features.spline)

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
        v, u = law.strains(md, sp, b, R, n, m, slot_pre)
        n, m, jump = loads.tendon_end_loads(md, ct, b, s, R, n, m, v, u, node, tau)
        if wp.static(features.point_loads):
            ig = row(b, md.pnode)
            ipf = row(b, md.pforce)
            for j in range(md.n_points):
                if md.pnode[ig, j] == node:
                    n = n - vec3(md.pforce[ipf, j, 0], md.pforce[ipf, j, 1], md.pforce[ipf, j, 2])
                    jump = 1
        E2 = E
        if wp.static(model == "coupled" and features.kinks):
            if jump != 0:
                n, m, E2 = loads.kink_loads(md, ct, sp, b, s, R, n, m, v, u, node, slot_pre, slot_post, t0, E, tau)
        if wp.static(friction):
            if store != 0:
                tau2, g2, h2 = tensions(md, ct, b, t0, E2, slot_post, zero, zero)
                store_node_profile(md, sp, b, slot_pre, tau, g)
                store_node_profile(md, sp, b, slot_post, tau2, g2)
        if wp.static(dynamic):
            if store != 0:
                v3, u3 = law.strains(md, sp, b, R, n, m, slot_post)
                law.store_slot(sp, b, slot_pre, v, u, q, w, vec3(), vec3())
                law.store_slot(sp, b, slot_post, v3, u3, q, w, vec3(), vec3())
        return n, m, E2

    @wp.func
    def span_end(md: Model, b: int, k: int, stride: int, n_int: int):
        """The node a step from node k ends at: up to ``stride`` intervals on, stopping at the
        first node something acts on (stride <= 1: k + 1)."""
        k1 = k + 1
        while k1 - k < stride and k1 < n_int:  # over nodes where nothing acts
            if node_busy(md, b, k1) != 0:
                break
            k1 = k1 + 1
        return k1

    return SimpleNamespace(node_busy=node_busy, node_jumps=node_jumps, span_end=span_end)


@functools.cache
def make_rod_funcs(dtype, model: str, dynamic: bool, rod: str = "cosserat", features: Features = ALL):
    """The rod's functions for one variant: ``rod`` "cosserat" (shear and extension) or
    "kirchhoff" (inextensible, unshearable: v = v*, so v' = 0 and the coupled tendon system
    shrinks to 3x3 for u'); ``features``: which physics compiles in (``Features``).

    With ``features.tendons`` = K > 0 the tension of tendon k at s is ``tensions(t0, E)``: t0
    the tension at the motor (``base_tensions``: commanded, or a shooting unknown under
    displacement control), times the capstan factor exp(-sigma mu Theta) (``friction``)."""
    if model not in MODELS:
        raise ValueError(f"model must be one of {MODELS}, got {model!r}")
    if rod not in RODS:
        raise ValueError(f"rod must be one of {RODS}, got {rod!r}")
    st = make_structs(dtype, dynamic)
    jumps = make_node_jumps(dtype, model, dynamic, rod, features)
    return SimpleNamespace(
        vec3=wp.types.vector(3, dtype), mat33=wp.types.matrix((3, 3), dtype), Model=st.Model, Control=st.Control,
        Step=st.Step, row=make_rows(dtype, dynamic).row, rhs=make_rhs(dtype, model, dynamic, rod, features).rhs,
        node_jumps=jumps.node_jumps, node_busy=jumps.node_busy, span_end=jumps.span_end,
        base_tensions=make_displacement(dtype, dynamic, features.tendons, features.displaced).base_tensions,
        tstate=features.tendons > 0, K=features.tendons)
