"""The elastic stability verdict of solved static rods, on the device: one thread per rod
integrates its solution and the 6 finite-difference probes of the base wrench side by side and
counts, node by node, the conjugate points of the clamp (tdcr_warp/physics/stability.py has the
theory).

The probes span the Jacobi fields that vanish at the clamp (U(0) = 0, the Dirichlet plane):
U the change of position and rotation, V the change of the total internal force and moment
(rod and tendons), symplectically scaled. The eigenvalues p of the symmetric P = V U^-1 give
phases phi = arccot p in [0, pi); a phase passes a multiple of pi where U is singular (a
conjugate point) and only forwards (the Legendre condition). Tracked from the base (all
phases 0) to the tip as continuous lifts, the index of the second variation with a free tip is

    index = sum_k floor((phi_k(L) - NEUTRAL) / pi + 1/2)

(the conjugate points inside, and at the tip the negative eigenvalues of P(L)): a phase within
NEUTRAL of an odd multiple of pi / 2 at the tip is a neutral mode (a symmetry), not a negative
one. P comes from the chart (U cos b + V sin b, V cos b - U sin b) of the best-conditioned of 4
angles b, so a singular U (a crossing, the inextensible rod's axial direction) needs no care.

A rod solved in segments (multiple shooting) has its fields carried over the segments: at every
node a pass reaches, the probes restart from the solution plus a small multiple of an orthonormal
basis of the fields (``restart``: the same plane, fields that grow along the rod stay resolved),
and at each later segment's start the solution restarts from the solved shape (tdcr_warp/physics/
stability.py, ``restart_nodes``).

  make_verdict_kernel   the kernel of one static variant (module "evaluate")
  kernels/dense6.py     its small dense linear algebra (6 x 6)
"""

import functools
import math
from types import SimpleNamespace

import warp as wp

from .backbone import make_backbone
from .dense6 import make_dense6
from .drivers import module_names
from .integration import N_BASE, make_nodes, make_residual
from .layout import FORCE_SCALE, KBT, KSE, LENGTH, MOMENT_SCALE
from .nodes import make_rod_funcs
from .segments import segmentable
from .stepping import make_interval
from .strains import make_strains
from .structs import make_rows, make_structs, tendon_vectors
from .tendons import make_routes
from .variants import STAGES, Features

CHARTS = 4  # angles b = j pi / CHARTS tried for the best-conditioned chart
CHART_MIN = 0.05  # a chart is kept from node to node while its Hadamard ratio stays above this
U_SLOT, V_SLOT, A_SLOT, X_SLOT, D_SLOT = 0, 1, 2, 3, 4  # the matrices of a thread's work array (B, 5, 6, 6)
SHEAR_STEPS = 16  # the disk model: a disk's jump of V, followed in this many steps


@functools.cache
def make_fields(dtype, model: str, rod: str, features: Features):
    """The totals and the Jacobi-field columns of one static variant."""
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)
    dn = make_dense6(dtype)
    vec6 = dn.vec6
    K = features.tendons
    kvec = tendon_vectors(dtype, K)[0]
    st = make_structs(dtype, False)
    Model, Control, Step = st.Model, st.Control, st.Step
    rows = make_rows(dtype, False)
    law = make_strains(dtype, False, rod == "kirchhoff")
    stiffness = make_backbone(dtype, False, features.sections).stiffness
    route = make_routes(dtype, False, features.helix, features.spline)
    coupled = model == "coupled"
    half = dtype(0.5)

    @wp.func
    def totals(md: Model, ct: Control, sp: Step, b: int, s: dtype, R: mat33, n: vec3, m: vec3, t0: kvec,
               node: int):
        """The total internal force n + sum_k tau_k t_k and moment m + sum_k tau_k (R r_k) x t_k
        at ``node`` (just proximal of its jumps), over the tendons that run there (frictionless:
        each at its motor's tension, t0 with tendon states, else the command)."""
        Nt = n
        Mt = m
        if wp.static(coupled):
            kse, kbt = stiffness(md, b, s, 1)
            v, u = law.strains(md, sp, b, kse, kbt, R, n, m, 0)
            for k in range(md.n_tendons):
                if rows.term_node(md, b, k) >= node:
                    tau = ct.tau[b, k]
                    if wp.static(K > 0):
                        tau = t0[k]
                    r, dr, _ddr = route.tendon_route(md, b, k, s)
                    t = route.tendon_tangent(R, v, u, r, dr)
                    Nt = Nt + tau * t
                    Mt = Mt + tau * wp.cross(R * r, t)
        return Nt, Mt

    @wp.func
    def put_column(wk: dn.Work, b: int, j: int, dp: vec3, eta: vec3, dN: vec3, dM: vec3):
        """Column j of U (slot U_SLOT) and V (slot V_SLOT)."""
        for i in range(3):
            wk[b, U_SLOT, i, j] = dp[i]
            wk[b, U_SLOT, 3 + i, j] = eta[i]
            wk[b, V_SLOT, i, j] = dN[i]
            wk[b, V_SLOT, 3 + i, j] = dM[i]

    @wp.func
    def column(p0: vec3, R0: mat33, N0: vec3, M0: vec3, p: vec3, R: mat33, Nt: vec3, Mt: vec3, h: dtype,
               sc: vec6):
        """A Jacobi field from a probe h away, scaled by sc = [a / L, a, L / a, 1 / a]."""
        W = (R - R0) * wp.transpose(R0)
        eta = half * vec3(W[2, 1] - W[1, 2], W[0, 2] - W[2, 0], W[1, 0] - W[0, 1]) / h
        dM = (Mt - M0) / h - half * wp.cross(eta, M0)
        return (p - p0) / h * sc[0], eta * sc[1], (Nt - N0) / h * sc[2], dM * sc[3]

    return SimpleNamespace(totals=totals, put_column=put_column, column=column)


