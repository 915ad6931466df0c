"""Spacer disks: tendons that run straight from hole to hole and load the backbone only at the
disks (the tendon model "disks", statics).

Tendon k passes through a hole at h_jk = p(s_j) + R(s_j) r_k(s_j) in disk j (the base plate is
disk 0, part of the ground) and runs straight to the next, along the chord u_jk = (h_jk -
h_(j-1)k) / |h_jk - h_(j-1)k|. Each disk it passes takes the pull of both chords, the last only
the one it ends in:

    F_jk = tau_k (u_(j+1)k - u_jk)   (passing),      F_jk = -tau_k u_jk   (ending),

at the hole, so n(s_j+) = n(s_j-) - sum F and m(s_j+) = m(s_j-) - sum (h_jk - p) x F. Between
disks the rod carries no tendon load. The load at disk j needs the chord to disk j + 1, which
the state at s_j does not know: ``disk_jumps`` finds it by integrating ahead to the next disk
(with the same steps the shooting then takes) from a guess of the chords, and repeating with
the chords that come out until their pull stops moving. Alone, each repeat shrinks the error by
a factor of order tau (r + spacing) spacing / EI (measured on v4, 22 N through a disk: 0.05;
more near buckling); an Anderson(1) step (the secant through the last two passes, on the disk's
force and moment) speeds that up and keeps it going beyond 1. The guess turns the incoming chord
as the chord before it turned (at the first disk: mirrors it about the hole path's tangent).

Tendon states: ``features.tendons`` is 4 x the tendon count K here, so E has three blocks of
4K. Block 0 holds the hole each tendon last passed (3 per tendon, E[3k + i]), block 1 the path
length less the arc length run (E[4K + k]) and then the current chords (E[5K + 3k + i]), block 2
the unstretched length less the arc length run (E[8K + k]) and the chords before them
(E[9K + 3k + i], for the next guess). The rates of kernels/tendons.py (``chord_rates``) take 1
per unit s off the lengths and the disks add each chord's length as it ends.

  disk_jumps   the tendon loads at a disk and the chords that leave it
"""

import functools
from types import SimpleNamespace

import warp as wp

from .backbone import make_backbone
from .layout import T_COMPLIANCE
from .rod import make_point_jumps
from .stepping import make_interval
from .strains import make_strains
from .structs import make_rows, make_structs, tendon_vectors
from .tendons import make_routes
from .variants import Features

__all__ = ["DISK_SWEEPS", "DISK_TOL", "make_disk_jumps"]

DISK_SWEEPS = 40  # most look-aheads per disk (4-6 on the real robots: a guess 3e-4 off, then 1e-5, 1e-11, ...)
DISK_TOL = 1e-13  # they stop once the disk's force and moment / spacing move by less than this x the tension
# through it (float64; float32: 1e-6). At 1e-11 the residual's noise (~6e-10 m on v4) was above Newton's 1e-10 m
# tolerance: 1538 of v4's 1620 rows converged instead of 1558, and slower


@functools.cache
def _basics(dtype, features: Features) -> SimpleNamespace:
    """Types, structs, and E's holes and chords (``get3``, ``put3``) and a hole's position."""
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)
    kvec, evec = tendon_vectors(dtype, features.tendons)
    st = make_structs(dtype, False)
    Model = st.Model
    rows = make_rows(dtype, False)
    tendon_route = make_routes(dtype, False, features.helix, features.spline).tendon_route

    @wp.func
    def get3(E: evec, at: int):
        return vec3(E[at], E[at + 1], E[at + 2])

    @wp.func
    def put3(E: evec, at: int, a: vec3):
        E[at] = a[0]
        E[at + 1] = a[1]
        E[at + 2] = a[2]
        return E

    @wp.func
    def hole_at(md: Model, b: int, k: int, s: dtype, p: vec3, R: mat33):
        r, _dr, _ddr = tendon_route(md, b, k, s)
        return p + R * r

    return SimpleNamespace(vec3=vec3, mat33=mat33, kvec=kvec, evec=evec, Model=Model, Control=st.Control,
                           Step=st.Step, row=rows.row, term_node=rows.term_node, tendon_route=tendon_route,
                           get3=get3, put3=put3, hole_at=hole_at)


