"""Contact of the backbone with rigid obstacles: a penalty force at every node.

The distance from a node's centre-line point p to each obstacle's surface, on the side the rod
may be (outside a plane, sphere or capsule; inside a tube's lumen), less the rod's radius, is
the gap g; the penetration is delta = -g. The obstacle pushes the node along the surface normal
with the point force

    F = k w phi(delta) n,   phi(delta) = 0                           delta <= -eps/2
                                         (delta + eps/2)^2 / (2 eps)  |delta| < eps/2
                                         delta                        delta >= eps/2

k [N/m per m] the penalty stiffness, w the node's share of the rod (half of each interval next
to it), n the unit normal. phi is the linear penalty with its corner rounded over a band of
width eps = E I / (k L^3) centred on the surface, so the force and its derivative are
continuous (Newton needs that) and, beyond a force per length of E I / (2 L^3), the law is
exactly the linear penalty; as k grows, eps and the penetration at a given force shrink as
1 / k. (Within the band a node is pushed while up to eps / 2 off the surface: that too is an
error of the penalty, which the stiffening of tdcr_warp/physics/contact.py bounds.) The force
acts through the centre line (a frictionless surface), so it adds no moment, and being a point
force at a node it keeps global force and moment balance exact.

A lumen (a tube or bent tube) takes phi(delta) - phi(delta_axis), delta_axis = r - R the
penetration on its axis (R its inner radius, r the rod's), and 0 below it: a point on the axis
has no nearest wall (the normal there is an arbitrary side), so a band reaching the axis (a soft
stiffness in a narrow tube) would push a centred rod sideways, discontinuously; less its axis
value the force vanishes there and stays continuous, the lumen's potential radial. Where the band
stays off the axis (eps / 2 < R - r, e.g. at k0 wherever the clearance exceeds 0.01 r) nothing
changes.

In dynamics the force is damped the Hunt-Crossley way: times max(0, 1 + c d delta/dt), c the
obstacle's damping [s/m] and d delta/dt = -n . p_t the rate at which the node presses in (p_t =
R q its velocity). The damping vanishes with the penetration, so the force is continuous at
first touch, and it never pulls the rod back onto the surface.

The force acts at the nodes, but the centre line between them is checked too: each interval is
drawn as the cubic Hermite curve through its end nodes with tangents h R e3 (h its length), cut
into INTERVAL_CHORDS pieces, and each piece's gap is taken at its end and at the point of the
curve where its chord comes nearest a sphere's centre or a capsule's axis (its middle for the
other kinds). Both are points of the curve, so a convex wall is not seen deeper than it is (a
chord of a rod wrapped on a sphere cuts into it by its sagitta), and an obstacle smaller than a
piece is still found where the chord passes it. An obstacle that falls between two nodes, or a
rod pulled through one, is then seen: its interval's gap is negative.

  surface        the distance from p to an obstacle's surface and the normal there
  nearest_on_chord  where a chord of the centre line comes nearest an obstacle's core
  core_distance  how near the straight way between two points passes an obstacle's core
  contact_force  the sum of the obstacles' forces at a node and the smallest gap
  contact kernels the force and gap at every node of solved shapes and the smallest gap along
                 every interval (outputs)
"""

import functools
from types import SimpleNamespace

import warp as wp

from .layout import (
    BENT_TUBE,
    CAPSULE,
    FORCE_SCALE,
    KBT,
    LENGTH,
    OB_A,
    OB_ALONG,
    OB_ANGLE,
    OB_B,
    OB_BEND,
    OB_C,
    OB_DAMP,
    OB_KIND,
    OB_RADIUS,
    OB_REACH,
    OB_STIFF,
    PLANE,
    SPHERE,
    TUBE,
    USTAR,
)
from .structs import make_rows, make_structs

__all__ = ["FAR", "INTERVAL_CHORDS", "make_contact", "make_contact_kernel", "make_interval_kernels"]

FAR = 1.0e30  # the distance reported where an obstacle cannot be touched (beyond a tube's ends)
INTERVAL_CHORDS = 4  # chords per interval of the centre line in the check between nodes