@functools.cache
def make_charts(dtype):
    """The phases of a Lagrangian plane (U, V) at one node, from a well-conditioned chart."""
    dn = make_dense6(dtype)
    vec6 = dn.vec6
    pi = dtype(math.pi)

    @wp.func
    def conditioning(wk: dn.Work, b: int, beta: dtype):
        """A_SLOT = U cos beta + V sin beta (then overwritten by its LU factors): its Hadamard
        ratio |det A| / prod |a_j| in [0, 1] (1: orthogonal columns, 0: singular)."""
        cb = wp.cos(beta)
        sb = wp.sin(beta)
        norms = dtype(1.0)
        for j in range(6):
            c2 = dtype(0.0)
            for i in range(6):
                a = wk[b, U_SLOT, i, j] * cb + wk[b, V_SLOT, i, j] * sb
                wk[b, A_SLOT, i, j] = a
                c2 = c2 + a * a
            norms = norms * wp.sqrt(c2)
        return dn.abs_det(wk, b, A_SLOT) / wp.max(norms, dtype(1e-300))

    @wp.func
    def denominator(wk: dn.Work, b: int, beta: dtype):
        """A_SLOT = U cos beta + V sin beta."""
        cb = wp.cos(beta)
        sb = wp.sin(beta)
        for i in range(6):
            for j in range(6):
                wk[b, A_SLOT, i, j] = wk[b, U_SLOT, i, j] * cb + wk[b, V_SLOT, i, j] * sb

    @wp.func
    def phases(wk: dn.Work, b: int, beta: dtype):
        """The phases arccot(p) in [0, pi) of the eigenvalues p of P = V U^-1 (slots U_SLOT,
        V_SLOT) and the chart used: ``beta`` (the last node's) while the denominator
        U cos b + V sin b stays well conditioned (Hadamard ratio above CHART_MIN), else the
        best of CHARTS angles."""
        if conditioning(wk, b, beta) < dtype(CHART_MIN):
            best = dtype(-1.0)
            for c in range(CHARTS):
                bc = dtype(c) * pi / dtype(CHARTS)
                ratio = conditioning(wk, b, bc)
                if ratio > best:
                    best = ratio
                    beta = bc
        denominator(wk, b, beta)
        dn.invert(wk, b, A_SLOT, X_SLOT)
        cb = wp.cos(beta)
        sb = wp.sin(beta)
        for i in range(6):  # P = (V cos b - U sin b) X into A_SLOT
            for j in range(6):
                acc = dtype(0.0)
                for k in range(6):
                    acc = acc + (wk[b, V_SLOT, i, k] * cb - wk[b, U_SLOT, i, k] * sb) * wk[b, X_SLOT, k, j]
                wk[b, A_SLOT, i, j] = acc
        for i in range(6):
            for j in range(i + 1, 6):
                sym = dtype(0.5) * (wk[b, A_SLOT, i, j] + wk[b, A_SLOT, j, i])
                wk[b, A_SLOT, i, j] = sym
                wk[b, A_SLOT, j, i] = sym
        ev = dn.symmetric_eigenvalues(wk, b, A_SLOT)
        phi = vec6()
        for i in range(6):
            ph = wp.atan2(dtype(1.0), ev[i]) - beta
            phi[i] = ph - pi * wp.floor(ph / pi)
        return phi, beta

    return SimpleNamespace(phases=phases)


