"""Batched shooting and Newton kernels: statics, and one BDF-alpha time step of dynamics.

Unknowns per rod, scaled to O(1): x = [n(0) L^2 / EI, m(0) L / EI]. Residual, scaled the
same way: r = [(n(L+) - F_tip) L^2 / EI, (m(L+) - L_tip) L / EI], so ``L |r|`` is a
tip-displacement-like error in metres (the convergence test).
"""

import functools
from types import SimpleNamespace

import warp as wp

from .layout import (CONVERGED, KBT, LENGTH, MAX_ITER, NONFINITE, PRECISION_LIMITED, SINGULAR, STALLED, TIP_F,
                     TIP_M)
from .rod import ALL, Features, make_rod_funcs

INTEGRATORS = ("euler", "midpoint", "rk4")
STAGES = {"euler": 1, "midpoint": 2, "rk4": 4}


@functools.cache
def make_shooting_kernels(dtype, integrator: str, model: str, dynamic: bool = False, rod: str = "cosserat",
                          features: Features = ALL):
    """Shooting and Newton kernels for one precision, integrator, tendon model and physics.

    ``dynamic``: one BDF-alpha time step (needs ``RodArgs.dyn``, ``hist``, ``ycur``, ``c0``);
    otherwise statics (those fields are not read). ``rod`` and ``features``: see ``make_rod_funcs``.

    Jacobian probes: forward differences in statics (6 probes); central differences in
    dynamics (12 probes), where inertia at small dt amplifies bending along s by up to
    ~1e8 and the second-order term of a forward difference swamps the axial rows (measured:
    forward differences stall Newton at dt = 2.5e-4 s on a 0.5 m steel rod).
    """
    if integrator not in INTEGRATORS:
        raise ValueError(f"integrator must be one of {INTEGRATORS}, got {integrator!r}")
    rf = make_rod_funcs(dtype, model, dynamic, rod, features)
    vec3, mat33, RodArgs = rf.vec3, rf.mat33, rf.RodArgs
    vec6 = wp.types.vector(6, dtype)
    mat66 = wp.types.matrix((6, 6), dtype)
    rk4 = integrator == "rk4"
    midpoint = integrator == "midpoint"
    stages = STAGES[integrator]
    zero = dtype(0.0)
    half = dtype(0.5)
    sixth = dtype(1.0 / 6.0)
    two = dtype(2.0)
    f64 = dtype == wp.float64
    central = dynamic
    n_probes = 13 if central else 7  # the trial point + its finite-difference probes
    fd_rel = dtype(1.5e-8) if f64 else dtype(3.0e-4)
    pivot_rel = dtype(1.0e-13) if f64 else dtype(1.0e-6)
    # A Newton step this small (relative to x) from a fresh Jacobian: x is exact to working
    # precision, and the residual is at its round-off floor (stiff problems, e.g. small dt).
    x_floor = dtype(1.0e-12) if f64 else dtype(1.0e-5)

    @wp.func
    def fd_step(x: dtype):
        return fd_rel * wp.max(dtype(1.0), wp.abs(x))

    @wp.struct
    class Shapes:
        """Per-node outputs of the evaluation at the trial point, (B, N+1) each."""

        p: wp.array2d(dtype=vec3)
        R: wp.array2d(dtype=mat33)
        n: wp.array2d(dtype=vec3)
        m: wp.array2d(dtype=vec3)
        q: wp.array2d(dtype=vec3)  # dynamics only
        w: wp.array2d(dtype=vec3)  # dynamics only
        orth: wp.array(dtype=dtype)  # max |R^T R - I| over the nodes

    @wp.func
    def store_node(out: Shapes, b: int, k: int, p: vec3, R: mat33, n: vec3, m: vec3, q: vec3, w: vec3):
        out.p[b, k] = p
        out.R[b, k] = R
        out.n[b, k] = n
        out.m[b, k] = m
        if wp.static(dynamic):
            out.q[b, k] = q
            out.w[b, k] = w

    @wp.func
    def shoot(x: vec6, a: RodArgs, b: int, store: int, out: Shapes):
        """Integrate base to tip from the scaled unknowns x; return the scaled residual."""
        L = a.rod[b % a.rod.shape[0], LENGTH]
        EI = a.rod[b % a.rod.shape[0], KBT]
        fs = EI / (L * L)
        ms = EI / L
        p = vec3()
        R = wp.identity(3, dtype)
        n = vec3(x[0], x[1], x[2]) * fs
        m = vec3(x[3], x[4], x[5]) * ms
        q = vec3()
        w = vec3()
        ig = b % a.grid.shape[0]
        n_int = a.grid.shape[1] - 1
        jslot = n_int * stages  # first of the two slots per node used by the jumps
        orth = zero
        if store != 0:
            store_node(out, b, 0, p, R, n, m, q, w)
        n, m = rf.node_jumps(a, b, zero, R, n, m, q, w, 0, jslot, jslot + 1, store)
        for k in range(n_int):
            s = a.grid[ig, k]
            h = a.grid[ig, k + 1] - s
            sl = k * stages
            dp1, dR1, dn1, dm1, dq1, dw1 = rf.rhs(a, b, s, p, R, n, m, q, w, k, sl, store)
            if wp.static(rk4):
                hh = half * h
                sm = s + hh
                dp2, dR2, dn2, dm2, dq2, dw2 = rf.rhs(a, b, sm, p + hh * dp1, R + hh * dR1, n + hh * dn1,
                                                      m + hh * dm1, q + hh * dq1, w + hh * dw1, k, sl + 1,
                                                      store)
                dp3, dR3, dn3, dm3, dq3, dw3 = rf.rhs(a, b, sm, p + hh * dp2, R + hh * dR2, n + hh * dn2,
                                                      m + hh * dm2, q + hh * dq2, w + hh * dw2, k, sl + 2,
                                                      store)
                dp4, dR4, dn4, dm4, dq4, dw4 = rf.rhs(a, b, s + h, p + h * dp3, R + h * dR3, n + h * dn3,
                                                      m + h * dm3, q + h * dq3, w + h * dw3, k, sl + 3,
                                                      store)
                hs = h * sixth
                p = p + hs * (dp1 + two * (dp2 + dp3) + dp4)
                R = R + hs * (dR1 + two * (dR2 + dR3) + dR4)
                n = n + hs * (dn1 + two * (dn2 + dn3) + dn4)
                m = m + hs * (dm1 + two * (dm2 + dm3) + dm4)
                if wp.static(dynamic):
                    q = q + hs * (dq1 + two * (dq2 + dq3) + dq4)
                    w = w + hs * (dw1 + two * (dw2 + dw3) + dw4)
            elif wp.static(midpoint):
                hh = half * h
                dp2, dR2, dn2, dm2, dq2, dw2 = rf.rhs(a, b, s + hh, p + hh * dp1, R + hh * dR1, n + hh * dn1,
                                                      m + hh * dm1, q + hh * dq1, w + hh * dw1, k, sl + 1,
                                                      store)
                p = p + h * dp2
                R = R + h * dR2
                n = n + h * dn2
                m = m + h * dm2
                if wp.static(dynamic):
                    q = q + h * dq2
                    w = w + h * dw2
            else:
                p = p + h * dp1
                R = R + h * dR1
                n = n + h * dn1
                m = m + h * dm1
                if wp.static(dynamic):
                    q = q + h * dq1
                    w = w + h * dw1
            R = rf.orthonormalize(R)
            if store != 0:
                store_node(out, b, k + 1, p, R, n, m, q, w)
                E = wp.transpose(R) * R - wp.identity(3, dtype)
                for i in range(3):
                    for j in range(3):
                        orth = wp.max(orth, wp.abs(E[i, j]))
            js = jslot + 2 * (k + 1)
            n, m = rf.node_jumps(a, b, a.grid[ig, k + 1], R, n, m, q, w, k + 1, js, js + 1, store)
        if store != 0:
            out.orth[b] = orth
        rn = (n - rf.rvec(a, b, TIP_F)) / fs
        rm = (m - rf.rvec(a, b, TIP_M)) / ms
        return vec6(rn[0], rn[1], rn[2], rm[0], rm[1], rm[2])

    @wp.kernel(module="unique", enable_backward=False)
    def shoot_kernel(
        a: RodArgs,
        x_in: wp.array(dtype=vec6),
        active_in: wp.array(dtype=int),
        need_jac_in: wp.array(dtype=int),
        res_out: wp.array2d(dtype=vec6),
        out: Shapes,
    ):
        """Thread (rod, j): j = 0 integrates the trial point (and stores it), j >= 1 its
        finite-difference probes."""
        tid = wp.tid()
        b = tid // n_probes
        j = tid - b * n_probes
        if active_in[b] == 0:
            return
        if j > 0 and need_jac_in[b] == 0:
            return
        x = x_in[b]
        store = int(1)
        if j > 6:
            x[j - 7] = x[j - 7] - fd_step(x[j - 7])
            store = 0
        elif j > 0:
            x[j - 1] = x[j - 1] + fd_step(x[j - 1])
            store = 0
        res_out[b, j] = shoot(x, a, b, store, out)

    @wp.func
    def solve6(A: mat66, b: vec6):
        """Gaussian elimination with partial pivoting; ok = 0 for a (near) singular A."""
        scale = zero
        for i in range(6):
            for k in range(6):
                scale = wp.max(scale, wp.abs(A[i, k]))
        ok = int(1)
        if not (scale > zero) or not wp.isfinite(scale):
            ok = 0
            scale = dtype(1.0)
        tiny = scale * pivot_rel
        for c in range(6):
            piv = c
            best = wp.abs(A[c, c])
            for r in range(c + 1, 6):
                if wp.abs(A[r, c]) > best:
                    best = wp.abs(A[r, c])
                    piv = r
            if best <= tiny:
                ok = 0
                best = scale
                A[c, c] = scale
            if piv != c:
                for k in range(6):
                    tmp = A[c, k]
                    A[c, k] = A[piv, k]
                    A[piv, k] = tmp
                tb = b[c]
                b[c] = b[piv]
                b[piv] = tb
            for r in range(c + 1, 6):
                fac = A[r, c] / A[c, c]
                for k in range(c, 6):
                    A[r, k] = A[r, k] - fac * A[c, k]
                b[r] = b[r] - fac * b[c]
        x = vec6()
        for ii in range(6):
            i = 5 - ii
            acc = b[i]
            for k in range(i + 1, 6):
                acc = acc - A[i, k] * x[k]
            x[i] = acc / A[i, i]
        return x, ok

    @wp.kernel(module="unique", enable_backward=False)
    def newton_kernel(
        rod: wp.array2d(dtype=dtype),
        res_in: wp.array2d(dtype=vec6),
        tol: dtype,
        max_iter: int,
        max_step: dtype,
        broyden: int,
        x: wp.array(dtype=vec6),
        r: wp.array(dtype=vec6),
        J: wp.array(dtype=mat66),
        xt: wp.array(dtype=vec6),
        active: wp.array(dtype=int),
        need_jac: wp.array(dtype=int),
        flags: wp.array(dtype=int),
        lam: wp.array(dtype=dtype),
        status: wp.array(dtype=int),
        iters: wp.array(dtype=int),
        n_shoot: wp.array(dtype=int),
        resnorm: wp.array(dtype=dtype),
        n_active: wp.array(dtype=int),
    ):
        """One damped (quasi-)Newton update per rod from the residuals of ``shoot_kernel``.

        broyden = 1: rank-one updates of J between finite-difference rebuilds (a rebuild when
        a step fails to reduce |r|); broyden = 0: a finite-difference J at every new point.

        flags bit 1: x/r hold an accepted point; bit 2: J was built by finite differences
        at x (not a Broyden update); bit 4: the last trial re-evaluated x to refresh J.
        """
        i = wp.tid()
        if active[i] == 0:
            return
        L = rod[i % rod.shape[0], LENGTH]
        rt = res_in[i, 0]
        fl = flags[i]
        have_x = fl & 1
        fresh = (fl >> 1) & 1
        refresh = (fl >> 2) & 1
        nj = need_jac[i]
        n_shoot[i] = n_shoot[i] + 1 + (n_probes - 1) * nj
        it = iters[i] + 1
        iters[i] = it
        finite = wp.isfinite(wp.length_sq(rt))
        accept = finite
        if have_x != 0 and refresh == 0:
            accept = finite and wp.length(rt) < wp.length(r[i])
        if accept:
            xi = xt[i]
            if nj != 0:
                Jn = mat66()
                for c in range(6):
                    col = (res_in[i, c + 1] - rt) / fd_step(xi[c])
                    if wp.static(central):
                        col = (res_in[i, c + 1] - res_in[i, c + 7]) / (dtype(2.0) * fd_step(xi[c]))
                    for row in range(6):
                        Jn[row, c] = col[row]
                J[i] = Jn
                fresh = 1
            elif have_x != 0:
                sx = xi - x[i]
                Ji = J[i]
                dr = (rt - r[i]) - Ji * sx
                J[i] = Ji + wp.outer(dr, sx) / wp.dot(sx, sx)
                fresh = 0
            x[i] = xi
            r[i] = rt
            have_x = 1
            lam[i] = dtype(1.0)
            rn = L * wp.length(rt)
            resnorm[i] = rn
            if rn < tol:
                status[i] = CONVERGED
                active[i] = 0
                flags[i] = 1
                return
        elif have_x == 0:
            status[i] = NONFINITE
            active[i] = 0
            return
        elif fresh == 0:
            # A Broyden Jacobian led astray: rebuild it by finite differences at x.
            need_jac[i] = 1
            flags[i] = 1 | 4
            xt[i] = x[i]
            lam[i] = dtype(1.0)
            wp.atomic_add(n_active, 0, 1)
            return
        else:
            lam[i] = lam[i] * half
            if lam[i] < dtype(1.0e-4):
                status[i] = STALLED
                active[i] = 0
                return
        need_jac[i] = 1 - broyden  # plain Newton rebuilds J at every new point
        if it >= max_iter:
            status[i] = MAX_ITER
            active[i] = 0
            flags[i] = have_x | (fresh << 1)
            return
        dx, ok = solve6(J[i], -r[i])
        if ok == 0 or not wp.isfinite(wp.length_sq(dx)):
            if fresh != 0:
                status[i] = SINGULAR
                active[i] = 0
                return
            need_jac[i] = 1
            flags[i] = 1 | 4
            xt[i] = x[i]
            wp.atomic_add(n_active, 0, 1)
            return
        nd = wp.length(dx)
        if fresh != 0 and nd < x_floor * wp.max(dtype(1.0), wp.length(x[i])):
            status[i] = CONVERGED | PRECISION_LIMITED
            active[i] = 0
            flags[i] = 1 | 2
            return
        if nd > max_step:
            dx = dx * (max_step / nd)
        xt[i] = x[i] + lam[i] * dx
        flags[i] = 1 | (fresh << 1)
        wp.atomic_add(n_active, 0, 1)

    return SimpleNamespace(shoot=shoot_kernel, newton=newton_kernel, RodArgs=RodArgs, Shapes=Shapes,
                           vec3=vec3, mat33=mat33, vec6=vec6, mat66=mat66, stages=stages,
                           n_probes=n_probes)