@functools.cache
def make_surface(dtype, dynamic: bool):
    """``surface``: the distance to an obstacle and its normal, for one precision."""
    vec3 = wp.types.vector(3, dtype)
    zero = dtype(0.0)
    far = dtype(FAR)
    two_pi = dtype(6.283185307179586)
    Model = make_structs(dtype, dynamic).Model

    @wp.func
    def column(md: Model, i: int, j: int, c: int):
        return vec3(md.obst[i, j, c], md.obst[i, j, c + 1], md.obst[i, j, c + 2])

    @wp.func
    def away(r: vec3, dist: dtype, fallback: vec3):
        """r / dist, or ``fallback`` where r vanishes (p on an axis or a centre)."""
        if dist > zero:
            return r / dist
        return fallback

    @wp.func
    def surface(md: Model, i: int, j: int, p: vec3):
        """The distance d from p to the surface of obstacle j (row i of the table), positive on
        the rod's side, and the unit normal n pointing to that side (d = FAR: out of reach)."""
        kind = int(md.obst[i, j, OB_KIND])
        a = column(md, i, j, OB_A)
        bv = column(md, i, j, OB_B)
        rad = md.obst[i, j, OB_RADIUS]
        d = far
        nrm = vec3()
        if kind == PLANE:
            d = wp.dot(p - a, bv)
            nrm = bv
        elif kind == SPHERE:
            r = p - a
            lr = wp.length(r)
            d = lr - rad
            nrm = away(r, lr, vec3(zero, zero, dtype(1.0)))
        elif kind == CAPSULE or kind == TUBE:
            ab = bv - a
            t = wp.dot(p - a, ab) / wp.dot(ab, ab)
            if kind == CAPSULE:
                t = wp.clamp(t, zero, dtype(1.0))
            if t >= zero and t <= dtype(1.0):
                r = p - (a + t * ab)
                lr = wp.length(r)
                nrm = away(r, lr, vec3(zero, zero, dtype(1.0)))
                d = lr - rad
                if kind == TUBE:
                    d = rad - lr
                    nrm = -nrm
        elif kind == BENT_TUBE:
            cv = column(md, i, j, OB_C)
            bend = md.obst[i, j, OB_BEND]
            centre = a + bend * cv
            z = wp.cross(bv, cv)
            w = p - centre
            w = w - wp.dot(w, z) * z
            lw = wp.length(w)
            if lw > zero:
                u = w / lw
                theta = wp.atan2(wp.dot(u, bv), -wp.dot(u, cv))
                if theta < zero:
                    theta = theta + two_pi
                if theta <= md.obst[i, j, OB_ANGLE]:
                    r = p - (centre + bend * u)
                    lr = wp.length(r)
                    d = rad - lr
                    nrm = -away(r, lr, u)
        return d, nrm

    return SimpleNamespace(surface=surface, column=column)


