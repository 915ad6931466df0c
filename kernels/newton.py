"""Damped (quasi-)Newton iterations, one per rod, for a residual of nu unknowns: finite-
difference Jacobians, Broyden updates between them, backtracking, and the verdict (converged /
singular / non-finite / iteration cap) of every rod.

Nothing here knows what the unknowns mean: a shooting problem supplies the residual of a
trial point and of its probes (``Newton.res``), and calls ``update`` once per iteration.

  Newton, begin, refresh   the per-rod solver state; start a rod; rebuild J at x next
  solve_dense              Gaussian elimination with partial pivoting
  fd_step, probe_point     the finite-difference probes of a trial point
  new_jacobian             J from the probes' residuals (forward or central differences)
  take_point               the trial point becomes x: J rebuilt or Broyden-updated
  newton_step              the next trial point from J, x and r
  update                   one iteration's verdict and next trial point

``make_newton(dtype, nu, central)`` builds the functions for one precision and size.
"""

import functools
from types import SimpleNamespace

import warp as wp

from .layout import CONVERGED, MAX_ITER, NONFINITE, PRECISION_LIMITED, SINGULAR, STALLED


def probe_counts(nu: int, central: bool):
    """n_probes: the trial point + its finite-difference probes (2 nu central, nu forward);
    width: the residual table's columns (forward: + the base of approximate probes)."""
    n_probes = 1 + (2 * nu if central else nu)
    return n_probes, n_probes + (0 if central else 1)


@functools.cache
def make_newton_state(dtype, nu: int):
    """The ``Newton`` struct of one precision and size, ``begin`` and ``refresh``."""
    vec = wp.types.vector(nu, dtype)
    mat = wp.types.matrix((nu, nu), dtype)

    @wp.struct
    class Newton:
        """Per-rod solver state, (B,) unless noted. flags bit 1: x/r hold an accepted point;
        bit 2: J was built by finite differences at x (not a Broyden update); bit 4: the last
        trial re-evaluated x to refresh J."""

        x: wp.array(dtype=vec)  # accepted point (the solution once converged)
        r: wp.array(dtype=vec)  # residual at x
        J: wp.array(dtype=mat)  # Jacobian dr/dx at x
        xt: wp.array(dtype=vec)  # trial point
        res: wp.array2d(dtype=vec)  # (B, width) residuals of the trial point, its probes (and their base)
        active: wp.array(dtype=int)  # 1 while the rod is solving
        need_jac: wp.array(dtype=int)  # 1: evaluate the probes at the trial point
        flags: wp.array(dtype=int)
        lam: wp.array(dtype=dtype)  # backtracking factor
        status: wp.array(dtype=int)  # layout status bits
        iters: wp.array(dtype=int)
        n_shoot: wp.array(dtype=int)  # integrations spent
        resnorm: wp.array(dtype=dtype)  # scale |r| at x [m]
        n_active: wp.array(dtype=int)  # (1,) rods still solving after the last update

    @wp.func
    def begin(nw: Newton, i: int, x_from: wp.array(dtype=vec), fresh_jacobian: int):
        """Start rod i at x_from[i] (the trial point), with a finite-difference J first or not."""
        nw.xt[i] = x_from[i]
        nw.active[i] = 1
        nw.need_jac[i] = fresh_jacobian
        nw.flags[i] = 0
        nw.status[i] = 0
        nw.iters[i] = 0
        nw.n_shoot[i] = 0
        nw.lam[i] = dtype(1.0)
        nw.resnorm[i] = dtype(wp.inf)
        wp.atomic_add(nw.n_active, 0, 1)

    @wp.func
    def refresh(nw: Newton, i: int, it: int, max_iter: int):
        """Rebuild J by finite differences at the accepted point (next iteration)."""
        if it >= max_iter:
            nw.status[i] = MAX_ITER
            nw.active[i] = 0
            nw.flags[i] = 1 | 4
            return
        nw.need_jac[i] = 1
        nw.flags[i] = 1 | 4
        nw.xt[i] = nw.x[i]
        nw.lam[i] = dtype(1.0)
        wp.atomic_add(nw.n_active, 0, 1)

    return SimpleNamespace(Newton=Newton, vec=vec, mat=mat, begin=begin, refresh=refresh)