@functools.cache
def make_tracking(dtype):
    """The phases followed from node to node as continuous lifts, the count and the check."""
    dn = make_dense6(dtype)
    vec6 = dn.vec6
    pi = dtype(math.pi)
    half_pi = dtype(0.5 * math.pi)

    @wp.func
    def wrap(d: dtype):
        """d into [-pi/2, pi/2) (phases live modulo pi)."""
        return d - pi * wp.floor((d + half_pi) / pi)

    @wp.func
    def track(cur: vec6, lift: vec6, phi: vec6):
        """The lifts moved by the nearest matching of the new phases ``phi`` to ``cur``, and the
        largest move matched (a move near pi / 2 is ambiguous: the step was too long)."""
        used_old = int(0)  # noqa: UP018, RUF046 (a dynamic variable for Warp)
        used_new = int(0)  # noqa: UP018, RUF046
        nxt = vec6()
        jump = dtype(0.0)
        for _round in range(6):
            bi = int(0)  # noqa: UP018, RUF046
            bj = int(0)  # noqa: UP018, RUF046
            bd = dtype(1e30)
            for i in range(6):
                if (used_old >> i) & 1 == 0:
                    for j in range(6):
                        if (used_new >> j) & 1 == 0:
                            d = wp.abs(wrap(phi[j] - cur[i]))
                            if d < bd:
                                bd = d
                                bi = i
                                bj = j
            lift[bi] = lift[bi] + wrap(phi[bj] - cur[bi])
            nxt[bi] = phi[bj]
            jump = wp.max(jump, bd)
            used_old = used_old | (1 << bi)
            used_new = used_new | (1 << bj)
        return nxt, lift, jump


    @wp.func
    def verdict(lift: vec6, neutral: dtype):
        """The index sum floor((lift - neutral) / pi + 1/2) and the margin: the smallest distance
        of a lift from an odd multiple of pi / 2 [rad]."""
        index = int(0)  # noqa: UP018, RUF046
        margin = dtype(1e30)
        for i in range(6):
            index = index + int(wp.floor((lift[i] - neutral) / pi + dtype(0.5)))
            d = lift[i] / pi - dtype(0.5)
            margin = wp.min(margin, wp.abs(d - wp.round(d)) * pi)
        return index, margin

    @wp.func
    def asymmetry(wk: dn.Work, b: int):
        """|U^T V - V^T U| and max(|U|, |V|)^2 (Frobenius): the plane stays Lagrangian."""
        a = dtype(0.0)
        nu = dtype(0.0)
        nv = dtype(0.0)
        for i in range(6):
            for j in range(6):
                d = dtype(0.0)
                for k in range(6):
                    d = d + wk[b, U_SLOT, k, i] * wk[b, V_SLOT, k, j] - wk[b, V_SLOT, k, i] * wk[b, U_SLOT, k, j]
                a = a + d * d
                nu = nu + wk[b, U_SLOT, i, j] * wk[b, U_SLOT, i, j]
                nv = nv + wk[b, V_SLOT, i, j] * wk[b, V_SLOT, i, j]
        return wp.sqrt(a), wp.max(nu, nv)

    return SimpleNamespace(track=track, verdict=verdict, asymmetry=asymmetry)


@functools.cache
def make_trajectory_state(dtype, tendons: int, displaced: int):
    """``Fields``: per rod (B, 1 + nu) the state of the solution and of each probe at the last
    node, and the work matrices; ``probe_x`` the start of trajectory j; ``keep`` a state."""
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)
    evec = tendon_vectors(dtype, tendons)[1]
    vecu = wp.types.vector(N_BASE + displaced, dtype)
    dn = make_dense6(dtype)

    @wp.struct
    class Fields:
        """Per rod (B, 1 + nu) the state of each trajectory at the last node, and the work matrices."""

        p: wp.array2d(dtype=vec3)
        R: wp.array2d(dtype=mat33)
        n: wp.array2d(dtype=vec3)
        m: wp.array2d(dtype=vec3)
        E: wp.array2d(dtype=evec)
        wk: dn.Work

    @wp.func
    def probe_x(x: vecu, h: vecu, j: int):
        """Trajectory j: the solution (0) or the probe of unknown j - 1."""
        xj = x
        if j > 0:
            xj[j - 1] = xj[j - 1] + h[j - 1]
        return xj

    @wp.func
    def keep(fd: Fields, b: int, j: int, p: vec3, R: mat33, n: vec3, m: vec3, E: evec):
        fd.p[b, j] = p
        fd.R[b, j] = R
        fd.n[b, j] = n
        fd.m[b, j] = m
        fd.E[b, j] = E

    return SimpleNamespace(Fields=Fields, probe_x=probe_x, keep=keep, vecu=vecu)