@functools.cache
def make_chords(dtype, dynamic: bool):
    """``nearest_on_chord`` and ``core_distance``: a straight piece of the centre line against an
    obstacle's core, for one precision."""
    vec3 = wp.types.vector(3, dtype)
    zero = dtype(0.0)
    far = dtype(FAR)
    Model = make_structs(dtype, dynamic).Model
    column = make_surface(dtype, dynamic).column

    @wp.func
    def point_segment(p: vec3, a: vec3, b: vec3):
        """The parameter t in [0, 1] of the point of the segment a-b nearest p."""
        ab = b - a
        return wp.clamp(wp.dot(p - a, ab) / wp.max(wp.dot(ab, ab), dtype(1e-30)), zero, dtype(1.0))

    @wp.func
    def segment_segment(p1: vec3, q1: vec3, p2: vec3, q2: vec3):
        """The parameters (s, t) in [0, 1] of the nearest points of the segments p1-q1 and p2-q2."""
        d1 = q1 - p1
        d2 = q2 - p2
        r = p1 - p2
        a = wp.dot(d1, d1)
        e = wp.dot(d2, d2)
        f = wp.dot(d2, r)
        s = zero
        t = zero
        if a <= zero:
            if e > zero:
                t = wp.clamp(f / e, zero, dtype(1.0))
        else:
            c = wp.dot(d1, r)
            if e <= zero:
                s = wp.clamp(-c / a, zero, dtype(1.0))
            else:
                bb = wp.dot(d1, d2)
                denom = a * e - bb * bb
                if denom > zero:
                    s = wp.clamp((bb * f - c * e) / denom, zero, dtype(1.0))
                t = (bb * s + f) / e
                if t < zero:
                    t = zero
                    s = wp.clamp(-c / a, zero, dtype(1.0))
                elif t > dtype(1.0):
                    t = dtype(1.0)
                    s = wp.clamp((bb - c) / a, zero, dtype(1.0))
        return s, t

    @wp.func
    def nearest_on_chord(md: Model, i: int, j: int, a: vec3, b: vec3):
        """Where along the chord a-b (t in [0, 1]) it comes nearest the core of obstacle j (row i):
        a sphere's centre, a capsule's axis; the middle for the others."""
        kind = int(md.obst[i, j, OB_KIND])
        t = dtype(0.5)
        if kind == SPHERE:
            t = point_segment(column(md, i, j, OB_A), a, b)
        elif kind == CAPSULE:
            t, _t = segment_segment(a, b, column(md, i, j, OB_A), column(md, i, j, OB_B))
        return t

    @wp.func
    def core_distance(md: Model, i: int, j: int, a: vec3, b: vec3):
        """How far the straight way from a to b passes from the core of obstacle j (row i), in
        units of its radius plus the rod's: 1 grazes the surface, 0 goes through the centre or the
        axis (a sphere or capsule; FAR for the others, which have no inside to cross)."""
        kind = int(md.obst[i, j, OB_KIND])
        reach = md.obst[i, j, OB_RADIUS] + md.obst[i, j, OB_REACH]
        d = far
        if kind == SPHERE:
            c = column(md, i, j, OB_A)
            d = wp.length(a + point_segment(c, a, b) * (b - a) - c) / reach
        elif kind == CAPSULE:
            p = column(md, i, j, OB_A)
            q = column(md, i, j, OB_B)
            s, t = segment_segment(a, b, p, q)
            d = wp.length(a + s * (b - a) - (p + t * (q - p))) / reach
        return d

    return SimpleNamespace(nearest_on_chord=nearest_on_chord, core_distance=core_distance)


