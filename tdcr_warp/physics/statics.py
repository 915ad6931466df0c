"""Batched static shooting: ``solve_static(robot, tensions)`` for B rods at once.

Newton on the 6 base unknowns (n(0), m(0)) per rod (kernels/newton.py), with a
forward-difference Jacobian, Broyden updates between rebuilds, backtracking on the residual
norm, a bounded step and a per-rod verdict; a per-rod load continuation where the start is
far from the answer (tdcr_warp/core/homotopy.py). On the CPU the batch is split over threads
(Warp releases the GIL while a CPU kernel runs). Repeated solves of the same robot object and
batch shape reuse its device arrays (``StaticProblem``).
"""

from __future__ import annotations

import functools
import threading
import weakref
from collections import OrderedDict
from dataclasses import asdict, dataclass, field, fields, replace

import numpy as np
import warp as wp

from tdcr_warp.core.build import Tables
from tdcr_warp.core.homotopy import continuation_steps, load_continuation
from tdcr_warp.core.parallel import parallel, split
from tdcr_warp.core.solver import Shooting
from tdcr_warp.kernels import layout
from tdcr_warp.model.options import StaticOptions, describe_status
from tdcr_warp.model.robot import InputError, Robot, check_command, check_slip, real_array, require_memory
from tdcr_warp.physics.sensitivity import linearise, parameter_tables
from tdcr_warp.physics.stability import jacobi_index, node_routing

__all__ = ["StaticOptions", "StaticProblem", "StaticSolution", "reference_lengths", "solve_static"]