@functools.cache
def _parts(dtype, integrator: str, rod: str, features: Features) -> SimpleNamespace:
    """The steps of ``disk_jumps``: the look-ahead, the chords' pull and the arrival at a disk."""
    one = dtype(1.0)
    KB = features.tendons  # the width of E's blocks: 4 x the tendon count
    K = KB // 4
    v = _basics(dtype, features)
    vec3, mat33, kvec, evec, Model, Control, Step = v.vec3, v.mat33, v.kvec, v.evec, v.Model, v.Control, v.Step
    row, term_node, get3, put3, hole_at = v.row, v.term_node, v.get3, v.put3, v.hole_at
    # the look-ahead steps the rod alone: the same p, R, n, m, without the tendon states
    free = features._replace(tendons=0, displaced=0)
    kfree, efree = tendon_vectors(dtype, 0)
    interval = make_interval(dtype, integrator, "point", False, rod, free).interval
    point_jumps = make_point_jumps(dtype, False, features.point_loads).point_jumps

    @wp.func
    def ahead(md: Model, ct: Control, sp: Step, b: int, node: int, nxt: int, p: vec3, R: mat33, n: vec3, m: vec3):
        """p and R at node ``nxt`` from the state just past ``node`` (point forces on the way)."""
        ig = row(b, md.grid)
        k = node
        while k < nxt:
            s = md.grid[ig, k]
            p, R, n, m, _q, _w, _E = interval(md, ct, sp, b, s, md.grid[ig, k + 1] - s, p, R, n, m, vec3(), vec3(),
                                              kfree(), efree(), k, 0)
            k = k + 1
            if k < nxt:
                n, _j = point_jumps(md, b, k, n)
        return p, R

    @wp.func
    def chord_loads(md: Model, b: int, node: int, p: vec3, t0: kvec, E: evec):
        """The pull of the chords that leave ``node`` (stored in E) on the backbone there."""
        F = vec3()
        L = vec3()
        for k in range(md.n_tendons):
            if term_node(md, b, k) > node:
                f = t0[k] * get3(E, 5 * K + 3 * k)
                F += f
                L += wp.cross(get3(E, 3 * k) - p, f)
        return F, L

    @wp.func
    def arrive(md: Model, b: int, s: dtype, p: vec3, R: mat33, n: vec3, m: vec3, t0: kvec, E: evec, node: int):
        """At a disk: the chords that end here pull it back toward the previous holes (and add
        their lengths); every tendon present records its hole here."""
        it = row(b, md.tendon)
        for k in range(md.n_tendons):
            if term_node(md, b, k) >= node:
                h = hole_at(md, b, k, s, p, R)
                if node > 0:
                    c = h - get3(E, 3 * k)
                    lc = wp.length(c)
                    F = -t0[k] / lc * c
                    n = n - F
                    m = m - wp.cross(h - p, F)
                    E[KB + k] = E[KB + k] + lc
                    E[2 * KB + k] = E[2 * KB + k] + lc / (one + md.tendon[it, k, T_COMPLIANCE] * t0[k])
                E = put3(E, 3 * k, h)
        return n, m, E


    return SimpleNamespace(ahead=ahead, chord_loads=chord_loads, arrive=arrive)


@functools.cache
def _guess(dtype, rod: str, features: Features):
    """``guess``: the first chords out of a disk."""
    zero = dtype(0.0)
    one = dtype(1.0)
    two = dtype(2.0)
    K = features.tendons // 4
    v = _basics(dtype, features)
    vec3, mat33, evec, Model, Step = v.vec3, v.mat33, v.evec, v.Model, v.Step
    term_node, tendon_route, get3, put3 = v.term_node, v.tendon_route, v.get3, v.put3
    law = make_strains(dtype, False, rod == "kirchhoff")
    stiffness = make_backbone(dtype, False, features.sections).stiffness

    @wp.func
    def guess(md: Model, sp: Step, b: int, s: dtype, p: vec3, R: mat33, n: vec3, m: vec3, E: evec, node: int):
        """First chords out of ``node``: the incoming chord turned as the one before it turned
        into it (from the second disk on), else mirrored about the hole path's tangent (at the
        base: the tangent). Keeps the incoming chord for the next disk's guess."""
        kse, kbt = stiffness(md, b, s, 0)
        v, u = law.strains(md, sp, b, kse, kbt, R, n, m, 0)
        for k in range(md.n_tendons):
            if term_node(md, b, k) > node:
                r, dr, _ddr = tendon_route(md, b, k, s)
                t = wp.normalize(R * (wp.cross(u, r) + dr + v))
                if node > 0:
                    a = get3(E, 5 * K + 3 * k)  # the chord into this disk
                    a0 = get3(E, 9 * K + 3 * k)  # the one before it
                    if wp.length_sq(a0) > zero:
                        w = wp.cross(a0, a)
                        c = wp.dot(a0, a)
                        t = c * a + wp.cross(w, a) + wp.dot(w, a) / (one + c) * w
                    else:
                        t = wp.normalize(two * t - a)
                    E = put3(E, 9 * K + 3 * k, a)
                E = put3(E, 5 * K + 3 * k, t)
        return E

    return guess