@functools.cache
def make_contact(dtype, dynamic: bool):
    """``surface``, ``pressed`` and ``contact_force`` for one precision."""
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)
    zero = dtype(0.0)
    half = dtype(0.5)
    far = dtype(FAR)
    Model = make_structs(dtype, dynamic).Model
    rows = make_rows(dtype, dynamic)
    row = rows.row
    surface = make_surface(dtype, dynamic).surface
    nearest_on_chord = make_chords(dtype, dynamic).nearest_on_chord

    @wp.func
    def law(delta: dtype, eps: dtype):
        """The rounded penalty's depth phi(delta) [m] at a penetration delta, band eps."""
        phi = zero
        if delta >= half * eps:
            phi = delta
        elif delta > -half * eps:
            e = delta + half * eps
            phi = e * e / (dtype(2.0) * eps)
        return phi

    @wp.func
    def pressed(md: Model, b: int, i: int, j: int, node: int, p: vec3, R: mat33, m: vec3):
        """The distance to obstacle j (row i) and its normal where the law measures it: at the
        node's point p, or with OB_ALONG (a sphere or capsule) at the point of the node's share of
        the centre line nearest its core, on the local curve p + sigma t + sigma^2 / 2 R (u x e3)
        (t = R e3, u = Kbt^-1 R^T m + u* the curvature; statics)."""
        kind = int(md.obst[i, j, OB_KIND])
        q = p
        if md.obst[i, j, OB_ALONG] > zero and (kind == SPHERE or kind == CAPSULE):
            ig = row(b, md.grid)
            h_lo = half * (md.grid[ig, node] - md.grid[ig, wp.max(node - 1, 0)])
            h_hi = half * (md.grid[ig, wp.min(node + 1, md.grid.shape[1] - 1)] - md.grid[ig, node])
            t = vec3(R[0, 2], R[1, 2], R[2, 2])
            u = wp.cw_div(wp.transpose(R) * m, rows.rvec(md, b, KBT)) + rows.rvec(md, b, USTAR)
            sigma = -h_lo + (h_lo + h_hi) * nearest_on_chord(md, i, j, p - h_lo * t, p + h_hi * t)
            q = p + sigma * t + (half * sigma * sigma) * (R * wp.cross(u, vec3(zero, zero, dtype(1.0))))
        return surface(md, i, j, q)

    @wp.func
    def contact_force(md: Model, b: int, node: int, p: vec3, R: mat33, m: vec3, vel: vec3):
        """The obstacles' point force on ``node`` at p (orientation R, internal moment m) moving at
        vel (world frame; dynamics) [N] and the smallest gap the law saw [m] (negative: penetration)."""
        i = row(b, md.obst)
        ig = row(b, md.grid)
        n_int = md.grid.shape[1] - 1
        lo = wp.max(node - 1, 0)
        hi = wp.min(node + 1, n_int)
        share = half * (md.grid[ig, hi] - md.grid[ig, lo])
        ir = row(b, md.rod)
        per_len = md.rod[ir, FORCE_SCALE] / md.rod[ir, LENGTH]  # E I / L^3 [N/m] is k eps
        force = vec3()
        gap = far
        for j in range(md.n_obst):
            d, nrm = pressed(md, b, i, j, node, p, R, m)
            g = d - md.obst[i, j, OB_REACH]
            gap = wp.min(gap, g)
            k = md.obst[i, j, OB_STIFF]
            eps = per_len / k
            phi = law(-g, eps)
            kind = int(md.obst[i, j, OB_KIND])
            if kind == TUBE or kind == BENT_TUBE:  # less its value on the axis, which has no nearest wall
                phi = wp.max(zero, phi - law(md.obst[i, j, OB_REACH] - md.obst[i, j, OB_RADIUS], eps))
            if wp.static(dynamic):
                phi = phi * wp.max(zero, dtype(1.0) - md.obst[i, j, OB_DAMP] * wp.dot(nrm, vel))
            force += (k * share * phi) * nrm
        return force, gap

    return SimpleNamespace(surface=surface, pressed=pressed, contact_force=contact_force)


@functools.cache
def make_contact_kernel(dtype, dynamic: bool = False):
    """The kernel ``contact_nodes``: at every node of solved shapes (positions ``pos``) the
    contact force [N], the gap to each obstacle [m] and the gap where that obstacle's stiffness
    holds the node (``pressing``: the gap the law sees, ``pressed``; FAR where its damping takes half the elastic force or more: in
    dynamics a node leaving the surface at 1 / (2 damping) or faster, whose depth its way out
    sets, not the stiffness; at 1 / damping it carries no force) (outputs; compiled only for
    scenes with obstacles). In dynamics the force is damped by the nodes' velocities R q (``rot`` and
    the body-frame ``vel``; statics ignores both, and ``pressing`` is the gap)."""
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)
    Model = make_structs(dtype, dynamic).Model
    funcs = make_contact(dtype, dynamic)
    row = make_rows(dtype, dynamic).row

    @wp.kernel
    def contact_nodes(md: Model, pos: wp.array2d(dtype=vec3), rot: wp.array2d(dtype=mat33),
                      mom: wp.array2d(dtype=vec3), vel: wp.array2d(dtype=vec3), force: wp.array2d(dtype=vec3),
                      gap: wp.array3d(dtype=dtype), pressing: wp.array3d(dtype=dtype)):
        b, k = wp.tid()
        p = pos[b, k]
        R = rot[b, k]
        pt = vec3()
        if wp.static(dynamic):
            pt = R * vel[b, k]
        f, _g = funcs.contact_force(md, b, k, p, R, mom[b, k], pt)
        force[b, k] = f
        i = row(b, md.obst)
        for j in range(md.n_obst):
            d, _nd = funcs.surface(md, i, j, p)
            gap[b, k, j] = d - md.obst[i, j, OB_REACH]
            dl, nrm = funcs.pressed(md, b, i, j, k, p, R, mom[b, k])
            pressing[b, k, j] = dl - md.obst[i, j, OB_REACH]
            if wp.static(dynamic):
                if md.obst[i, j, OB_DAMP] * wp.dot(nrm, pt) >= dtype(0.5):
                    pressing[b, k, j] = dtype(FAR)

    return contact_nodes


