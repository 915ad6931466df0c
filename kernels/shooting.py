"""Batched shooting of the rod ODE: statics, and one BDF-alpha time step of dynamics.

Unknowns per rod, scaled to O(1): x = [n(0) L^2 / EI, m(0) L / EI]. Residual, scaled the
same way: r = [(n(L+) - F_tip) L^2 / EI, (m(L+) - L_tip) L / EI], so ``L |r|`` is a
tip-displacement-like error in metres (the convergence test). The Newton machinery
(kernels/newton.py) sees only x and r.

Two drivers of the same Newton update: ``solve`` runs the whole Newton loop of a rod in one
thread (probes one after another: the fastest on a CPU, where a launch runs its threads in
turn, and no host round trip at all), ``probe`` + ``update`` run one iteration with a
thread per (rod, probe) (for GPUs; the host repeats them, or a CUDA graph does).
"""

import functools
from types import SimpleNamespace

import warp as wp

from .layout import (
    CONVERGED,
    FORCE_SCALE,
    LENGTH,
    MAX_ITER,
    MOMENT_SCALE,
    TIP_F,
    TIP_M,
    TO_BASE,
    TO_END,
    TO_FREE,
    TO_PATH,
    TO_TURN,
)
from .newton import make_newton
from .rod import ALL, Features, make_rod_funcs

INTEGRATORS = ("euler", "midpoint", "rk4")
STAGES = {"euler": 1, "midpoint": 2, "rk4": 4}
N_BASE = 6  # n(0), m(0); + one tension per displacement-controlled tendon


