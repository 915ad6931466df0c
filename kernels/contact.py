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

  surface        the distance from p to an obstacle's surface and the normal there
  contact_force  the sum of the obstacles' forces at a node and the smallest gap
  contact kernel the force and gap at every node of solved shapes (outputs)
"""

import functools
from types import SimpleNamespace

import warp as wp

from .layout import (
    BENT_TUBE,
    CAPSULE,
    FORCE_SCALE,
    LENGTH,
    OB_A,
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
)
from .structs import make_rows, make_structs

__all__ = ["FAR", "make_contact", "make_contact_kernel"]

FAR = 1.0e30  # the distance reported where an obstacle cannot be touched (beyond a tube's ends)


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

    return SimpleNamespace(surface=surface)


@functools.cache
def make_contact(dtype, dynamic: bool):
    """``surface`` and ``contact_force`` for one precision."""
    vec3 = wp.types.vector(3, dtype)
    zero = dtype(0.0)
    half = dtype(0.5)
    far = dtype(FAR)
    Model = make_structs(dtype, dynamic).Model
    row = make_rows(dtype, dynamic).row
    surface = make_surface(dtype, dynamic).surface

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
    def contact_force(md: Model, b: int, node: int, p: vec3, vel: vec3):
        """The obstacles' point force on ``node`` at p moving at vel (world frame; dynamics) [N]
        and the smallest gap there [m] (negative: penetration)."""
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
            d, nrm = surface(md, i, j, p)
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

    return SimpleNamespace(surface=surface, contact_force=contact_force)


@functools.cache
def make_contact_kernel(dtype, dynamic: bool = False):
    """The kernel ``contact_nodes``: at every node of solved shapes (positions ``pos``) the
    contact force [N], the gap to each obstacle [m] and the gap where that obstacle's stiffness
    holds the node (``pressing``; FAR where its damping takes half the elastic force or more: in
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
                      vel: wp.array2d(dtype=vec3), force: wp.array2d(dtype=vec3), gap: wp.array3d(dtype=dtype),
                      pressing: wp.array3d(dtype=dtype)):
        b, k = wp.tid()
        p = pos[b, k]
        pt = vec3()
        if wp.static(dynamic):
            pt = rot[b, k] * vel[b, k]
        f, _g = funcs.contact_force(md, b, k, p, pt)
        force[b, k] = f
        i = row(b, md.obst)
        for j in range(md.n_obst):
            d, nrm = funcs.surface(md, i, j, p)
            g = d - md.obst[i, j, OB_REACH]
            gap[b, k, j] = g
            pressing[b, k, j] = g
            if wp.static(dynamic):
                if md.obst[i, j, OB_DAMP] * wp.dot(nrm, pt) >= dtype(0.5):
                    pressing[b, k, j] = dtype(FAR)

    return contact_nodes