@functools.cache
def _shared(dtype, integrator: str, model: str, rod: str, features: Features) -> SimpleNamespace:
    """What the trajectory functions of one variant share: its types, structs and rod terms."""
    ts = make_trajectory_state(dtype, features.tendons, features.displaced)
    st = make_structs(dtype, False)
    return SimpleNamespace(vec3=wp.types.vector(3, dtype), nu=N_BASE + features.displaced, vec6=make_dense6(dtype).vec6,
                           vecu=ts.vecu, evec=tendon_vectors(dtype, features.tendons)[1], Model=st.Model,
                           Control=st.Control, Step=st.Step, Fields=ts.Fields, probe_x=ts.probe_x, keep=ts.keep,
                           rf=make_rod_funcs(dtype, integrator, model, False, rod, features),
                           fl=make_fields(dtype, model, rod, features))


@functools.cache
def make_clamp(dtype, integrator: str, model: str, rod: str, features: Features):
    """``clamp``: every trajectory at s = 0; ``steps``: the probes' steps."""
    zero = dtype(0.0)
    one = dtype(1.0)
    v = _shared(dtype, integrator, model, rod, features)
    vec3, nu, vec6, vecu, evec = v.vec3, v.nu, v.vec6, v.vecu, v.evec
    Model, Control, Step, Fields, probe_x, keep, rf, fl = v.Model, v.Control, v.Step, v.Fields, v.probe_x, v.keep, v.rf, v.fl
    stages = STAGES[integrator]  # times the intervals: the first slot of the jumps (kernels/integration.py)

    @wp.func
    def clamp(md: Model, ct: Control, sp: Step, fd: Fields, b: int, x: vecu, h: vecu, sc: vec6):
        """Every trajectory at s = 0 (past the jumps there); returns the columns' scales: 1 / |V(0)|."""
        ir = rf.row(b, md.rod)
        jumps = (md.grid.shape[1] - 1) * stages
        colscale = vec6()
        N0 = vec3()
        M0 = vec3()
        for j in range(nu + 1):
            xj = probe_x(x, h, j)
            t0 = rf.base_tensions(md, ct, b, xj)
            R = wp.identity(3, dtype)
            n = vec3(xj[0], xj[1], xj[2]) * md.rod[ir, FORCE_SCALE]
            m = vec3(xj[3], xj[4], xj[5]) * md.rod[ir, MOMENT_SCALE]
            Nt, Mt = fl.totals(md, ct, sp, b, zero, R, n, m, t0, 0)
            if j == 0:
                N0 = Nt
                M0 = Mt
            elif j <= 6:
                _dp, _eta, dN, dM = fl.column(vec3(), R, N0, M0, vec3(), R, Nt, Mt, h[j - 1], sc)
                colscale[j - 1] = one / wp.sqrt(wp.length_sq(dN) + wp.length_sq(dM))
            n, m, E = rf.node_jumps(md, ct, sp, b, zero, vec3(), R, n, m, vec3(), vec3(), t0, evec(), 0, jumps,
                                    jumps + 1, 0)
            keep(fd, b, j, vec3(), R, n, m, E)
        return colscale

    @wp.func
    def steps(md: Model, b: int, x: vecu, rel: dtype, axial_strain: dtype):
        """The probe steps: rel max(1, |x|), the axial force at least an axial strain's worth."""
        h = vecu()
        for j in range(nu):
            h[j] = rel * wp.max(one, wp.abs(x[j]))
        ir = rf.row(b, md.rod)
        h[2] = wp.max(h[2], axial_strain * md.rod[ir, KSE + 2] / md.rod[ir, FORCE_SCALE])
        return h

    return SimpleNamespace(clamp=clamp, steps=steps)


