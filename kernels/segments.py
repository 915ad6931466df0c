"""Multiple shooting: the rod integrated segment by segment, each from a given start state.

Single shooting integrates base to tip from the base wrench; a start error grows along s like
exp(L (rho A c0^2 / E I)^(1/4) / sqrt 2) in dynamics at small dt (and like exp(2 beta l) along a
line contact), beyond what float64 resolves. Splitting the rod at the nodes ``bounds`` into M
segments, with the full state at each segment's start as unknowns, bounds the growth to a
segment's; the host (tdcr_warp/physics/segments.py) closes the gaps between segments by Newton.

  segment_ends   kernel over (rod b, column c), for the rods with ``rods[b]`` != 0 (the others
                 are left as they are): integrate segment ``seg[c]`` from the start
                 state ``start[b, c]`` (p, R, n, m, q, w as 24 numbers, world frame, R row-major)
                 over its intervals, the jumps at its end node included (and at node 0 for the
                 first segment); write the end state, and for the last segment the scaled tip
                 residual. With ``store`` the shape and, in dynamics, the BDF-alpha slots of its
                 nodes are kept (the final evaluation of a step).

Only the rod's own state crosses a segment boundary, so variants with tendon states (displacement
control, friction) or a constrained tip are not segmented.
"""

import functools

import warp as wp

from .drivers import module_names
from .integration import make_nodes, make_residual
from .nodes import make_rod_funcs
from .stepping import make_interval
from .structs import tendon_vectors
from .variants import STAGES, Features

__all__ = ["STATE", "make_segment_kernel", "segmentable"]

STATE = 24  # p (3), R (9, row-major), n (3), m (3), q (3), w (3)


def segmentable(model: str, features: Features) -> bool:
    """Whether a variant can be segmented: no tendon states, constrained tip, disks or sections (only
    the rod's own state crosses a segment boundary; sections: not tested with it)."""
    return not (features.tendons or features.tip or model == "disks" or features.sections)


@functools.cache
def make_segment_kernel(dtype, integrator: str, model: str, dynamic: bool, rod: str, features: Features):
    """The kernel ``segment_ends`` of one variant (without tendon states or a constrained tip)."""
    if not segmentable(model, features):
        raise ValueError("multiple shooting needs a variant without tendon states, a constrained tip or disks")
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)
    rf = make_rod_funcs(dtype, integrator, model, dynamic, rod, features)
    Model, Control, Step = rf.Model, rf.Control, rf.Step
    nodes = make_nodes(dtype, dynamic, False)
    Nodes, store_node = nodes.Nodes, nodes.store_node
    interval = make_interval(dtype, integrator, model, dynamic, rod, features).interval
    resid = make_residual(dtype, dynamic, 0, 0, 0)
    uvec = wp.types.vector(6, dtype)
    evec = tendon_vectors(dtype, 0)[1]
    stages = STAGES[integrator]
    zero = dtype(0.0)

    @wp.func
    def column(a: wp.array3d(dtype=dtype), b: int, c: int, i: int):
        return vec3(a[b, c, i], a[b, c, i + 1], a[b, c, i + 2])

    @wp.func
    def put(a: wp.array3d(dtype=dtype), b: int, c: int, i: int, v: vec3):
        a[b, c, i] = v[0]
        a[b, c, i + 1] = v[1]
        a[b, c, i + 2] = v[2]

    module = module_names(dtype, integrator, model, dynamic, rod, features)["fused"].replace("_fused_", "_segments_")

    @wp.kernel(module=module, enable_backward=False)  # a module of its own per variant (as the drivers')
    def segment_ends(md: Model, ct: Control, sp: Step, rods: wp.array(dtype=int), start: wp.array3d(dtype=dtype),
                     seg: wp.array(dtype=int), bounds: wp.array(dtype=int), store: int, out: Nodes,
                     end: wp.array3d(dtype=dtype), tip: wp.array3d(dtype=dtype)):
        b, c = wp.tid()
        if rods[b] == 0:
            return
        j = seg[c]
        k = bounds[j]
        k_end = bounds[j + 1]
        p = column(start, b, c, 0)
        R = mat33(start[b, c, 3], start[b, c, 4], start[b, c, 5], start[b, c, 6], start[b, c, 7], start[b, c, 8],
                  start[b, c, 9], start[b, c, 10], start[b, c, 11])
        n = column(start, b, c, 12)
        m = column(start, b, c, 15)
        q = column(start, b, c, 18)
        w = column(start, b, c, 21)
        t0 = rf.base_tensions(md, ct, b, uvec())
        E = evec()
        ig = rf.row(b, md.grid)
        n_int = md.grid.shape[1] - 1
        jslot = n_int * stages
        if k == 0:
            if store != 0:
                store_node(out, b, 0, p, R, n, m, q, w)
            n, m, _E = rf.node_jumps(md, ct, sp, b, zero, p, R, n, m, q, w, t0, E, 0, jslot, jslot + 1, store)
        while k < k_end:
            k1 = k + 1
            s = md.grid[ig, k]
            p, R, n, m, q, w, _E2 = interval(md, ct, sp, b, s, md.grid[ig, k1] - s, p, R, n, m, q, w, t0, E, k,
                                             store)
            if store != 0:
                store_node(out, b, k1, p, R, n, m, q, w)
            js = jslot + 2 * k1
            n, m, _E3 = rf.node_jumps(md, ct, sp, b, md.grid[ig, k1], p, R, n, m, q, w, t0, E, k1, js, js + 1, store)
            k = k1
        put(end, b, c, 0, p)
        for i in range(3):
            for jj in range(3):
                end[b, c, 3 + 3 * i + jj] = R[i, jj]
        put(end, b, c, 12, n)
        put(end, b, c, 15, m)
        put(end, b, c, 18, q)
        put(end, b, c, 21, w)
        if k_end == n_int:
            r = resid.tip_residual(md, ct, b, uvec(), p, n, m, E)
            for i in range(6):
                tip[b, c, i] = r[i]

    return segment_ends