@dataclass
class StaticSolution:
    """Solved shapes and diagnostics of B rods (float64 NumPy arrays on the host).

    s: (B, N+1) arc length of the nodes [m]; positions: (B, N+1, 3) [m]; rotations:
    (B, N+1, 3, 3) body-to-world; n, m: (B, N+1, 3) internal force [N] and moment [N m]
    (world frame) just proximal of each node (so n[:, -1] = n(L-), before the tip loads);
    tip_position (B, 3), tip_rotation (B, 3, 3); base_wrench (B, 6) = [n(0), m(0)].
    converged (B,) bool; status (B,) bit flags (kernels/layout.py); iterations (B,);
    integrations (B,): base-to-tip integrations spent (the 7 of a first Jacobian in a Broyden RK4 solve with
    N >= 16 run over double steps, at about half the cost; the probes of sensitivities included); residual (B,): L |r| [m];
    orthogonality_error (B,): max |R^T R - I| over the nodes; jacobian (B, nu, nu): the last
    scaled shooting Jacobian (reused by a warm start); unknowns (B, nu): the scaled shooting
    unknowns (nu = 6 + one per displacement-controlled tendon). tip_error_estimate (B,) [m]:
    with ``error_estimate`` only.

    Sensitivities (``sensitivities``; NaN for rods that did not converge; the tip pose is
    [p(L) [m], theta [rad]], theta the world-frame rotation vector of a small tip rotation):
    tip_jacobian (B, 6, K) d pose / d command, per tendon its tension [N] under tension control
    or its motor displacement [m] under displacement control; tip_compliance (B, 6, 6) d pose /
    d [F_tip [N], M_tip [N m]] (world frame); tension_jacobian (B, K, K) d tendon_tension_base[k] /
    d command[l] (the identity for tension control; zero rows for slack tendons); slack_jacobian
    (B, K, K) d (slack length [m] of slack tendon k) / d command[l] (zero rows for taut tendons);
    parameter_jacobian (B, 6, P) d pose / d parameter (units of each parameter,
    ``parameter_names``). Stability (``stability``): stability_index
    (B,) the number of unstable directions (0: stable; -1: not assessed: not converged,
    friction, or point-model tendons); lagrangian_error (B,) the check of the test (small:
    trustworthy); with "stable" also branch (B,) int8 (0: as solved, 1: the solve landed on an
    unstable equilibrium and a restart found this stable one, -1: unstable, no stable one
    found) and multiple_stable (B,) bool (restarts found distinct stable equilibria).

    Per tendon (B, K): tendon_tension_base (at the motor side, s = 0) and tendon_tension_end
    (just before its termination) [N]. With tendon states (displacement control or friction;
    None otherwise): tendon_path_length, the length of its deformed path [m];
    tendon_free_length, the unstretched tendon that path holds [m]; tendon_turning (with
    friction), the total turning of its path [rad], kinks included where they are modelled;
    tendon_tension (B, N+1, K) just distal of every node [N]; slack
    (B, K): a displacement-controlled tendon with zero tension and length to spare. With
    friction: slip (B, K), the slip direction each tendon was solved with (+1 pulled, -1
    released, 0: stick-slip from ``history``); slip_state (B, N+1, K) int8 just distal of each
    node: +1 sliding toward the motor, -1 away from it, 0 stuck; tension_slots: the profile a
    following quasi-static solve starts from (``history``).
    """

    s: np.ndarray
    positions: np.ndarray
    rotations: np.ndarray
    n: np.ndarray
    m: np.ndarray
    base_wrench: np.ndarray
    converged: np.ndarray
    status: np.ndarray
    iterations: np.ndarray
    integrations: np.ndarray
    residual: np.ndarray
    orthogonality_error: np.ndarray
    jacobian: np.ndarray
    options: StaticOptions = field(repr=False)
    unknowns: np.ndarray | None = None
    tendon_tension_base: np.ndarray | None = None
    tendon_tension_end: np.ndarray | None = None
    tendon_path_length: np.ndarray | None = None
    tendon_free_length: np.ndarray | None = None
    tendon_turning: np.ndarray | None = None
    tendon_tension: np.ndarray | None = None
    slack: np.ndarray | None = None
    slip: np.ndarray | None = None
    slip_state: np.ndarray | None = None
    tension_slots: np.ndarray | None = field(default=None, repr=False)
    tip_error_estimate: np.ndarray | None = None
    tip_jacobian: np.ndarray | None = None
    tip_compliance: np.ndarray | None = None
    tension_jacobian: np.ndarray | None = None
    slack_jacobian: np.ndarray | None = None
    parameter_jacobian: np.ndarray | None = None
    parameter_names: tuple = ()
    stability_index: np.ndarray | None = None
    lagrangian_error: np.ndarray | None = None
    branch: np.ndarray | None = None
    multiple_stable: np.ndarray | None = None

    @property
    def stable(self) -> np.ndarray | None:
        """(B,) bool: converged to an equilibrium the Jacobi test found stable (None without
        ``stability``; False also where it was not assessed, stability_index -1)."""
        return None if self.stability_index is None else self.converged & (self.stability_index == 0)

    @property
    def tip_position(self) -> np.ndarray:
        return self.positions[:, -1]

    @property
    def tip_rotation(self) -> np.ndarray:
        return self.rotations[:, -1]

    def _batched(self):
        """The fields with a row per rod."""
        B = len(self.converged)
        return [f.name for f in fields(self) if isinstance(getattr(self, f.name), np.ndarray)
                and getattr(self, f.name).ndim and len(getattr(self, f.name)) == B]

    def rows(self, index) -> "StaticSolution":
        """The rods ``index`` (indices or a mask) of this solution, e.g. a warm start for a sub-batch."""
        return replace(self, **{k: getattr(self, k)[index] for k in self._batched()})

    def replaced(self, index: np.ndarray, other: "StaticSolution") -> "StaticSolution":
        """This solution with its rods ``index`` (indices) replaced by the rods of ``other``, in order."""
        out = {}
        for k in self._batched():
            v = getattr(self, k).copy()
            v[index] = getattr(other, k)
            out[k] = v
        return replace(self, **out)

    def failure_reasons(self) -> list[str]:
        """One string per rod: "converged" or why it failed."""
        return [describe_status(st) for st in self.status]

    def to_npz(self, path) -> None:
        arrays = {k: v for k, v in asdict(self).items() if isinstance(v, np.ndarray)}
        np.savez_compressed(path, **arrays)