@functools.cache
def make_advance(dtype, integrator: str, model: str, rod: str, features: Features):
    """``advance``: every trajectory over the next interval, U and V at its end."""
    v = _shared(dtype, integrator, model, rod, features)
    vec3, nu, vec6, vecu = v.vec3, v.nu, v.vec6, v.vecu
    Model, Control, Step, Fields, probe_x, keep, rf, fl = v.Model, v.Control, v.Step, v.Fields, v.probe_x, v.keep, v.rf, v.fl
    interval = make_interval(dtype, integrator, model, False, rod, features).interval
    stages = STAGES[integrator]  # times the intervals: the first slot of the jumps (kernels/integration.py)

    @wp.func
    def advance(md: Model, ct: Control, sp: Step, fd: Fields, b: int, x: vecu, h: vecu, sc: vec6, colscale: vec6,
                k: int, s: dtype, s1: dtype, k1: int, at_node: int):
        """Every trajectory from s (in interval k or at its node) to s1 (node k1 with ``at_node``,
        else inside interval k, k1 = k + 1); U and V (scaled) at s1, before the node's jumps."""
        js = (md.grid.shape[1] - 1) * stages + 2 * k1
        p0 = vec3()
        R0 = wp.identity(3, dtype)
        N0 = vec3()
        M0 = vec3()
        for j in range(nu + 1):
            t0 = rf.base_tensions(md, ct, b, probe_x(x, h, j))
            p, R, n, m, _q, _w, E = interval(md, ct, sp, b, s, s1 - s, fd.p[b, j], fd.R[b, j], fd.n[b, j], fd.m[b, j],
                                               vec3(), vec3(), t0, fd.E[b, j], k, 0)
            if j <= 6:
                Nt, Mt = fl.totals(md, ct, sp, b, s1, R, n, m, t0, k1)
                if j == 0:
                    p0 = p
                    R0 = R
                    N0 = Nt
                    M0 = Mt
                else:
                    dp, eta, dN, dM = fl.column(p0, R0, N0, M0, p, R, Nt, Mt, h[j - 1], sc)
                    cs = colscale[j - 1]
                    fl.put_column(fd.wk, b, j - 1, dp * cs, eta * cs, dN * cs, dM * cs)
            if at_node != 0:
                n, m, E = rf.node_jumps(md, ct, sp, b, s1, p, R, n, m, vec3(), vec3(), t0, E, k1, js, js + 1, 0)
            keep(fd, b, j, p, R, n, m, E)

    return advance


@functools.cache
def make_state_basis(dtype, integrator: str, model: str, rod: str, features: Features):
    """The fields in state form past a node (Y, 12 x 6 in slots A_SLOT and X_SLOT), made orthonormal."""
    v = _shared(dtype, integrator, model, rod, features)
    vec3, vecu, Fields = v.vec3, v.vecu, v.Fields
    Work = make_dense6(dtype).Work
    half = dtype(0.5)

    @wp.func
    def field(wk: Work, i: int, b: int, j: int):
        """Row i of the state fields Y (12 x 6: dp / L, eta, dn / F, dm / M) in slots A_SLOT, X_SLOT."""
        return wk[b, wp.where(i < 6, A_SLOT, X_SLOT), i % 6, j]

    @wp.func
    def orthonormalise(wk: Work, b: int):
        """The columns of Y made orthonormal (Gram-Schmidt, twice): the same plane."""
        for j in range(6):
            for _again in range(2):
                for i in range(j):
                    d = dtype(0.0)
                    for r in range(12):
                        d = d + field(wk, r, b, i) * field(wk, r, b, j)
                    for r in range(12):
                        wk[b, wp.where(r < 6, A_SLOT, X_SLOT), r % 6, j] = field(wk, r, b, j) - d * field(wk, r, b, i)
            c2 = dtype(0.0)
            for r in range(12):
                c2 = c2 + field(wk, r, b, j) * field(wk, r, b, j)
            inv = dtype(1.0) / wp.sqrt(c2)
            for r in range(12):
                wk[b, wp.where(r < 6, A_SLOT, X_SLOT), r % 6, j] = field(wk, r, b, j) * inv

    @wp.func
    def state_fields(fd: Fields, b: int, h: vecu, L: dtype, F: dtype, Mo: dtype):
        """Y from the trajectories' states past the node (columns: the 6 probes)."""
        R0 = fd.R[b, 0]
        for j in range(6):
            W = (fd.R[b, j + 1] - R0) * wp.transpose(R0)
            eta = half * vec3(W[2, 1] - W[1, 2], W[0, 2] - W[2, 0], W[1, 0] - W[0, 1])
            dp = (fd.p[b, j + 1] - fd.p[b, 0]) / L
            dn = (fd.n[b, j + 1] - fd.n[b, 0]) / F
            dm = (fd.m[b, j + 1] - fd.m[b, 0]) / Mo
            for i in range(3):
                fd.wk[b, A_SLOT, i, j] = dp[i] / h[j]
                fd.wk[b, A_SLOT, 3 + i, j] = eta[i] / h[j]
                fd.wk[b, X_SLOT, i, j] = dn[i] / h[j]
                fd.wk[b, X_SLOT, 3 + i, j] = dm[i] / h[j]

    return SimpleNamespace(field=field, orthonormalise=orthonormalise, state_fields=state_fields)