@functools.cache
def make_disk_jumps(dtype, integrator: str, rod: str, features: Features):
    """``disk_jumps`` of one static variant of the disk model."""
    zero = dtype(0.0)
    tol = dtype(DISK_TOL if dtype == wp.float64 else 1e-6)
    K = features.tendons // 4
    v = _basics(dtype, features)
    vec3, mat33, kvec, evec, Model, Control, Step = v.vec3, v.mat33, v.kvec, v.evec, v.Model, v.Control, v.Step
    row, term_node, get3, put3, hole_at = v.row, v.term_node, v.get3, v.put3, v.hole_at
    pt = _parts(dtype, integrator, rod, features)
    ahead, chord_loads, arrive = pt.ahead, pt.chord_loads, pt.arrive
    guess = _guess(dtype, rod, features)

    @wp.func
    def disk_jumps(md: Model, ct: Control, sp: Step, b: int, s: dtype, p: vec3, R: mat33, n: vec3, m: vec3,
                   t0: kvec, E: evec, node: int):
        """n, m and E past ``node`` if it is a disk (or the base), else as they are."""
        nxt = md.dnext[row(b, md.dnext), node]
        if nxt < 0:
            return n, m, E
        n, m, E2 = arrive(md, b, s, p, R, n, m, t0, E, node)
        if nxt == node:  # the last disk
            return n, m, E2
        E2 = guess(md, sp, b, s, p, R, n, m, E2, node)
        se = md.grid[row(b, md.grid), nxt]
        rho = se - s  # moments per force
        F = vec3()
        L = vec3()
        if node > 0:  # the base plate takes the first chords' pull
            F, L = chord_loads(md, b, node, p, t0, E2)
        size = zero
        for k in range(md.n_tendons):
            if term_node(md, b, k) > node:
                size = size + t0[k]
        gFp = vec3()
        gLp = vec3()
        fFp = vec3()
        fLp = vec3()
        for sweep in range(DISK_SWEEPS):
            pe, Re = ahead(md, ct, sp, b, node, nxt, p, R, n - F, m - L)
            for k in range(md.n_tendons):
                if term_node(md, b, k) > node:
                    c = wp.normalize(hole_at(md, b, k, se, pe, Re) - get3(E2, 3 * k))
                    E2 = put3(E2, 5 * K + 3 * k, c)
            if node == 0:
                break
            gF, gL = chord_loads(md, b, node, p, t0, E2)
            fF = gF - F
            fL = (gL - L) / rho
            if wp.max(wp.length(fF), wp.length(fL)) <= tol * size:
                break
            th = zero  # Anderson(1): the secant step through the last two passes
            if sweep > 0:
                dF = fF - fFp
                dL = fL - fLp
                den = wp.dot(dF, dF) + wp.dot(dL, dL)
                if den > zero:
                    th = (wp.dot(fF, dF) + wp.dot(fL, dL)) / den
            F = gF - th * (gF - gFp)
            L = gL - th * (gL - gLp)
            gFp = gF
            gLp = gL
            fFp = fF
            fLp = fL
        if node > 0:
            F, L = chord_loads(md, b, node, p, t0, E2)
        return n - F, m - L, E2

    return SimpleNamespace(disk_jumps=disk_jumps)
