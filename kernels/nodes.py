"""The jumps of the rod's state at a node, and one variant's rod functions gathered.

  node_busy            whether anything acts at a node
  span_end             the end of a step over several intervals (to the next busy node)
  node_jumps           the jumps of n, m (and E) at a node: tendon ends, point forces, kinks,
                       the spacer disks (kernels/disks.py), contact (kernels/contact.py)

``make_rod_funcs(dtype, integrator, model, dynamic, rod, features)`` returns them with the
right-hand side for one precision, one tendon model ("coupled", "point" or "disks"), statics
or dynamics, one rod model and feature set (the disks look ahead with ``integrator``).
"""

import functools
from types import SimpleNamespace

import warp as wp

from .backbone import make_backbone
from .contact import make_contact
from .disks import make_disk_jumps
from .friction import make_profiles, make_tensions
from .rod import make_point_jumps, make_rhs
from .strains import make_strains
from .structs import make_rows, make_structs, tendon_vectors
from .tendons import make_displacement, make_node_loads
from .variants import ALL, MODELS, RODS, Features

__all__ = ["make_node_busy", "make_node_jumps", "make_rod_funcs"]


@functools.cache
def make_node_busy(dtype, model: str, dynamic: bool, features: Features):
    """``node_busy``: whether anything acts at a node; ``span_end``: a step's end node."""
    Model = make_structs(dtype, dynamic).Model
    rows = make_rows(dtype, dynamic)
    row, term_node = rows.row, rows.term_node
    disks = model == "disks"
    bb = make_backbone(dtype, dynamic, features.sections)

    @wp.func
    def node_busy(md: Model, b: int, node: int):
        """1 if a tendon ends, a disk sits or a point force acts at ``node``, or (with obstacles)
        contact may push there (``md.near``: every node, but in the probes of a solved shape)."""
        busy = int(0)  # noqa: UP018 (a dynamic variable for Warp)
        if wp.static(features.contact):
            busy = md.near[row(b, md.near), node]
        if wp.static(disks):
            if md.dnext[row(b, md.dnext), node] >= 0:
                busy = 1
        else:
            for k in range(md.n_tendons):
                if term_node(md, b, k) == node:
                    busy = 1
        if wp.static(features.point_loads):
            for j in range(md.n_points):
                if md.pnode[row(b, md.pnode), j] == node:
                    busy = 1
        if wp.static(features.sections):
            busy = busy | bb.boundary(md, b, md.grid[row(b, md.grid), node])
        return busy

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

    return SimpleNamespace(node_busy=node_busy, span_end=span_end)