@functools.cache
def make_restart(dtype, integrator: str, model: str, rod: str, features: Features):
    """``restart``: the fields of a split rod carried over a node: the probes start again from
    the solution plus a small multiple of an orthonormal basis of the fields' plane (the same
    plane: the phases go on), so that fields that grow along the rod (a long contact: like
    exp(2 beta l)) stay resolved; at a segment's start the solution from the solved shape."""
    v = _shared(dtype, integrator, model, rod, features)
    vec3, nu, vecu, Model, Control, Step, Fields, keep, rf = (v.vec3, v.nu, v.vecu, v.Model, v.Control, v.Step,
                                                              v.Fields, v.keep, v.rf)
    Nodes = make_nodes(dtype, False, features.tendons > 0).Nodes
    ys = make_state_basis(dtype, integrator, model, rod, features)
    field = ys.field
    mat33 = wp.types.matrix((3, 3), dtype)
    half = dtype(0.5)
    stages = STAGES[integrator]

    @wp.func
    def restart(md: Model, ct: Control, sp: Step, fd: Fields, nd: Nodes, b: int, x: vecu, h: vecu, k1: int,
                s1: dtype, step: dtype, anchor: int):
        """The probes restarted past node k1 from the solution plus ``step`` (scaled units) times
        an orthonormal basis of the fields; with ``anchor`` the solution first restarted from the
        stored shape (its jumps at k1 applied). Returns the probes' new steps."""
        ir = rf.row(b, md.rod)
        L = md.rod[ir, LENGTH]
        F = md.rod[ir, FORCE_SCALE]
        Mo = md.rod[ir, MOMENT_SCALE]
        ys.state_fields(fd, b, h, L, F, Mo)
        ys.orthonormalise(fd.wk, b)
        p = fd.p[b, 0]
        R = fd.R[b, 0]
        n = fd.n[b, 0]
        m = fd.m[b, 0]
        E = fd.E[b, 0]
        if anchor != 0:
            js = (md.grid.shape[1] - 1) * stages + 2 * k1
            p = nd.p[b, k1]
            R = nd.R[b, k1]
            n, m, E = rf.node_jumps(md, ct, sp, b, s1, p, R, nd.n[b, k1], nd.m[b, k1], vec3(), vec3(),
                                    rf.base_tensions(md, ct, b, x), E, k1, js, js + 1, 0)
            keep(fd, b, 0, p, R, n, m, E)
        for j in range(6):
            y = vec3(field(fd.wk, 3, b, j), field(fd.wk, 4, b, j), field(fd.wk, 5, b, j)) * step
            K = mat33(dtype(0.0), -y[2], y[1], y[2], dtype(0.0), -y[0], -y[1], y[0], dtype(0.0))
            turn = wp.identity(3, dtype) + K + half * K * K  # exp(K) to O(step^3)
            dp = vec3(field(fd.wk, 0, b, j), field(fd.wk, 1, b, j), field(fd.wk, 2, b, j)) * (step * L)
            dn = vec3(field(fd.wk, 6, b, j), field(fd.wk, 7, b, j), field(fd.wk, 8, b, j)) * (step * F)
            dm = vec3(field(fd.wk, 9, b, j), field(fd.wk, 10, b, j), field(fd.wk, 11, b, j)) * (step * Mo)
            keep(fd, b, j + 1, p + dp, turn * R, n + dn, m + dm, E)
        hn = vecu()
        for j in range(nu):
            hn[j] = step
        return hn

    return SimpleNamespace(restart=restart, Nodes=Nodes)


