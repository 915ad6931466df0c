"""Integration of the rod ODE from base to tip: the shooting residual of a trial point.

  shoot                base to tip from the unknowns x: the residual and the tip pose
  tip_residual         the scaled residual at the tip (and of the displaced tendons)
  Nodes, store_node    the shape a solve keeps: the state at every node
  store_tensions, store_end_tensions, store_tendon_outputs   what it keeps of the tendons

Unknowns per rod, scaled to O(1): x = [n(0) L^2 / EI, m(0) L / EI] (+ one tension per
displacement-controlled tendon). Residual, scaled the same way: r = [(n(L+) - F_tip) L^2 / EI,
(m(L+) - L_tip) L / EI], so ``L |r|`` is a tip-displacement-like error in metres.
"""

import functools
from types import SimpleNamespace

import warp as wp

from .friction import make_tensions
from .layout import (
    FORCE_SCALE,
    LENGTH,
    MOMENT_SCALE,
    TC_BASIS,
    TC_COMPLIANCE,
    TC_POINT,
    TIP_F,
    TIP_M,
    TO_BASE,
    TO_END,
    TO_FREE,
    TO_PATH,
    TO_TURN,
)
from .nodes import make_rod_funcs
from .stepping import make_interval, make_stages
from .structs import make_rows, make_structs, tendon_vectors
from .tendons import make_displacement
from .variants import STAGES, Features

N_BASE = 6  # n(0), m(0); + one tension per displacement-controlled tendon, + a constrained tip's reaction


@functools.cache
def make_nodes(dtype, dynamic: bool, tstate: bool):
    """The kernel ``Nodes``: the state at the nodes of the last trial point (State.nodes)."""
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)

    @wp.struct
    class Nodes:
        """The state at the nodes of the last trial point, (B, N+1) each (State.nodes)."""

        p: wp.array2d(dtype=vec3)
        R: wp.array2d(dtype=mat33)
        n: wp.array2d(dtype=vec3)
        m: wp.array2d(dtype=vec3)
        orth: wp.array(dtype=dtype)  # max |R^T R - I| over the nodes
        if tstate:
            tend: wp.array3d(dtype=dtype)  # (B, K, TO_WIDTH) per tendon (kernels/layout.py)
            taun: wp.array3d(dtype=dtype)  # (B, N+1, K) tension just distal of every node [N]
        if dynamic:
            q: wp.array2d(dtype=vec3)
            w: wp.array2d(dtype=vec3)

    @wp.func
    def store_node(out: Nodes, b: int, k: int, p: vec3, R: mat33, n: vec3, m: vec3, q: vec3, w: vec3):
        out.p[b, k] = p
        out.R[b, k] = R
        out.n[b, k] = n
        out.m[b, k] = m
        if wp.static(dynamic):
            out.q[b, k] = q
            out.w[b, k] = w

    return SimpleNamespace(Nodes=Nodes, store_node=store_node)


