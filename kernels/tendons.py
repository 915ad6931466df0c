"""Tendons: their routes, the loads they put on the backbone, their states along s, and the
unknowns and residuals of displacement control.

  tendon_route         body-frame tendon path r(s) and its arc-length derivatives
  tendon_tangent       world-frame unit tangent of a tendon's path
  coupled_tendon_load  the distributed tendon load of the coupled model [RW11], as the blocks of
                       the 6x6 system for (v', u') and the known part of the load
  tendon_end_loads     the pull of the tendons that end at a node
  kink_loads           the push of the tendons that continue past a jump of n or m
  tendon_rates         d/ds of the tendon states E (turning, path and unstretched length) and
                       with friction the friction load sum tau' t
  chord_rates          the same in the disk model (straight chords, lengths added at the disks)
  base_tensions        the tension of every tendon at the motor (s = 0)
  length_residuals     the residual of each displacement-controlled tendon

With tendon states (``tendons`` = K > 0) the state along s gains E = (Theta_k, ell_k - s,
ell0_k - s), k < K: the turning of each tendon's path, its length and its unstretched length,
less the arc length run (tendons that have ended stop accumulating). Loops over the tendons run
to the runtime count md.n_tendons (= K), not to the constant K: Warp unrolls constant-bound
loops, which multiplied the code of every call site.
Sources: [RW11] Rucker & Webster 2011.
"""

import functools
from types import SimpleNamespace

import warp as wp

from .friction import make_tensions
from .layout import (
    FORCE_SCALE,
    LENGTH,
    T_A,
    T_COMPLIANCE,
    T_DX,
    T_DY,
    T_PHASE,
    T_SLACK_SLOPE,
    T_W,
    T_X0,
    T_Y0,
)
from .strains import make_strains
from .structs import make_rows, make_structs, tendon_vectors


@functools.cache
def make_routes(dtype, dynamic: bool, helix: bool, spline: bool):
    """``helix``: routes with a varying offset (helical, converging; else straight and parallel);
    ``spline``: tendons routed through points (cubic segments in Model.route)."""
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)
    zero = dtype(0.0)
    Model = make_structs(dtype, dynamic).Model
    row = make_rows(dtype, dynamic).row

    @wp.func
    def tendon_route(md: Model, b: int, k: int, s: dtype):
        """Body-frame routing r(s) of tendon k and its first two arc-length derivatives."""
        it = row(b, md.tendon)
        if wp.static(not helix):
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
        if wp.static(spline):  # a tendon through points: its cubic segment at s (others add zeros)
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
    def tendon_tangent(R: mat33, v: vec3, u: vec3, r: vec3, dr: vec3):
        """World-frame unit tangent of a tendon path p + R r."""
        return wp.normalize(R * (wp.cross(u, r) + dr + v))

    return SimpleNamespace(tendon_route=tendon_route, tendon_tangent=tendon_tangent)


@functools.cache
def make_planar_crosses(dtype):
    """a x r and r x a for a routing point r = (x, y, 0) in the cross-section, without its zero."""
    vec3 = wp.types.vector(3, dtype)

    @wp.func
    def cross_r(a: vec3, r: vec3):
        return vec3(-a[2] * r[1], a[2] * r[0], a[0] * r[1] - a[1] * r[0])

    @wp.func
    def r_cross(r: vec3, a: vec3):
        return vec3(r[1] * a[2], -r[0] * a[2], r[0] * a[1] - r[1] * a[0])

    return cross_r, r_cross


@functools.cache
def make_coupled_load(dtype, dynamic: bool, tendons: int, friction: bool, helix: bool, spline: bool):
    """The coupled model's distributed tendon load (see ``coupled_tendon_load``)."""
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)
    zero = dtype(0.0)
    kvec = tendon_vectors(dtype, tendons)[0]
    st = make_structs(dtype, dynamic)
    Model, Control = st.Model, st.Control
    term_node = make_rows(dtype, dynamic).term_node
    tendon_route = make_routes(dtype, dynamic, helix, spline).tendon_route
    tension_of = make_tensions(dtype, dynamic, tendons, friction).tension_of

    routed = helix or spline  # else straight tendons: r' = r'' = 0
    cross_r, r_cross = make_planar_crosses(dtype)

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
        ad, ao, hd, ho = vec3(), vec3(), vec3(), vec3()  # sums e pb pb^T, e q q^T: diagonals, (01, 02, 12)
        Bm = mat33()  # sum e q pb^T
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
                if wp.static(routed):
                    pb = cross_r(u, r) + dr + v
                else:
                    pb = cross_r(u, r) + v
                pp = wp.dot(pb, pb)
                e = t / (pp * wp.sqrt(pp))
                w = e * pp
                q = r_cross(r, pb)
                epb = e * pb
                eq = e * q
                ad += wp.cw_mul(epb, pb)
                ao += vec3(epb[0] * pb[1], epb[0] * pb[2], epb[1] * pb[2])
                hd += wp.cw_mul(eq, q)
                ho += vec3(eq[0] * q[1], eq[0] * q[2], eq[1] * q[2])
                Bm += wp.outer(eq, pb)
                W += w
                pulls = 1
                Wr += w * r
                wx = w * r[0]
                wy = w * r[1]
                wxx += wx * r[0]
                wxy += wx * r[1]
                wyy += wy * r[1]
                if wp.static(routed):
                    y = wp.cross(u, pb + dr) + ddr
                else:
                    y = wp.cross(u, pb)
                ai = w * y - wp.dot(pb, y) * epb
                a_sum += ai
                b_sum += r_cross(r, ai)
        As = mat33(W - ad[0], -ao[0], -ao[1], -ao[0], W - ad[1], -ao[2], -ao[1], -ao[2], W - ad[2])
        Bs = wp.skew(Wr) - Bm
        Hs = mat33(wyy - hd[0], -wxy - ho[0], -ho[1], -wxy - ho[0], wxx - hd[1], -ho[2], -ho[1], -ho[2],
                   wxx + wyy - hd[2])
        return As, Bs, Hs, a_sum, b_sum, pulls

    return SimpleNamespace(coupled_tendon_load=coupled_tendon_load)