@functools.cache
def make_shear(dtype, integrator: str, model: str, rod: str, features: Features):
    """``shear``: the disk model's jump at a disk followed as a path of planes (U, V + t D), t from
    0 to 1, D the jump of V: the chords' pull at a disk depends on its holes' positions, a stiffness
    that moves the phases at once (a single disk's, whose chords come from the fixed base plate: a
    conservative point load, D = K U with K symmetric; tdcr_warp/physics/stability.py)."""
    v = _shared(dtype, integrator, model, rod, features)
    vec6, vecu, Fields, fl = v.vec6, v.vecu, v.Fields, v.fl
    ch, tk = make_charts(dtype), make_tracking(dtype)
    zero = dtype(0.0)
    frac = dtype(1.0 / SHEAR_STEPS)

    @wp.func
    def shear(fd: Fields, b: int, h: vecu, sc: vec6, cs: vec6, beta: dtype, cur: vec6, lift: vec6):
        """The phases tracked from V before the jumps (in its slot) to V past them (the kept states);
        returns the chart, the phases, the lifts and the largest move."""
        p0 = fd.p[b, 0]
        R0 = fd.R[b, 0]
        for j in range(6):
            _dp, _eta, dN, dM = fl.column(p0, R0, fd.n[b, 0], fd.m[b, 0], fd.p[b, j + 1], fd.R[b, j + 1],
                                          fd.n[b, j + 1], fd.m[b, j + 1], h[j], sc)
            for i in range(3):
                fd.wk[b, D_SLOT, i, j] = (dN[i] * cs[j] - fd.wk[b, V_SLOT, i, j]) * frac
                fd.wk[b, D_SLOT, 3 + i, j] = (dM[i] * cs[j] - fd.wk[b, V_SLOT, 3 + i, j]) * frac
        jump = zero
        for _t in range(wp.static(SHEAR_STEPS)):
            for i in range(6):
                for j in range(6):
                    fd.wk[b, V_SLOT, i, j] = fd.wk[b, V_SLOT, i, j] + fd.wk[b, D_SLOT, i, j]
            phi, beta = ch.phases(fd.wk, b, beta)
            cur, lift, moved = tk.track(cur, lift, phi)
            jump = wp.max(jump, moved)
        return beta, cur, lift, jump

    return shear


@functools.cache
def make_sweep(dtype, integrator: str, model: str, rod: str, features: Features):
    """``sweep``: the fields from the clamp to the tip over the steps of one pass, their phases
    tracked: the lifts at the tip and the largest move between two steps."""
    zero = dtype(0.0)
    one = dtype(1.0)
    v = _shared(dtype, integrator, model, rod, features)
    vec6, vecu, Model, Control, Step, Fields, rf = v.vec6, v.vecu, v.Model, v.Control, v.Step, v.Fields, v.rf
    advance = make_advance(dtype, integrator, model, rod, features)
    ch, tk = make_charts(dtype), make_tracking(dtype)
    rs = make_restart(dtype, integrator, model, rod, features)
    splits = segmentable(model, features)  # a variant multiple shooting can split
    disks = model == "disks"
    shear = make_shear(dtype, integrator, model, rod, features)

    @wp.func
    def sweep(md: Model, ct: Control, sp: Step, fd: Fields, b: int, x0: vecu, h: vecu, sc: vec6, colscale: vec6,
              stride: int, nd: rs.Nodes, restarts: wp.array2d(dtype=int), rel: dtype):
        """stride >= 2: up to ``stride`` intervals a step, stopping at every node something acts
        on; 1: the full grid; <= -2: -stride steps an interval. ``restarts`` (B, N+1), per node (a
        step takes the largest over the nodes it ends or passes): 1 the probes restart from the
        solution (``restart``: an orthonormal basis of the fields, steps of ``rel``), 2 the
        solution also from the solved shape ``nd`` (a segment's start); 0 neither."""
        n_int = md.grid.shape[1] - 1
        lift = vec6()  # the phases leave 0 at the clamp
        cur = vec6()
        beta = zero
        jump = zero
        hs = h * one  # the probes' steps and the columns' scales (a restart resets them)
        cs = colscale * one
        ig = rf.row(b, md.grid)
        parts = wp.max(-stride, 1)  # steps per interval
        k = int(0)  # noqa: UP018, RUF046 (a dynamic variable for Warp)
        part = int(0)  # noqa: UP018, RUF046
        while k < n_int:
            k1 = rf.span_end(md, b, k, stride, n_int)
            s = md.grid[ig, k]
            ds = (md.grid[ig, k1] - s) / dtype(parts)
            at_node = wp.where(part + 1 == parts, 1, 0)
            advance(md, ct, sp, fd, b, x0, hs, sc, cs, k, s + dtype(part) * ds,
                    wp.where(at_node == 1, md.grid[ig, k1], s + dtype(part + 1) * ds), k1, at_node)
            phi, beta = ch.phases(fd.wk, b, beta)
            cur, lift, moved = tk.track(cur, lift, phi)
            jump = wp.max(jump, moved)
            part = part + 1
            if at_node == 1:
                if wp.static(disks):
                    if md.dnext[rf.row(b, md.dnext), k1] >= 0:  # a disk: its stiffness
                        beta, cur, lift, moved = shear(fd, b, hs, sc, cs, beta, cur, lift)
                        jump = wp.max(jump, moved)
                if wp.static(splits):
                    todo = int(0)  # noqa: UP018, RUF046
                    for kk in range(k + 1, k1 + 1):
                        todo = wp.max(todo, restarts[b, kk])
                    if todo != 0 and k1 < n_int:
                        hs = rs.restart(md, ct, sp, fd, nd, b, x0, hs, k1, md.grid[ig, k1], rel, todo - 1)
                        cs = vec6(one / sc[1], one / sc[1], one / sc[1], one / sc[1], one / sc[1], one / sc[1])
                k = k1
                part = 0
        return lift, jump

    return sweep


