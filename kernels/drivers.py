"""The Warp kernels of a shooting solve: two drivers of the same Newton update, and a plain
evaluation.

  solve_kernel    (module "fused") the whole Newton loop of a rod in one thread: probes one
                  after another (the fastest on a CPU, where a launch runs its threads in turn,
                  and no host round trip at all)
  probe_kernel, update_kernel, finish_kernel, begin_kernel   (module "probes") one iteration
                  with a thread per (rod, probe) (for GPUs; the host repeats them, or a CUDA
                  graph does)
  evaluate_kernel (module "evaluate") one integration per rod: dynamics, and the probes of
                  sensitivities
  coarse_now, evaluation, needs_final_shape   what an iteration evaluates

One Warp module per variant and driver (``module_names``): a solve compiles only what its
device runs.
"""

import functools
from types import SimpleNamespace

import warp as wp

from .integration import N_BASE, make_shoot
from .layout import CONVERGED, MAX_ITER
from .newton import make_newton
from .structs import make_structs
from .variants import Features


def module_names(dtype, integrator: str, model: str, dynamic: bool, rod: str, features: Features) -> dict:
    """The Warp module of each kernel group ("fused", "probes", "evaluate") of one variant."""
    key = (f"{wp.types.type_repr(dtype)}_{integrator}_{model}_{'dyn' if dynamic else 'static'}_{rod}_"
           + "".join(str(int(f)) for f in features[:4]) + ("" if features.kinks else "_nokink")
           + (f"_k{features.tendons}" if features.tendons else "") + ("_mu" if features.friction else "")
           + (f"_d{features.displaced}" if features.displaced else "") + ("_spline" if features.spline else "")
           + ("_contact" if features.contact else "") + (f"_t{features.tip}" if features.tip else ""))
    return {grp: f"tdcr_warp_{grp}_{key}" for grp in ("fused", "probes", "evaluate")}


@functools.cache
def make_iteration(dtype, nu: int, dynamic: bool):
    """What an iteration of a rod evaluates. Jacobian probes: forward differences in statics
    (with a first Jacobian over long steps), central differences in dynamics (``make_shooting_kernels``)."""
    nt = make_newton(dtype, nu, dynamic)
    Newton, n_probes = nt.Newton, nt.n_probes

    @wp.func
    def coarse_now(nw: Newton, b: int, coarse_jacobian: int, broyden: int):
        """The probes' stride (``shoot``'s coarse; 0: the fine grid) this iteration: coarse_jacobian
        for the first Jacobian of a Broyden solve (a rebuild after a failed step, or plain Newton,
        uses the fine grid)."""
        if wp.static(dynamic):
            return 0
        if coarse_jacobian != 0 and broyden != 0 and nw.need_jac[b] != 0 and nw.iters[b] == 0:
            return coarse_jacobian
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

    return SimpleNamespace(coarse_now=coarse_now, evaluation=evaluation, needs_final_shape=needs_final_shape)


def _parts(dtype, integrator, model, dynamic, rod, features):
    """The structs and functions every kernel factory of a variant reads."""
    nu = N_BASE + features.displaced + features.tip
    st = make_structs(dtype, dynamic)
    return (st, make_newton(dtype, nu, dynamic), make_shoot(dtype, integrator, model, dynamic, rod, features),
            make_iteration(dtype, nu, dynamic), module_names(dtype, integrator, model, dynamic, rod, features))


@functools.cache
def make_fused_kernel(dtype, integrator: str, model: str, dynamic: bool, rod: str, features: Features):
    st, nt, sh, itr, modules = _parts(dtype, integrator, model, dynamic, rod, features)
    Model, Control, Step, Newton, Nodes, vecu = st.Model, st.Control, st.Step, nt.Newton, sh.Nodes, nt.vec

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
            coarse = itr.coarse_now(nw, b, coarse_jacobian, broyden)
            if solving == 0:
                if not itr.needs_final_shape(nw, b):
                    break
                x = nw.x[b]
                n_eval = 1
            for j in range(n_eval):  # a runtime bound: one copy of the integrator, not n_probes
                e = itr.evaluation(nw, b, j, coarse)
                if e >= 0:
                    r, p_tip, R_tip = sh.shoot(nt.probe_point(x, j), md, ct, sp, b, e, coarse * (1 - e), out)
                    nw.res[b, j] = r
            if solving == 0:
                break
            nt.update(nw, b, sh.residual_scale(md, b), tol, max_iter, max_step, broyden, coarse)

    return solve_kernel