@functools.cache
def make_node_loads(dtype, dynamic: bool, kirchhoff: bool, tendons: int, friction: bool, helix: bool, spline: bool):
    """The point loads of the tendons at a node: their ends, and their kinks (coupled model)."""
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)
    zero = dtype(0.0)
    kvec, evec = tendon_vectors(dtype, tendons)
    st = make_structs(dtype, dynamic)
    Model, Control, Step = st.Model, st.Control, st.Step
    term_node = make_rows(dtype, dynamic).term_node
    routes = make_routes(dtype, dynamic, helix, spline)
    tendon_route, tendon_tangent = routes.tendon_route, routes.tendon_tangent
    tens = make_tensions(dtype, dynamic, tendons, friction)
    tensions, tension_of = tens.tensions, tens.tension_of
    strains = make_strains(dtype, dynamic, kirchhoff).strains

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
                   u: vec3, kse: vec3, kbt: vec3, node: int, slot_pre: int, slot_post: int, t0: kvec, E: evec,
                   tau: kvec):
        """n, m (and E) after a jump at ``node`` in the coupled model: a jump of n or m kinks
        the tendons that go on (their tangent t depends on v, u), and each pushes on the
        backbone with tau+ t(s+) - tau- t(s-), the delta part of the distributed tendon load
        (with friction the kink angle adds to the turning Theta, and tau+ follows from it). It
        depends on the state after the jump, so it is found by fixed-point iteration from n1, m1
        (the state after the other point loads; contraction ~ tau r^2 / EI, far below 1). kse, kbt:
        the stiffness distal of the node (a section's end: the strains jump with it)."""
        n = n1
        m = m1
        E2 = E
        for _sweep in range(4):
            v2, u2 = strains(md, sp, b, kse, kbt, R, n, m, slot_post)
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

    return SimpleNamespace(tendon_end_loads=tendon_end_loads, kink_loads=kink_loads)


@functools.cache
def make_tendon_rates(dtype, dynamic: bool, tendons: int, friction: bool, helix: bool, spline: bool):
    """d/ds of the tendon states, and the friction load (see ``tendon_rates``)."""
    vec3 = wp.types.vector(3, dtype)
    one = dtype(1.0)
    K = tendons
    kvec, evec = tendon_vectors(dtype, K)
    Model = make_structs(dtype, dynamic).Model
    rows = make_rows(dtype, dynamic)
    row, term_node = rows.row, rows.term_node
    tendon_route = make_routes(dtype, dynamic, helix, spline).tendon_route

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

    return SimpleNamespace(tendon_rates=tendon_rates)


@functools.cache
def make_chord_rates(dtype, tendons: int):
    """``chord_rates``: d/ds of the tendon states in the disk model (kernels/disks.py)."""
    one = dtype(1.0)
    evec = tendon_vectors(dtype, tendons)[1]
    K = tendons  # E's block width: 4 x the tendon count
    Model = make_structs(dtype, False).Model
    term_node = make_rows(dtype, False).term_node

    @wp.func
    def chord_rates(md: Model, b: int, step: int):
        """The lengths less the arc length run lose 1 per unit s (each chord adds its length at
        the disk it ends at)."""
        dE = evec()
        for k in range(md.n_tendons):
            if step < term_node(md, b, k):
                dE[K + k] = -one
                dE[2 * K + k] = -one
        return dE

    return SimpleNamespace(chord_rates=chord_rates)


@functools.cache
def make_displacement(dtype, dynamic: bool, tendons: int, displaced: int, tip: int = 0):
    """Displacement control: the tensions at the motor and the length residuals (``displaced``:
    how many tendons are displacement-controlled, each one more shooting unknown; ``tip``: the
    unknowns of a constrained tip after them)."""
    zero = dtype(0.0)
    K = tendons
    kvec, evec = tendon_vectors(dtype, K)
    uvec = wp.types.vector(6 + displaced + tip, dtype)  # the shooting unknowns
    st = make_structs(dtype, dynamic)
    Model, Control = st.Model, st.Control
    row = make_rows(dtype, dynamic).row

    @wp.func
    def base_tensions(md: Model, ct: Control, b: int, x: uvec):
        """Tension of every tendon at the motor (s = 0): commanded, or under displacement control
        the unknown x[6 + j] (scaled like n(0)) if the tendon is taut, 0 if it is slack (then
        x[6 + j] measures its slack, ``length_residuals``; the host settles which, per rod)."""
        t0 = kvec()
        if wp.static(K > 0):
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
    def length_residuals(md: Model, ct: Control, b: int, x: uvec, E: evec, res: uvec):
        """The residual of each displacement-controlled tendon j (tendon k): (ell0 - avail) / L,
        the unstretched length its path needs minus what the motor gives it (both less the
        tendon's arc length l: E holds ell0 - l, Control.avail holds avail - l), scaled like the rod
        residual (L |r| is a length error [m]). A taut tendon's unknown is its tension; a slack
        one carries none and its residual is minus slope x more, so that -x slope L is its
        slack (the slope of the taut branch at zero tension on a straight rod): a consistent
        solution has x >= 0 taut and x <= 0 slack, and x is continuous where a tendon switches."""
        if wp.static(displaced > 0):
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

    return SimpleNamespace(base_tensions=base_tensions, length_residuals=length_residuals)