@functools.cache
def make_history_kernel(dtype):
    """BDF-alpha history update per (rod, slot, quantity) after a converged time step."""
    vec3 = wp.types.vector(3, dtype)

    @wp.kernel(module="unique", enable_backward=False)
    def advance_history(
        ycur: wp.array3d(dtype=vec3),
        yprev: wp.array3d(dtype=vec3),
        hist: wp.array3d(dtype=vec3),
        ok: wp.array(dtype=int),
        c0: dtype,
        c1: dtype,
        c2: dtype,
        d1: dtype,
        at_rest: int,
    ):
        """y_h <- c1 y(i) + c2 y(i-1) + d1 y_t(i), y_t(i) = c0 y(i) + y_h; y(i-1) <- y(i).

        at_rest = 1 starts from equilibrium: y(i-1) = y(i) and y_t(i) = 0, so that the next
        step sees y_t = c0 y + y_h = 0 at the same state.
        """
        b, sl, c = wp.tid()
        if ok[b] == 0:
            return
        y = ycur[b, sl, c]
        yt = c0 * y + hist[b, sl, c]
        yp = yprev[b, sl, c]
        if at_rest != 0:
            yt = vec3()
            yp = y
        hist[b, sl, c] = c1 * y + c2 * yp + d1 * yt
        yprev[b, sl, c] = y

    return advance_history