@functools.cache
def make_interval_kernels(dtype, dynamic: bool = False):
    """The kernels of the centre line between the nodes (outputs; in the contact kernels' module):
    ``intervals``, along every interval the smallest gap to each obstacle [m] (the module's check
    between nodes); ``crossing``, for two shapes of the same rods (``pos0``, ``rot0``: where they
    started), how near the straight way of each point of an interval from its first shape to its
    second passes the core of each sphere or capsule (``core_distance``, its smallest over the
    interval's samples)."""
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)
    Model = make_structs(dtype, dynamic).Model
    surface = make_surface(dtype, dynamic).surface
    chords = make_chords(dtype, dynamic)
    row = make_rows(dtype, dynamic).row
    one, two, three = dtype(1.0), dtype(2.0), dtype(3.0)
    step = dtype(1.0 / INTERVAL_CHORDS)

    @wp.func
    def tangent(R: mat33, h: dtype):
        """h R e3: the Hermite tangent of an interval of length h [m]."""
        return vec3(R[0, 2], R[1, 2], R[2, 2]) * h

    @wp.func
    def hermite(md: Model, b: int, k: int, pos: wp.array2d(dtype=vec3), rot: wp.array2d(dtype=mat33), x: dtype):
        """The centre line of interval k at x in [0, 1]: the cubic Hermite curve through its end
        nodes with tangents h R e3."""
        h = md.grid[row(b, md.grid), k + 1] - md.grid[row(b, md.grid), k]
        x2 = x * x
        x3 = x2 * x
        return ((two * x3 - three * x2 + one) * pos[b, k] + (x3 - two * x2 + x) * tangent(rot[b, k], h)
                + (three * x2 - two * x3) * pos[b, k + 1] + (x3 - x2) * tangent(rot[b, k + 1], h))

    @wp.kernel
    def contact_intervals(md: Model, pos: wp.array2d(dtype=vec3), rot: wp.array2d(dtype=mat33),
                          igap: wp.array3d(dtype=dtype)):
        b, k = wp.tid()
        i = row(b, md.obst)
        for j in range(md.n_obst):
            smallest = dtype(FAR)
            a = pos[b, k]
            for c in range(wp.static(INTERVAL_CHORDS)):
                x = dtype(c) * step
                q = hermite(md, b, k, pos, rot, x + step)
                near = hermite(md, b, k, pos, rot, x + step * chords.nearest_on_chord(md, i, j, a, q))
                d_end, _n_end = surface(md, i, j, q)
                d_near, _n_near = surface(md, i, j, near)
                smallest = wp.min(smallest, wp.min(d_end, d_near))
                a = q
            igap[b, k, j] = smallest - md.obst[i, j, OB_REACH]

    @wp.kernel
    def crossing(md: Model, pos0: wp.array2d(dtype=vec3), rot0: wp.array2d(dtype=mat33),
                 pos: wp.array2d(dtype=vec3), rot: wp.array2d(dtype=mat33), core: wp.array3d(dtype=dtype)):
        b, k = wp.tid()
        i = row(b, md.obst)
        for j in range(md.n_obst):
            nearest = dtype(FAR)
            for c in range(wp.static(INTERVAL_CHORDS)):
                x = dtype(c) * step
                d = chords.core_distance(md, i, j, hermite(md, b, k, pos0, rot0, x), hermite(md, b, k, pos, rot, x))
                nearest = wp.min(nearest, d)
            if k == pos.shape[1] - 2:  # the tip
                nearest = wp.min(nearest, chords.core_distance(md, i, j, pos0[b, k + 1], pos[b, k + 1]))
            core[b, k, j] = nearest

    return SimpleNamespace(intervals=contact_intervals, crossing=crossing)