@functools.cache
def make_shooting_kernels(dtype, integrator: str, model: str, dynamic: bool = False, rod: str = "cosserat",
                          features: Features = ALL):
    """Shooting and Newton kernels for one precision, integrator, tendon model and physics.

    ``dynamic``: one BDF-alpha time step (reads ``Step``); otherwise statics. ``rod`` and
    ``features``: see ``make_rod_funcs``.

    Jacobian probes: forward differences in statics (6 probes); central differences in
    dynamics (12 probes), where inertia at small dt amplifies bending along s by up to
    ~1e8 and the second-order term of a forward difference swamps the axial rows (measured:
    forward differences stall Newton at dt = 2.5e-4 s on a 0.5 m steel rod).
    """
    if integrator not in INTEGRATORS:
        raise ValueError(f"integrator must be one of {INTEGRATORS}, got {integrator!r}")
    rf = make_rod_funcs(dtype, model, dynamic, rod, features)
    vec3, mat33 = rf.vec3, rf.mat33
    Model, Control, Step = rf.Model, rf.Control, rf.Step
    nu = N_BASE + features.displaced
    nt = make_newton(dtype, nu, dynamic)
    Newton, vecu = nt.Newton, nt.vec
    kvec, evec = rf.kvec, rf.evec
    K = rf.K
    tstate = rf.tstate
    n_probes = nt.n_probes
    width = nt.width
    # One Warp module per variant and driver: a solve compiles only what its device runs.
    key = (f"{wp.types.type_repr(dtype)}_{integrator}_{model}_{'dyn' if dynamic else 'static'}_{rod}_"
           + "".join(str(int(f)) for f in features[:4]) + ("" if features.kinks else "_nokink")
           + (f"_k{features.tendons}" if features.tendons else "") + ("_mu" if features.friction else "")
           + (f"_d{features.displaced}" if features.displaced else "") + ("_spline" if features.spline else ""))
    modules = {grp: f"tdcr_warp_{grp}_{key}" for grp in ("fused", "probes", "evaluate")}
    rk4 = integrator == "rk4"
    midpoint = integrator == "midpoint"
    stages = STAGES[integrator]
    zero = dtype(0.0)
    half = dtype(0.5)
    sixth = dtype(1.0 / 6.0)
    third = dtype(1.0 / 3.0)  # from Python: a literal inside a kernel would be float32

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

    @wp.func
    def stage_c(st: int):
        """Where stage st is evaluated, as a fraction of the interval."""
        if wp.static(rk4):
            return wp.where(st == 0, zero, wp.where(st == 3, dtype(1.0), half))
        if wp.static(midpoint):
            return wp.where(st == 0, zero, half)
        return zero

    @wp.func
    def stage_w(st: int):
        """The weight of stage st (RK4: 1/6, 1/3, 1/3, 1/6; midpoint: 0, 1; Euler: 1)."""
        if wp.static(rk4):
            return wp.where(st == 0 or st == 3, sixth, third)
        if wp.static(midpoint):
            return wp.where(st == 0, zero, dtype(1.0))
        return dtype(1.0)

    @wp.func
    def store_tensions(md: Model, ct: Control, b: int, out: Nodes, t0: kvec, E: evec, node: int, slot: int):
        """The tensions just distal of ``node`` (store pass, tendon states only; ``slot``: an
        evaluation there, whose remembered tension a stick-slip solve reads)."""
        if wp.static(tstate):
            tau, g, h = rf.tensions(md, ct, b, t0, E, slot, zero, zero)
            for k in range(md.n_tendons):
                out.taun[b, node, k] = tau[k]

    @wp.func
    def store_end_tensions(md: Model, ct: Control, b: int, out: Nodes, t0: kvec, E: evec, node: int, slot: int):
        """The tension of each tendon ending at ``node``, just before its end."""
        if wp.static(tstate):
            tau, g, h = rf.tensions(md, ct, b, t0, E, slot, zero, zero)
            for k in range(md.n_tendons):
                if rf.term_node(md, b, k) == node:
                    out.tend[b, k, TO_END] = tau[k]

    @wp.func
    def shoot(x: vecu, md: Model, ct: Control, sp: Step, b: int, store: int, coarse: int, out: Nodes):
        """Integrate base to tip from the scaled unknowns x; return the scaled residual and the
        tip's position and orientation.
        coarse = 1 (statics, never with store): steps over two intervals wherever no load sits
        on the node between them, about half the work (the probes of a first Jacobian)."""
        fs = md.rod[rf.row(b, md.rod), FORCE_SCALE]
        ms = md.rod[rf.row(b, md.rod), MOMENT_SCALE]
        p = vec3()
        R = wp.identity(3, dtype)
        n = vec3(x[0], x[1], x[2]) * fs
        m = vec3(x[3], x[4], x[5]) * ms
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
        n, m, E = rf.node_jumps(md, ct, sp, b, zero, R, n, m, q, w, t0, E, 0, jslot, jslot + 1, store)
        if store != 0:
            store_tensions(md, ct, b, out, t0, E, 0, 0)
        k = int(0)
        while k < n_int:
            k1 = k + 1
            if coarse != 0 and k + 2 <= n_int:
                if rf.node_busy(md, b, k1) == 0:
                    k1 = k + 2
            s = md.grid[ig, k]
            h = md.grid[ig, k1] - s
            sl = k * stages
            # Explicit stages, each from the last: y_i = y + c_i h k_(i-1), y <- y + h sum_i w_i k_i.
            # A runtime stage count keeps one call site of the right-hand side (compile time).
            Ap = vec3()
            AR = mat33()
            An = vec3()
            Am = vec3()
            Aq = vec3()
            Aw = vec3()
            AE = evec()
            kE = evec()
            kp = vec3()
            kR = mat33()
            kn = vec3()
            km = vec3()
            kq = vec3()
            kw = vec3()
            for st in range(stages + 0 * n_int):
                ch = stage_c(st) * h
                kp, kR, kn, km, kq, kw, kE = rf.rhs(md, ct, sp, b, s + ch, p + ch * kp, R + ch * kR, n + ch * kn,
                                                    m + ch * km, q + ch * kq, w + ch * kw, t0, E + ch * kE, k,
                                                    sl + st, store)
                wt = stage_w(st)
                Ap += wt * kp
                AR += wt * kR
                An += wt * kn
                Am += wt * km
                if wp.static(dynamic):
                    Aq += wt * kq
                    Aw += wt * kw
                if wp.static(tstate):
                    AE += wt * kE
            p = p + h * Ap
            R = R + h * AR
            n = n + h * An
            m = m + h * Am
            if wp.static(dynamic):
                q = q + h * Aq
                w = w + h * Aw
            if wp.static(tstate):
                E = E + h * AE
            R = rf.orthonormalize(R)
            if store != 0:
                store_node(out, b, k1, p, R, n, m, q, w)
                dev = wp.transpose(R) * R - wp.identity(3, dtype)
                for i in range(3):
                    for j in range(3):
                        orth = wp.max(orth, wp.abs(dev[i, j]))
            js = jslot + 2 * k1
            if store != 0:
                store_end_tensions(md, ct, b, out, t0, E, k1, js)
            n, m, E = rf.node_jumps(md, ct, sp, b, md.grid[ig, k1], R, n, m, q, w, t0, E, k1, js, js + 1, store)
            if store != 0:  # the first stage of the next interval is just distal of node k1
                store_tensions(md, ct, b, out, t0, E, k1, wp.where(k1 < n_int, k1 * stages, js + 1))
            k = k1
        if store != 0:
            out.orth[b] = orth
            if wp.static(tstate):
                for kk in range(md.n_tendons):
                    out.tend[b, kk, TO_BASE] = t0[kk]
                    out.tend[b, kk, TO_PATH] = E[K + kk]
                    out.tend[b, kk, TO_FREE] = E[2 * K + kk]
                    out.tend[b, kk, TO_TURN] = E[kk]
        rn = (n - rf.rvec(md, b, TIP_F)) / fs
        rm = (m - rf.rvec(md, b, TIP_M)) / ms
        res = vecu()
        for i in range(3):
            res[i] = rn[i]
            res[3 + i] = rm[i]
        return rf.length_residuals(md, ct, b, x, E, res), p, R

    @wp.func
    def residual_scale(md: Model, b: int):
        return md.rod[rf.row(b, md.rod), LENGTH]

    @wp.func
    def coarse_now(nw: Newton, b: int, coarse_jacobian: int, broyden: int):
        """1 where the probes of this iteration may run coarse: the first Jacobian of a Broyden
        solve (a rebuild after a failed step, or plain Newton, uses the full grid)."""
        if wp.static(dynamic):
            return 0
        if coarse_jacobian != 0 and broyden != 0 and nw.need_jac[b] != 0 and nw.iters[b] == 0:
            return 1
        return 0

    @wp.func
    def evaluation(nw: Newton, b: int, j: int, coarse: int):
        """What evaluation j of rod b is this iteration: (store the shape, coarse), or skip (-1)."""
        if j == 0:
            return 1
        if nw.need_jac[b] == 0 or (j == n_probes and coarse == 0):
            return -1
        return 0

    @wp.func
    def needs_final_shape(nw: Newton, b: int):
        """A rod that stopped without converging shows the shape of its last accepted point
        (a converged rod stored its shape at its last, accepted, evaluation)."""
        return (nw.status[b] & CONVERGED) == 0 and (nw.flags[b] & 1) != 0

    @wp.kernel(module=modules["fused"], enable_backward=False)
    def solve_kernel(md: Model, ct: Control, sp: Step, nw: Newton, out: Nodes, x_from: wp.array(dtype=vecu),
                     fresh_jacobian: int, tol: dtype, max_iter: int, max_step: dtype, broyden: int,
                     coarse_jacobian: int, mask: wp.array(dtype=int)):
        """The whole Newton loop of rod b (``mask[b]`` = 1) in one thread, from x_from[b]. One
        call site of the integrator (compile time): the final shape of a rod that stopped without
        converging is one more pass of the loop, at its last accepted point."""
        b = wp.tid()
        if mask[b] == 0:
            return
        nt.begin(nw, b, x_from, fresh_jacobian)
        for _it in range(max_iter + 1):
            solving = nw.active[b]
            x = nw.xt[b]
            n_eval = nw.res.shape[1]
            coarse = coarse_now(nw, b, coarse_jacobian, broyden)
            if solving == 0:
                if not needs_final_shape(nw, b):
                    break
                x = nw.x[b]
                n_eval = 1
            for j in range(n_eval):  # a runtime bound: one copy of the integrator, not n_probes
                e = evaluation(nw, b, j, coarse)
                if e >= 0:
                    r, p_tip, R_tip = shoot(nt.probe_point(x, j), md, ct, sp, b, e, coarse * (1 - e), out)
                    nw.res[b, j] = r
            if solving == 0:
                break
            nt.update(nw, b, residual_scale(md, b), tol, max_iter, max_step, broyden, coarse)

    @wp.kernel(module=modules["probes"], enable_backward=False)
    def probe_kernel(md: Model, ct: Control, sp: Step, nw: Newton, out: Nodes, broyden: int, coarse_jacobian: int):
        """Thread (rod, j): j = 0 integrates the trial point (and stores it), j >= 1 its
        finite-difference probes (and their base)."""
        tid = wp.tid()
        b = tid // width
        j = tid - b * width
        if nw.active[b] == 0:
            return
        coarse = coarse_now(nw, b, coarse_jacobian, broyden)
        e = evaluation(nw, b, j, coarse)
        if e >= 0:
            r, p_tip, R_tip = shoot(nt.probe_point(nw.xt[b], j), md, ct, sp, b, e, coarse * (1 - e), out)
            nw.res[b, j] = r

    @wp.kernel(module=modules["probes"], enable_backward=False)
    def update_kernel(md: Model, nw: Newton, tol: dtype, max_iter: int, max_step: dtype, broyden: int,
                      coarse_jacobian: int):
        b = wp.tid()
        if nw.active[b] != 0:
            nt.update(nw, b, residual_scale(md, b), tol, max_iter, max_step, broyden,
                      coarse_now(nw, b, coarse_jacobian, broyden))

    @wp.kernel(module=modules["probes"], enable_backward=False)
    def finish_kernel(md: Model, ct: Control, sp: Step, nw: Newton, out: Nodes, mask: wp.array(dtype=int)):
        b = wp.tid()
        if mask[b] == 0:
            return
        if nw.active[b] != 0:  # out of host iterations
            nw.status[b] = MAX_ITER
            nw.active[b] = 0
        if needs_final_shape(nw, b):
            r, p_tip, R_tip = shoot(nw.x[b], md, ct, sp, b, 1, 0, out)

    @wp.kernel(module=modules["probes"], enable_backward=False)
    def begin_kernel(nw: Newton, x_from: wp.array(dtype=vecu), fresh_jacobian: int, mask: wp.array(dtype=int)):
        b = wp.tid()
        if mask[b] != 0:
            nt.begin(nw, b, x_from, fresh_jacobian)

    @wp.kernel(module=modules["evaluate"], enable_backward=False)
    def evaluate_kernel(md: Model, ct: Control, sp: Step, x: wp.array(dtype=vecu), out: Nodes,
                        res: wp.array(dtype=vecu), tip_p: wp.array(dtype=vec3), tip_R: wp.array(dtype=mat33),
                        store: int):
        """One integration per rod from x: its residual and tip pose, and with ``store`` its shape
        (and the dynamics slots) in ``out`` (without, a probe of a sensitivity,
        tdcr_warp/physics/sensitivity.py, at the cost of the integration alone)."""
        b = wp.tid()
        r, p_tip, R_tip = shoot(x[b], md, ct, sp, b, store, 0, out)
        res[b] = r
        tip_p[b] = p_tip
        tip_R[b] = R_tip

    return SimpleNamespace(solve=solve_kernel, probe=probe_kernel, update=update_kernel, finish=finish_kernel,
                           begin=begin_kernel, evaluate=evaluate_kernel, Model=Model, Control=Control, Step=Step,
                           Nodes=Nodes, Newton=Newton, vec3=vec3, mat33=mat33, vecu=vecu, matu=nt.mat,
                           stages=stages, n_probes=n_probes, width=nt.width, nu=nu, K=K, tstate=tstate,
                           friction=features.friction, modules=modules)