@functools.cache
def make_dense_solve(dtype, nu: int):
    """``solve_dense``: A x = b for one nu x nu system."""
    vec = wp.types.vector(nu, dtype)
    mat = wp.types.matrix((nu, nu), dtype)
    zero = dtype(0.0)
    pivot_rel = dtype(1.0e-13) if dtype == wp.float64 else dtype(1.0e-6)

    @wp.func
    def solve_dense(A: mat, b: vec):
        """Gaussian elimination with partial pivoting; ok = 0 for a (near) singular A."""
        scale = zero
        for i in range(nu):
            for k in range(nu):
                scale = wp.max(scale, wp.abs(A[i, k]))
        ok = int(1)
        if not (scale > zero) or not wp.isfinite(scale):
            ok = 0
            scale = dtype(1.0)
        tiny = scale * pivot_rel
        for c in range(nu):
            piv = c
            best = wp.abs(A[c, c])
            for r in range(c + 1, nu):
                if wp.abs(A[r, c]) > best:
                    best = wp.abs(A[r, c])
                    piv = r
            if best <= tiny:
                ok = 0
                best = scale
                A[c, c] = scale
            if piv != c:
                for k in range(nu):
                    tmp = A[c, k]
                    A[c, k] = A[piv, k]
                    A[piv, k] = tmp
                tb = b[c]
                b[c] = b[piv]
                b[piv] = tb
            for r in range(c + 1, nu):
                fac = A[r, c] / A[c, c]
                for k in range(c, nu):
                    A[r, k] = A[r, k] - fac * A[c, k]
                b[r] = b[r] - fac * b[c]
        x = vec()
        for ii in range(nu):
            i = nu - 1 - ii
            acc = b[i]
            for k in range(i + 1, nu):
                acc = acc - A[i, k] * x[k]
            x[i] = acc / A[i, i]
        return x, ok

    return SimpleNamespace(solve_dense=solve_dense)


@functools.cache
def make_probes(dtype, nu: int, central: bool):
    """The finite-difference probes of a trial point, and the Jacobian at an accepted one."""
    vec = wp.types.vector(nu, dtype)
    n_probes = probe_counts(nu, central)[0]
    fd_rel = dtype(1.5e-8) if dtype == wp.float64 else dtype(3.0e-4)
    st = make_newton_state(dtype, nu)
    Newton, mat = st.Newton, st.mat

    @wp.func
    def fd_step(x: dtype):
        return fd_rel * wp.max(dtype(1.0), wp.abs(x))

    @wp.func
    def probe_point(x: vec, j: int):
        """Probe j of the trial point x (j = 0 and j = n_probes, the base: x itself)."""
        if j >= n_probes:
            return x
        if j > nu:
            x[j - nu - 1] = x[j - nu - 1] - fd_step(x[j - nu - 1])
        elif j > 0:
            x[j - 1] = x[j - 1] + fd_step(x[j - 1])
        return x

    @wp.func
    def new_jacobian(nw: Newton, i: int, rt: vec, xi: vec, coarse: int):
        """J at the trial point xi from the residuals of its probes; coarse != 0: forward
        differences from the trial point evaluated like the probes (``res[i, n_probes]``)."""
        Jn = mat()
        base = rt
        if coarse != 0:
            base = nw.res[i, n_probes]
        for c in range(nu):
            col = (nw.res[i, c + 1] - base) / fd_step(xi[c])
            if wp.static(central):
                col = (nw.res[i, c + 1] - nw.res[i, c + 1 + nu]) / (dtype(2.0) * fd_step(xi[c]))
            for row in range(nu):
                Jn[row, c] = col[row]
        return Jn

    @wp.func
    def take_point(nw: Newton, i: int, rt: vec, nj: int, have_x: int, fresh: int, coarse: int):
        """The trial point becomes x: J rebuilt from its probes (``nj``) or Broyden-updated
        from the last x. Returns whether J is a finite-difference one."""
        xi = nw.xt[i]
        if nj != 0:
            nw.J[i] = new_jacobian(nw, i, rt, xi, coarse)
            fresh = 1
        elif have_x != 0:
            sx = xi - nw.x[i]
            Ji = nw.J[i]
            dr = (rt - nw.r[i]) - Ji * sx
            nw.J[i] = Ji + wp.outer(dr, sx) / wp.dot(sx, sx)
            fresh = 0
        nw.x[i] = xi
        nw.r[i] = rt
        return fresh

    return SimpleNamespace(fd_step=fd_step, probe_point=probe_point, new_jacobian=new_jacobian, take_point=take_point)