@functools.cache
def make_verdict_kernel(dtype, integrator: str, model: str, rod: str, features: Features):
    """``verdict_kernel``: per rod (mask), from its solution x, the stability index, margin and
    Lagrangian check, the largest phase move between two nodes, and the shooting Jacobian
    J = dr/dx by forward differences (the probes of the displaced tendons' tensions run beside,
    for the wires' correction on the host). stride >= 2: the fields are integrated over up to
    ``stride`` intervals a step, stopping at every node something acts on; 1: the full grid;
    stride <= -2: -stride steps an interval (phases that turn too fast for the grid). nd: the
    solved shape and restarts (B, N+1) the restarts of split rods (``sweep``; J is then meaningless)."""
    zero = dtype(0.0)
    one = dtype(1.0)
    v = _shared(dtype, integrator, model, rod, features)
    nu, vec6, vecu, Model, Control, Step, Fields, probe_x, rf = (v.nu, v.vec6, v.vecu, v.Model, v.Control, v.Step,
                                                                 v.Fields, v.probe_x, v.rf)
    matu = wp.types.matrix((nu, nu), dtype)
    cl = make_clamp(dtype, integrator, model, rod, features)
    sweep = make_sweep(dtype, integrator, model, rod, features)
    resid = make_residual(dtype, False, features.tendons, features.displaced)
    tk = make_tracking(dtype)
    module = module_names(dtype, integrator, model, False, rod, features)["evaluate"]
    Nodes = make_nodes(dtype, False, features.tendons > 0).Nodes

    @wp.func
    def shooting_jacobian(md: Model, ct: Control, fd: Fields, b: int, x: vecu, h: vecu):
        """J = dr/dx at the tip by forward differences of the trajectories."""
        J = matu()
        r0 = resid.tip_residual(md, ct, b, x, fd.p[b, 0], fd.n[b, 0], fd.m[b, 0], fd.E[b, 0])
        for j in range(1, nu + 1):
            rj = resid.tip_residual(md, ct, b, probe_x(x, h, j), fd.p[b, j], fd.n[b, j], fd.m[b, j], fd.E[b, j])
            for i in range(nu):
                J[i, j - 1] = (rj[i] - r0[i]) / h[j - 1]
        return J

    @wp.kernel(module=module, enable_backward=False)
    def verdict_kernel(md: Model, ct: Control, sp: Step, x: wp.array(dtype=vecu), mask: wp.array(dtype=int),
                       rel: dtype, axial_strain: dtype, neutral: dtype, stride: int, fd: Fields,
                       jac: wp.array(dtype=matu), index: wp.array(dtype=int), margin: wp.array(dtype=dtype),
                       lag: wp.array(dtype=dtype), jumps: wp.array(dtype=dtype), nd: Nodes,
                       restarts: wp.array2d(dtype=int)):
        b = wp.tid()
        if mask[b] == 0:
            return
        x0 = x[b]
        h = cl.steps(md, b, x0, rel, axial_strain)
        ir = rf.row(b, md.rod)
        L = md.rod[ir, LENGTH]
        a = wp.sqrt(md.rod[ir, KBT] / L)
        sc = vec6(a / L, a, L / a, one / a, zero, zero)  # symplectic scaling of [dp, eta, dN, dM]
        colscale = cl.clamp(md, ct, sp, fd, b, x0, h, sc)
        lift, jump = sweep(md, ct, sp, fd, b, x0, h, sc, colscale, stride, nd, restarts, rel)
        idx, mg = tk.verdict(lift, neutral)
        index[b] = idx
        margin[b] = mg
        asym, size = tk.asymmetry(fd.wk, b)  # at the tip: U^T V is constant along s, its errors add up
        lag[b] = asym / wp.max(size, dtype(1e-300))
        jumps[b] = jump
        jac[b] = shooting_jacobian(md, ct, fd, b, x0, h)

    return SimpleNamespace(kernel=verdict_kernel, Fields=Fields)