def _constant_curvature(robot: Robot, tau: np.ndarray, opts: StaticOptions) -> StaticSolution:
    """The cheapest rung: closed-form arcs. Straight tendons ending at the tip and no external
    load give the coupled model's exact solution without shear and extension: a constant
    curvature u = Kbt^-1 sum_i r_i x (-tau_i e3), compression n = -sum(tau) t."""
    L = robot.length
    problems = [name for name, bad in (
        ("gravity", np.any(robot.gravity != 0)), ("tip_force", np.any(robot.tip_force != 0)),
        ("tip_moment", np.any(robot.tip_moment != 0)), ("point_forces", bool(robot.point_forces)),
        ("precurvature", np.any(robot.precurvature != 0)),
        ("helical tendons", any(np.any(t.helix_radius != 0) for t in robot.tendons)),
        ("tendons ending before the tip", any(t.length is not None and np.any(t.length < L * (1 - 1e-12))
                                              for t in robot.tendons)))
        if bad]
    if problems:
        raise InputError(f"solver model 'constant_curvature' needs straight tendons ending at the tip and no "
                         f"external load; this scene has {', '.join(problems)}")
    B, N = tau.shape[0], opts.nodes
    e3 = np.array([0.0, 0.0, 1.0])
    kbt = np.broadcast_to(robot.section()["kbt"], (B, 3))
    moment = np.zeros((B, 3))
    for k, t in enumerate(robot.tendons):
        off = np.broadcast_to(t.offset, (B, 2))
        r = np.c_[off, np.zeros(B)]
        moment += np.cross(r, -tau[:, k:k + 1] * e3)
    u = moment / kbt
    kappa = np.linalg.norm(u, axis=1)
    axis = np.where(kappa[:, None] > 0, u / np.maximum(kappa, 1e-300)[:, None], 0.0)
    Lb = np.broadcast_to(L, (B,))
    s = Lb[:, None] * np.linspace(0.0, 1.0, N + 1)[None]
    A = np.zeros((B, 3, 3))
    A[:, 0, 1], A[:, 0, 2], A[:, 1, 2] = -axis[:, 2], axis[:, 1], -axis[:, 0]
    A = A - np.transpose(A, (0, 2, 1))
    ks = kappa[:, None] * s
    eye = np.eye(3)[None, None]
    R = eye + np.sin(ks)[..., None, None] * A[:, None] + (1 - np.cos(ks))[..., None, None] * (A @ A)[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        c1 = np.where(kappa[:, None] > 0, (1 - np.cos(ks)) / kappa[:, None], 0.0)
        c2 = np.where(kappa[:, None] > 0, s - np.sin(ks) / kappa[:, None], 0.0)
    p = (s[..., None] * e3 + c1[..., None] * (A @ e3)[:, None] + c2[..., None] * (A @ A @ e3)[:, None])
    total = tau.sum(axis=1)
    n = -total[:, None, None] * (R @ e3)
    m = np.einsum("bsij,bj->bsi", R, kbt * u)
    status = np.full(B, layout.CONVERGED, dtype=np.int32)
    zeros = np.zeros(B)
    return StaticSolution(s=s, positions=p, rotations=R, n=n, m=m, base_wrench=np.c_[n[:, 0], m[:, 0]],
                          converged=np.ones(B, bool), status=status, iterations=zeros.astype(np.int32),
                          integrations=zeros.astype(np.int32), residual=zeros, orthogonality_error=zeros,
                          jacobian=np.zeros((B, 6, 6)), options=opts,
                          tip_error_estimate=zeros if opts.error_estimate else None)


class StaticProblem:
    """The device arrays of one robot batch at one shape (B rods, options, device), built
    once and reused by every solve of that shape: the tables, and per CPU thread the
    Model / Control / State / Work of its rods (tdcr_warp.core.solver.Shooting). ``mode``
    "reference": every tendon in tension control, frictionless (tdcr_warp.core.build.scene_features)."""

    def __init__(self, robot: Robot, B: int, opts: StaticOptions, device, mode: str = "solve"):
        self.robot, self.B, self.opts, self.device = robot, B, opts, device
        self.tables = Tables.of(robot, opts.nodes, opts.specialize, opts.kink_loads, mode, opts.tendon_states)
        self.chunks = split(B, device, opts.threads)
        K = robot.n_tendons
        self.solvers = [Shooting(self.tables, lo, hi, np.zeros((hi - lo, K)), precision=opts.precision,
                                 integrator=opts.integrator, model=opts.model, device=device, rod=opts.rod,
                                 driver=opts.driver)
                        for lo, hi in self.chunks]
        self.lock = threading.Lock()
        self._reference = None

    def reference_lengths(self) -> np.ndarray:
        """(B, K) the unstretched length of every tendon at the reference state (each tendon in
        tension control at its pretension, frictionless, under the robot's external loads),
        solved once, and for one rod where every rod has the same robot (the batch differs in its
        commands only): a displacement q asks the motor to take in q of it."""
        if self._reference is None:
            n = self.robot.batch_size  # 1 (shared) or B
            ref = StaticProblem(self.robot, n, self.opts, self.device, mode="reference")
            pre = np.broadcast_to(self.robot.tendon_columns("pretension"), (n, self.robot.n_tendons))
            sol = ref.solve(np.array(pre), None)
            if not sol.converged.all():
                bad = int(np.flatnonzero(~sol.converged)[0])
                raise InputError(f"the reference state of displacement control (every tendon at its pretension) "
                                 f"did not converge for rod {bad}: {sol.failure_reasons()[bad]}")
            self._reference = np.broadcast_to(sol.tendon_free_length, (self.B, self.robot.n_tendons)).copy()
        return self._reference

    def command(self, tau: np.ndarray, displacements: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
        """``available_lengths`` from this problem's reference state."""
        if not self.tables.features.displaced:
            return tau, None
        return available_lengths(self.robot, self.reference_lengths(), tau, displacements)

    def start(self, tau: np.ndarray, avail: np.ndarray | None) -> np.ndarray:
        """Scaled straight-rod start (B, nu): the displaced tendons at the tensions of the linear
        straight-rod model (``linear_tensions``), the base wrench of all tensions."""
        t, B = self.tables, self.B
        scales = t.scale_rows(B)
        if avail is None:
            return t.straight.guess(tau) / scales
        guess, z = self.linear_tensions(tau, avail)
        return np.concatenate([t.straight.guess(guess) / scales[:, :6], z], axis=1)

    @functools.cached_property
    def node_routes(self) -> tuple[np.ndarray, np.ndarray]:
        """r and r' of every tendon at the grid's nodes (tdcr_warp.physics.stability.node_routing), once."""
        return node_routing(self.robot, self.tables.grid)

    @functools.cached_property
    def tendon_compliance(self) -> np.ndarray:
        """(B, K, K) the linear model of a straight rod (``linear_tensions``): tendon k shortens by
        sum_j C_kj tau_j, C_kj = l_kj (r_k . r_j / EI + 1 / EA) + c_k l_k delta_kj (l_kj =
        min(l_k, l_j): the bending and the compression of tendon j act where it runs; r at the
        base). Built once per problem: it depends on the robot alone."""
        rb, B, K = self.robot, self.B, self.robot.n_tendons
        r = np.broadcast_to(rb.tendon_routing(0.0)[0], (B, K, 3))
        lk = np.broadcast_to(rb.tendon_lengths(), (B, K))
        lkj = np.minimum(lk[:, :, None], lk[:, None, :])
        sec = rb.section()
        ei = np.broadcast_to(sec["kbt"][:, 0], (B,))[:, None, None]
        ea = np.broadcast_to(sec["kse"][:, 2], (B,))[:, None, None]
        C = lkj * (np.einsum("bki,bji->bkj", r, r) / ei + 1.0 / ea)
        return C + np.eye(K) * (np.broadcast_to(rb.tendon_columns("compliance"), (B, K)) * lk)[:, :, None]

    def linear_tensions(self, tau: np.ndarray, avail: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tensions (B, K) of the displaced tendons in the linear model of a straight rod
        (``tendon_compliance``), and their scaled unknowns (B, Kd): the displaced set solves
        C_DD tau_D = free_D - avail_D - C_DT tau_T, with an active set for slack (a negative
        tension goes slack, the set solved again; pseudo-inverse: four tendons at 90 degrees
        have a co-contraction mode no length fixes)."""
        rb, t = self.robot, self.tables
        B, K = tau.shape
        disp = np.flatnonzero(t.tmode[0] >= 0)
        C = self.tendon_compliance
        is_disp = np.zeros(K, dtype=bool)
        is_disp[disp] = True
        free = np.broadcast_to(t.straight.path, (B, K))
        known = np.where(is_disp, 0.0, tau)
        rhs = free - avail - np.einsum("bkj,bj->bk", C, known)
        active = np.broadcast_to(is_disp, (B, K)).copy()
        for _ in range(len(disp) + 1):
            both = active[:, :, None] & active[:, None, :]
            M = np.where(both, C, np.eye(K))
            sol = np.einsum("bkj,bj->bk", np.linalg.pinv(M), np.where(active, rhs, 0.0))
            neg = active & (sol < 0)
            if not neg.any():
                break
            active &= ~neg
        guess = np.where(is_disp, np.where(active, sol, 0.0), tau)
        scales = t.scale_rows(B)[:, 6:]
        L = np.broadcast_to(rb.length, (B,))[:, None]
        slope = np.broadcast_to(t.tendon[..., layout.T_SLACK_SLOPE], (B, K))[:, disp]
        needed = (free - np.einsum("bkj,bj->bk", C, guess))[:, disp]
        z = np.where(active[:, disp], guess[:, disp] / scales, (needed - avail[:, disp]) / (L * slope))
        return guess, z

    def solve(self, tau: np.ndarray, initial: StaticSolution | None, displacements: np.ndarray | None = None,
              slip: np.ndarray | None = None, history: StaticSolution | None = None, *,
              sensitivities: bool = False, stability: str = "off", parameters: tuple = ()) -> StaticSolution:
        """One solve of the batch; with ``sensitivities`` or ``stability`` (see StaticOptions)
        also the rods' sensitivities (``parameters``: robot field names, tdcr_warp.physics.sensitivity)."""
        opts, tables, B = self.opts, self.tables, self.B
        ptables = parameter_tables(self.robot, tables, parameters, opts.precision, opts.nodes, opts.specialize,
                                   opts.kink_loads, opts.tendon_states) if parameters else []
        linear = sensitivities or stability != "off" or bool(parameters)
        nu = tables.nu
        scales = tables.scale_rows(B)
        tau, avail = self.command(tau, displacements)
        K = tau.shape[1]
        slip = np.ones((B, K)) if slip is None else slip
        profile = None
        if history is not None:
            if history.base_wrench.shape[0] != B:
                raise InputError(f"history: a solution of {history.base_wrench.shape[0]} rods, the batch has {B}")
            if tables.features.friction:
                if history.tension_slots is None or history.tension_slots.shape != (B, self.solvers[0].n_slots, 3 * K):
                    raise InputError("history: expected a solution of this robot and solver options with friction "
                                     "(its tension_slots)")
                profile = history.tension_slots
                # the predictor of a stick-slip step: the whole tendon slipping the way its motor moved
                was = history.tendon_tension_base if avail is None else history.tendon_free_length
                now = tau if avail is None else avail
                moved = np.where(np.broadcast_to(tables.tmode[0] >= 0, (B, K)), was - now, now - was)
                slip = np.where(moved >= 0, 1.0, -1.0)
        # a quasi-static step starts from the last one, with a fresh Jacobian (a chain of Broyden
        # updates goes stale as the shape and the stick-slip pattern move)
        start = initial or history
        warm = start is not None
        if warm:
            x_init = start.unknowns if start.unknowns is not None else start.base_wrench / scales[:, :6]
            if x_init.shape != (B, nu) or start.jacobian.shape[1:] != (nu, nu):
                raise InputError(f"initial: warm start has shape {x_init.shape}, this problem needs ({B}, {nu})")
            x0, J0 = x_init, (start.jacobian if initial is not None else None)
        else:
            x0, J0 = self.start(tau, avail), None
        newton = dict(tol=opts.tolerance, max_iter=opts.max_iter, max_step=opts.max_step,
                      broyden=opts.jacobian == "broyden")
        free = None if avail is None else np.broadcast_to(tables.straight.path, tau.shape)

        disp = np.flatnonzero(tables.tmode[0] >= 0)
        j_of = 6 + tables.tmode[0, disp]

        def run(i):
            lo, hi = self.chunks[i]
            sh = self.solvers[i]
            sh.set_command(tau[lo:hi], None if avail is None else avail[lo:hi])
            sh.set_memory(slip[lo:hi], None)
            taut = np.ones((hi - lo, K), dtype=bool)
            taut[:, disp] = x0[lo:hi, j_of] >= 0
            sh.set_taut(taut)
            if J0 is not None:
                sh.dev.put(sh.newton.J, J0[lo:hi])
            sh.solve(x0[lo:hi], fresh_jacobian=J0 is None, **newton)
            if opts.continuation and not warm:
                finite, large, steps = continuation_steps(x0[lo:hi], opts.continuation)
                redo = finite & (~sh.converged() | large)
                if redo.any():
                    load_continuation(sh, tables.rows("rod", lo, hi), tables.rows("pforce", lo, hi), tau[lo:hi],
                                      x0[lo:hi], redo, steps, newton,
                                      None if avail is None else (free[lo:hi], avail[lo:hi]))
            if len(disp):
                settle_slack(sh, taut, disp, j_of, newton)
            if profile is not None:  # the stick-slip corrector, from the slipping predictor
                ok = sh.converged()
                iters, shots = sh.counts()
                sh.set_memory(slip[lo:hi], profile[lo:hi])
                sh.solve(np.where(ok[:, None], sh.newton.x.numpy(), x0[lo:hi]), **newton)
                if len(disp):
                    settle_slack(sh, taut, disp, j_of, newton)
                it, sn = sh.counts()
                sh.set_counts(it + iters, sn + shots)
            res = sh.results()
            if linear:
                res |= self._linearise(sh, lo, hi, tau[lo:hi], taut, res, ptables, stability)
                if stability == "stable":
                    res = self._stable_branch(sh, lo, hi, tau[lo:hi], taut, res, ptables, newton, disp, j_of)
            return res

        parts = parallel(run, list(range(len(self.chunks))))
        out = parts[0] if len(parts) == 1 else {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
        x = out.pop("x")
        out["base_wrench"] = x[:, :6] * scales[:, :6]
        grid = tables.grid
        s = np.broadcast_to(grid, (B, grid.shape[1])).astype(np.float64)
        tendon = tendon_results(tables, out, x, tau, slip, profile is not None)
        if linear:
            bad = ~out["converged"]
            for k in ("tip_jacobian", "tip_compliance", "tension_jacobian", "slack_jacobian", "parameter_jacobian"):
                out[k][bad] = np.nan
            out["parameter_names"] = tuple(parameters)
            if stability != "off":
                st = out["stability_index"]
                out["status"] = np.where(st > 0, out["status"] | layout.UNSTABLE, out["status"]).astype(
                    out["status"].dtype)
        return StaticSolution(s=s, options=opts, unknowns=x, **out, **tendon)

    def _linearise(self, sh: Shooting, lo: int, hi: int, tau: np.ndarray, taut: np.ndarray, res: dict,
                   ptables: list, stability: str) -> dict:
        """The sensitivities and (``stability``) the Jacobi index of rods lo:hi from their
        solution ``res`` (the base of the probes: its shapes and residual)."""
        t, o = self.tables, self.opts
        base = {"res": sh.newton.r.numpy().astype(np.float64), "p": res["positions"][:, -1],
                "R": res["rotations"][:, -1], "P": res["positions"], "Rn": res["rotations"], "n": res["n"],
                "m": res["m"]}
        K = tau.shape[1]
        assess = stability != "off" and not t.features.friction and (o.model == "coupled" or K == 0)
        lin = linearise(sh, tau, t, lo, hi, o.precision, ptables, base=base, shapes=assess)
        b = hi - lo
        out = {k: lin[k] for k in ("tip_jacobian", "tip_compliance", "parameter_jacobian")}
        out["tension_jacobian"] = np.where(taut[:, :, None], lin["tension_jacobian"], 0.0)  # slack: no tension
        out["slack_jacobian"] = np.where(taut[:, :, None], 0.0, lin["slack_jacobian"])
        if stability != "off":
            index, lag = np.full(b, -1, dtype=np.int64), np.full(b, np.nan)
            if assess:
                tension = res["tendons"][..., layout.TO_BASE] if "tendons" in res else tau
                index, lag, _ = jacobi_index(sh, lin, t, self.node_routes, lo, hi, tension, o.precision,
                                             o.rod == "kirchhoff", o.model == "coupled",
                                             taut if t.features.displaced else None)
                index = np.where(res["converged"], index, -1)
            out |= {"stability_index": index, "lagrangian_error": lag}
        out["integrations"] = res["integrations"] + lin["integrations"]
        return out

    def _stable_branch(self, sh: Shooting, lo: int, hi: int, tau: np.ndarray, taut: np.ndarray, res: dict,
                       ptables: list, newton: dict, disp: np.ndarray, j_of: np.ndarray) -> dict:
        """Rods whose equilibrium is unstable are solved again from restarts (``RESTARTS``: the
        solution with an added base moment about each bending axis, both ways, of growing
        size); the first stable equilibrium found is returned (branch 1), distinct
        stable ones are reported (multiple_stable); a rod with none keeps its unstable
        solution (branch -1). Iterations and integrations add up over the restarts."""
        b = hi - lo
        bad = res["stability_index"] > 0
        branch = np.zeros(b, dtype=np.int8)
        out = {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in res.items()}
        if bad.any():
            x_star = res["x"]
            L = np.broadcast_to(self.tables.rows("rod", lo, hi)[:, layout.LENGTH], (b,))
            tips: list[list[np.ndarray]] = [[] for _ in range(b)]
            lam_l = np.sqrt(np.maximum(1.0, -x_star[:, 2]))  # x[2] = n_z(0) L^2 / EI
            for j, bend in RESTARTS:
                start = x_star.copy()
                start[:, j] += bend * lam_l
                sh.solve(start, mask=bad.astype(np.int32), **newton)
                if len(disp):
                    settle_slack(sh, taut.copy(), disp, j_of, newton)
                it, sn = sh.counts()
                out["iterations"] = out["iterations"] + np.where(bad, it, 0)
                out["integrations"] = out["integrations"] + np.where(bad, sn, 0)
                got = sh.results()
                got |= self._linearise(sh, lo, hi, tau, taut, got, ptables, "check")
                ok = bad & got["converged"] & (got["stability_index"] == 0)
                for i in np.flatnonzero(ok):
                    tip = got["positions"][i, -1]
                    if all(np.linalg.norm(tip - t) > DISTINCT * L[i] for t in tips[i]):
                        tips[i].append(tip)
                take = ok & (branch == 0)
                for k, v in got.items():
                    if isinstance(v, np.ndarray) and k not in ("iterations", "integrations"):
                        out[k][take] = v[take]
                branch[take] = 1
            branch[bad & (branch == 0)] = -1
            out["multiple_stable"] = np.array([len(t) > 1 for t in tips])
        else:
            out["multiple_stable"] = np.zeros(b, dtype=bool)
        out["branch"] = branch
        return out


def available_lengths(robot: Robot, reference: np.ndarray, tau: np.ndarray,
                      displacements: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Tensions with the displaced columns zeroed, and the unstretched length the motor gives
    each displaced tendon, reference - q (B, K) [m] (None: q = 0), or an InputError where that is
    not positive."""
    disp = list(robot.displaced)
    q = np.zeros_like(tau) if displacements is None else displacements
    avail = np.zeros_like(tau)
    avail[:, disp] = reference[:, disp] - q[:, disp]
    bad = avail[:, disp] <= 0
    if bad.any():
        b, j = np.argwhere(bad)[0]
        k = disp[j]
        raise InputError(f"displacements[{b}][{k}] = {float(q[b, k])!r} m needs a negative tendon length: tendon {k} "
                         f"holds {reference[b, k]:.6g} m of unstretched tendon at its reference")
    tau = tau.copy()
    tau[:, disp] = 0.0
    return tau, avail


SLACK_PASSES = 8
# Restarts of an unstable rod: (scaled base-moment unknown, added moment in units of
# max(1, lambda L) EI / L, lambda L = sqrt(P L^2 / EI) for the axial compression P at the
# base). The bent branch of a compressed cantilever has a base moment of about 0.8 to 2
# lambda L EI / L (the elastica from 1.1 to 10 times the buckling load).
RESTARTS = tuple((j, sign * size) for size in (1.0, 2.0, 4.0) for j in (3, 4) for sign in (1.0, -1.0))
DISTINCT = 1e-6  # stable equilibria whose tips are this many rod lengths apart are distinct


def settle_slack(sh: Shooting, taut: np.ndarray, disp: np.ndarray, j_of: np.ndarray, newton: dict) -> None:
    """The complementarity of displacement control, per rod: a taut tendon solved to a negative
    tension goes slack (also where the solve failed: a wrong taut set can keep Newton from
    converging), a slack one whose path needs more tendon than it has goes taut, and the rod is
    solved again from where it stopped, until the set settles (``SLACK_PASSES``; then flagged
    UNSETTLED). Each solve is smooth in its unknowns; the unknown of a tendon that switches is
    near zero either way. Iterations and integrations add up over the passes."""
    iters, shots = sh.counts()
    for _ in range(SLACK_PASSES):
        z = sh.newton.x.numpy()[:, j_of]
        ok = sh.converged()
        flip = np.where(taut[:, disp], z < 0, ok[:, None] & (z > 0))
        rods = flip.any(axis=1)
        if not rods.any():
            break
        taut[:, disp] ^= flip
        sh.set_taut(taut)
        sh.solve(None, mask=rods.astype(np.int32), **newton)
        it, sn = sh.counts()
        iters[rods] += it[rods]
        shots[rods] += sn[rods]
    else:
        z = sh.newton.x.numpy()[:, j_of]
        bad = np.where(taut[:, disp], z < 0, z > 0).any(axis=1)
        if bad.any():
            st = sh.newton.status.numpy()
            st[bad] = (st[bad] & ~layout.CONVERGED) | layout.UNSETTLED
            sh.dev.put(sh.newton.status, st)
    sh.set_counts(iters, shots)


def tendon_results(tables: Tables, out: dict, x: np.ndarray, tau: np.ndarray, slip: np.ndarray,
                   stick: bool) -> dict:
    """The per-tendon fields of a StaticSolution from a solve's raw results (popped from ``out``)."""
    f = tables.features
    if not f.tendons:
        return {"tendon_tension_base": tau.copy(), "tendon_tension_end": tau.copy()}
    td = out.pop("tendons")
    res = {"tendon_tension_base": td[..., layout.TO_BASE], "tendon_tension_end": td[..., layout.TO_END],
           "tendon_path_length": td[..., layout.TO_PATH], "tendon_free_length": td[..., layout.TO_FREE],
           "tendon_turning": td[..., layout.TO_TURN] if f.friction else None,
           "tendon_tension": out.pop("tension_nodes")}
    slack = np.zeros(tau.shape, dtype=bool)
    disp = np.flatnonzero(tables.tmode[0] >= 0)
    slack[:, disp] = td[:, disp, layout.TO_BASE] == 0
    res["slack"] = slack
    if f.friction:
        slots = out.pop("tension_slots")
        K = tau.shape[1]
        n_int = tables.grid.shape[1] - 1
        stages = (slots.shape[1] - 2 * (n_int + 1)) // n_int
        first = stages * np.minimum(np.arange(n_int + 1), n_int - 1)  # the first stage just distal of each node
        res["slip"] = np.zeros_like(slip) if stick else slip.copy()
        res["slip_state"] = slots[:, first, 2 * K:].astype(np.int8)
        res["tension_slots"] = slots
    return res


CACHE_SIZE = 8
CACHE_NODE_RODS = 1 << 17  # cache problems up to B (N + 1) of this (~20 MB of device arrays each)
_cache: OrderedDict = OrderedDict()
_cache_lock = threading.Lock()


def _problem(robot: Robot, B: int, opts: StaticOptions, device) -> tuple[StaticProblem, bool]:
    """A cached problem of this robot object and shape (locked for the caller), or a new one.
    Returns (problem, cached)."""
    if B * (opts.nodes + 1) > CACHE_NODE_RODS:
        return StaticProblem(robot, B, opts, device), False
    key = (id(robot), B, replace(opts, error_estimate=False, sensitivities=False, stability="off"), device.alias)
    with _cache_lock:
        hit = _cache.get(key)
        if hit is not None and hit[0]() is robot and hit[1].lock.acquire(blocking=False):
            _cache.move_to_end(key)
            return hit[1], True
    problem = StaticProblem(robot, B, opts, device)
    problem.lock.acquire()
    with _cache_lock:
        _cache[key] = (weakref.ref(robot), problem)
        while len(_cache) > CACHE_SIZE:
            _cache.popitem(last=False)
    return problem, True


def reference_lengths(robot: Robot, *, options: StaticOptions | None = None, device: str | None = None,
                      **overrides) -> np.ndarray:
    """(B, K) the unstretched length of every tendon in the reference state of displacement
    control: each tendon in tension control at its pretension, frictionless, under the robot's
    external loads [m] (a displacement q leaves the tendon this minus q)."""
    opts = (options or StaticOptions()).override(**overrides)
    problem, locked = _problem(robot, robot.batch_size, opts, wp.get_device(device))
    try:
        return problem.reference_lengths().copy()
    finally:
        if locked:
            problem.lock.release()


def solve_static(robot: Robot, tensions=None, *, displacements=None, slip=None, history: StaticSolution | None = None,
                 options: StaticOptions | None = None, device: str | None = None,
                 initial: StaticSolution | None = None, parameters=None, **overrides) -> StaticSolution:
    """Solve the statics of a batch of rods.

    robot: the batch (shared or per-rod fields); tensions: (B, K) or (K,) [N], each >= 0 (None:
    zeros), for the tendons under tension control (0 for the others). displacements: (B, K) or
    (K,) motor displacements [m], pull positive, for the tendons under displacement control
    (0 for the others): the motor takes in q of unstretched tendon relative to the reference
    state, where every tendon holds its pretension. slip: (B, K) or (K,) friction's slip
    direction per tendon, +1 (pulled, the default) or -1 (released). history: the previous
    solution of a quasi-static sequence (friction): each tendon keeps its previous tension where
    friction can hold it (stick) and slips where it cannot (README, *Tendons*); slip is then
    not used. options / overrides: :class:`StaticOptions` fields (nodes, integrator, model, ...).
    device: "cpu" or "cuda:0" (None: Warp's default). initial: an earlier solution of the
    same batch size to warm-start from (its unknowns and Jacobian). parameters: robot fields
    to differentiate the tip pose by (``parameter_jacobian``), e.g. "youngs_modulus",
    "tendons[0].offset[1]", "tip_force[0]" (tdcr_warp.physics.sensitivity; under displacement control
    the motor's given length is held, not the displacement).
    """
    opts = (options or StaticOptions()).override(**overrides)
    slip = None if slip is None else real_array(slip, "slip", copy=False)
    tau, q = check_command(robot, tensions, displacements,
                           None if slip is None or np.ndim(slip) != 2 else max(robot.batch_size, np.shape(slip)[0]))
    B = tau.shape[0]
    sg = None if slip is None else check_slip(robot, slip, B)
    if opts.model == "constant_curvature":
        if robot.displaced or robot.has_friction:
            raise InputError("solver model 'constant_curvature' has no displacement control or friction: "
                             "use model 'coupled' or 'point'")
        if opts.sensitivities or opts.stability != "off" or parameters:
            raise InputError("solver model 'constant_curvature' has no sensitivities or stability test: use model "
                             "'coupled' or 'point'")
        return _constant_curvature(robot, tau, opts)
    dev = wp.get_device(device)
    require_memory(B * (opts.nodes + 1) * 400.0, f"nodes = {opts.nodes} for {B} rods: the shapes")
    problem, locked = _problem(robot, B, opts, dev)
    try:
        sol = problem.solve(tau, initial, q, sg, history, sensitivities=opts.sensitivities,
                            stability=opts.stability, parameters=tuple(parameters or ()))
    finally:
        if locked:
            problem.lock.release()
    if opts.error_estimate:
        coarse = solve_static(robot, tau, displacements=q, slip=sg,
                              options=replace(opts, nodes=max(1, opts.nodes // 2), error_estimate=False,
                                              sensitivities=False, stability="off"),
                              device=device, initial=sol if history is None else None)
        order = {"euler": 1, "midpoint": 2, "rk4": 4}[opts.integrator]
        est = 2.0 * np.linalg.norm(sol.tip_position - coarse.tip_position, axis=1) / (2**order - 1)
        sol.tip_error_estimate = np.where(coarse.converged, est, np.inf)
    return sol