@functools.cache
def make_node_jumps(dtype, integrator: str, model: str, dynamic: bool, rod: str, features: Features):
    """``node_jumps``: n, m (and E) across a node; ``node_busy``: whether anything acts there
    (the disk model's look-ahead steps with ``integrator``)."""
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)
    zero = dtype(0.0)
    K, friction, kirchhoff = features.tendons, features.friction, rod == "kirchhoff"
    kvec, evec = tendon_vectors(dtype, K)
    st = make_structs(dtype, dynamic)
    Model, Control, Step = st.Model, st.Control, st.Step
    law = make_strains(dtype, dynamic, kirchhoff)
    tensions = make_tensions(dtype, dynamic, K, friction).tensions
    store_node_profile = make_profiles(dtype, dynamic, K).store_node_profile
    loads = make_node_loads(dtype, dynamic, kirchhoff, K, friction, features.helix, features.spline)
    point_jumps = make_point_jumps(dtype, dynamic, features.point_loads).point_jumps
    disks = model == "disks"
    dj = make_disk_jumps(dtype, integrator, rod, features) if disks else None
    bz = make_node_busy(dtype, model, dynamic, features)
    bb = make_backbone(dtype, dynamic, features.sections)
    node_busy = bz.node_busy
    contact_force = make_contact(dtype, dynamic).contact_force

    @wp.func
    def node_jumps(md: Model, ct: Control, sp: Step, b: int, s: dtype, p: vec3, R: mat33, n: vec3, m: vec3,
                   q: vec3, w: vec3, t0: kvec, E: evec, node: int, slot_pre: int, slot_post: int, store: int):
        """Point loads at ``node``: n(s+) = n(s-) - F, m(s+) = m(s-) - L (tendon ends, point
        forces, in the coupled model the kinks of the tendons that continue, in the disk model
        the disk's chords, the obstacles' contact). A node without any of them (most nodes)
        returns at once, unless dynamics stores its slots. Returns n, m and E after the node."""
        busy = node_busy(md, b, node)
        if wp.static(dynamic):
            busy = busy | store
        if busy == 0:
            return n, m, E
        touch = int(0)
        if wp.static(features.contact):
            fc, _gap = contact_force(md, b, node, p, R, m, R * q)
            if fc[0] != zero or fc[1] != zero or fc[2] != zero:
                n = n - fc
                touch = 1
        if wp.static(disks):
            n, _jump = point_jumps(md, b, node, n)
            return dj.disk_jumps(md, ct, sp, b, s, p, R, n, m, t0, E, node)
        tau, g, h = tensions(md, ct, b, t0, E, slot_pre, zero, zero)
        kse, kbt = bb.stiffness(md, b, s, 1)  # proximal of the node, and distal of it (kse2, kbt2)
        kse2, kbt2 = bb.stiffness(md, b, s, 0)
        v, u = law.strains(md, sp, b, kse, kbt, R, n, m, slot_pre)
        n, m, jump = loads.tendon_end_loads(md, ct, b, s, R, n, m, v, u, node, tau)
        n, pj = point_jumps(md, b, node, n)
        jump = jump | pj | touch | bb.boundary(md, b, s)  # a jump of stiffness kinks the tendons too
        E2 = E
        if wp.static(model == "coupled" and features.kinks):
            if jump != 0:
                n, m, E2 = loads.kink_loads(md, ct, sp, b, s, R, n, m, v, u, kse2, kbt2, node, slot_pre, slot_post,
                                            t0, E, tau)
        if wp.static(friction):
            if store != 0:
                tau2, g2, h2 = tensions(md, ct, b, t0, E2, slot_post, zero, zero)
                store_node_profile(md, sp, b, slot_pre, tau, g)
                store_node_profile(md, sp, b, slot_post, tau2, g2)
        if wp.static(dynamic):
            if store != 0:
                v3, u3 = law.strains(md, sp, b, kse2, kbt2, R, n, m, slot_post)
                law.store_slot(sp, b, slot_pre, v, u, q, w, vec3(), vec3())
                law.store_slot(sp, b, slot_post, v3, u3, q, w, vec3(), vec3())
        return n, m, E2

    return SimpleNamespace(node_busy=node_busy, node_jumps=node_jumps, span_end=bz.span_end)


@functools.cache
def make_rod_funcs(dtype, integrator: str, model: str, dynamic: bool, rod: str = "cosserat",
                   features: Features = ALL):
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
    disks = model == "disks"
    if disks and (dynamic or features.friction or features.contact or features.tendons % 4):
        raise ValueError("the disk model is static, frictionless and free of obstacles, with 4 x the tendon count "
                         "as features.tendons")
    st = make_structs(dtype, dynamic)
    jumps = make_node_jumps(dtype, integrator, model, dynamic, rod, features)
    return SimpleNamespace(
        vec3=wp.types.vector(3, dtype), mat33=wp.types.matrix((3, 3), dtype), Model=st.Model, Control=st.Control,
        Step=st.Step, row=make_rows(dtype, dynamic).row, rhs=make_rhs(dtype, model, dynamic, rod, features).rhs,
        node_jumps=jumps.node_jumps, node_busy=jumps.node_busy, span_end=jumps.span_end,
        base_tensions=make_displacement(dtype, dynamic, features.tendons, features.displaced,
                                        features.tip).base_tensions,
        tstate=features.tendons > 0, K=features.tendons // 4 if disks else features.tendons)