@functools.cache
def make_probe_kernels(dtype, integrator: str, model: str, dynamic: bool, rod: str, features: Features):
    st, nt, sh, itr, modules = _parts(dtype, integrator, model, dynamic, rod, features)
    Model, Control, Step, Newton, Nodes, vecu = st.Model, st.Control, st.Step, nt.Newton, sh.Nodes, nt.vec
    width = nt.width

    @wp.kernel(module=modules["probes"], enable_backward=False)
    def probe_kernel(md: Model, ct: Control, sp: Step, nw: Newton, out: Nodes, broyden: int, coarse_jacobian: int):
        """Thread (rod, j): j = 0 integrates the trial point (and stores it), j >= 1 its
        finite-difference probes (and their base)."""
        tid = wp.tid()
        b = tid // width
        j = tid - b * width
        if nw.active[b] == 0:
            return
        coarse = itr.coarse_now(nw, b, coarse_jacobian, broyden)
        e = itr.evaluation(nw, b, j, coarse)
        if e >= 0:
            r, p_tip, R_tip = sh.shoot(nt.probe_point(nw.xt[b], j), md, ct, sp, b, e, coarse * (1 - e), out)
            nw.res[b, j] = r

    @wp.kernel(module=modules["probes"], enable_backward=False)
    def update_kernel(md: Model, nw: Newton, tol: dtype, max_iter: int, max_step: dtype, broyden: int,
                      coarse_jacobian: int):
        b = wp.tid()
        if nw.active[b] != 0:
            nt.update(nw, b, sh.residual_scale(md, b), tol, max_iter, max_step, broyden,
                      itr.coarse_now(nw, b, coarse_jacobian, broyden))

    @wp.kernel(module=modules["probes"], enable_backward=False)
    def finish_kernel(md: Model, ct: Control, sp: Step, nw: Newton, out: Nodes, mask: wp.array(dtype=int)):
        b = wp.tid()
        if mask[b] == 0:
            return
        if nw.active[b] != 0:  # out of host iterations
            nw.status[b] = MAX_ITER
            nw.active[b] = 0
        if itr.needs_final_shape(nw, b):
            r, p_tip, R_tip = sh.shoot(nw.x[b], md, ct, sp, b, 1, 0, out)

    @wp.kernel(module=modules["probes"], enable_backward=False)
    def begin_kernel(nw: Newton, x_from: wp.array(dtype=vecu), fresh_jacobian: int, mask: wp.array(dtype=int)):
        b = wp.tid()
        if mask[b] != 0:
            nt.begin(nw, b, x_from, fresh_jacobian)

    return SimpleNamespace(probe=probe_kernel, update=update_kernel, finish=finish_kernel, begin=begin_kernel)


@functools.cache
def make_evaluate_kernel(dtype, integrator: str, model: str, dynamic: bool, rod: str, features: Features):
    st, nt, sh, itr, modules = _parts(dtype, integrator, model, dynamic, rod, features)
    Model, Control, Step, Nodes, vecu = st.Model, st.Control, st.Step, sh.Nodes, nt.vec
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)

    @wp.kernel(module=modules["evaluate"], enable_backward=False)
    def evaluate_kernel(md: Model, ct: Control, sp: Step, x: wp.array(dtype=vecu), out: Nodes,
                        res: wp.array(dtype=vecu), tip_p: wp.array(dtype=vec3), tip_R: wp.array(dtype=mat33),
                        store: int):
        """One integration per rod from x: its residual and tip pose, and with ``store`` its shape
        (and the dynamics slots) in ``out`` (without, a probe of a sensitivity,
        tdcr_warp/physics/sensitivity.py, at the cost of the integration alone)."""
        b = wp.tid()
        r, p_tip, R_tip = sh.shoot(x[b], md, ct, sp, b, store, 0, out)
        res[b] = r
        tip_p[b] = p_tip
        tip_R[b] = R_tip

    return evaluate_kernel


@functools.cache
def make_jacobian_kernel(dtype, integrator: str, model: str, dynamic: bool, rod: str, features: Features):
    st, nt, sh, _itr, modules = _parts(dtype, integrator, model, dynamic, rod, features)
    Model, Control, Step, Newton, Nodes, vecu = st.Model, st.Control, st.Step, nt.Newton, sh.Nodes, nt.vec
    n_probes = nt.n_probes

    @wp.kernel(module=modules["evaluate"], enable_backward=False)
    def jacobian_kernel(md: Model, ct: Control, sp: Step, nw: Newton, out: Nodes, x: wp.array(dtype=vecu),
                        coarse: int, mask: wp.array(dtype=int)):
        """The finite-difference Jacobian at x[b] into nw.J[b], as a Broyden solve makes its first
        one (the probes over ``coarse``-interval steps and their base evaluated the same way;
        coarse 0: the fine grid and the point itself), without a Newton step."""
        b = wp.tid()
        if mask[b] == 0:
            return
        xb = x[b]
        for j in range(nw.res.shape[1]):
            if (j == 0 and coarse != 0) or (j == n_probes and coarse == 0):
                continue
            r, _p_tip, _R_tip = sh.shoot(nt.probe_point(xb, j), md, ct, sp, b, 0, coarse, out)
            nw.res[b, j] = r
        nw.J[b] = nt.new_jacobian(nw, b, nw.res[b, 0], xb, coarse)

    return jacobian_kernel