@functools.cache
def make_tendon_outputs(dtype, dynamic: bool, tendons: int, friction: bool):
    """What a solve keeps of the tendons (tendon states only): tensions at the nodes, at each
    tendon's end and at the motor, path lengths and turning (``Nodes.taun``, ``Nodes.tend``)."""
    zero = dtype(0.0)
    K = tendons
    kvec, evec = tendon_vectors(dtype, K)
    st = make_structs(dtype, dynamic)
    Model, Control = st.Model, st.Control
    Nodes = make_nodes(dtype, dynamic, K > 0).Nodes
    tensions = make_tensions(dtype, dynamic, K, friction).tensions
    term_node = make_rows(dtype, dynamic).term_node

    @wp.func
    def store_tensions(md: Model, ct: Control, b: int, out: Nodes, t0: kvec, E: evec, node: int, slot: int):
        """The tensions just distal of ``node`` (store pass, tendon states only; ``slot``: an
        evaluation there, whose remembered tension a stick-slip solve reads)."""
        if wp.static(K > 0):
            tau, g, h = tensions(md, ct, b, t0, E, slot, zero, zero)
            for k in range(md.n_tendons):
                out.taun[b, node, k] = tau[k]

    @wp.func
    def store_end_tensions(md: Model, ct: Control, b: int, out: Nodes, t0: kvec, E: evec, node: int, slot: int):
        """The tension of each tendon ending at ``node``, just before its end."""
        if wp.static(K > 0):
            tau, g, h = tensions(md, ct, b, t0, E, slot, zero, zero)
            for k in range(md.n_tendons):
                if term_node(md, b, k) == node:
                    out.tend[b, k, TO_END] = tau[k]

    @wp.func
    def store_tendon_outputs(md: Model, b: int, out: Nodes, t0: kvec, E: evec):
        """Per tendon at the tip: the tension at the motor, the path's length, unstretched
        length and turning."""
        if wp.static(K > 0):
            for kk in range(md.n_tendons):
                out.tend[b, kk, TO_BASE] = t0[kk]
                out.tend[b, kk, TO_PATH] = E[K + kk]
                out.tend[b, kk, TO_FREE] = E[2 * K + kk]
                if wp.static(friction):  # (the disk model keeps its holes there)
                    out.tend[b, kk, TO_TURN] = E[kk]

    return SimpleNamespace(store_tensions=store_tensions, store_end_tensions=store_end_tensions,
                           store_tendon_outputs=store_tendon_outputs)


@functools.cache
def make_residual(dtype, dynamic: bool, tendons: int, displaced: int, tip: int = 0):
    """The scaled shooting residual at the tip, and its scale to a length (``tip``: the unknowns
    of a constrained tip, after those of the displaced tendons)."""
    vec3 = wp.types.vector(3, dtype)
    evec = tendon_vectors(dtype, tendons)[1]
    uvec = wp.types.vector(N_BASE + displaced + tip, dtype)
    first = N_BASE + displaced  # the first reaction unknown
    st = make_structs(dtype, dynamic)
    Model, Control = st.Model, st.Control
    rows = make_rows(dtype, dynamic)
    length_residuals = make_displacement(dtype, dynamic, tendons, displaced, tip).length_residuals

    @wp.func
    def tip_residual(md: Model, ct: Control, b: int, x: uvec, p: vec3, n: vec3, m: vec3, E: evec):
        """r = [(n(L+) - F_tip - F_c) / FORCE_SCALE, (m(L+) - L_tip) / MOMENT_SCALE], the length
        residuals of the displaced tendons and, with a constrained tip, (e_i . (p(L) - c) + kappa
        lambda_i) / L: the tip held (kappa = 0; else a spring) by the reaction F_c = sum_i lambda_i
        e_i, lambda_i = x_i FORCE_SCALE (layout.TC_POINT)."""
        fs = md.rod[rows.row(b, md.rod), FORCE_SCALE]
        ms = md.rod[rows.row(b, md.rod), MOMENT_SCALE]
        react = vec3()
        if wp.static(tip > 0):
            it = rows.row(b, md.tipc)
            for i in range(tip):
                c = TC_BASIS + 3 * i
                react += (x[first + i] * fs) * vec3(md.tipc[it, c], md.tipc[it, c + 1], md.tipc[it, c + 2])
        rn = (n - rows.rvec(md, b, TIP_F) - react) / fs
        rm = (m - rows.rvec(md, b, TIP_M)) / ms
        res = uvec()
        for i in range(3):
            res[i] = rn[i]
            res[3 + i] = rm[i]
        res = length_residuals(md, ct, b, x, E, res)
        if wp.static(tip > 0):
            it = rows.row(b, md.tipc)
            off = p - vec3(md.tipc[it, TC_POINT], md.tipc[it, TC_POINT + 1], md.tipc[it, TC_POINT + 2])
            ell = md.rod[rows.row(b, md.rod), LENGTH]
            soft = md.tipc[it, TC_COMPLIANCE] * md.rod[rows.row(b, md.rod), FORCE_SCALE]
            for i in range(tip):
                c = TC_BASIS + 3 * i
                e = vec3(md.tipc[it, c], md.tipc[it, c + 1], md.tipc[it, c + 2])
                res[first + i] = (wp.dot(e, off) + soft * x[first + i]) / ell
        return res

    @wp.func
    def residual_scale(md: Model, b: int):
        """L: L |r| is the convergence measure [m]."""
        return md.rod[rows.row(b, md.rod), LENGTH]

    return SimpleNamespace(tip_residual=tip_residual, residual_scale=residual_scale)