@functools.cache
def make_newton_step(dtype, nu: int):
    """``newton_step``: the next trial point from the accepted one."""
    # A Newton step this small (relative to x) from a fresh Jacobian: x is exact to working
    # precision, and the residual is at its round-off floor (stiff problems, e.g. small dt).
    x_floor = dtype(1.0e-12) if dtype == wp.float64 else dtype(1.0e-5)
    st = make_newton_state(dtype, nu)
    Newton, refresh = st.Newton, st.refresh
    solve_dense = make_dense_solve(dtype, nu).solve_dense

    @wp.func
    def newton_step(nw: Newton, i: int, fresh: int, it: int, max_iter: int, max_step: dtype):
        """The next trial point x + lam dx, J dx = -r (dx at most max_step long), or the verdict:
        singular, or converged to working precision (a tiny step from a fresh J)."""
        dx, ok = solve_dense(nw.J[i], -nw.r[i])
        if ok == 0 or not wp.isfinite(wp.length_sq(dx)):
            if fresh != 0:
                nw.status[i] = SINGULAR
                nw.active[i] = 0
                return
            refresh(nw, i, it, max_iter)
            return
        nd = wp.length(dx)
        if fresh != 0 and nd < x_floor * wp.max(dtype(1.0), wp.length(nw.x[i])):
            nw.status[i] = CONVERGED | PRECISION_LIMITED
            nw.active[i] = 0
            nw.flags[i] = 1 | 2
            return
        if nd > max_step:
            dx = dx * (max_step / nd)
        nw.xt[i] = nw.x[i] + nw.lam[i] * dx
        nw.flags[i] = 1 | (fresh << 1)
        wp.atomic_add(nw.n_active, 0, 1)

    return SimpleNamespace(newton_step=newton_step)


@functools.cache
def make_update(dtype, nu: int, central: bool):
    """``update``: one damped (quasi-)Newton iteration of a rod."""
    half = dtype(0.5)
    n_probes = probe_counts(nu, central)[0]
    st = make_newton_state(dtype, nu)
    Newton, refresh = st.Newton, st.refresh
    take_point = make_probes(dtype, nu, central).take_point
    newton_step = make_newton_step(dtype, nu).newton_step

    @wp.func
    def update(nw: Newton, i: int, scale: dtype, tol: dtype, max_iter: int, max_step: dtype, broyden: int,
               coarse: int):
        """One damped (quasi-)Newton update of rod i from the residuals in ``nw.res[i]``, and
        its verdict. ``scale`` turns |r| into the convergence measure (a length [m]).

        broyden = 1: rank-one updates of J between finite-difference rebuilds (a rebuild when
        a step fails to reduce |r|); broyden = 0: a finite-difference J at every new point.
        coarse != 0: the probes approximate the problem; their differences are taken from the
        trial point evaluated the same way (``res[i, n_probes]``, one more integration), and
        Broyden corrects the rest.
        """
        rt = nw.res[i, 0]
        fl = nw.flags[i]
        have_x = fl & 1
        fresh = (fl >> 1) & 1
        refreshed = (fl >> 2) & 1
        nj = nw.need_jac[i]
        nw.n_shoot[i] = nw.n_shoot[i] + 1 + (n_probes - 1) * nj + wp.where(coarse != 0, 1, 0)
        it = nw.iters[i] + 1
        nw.iters[i] = it
        finite = wp.isfinite(wp.length_sq(rt))
        better = finite
        if have_x != 0 and refreshed == 0:
            better = finite and wp.length(rt) < wp.length(nw.r[i])
        if better:
            fresh = take_point(nw, i, rt, nj, have_x, fresh, coarse)
            have_x = 1
            nw.lam[i] = dtype(1.0)
            rn = scale * wp.length(rt)
            nw.resnorm[i] = rn
            if rn < tol:
                nw.status[i] = CONVERGED
                nw.active[i] = 0
                nw.flags[i] = 1
                return
        elif have_x == 0:
            nw.status[i] = NONFINITE
            nw.active[i] = 0
            return
        elif fresh == 0:
            refresh(nw, i, it, max_iter)  # a Broyden Jacobian led astray
            return
        else:
            nw.lam[i] = nw.lam[i] * half
            if nw.lam[i] < dtype(1.0e-4):
                nw.status[i] = STALLED
                nw.active[i] = 0
                return
        nw.need_jac[i] = 1 - broyden  # plain Newton rebuilds J at every new point
        if it >= max_iter:
            nw.status[i] = MAX_ITER
            nw.active[i] = 0
            nw.flags[i] = have_x | (fresh << 1)
            return
        newton_step(nw, i, fresh, it, max_iter, max_step)

    return SimpleNamespace(update=update)


@functools.cache
def make_newton(dtype, nu: int, central: bool):
    """central: Jacobian by central differences (2 nu probes) instead of forward (nu). With
    forward differences the residual table has one more column: the trial point evaluated like
    the probes, the base of their differences when the probes are a cheaper approximation of the
    problem (``update(..., coarse)``, coarse != 0)."""
    st = make_newton_state(dtype, nu)
    pr = make_probes(dtype, nu, central)
    n_probes, width = probe_counts(nu, central)
    return SimpleNamespace(Newton=st.Newton, vec=st.vec, mat=st.mat, n_probes=n_probes, width=width, nu=nu,
                           probe_point=pr.probe_point, new_jacobian=pr.new_jacobian,
                           solve_dense=make_dense_solve(dtype, nu).solve_dense,
                           update=make_update(dtype, nu, central).update, begin=st.begin, fd_step=pr.fd_step)