@functools.cache
def make_shoot(dtype, integrator: str, model: str, dynamic: bool, rod: str, features: Features):
    """``shoot``: the residual of a trial point; ``residual_scale``: its scale to a length."""
    vec3 = wp.types.vector(3, dtype)
    zero = dtype(0.0)
    K = features.tendons
    evec = tendon_vectors(dtype, K)[1]
    uvec = wp.types.vector(N_BASE + features.displaced + features.tip, dtype)
    st = make_structs(dtype, dynamic)
    Model, Control, Step = st.Model, st.Control, st.Step
    rf = make_rod_funcs(dtype, integrator, model, dynamic, rod, features)
    nodes = make_nodes(dtype, dynamic, K > 0)
    Nodes, store_node = nodes.Nodes, nodes.store_node
    tout = make_tendon_outputs(dtype, dynamic, K, features.friction)
    interval = make_interval(dtype, integrator, model, dynamic, rod, features).interval
    orth_error = make_stages(dtype, integrator).orth_error
    resid = make_residual(dtype, dynamic, K, features.displaced, features.tip)
    stages = STAGES[integrator]

    @wp.func
    def shoot(x: uvec, md: Model, ct: Control, sp: Step, b: int, store: int, coarse: int, out: Nodes):
        """Integrate base to tip from the scaled unknowns x; return the scaled residual and the
        tip's position and orientation.
        coarse = c >= 2 (statics, never with store): steps over up to c intervals, stopping at
        every node where a load sits, about 1/c of the work (the probes of a first Jacobian)."""
        p = vec3()
        R = wp.identity(3, dtype)
        n = vec3(x[0], x[1], x[2]) * md.rod[rf.row(b, md.rod), FORCE_SCALE]
        m = vec3(x[3], x[4], x[5]) * md.rod[rf.row(b, md.rod), MOMENT_SCALE]
        q = vec3()
        w = vec3()
        t0 = rf.base_tensions(md, ct, b, x)
        E = evec()
        ig = rf.row(b, md.grid)
        n_int = md.grid.shape[1] - 1
        jslot = n_int * stages  # first of the two slots per node used by the jumps
        orth = zero
        if store != 0:
            store_node(out, b, 0, p, R, n, m, q, w)
        n, m, E = rf.node_jumps(md, ct, sp, b, zero, p, R, n, m, q, w, t0, E, 0, jslot, jslot + 1, store)
        if store != 0:
            tout.store_tensions(md, ct, b, out, t0, E, 0, 0)
        k = int(0)
        while k < n_int:
            k1 = rf.span_end(md, b, k, coarse, n_int)
            s = md.grid[ig, k]
            p, R, n, m, q, w, E = interval(md, ct, sp, b, s, md.grid[ig, k1] - s, p, R, n, m, q, w, t0, E, k, store)
            if store != 0:
                store_node(out, b, k1, p, R, n, m, q, w)
                orth = orth_error(R, orth)
            js = jslot + 2 * k1
            if store != 0:
                tout.store_end_tensions(md, ct, b, out, t0, E, k1, js)
            n, m, E = rf.node_jumps(md, ct, sp, b, md.grid[ig, k1], p, R, n, m, q, w, t0, E, k1, js, js + 1, store)
            if store != 0:  # the first stage of the next interval is just distal of node k1
                tout.store_tensions(md, ct, b, out, t0, E, k1, wp.where(k1 < n_int, k1 * stages, js + 1))
            k = k1
        if store != 0:
            out.orth[b] = orth
            tout.store_tendon_outputs(md, b, out, t0, E)
        return resid.tip_residual(md, ct, b, x, p, n, m, E), p, R

    return SimpleNamespace(shoot=shoot, residual_scale=resid.residual_scale, Nodes=Nodes)
