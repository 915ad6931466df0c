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
from contextlib import nullcontext
from dataclasses import asdict, dataclass, field, fields, replace

import numpy as np
import warp as wp

from tdcr_warp.core.build import Tables
from tdcr_warp.core.homotopy import continuation_steps, holding_path, load_continuation
from tdcr_warp.core.parallel import parallel, split
from tdcr_warp.core.solver import Shooting, first_jacobian
from tdcr_warp.kernels import layout
from tdcr_warp.kernels.segments import segmentable as kernel_segmentable
from tdcr_warp.model.options import StaticOptions, check_model_support, describe_status
from tdcr_warp.model.robot import InputError, Robot, check_command, check_slip, real_array, require_memory
from tdcr_warp.physics.assessment import Assessor
from tdcr_warp.physics.contact import Contact, chunk_contacts, penetration
from tdcr_warp.physics.crossing import lean_along, uncross
from tdcr_warp.physics.segments import Segments
from tdcr_warp.physics.sensitivity import parameter_tables
from tdcr_warp.physics.slack import available_lengths, linear_tensions, settle_slack, tendon_compliance

__all__ = ["StaticOptions", "StaticProblem", "StaticSolution", "armed_segments", "reference_lengths", "solve_static"]


class RodRows:
    """The rows of a dataclass of per-rod arrays (its fields with a row per rod): a sub-batch, a
    join of parts, a replacement of some rods."""

    def _batched(self):
        """The fields with a row per rod."""
        B = len(self.converged)
        return [f.name for f in fields(self) if isinstance(getattr(self, f.name), np.ndarray)
                and getattr(self, f.name).ndim and len(getattr(self, f.name)) == B]

    def rows(self, index) -> "RodRows":
        """The rods ``index`` (indices or a mask) of this solution, e.g. a warm start for a sub-batch."""
        return replace(self, **{k: getattr(self, k)[index] for k in self._batched()})

    @staticmethod
    def joined(parts: list) -> "RodRows":
        """The rods of ``parts`` (solutions of one robot and solver options) in order, as one solution."""
        return replace(parts[0], **{k: np.concatenate([getattr(p, k) for p in parts]) for k in parts[0]._batched()})

    def replaced(self, index: np.ndarray, other: "RodRows") -> "RodRows":
        """This solution with its rods ``index`` (indices) replaced by the rods of ``other``, in order."""
        out = {}
        for k in self._batched():
            v = getattr(self, k).copy()
            v[index] = getattr(other, k)
            out[k] = v
        return replace(self, **out)

    def to_npz(self, path) -> None:
        """Every array field into a compressed NumPy archive ``path``."""
        arrays = {k: v for k, v in asdict(self).items() if isinstance(v, np.ndarray)}
        np.savez_compressed(path, **arrays)


@dataclass
class StaticSolution(RodRows):
    """Solved shapes and diagnostics of B rods (float64 NumPy arrays on the host).

    s: (B, N+1) arc length of the nodes [m]; positions: (B, N+1, 3) [m]; rotations: (B, N+1, 3, 3) body-to-world;
    n, m: (B, N+1, 3) internal force [N] and moment [N m] (world frame) just proximal of each node (so n[:, -1] =
    n(L-), before the tip loads); tip_position (B, 3), tip_rotation (B, 3, 3); base_wrench (B, 6) = [n(0), m(0)].
    converged (B,) bool; status (B,) bit flags (kernels/layout.py); iterations (B,); integrations (B,):
    base-to-tip integrations spent (the 7 of a first Jacobian in a Broyden RK4 solve with N >= 16 run over double
    steps, at about half the cost; the probes of sensitivities included); residual (B,): L |r| [m];
    orthogonality_error (B,): max |R^T R - I| over the nodes; jacobian (B, nu, nu): the last scaled shooting
    Jacobian (reused by a warm start); unknowns (B, nu): the scaled shooting unknowns (nu = 6 + one per
    displacement-controlled tendon). tip_error_estimate (B,) [m]: with ``error_estimate`` only.

    Sensitivities (``sensitivities``; NaN for rods that did not converge; the tip pose is [p(L) [m], theta [rad]],
    theta the world-frame rotation vector of a small tip rotation): tip_jacobian (B, 6, K) d pose / d command, per
    tendon its tension [N] under tension control or its motor displacement [m] under displacement control;
    tip_compliance (B, 6, 6) d pose / d [F_tip [N], M_tip [N m]] (world frame); tension_jacobian (B, K, K) d
    tendon_tension_base[k] / d command[l] (the identity for tension control; zero rows for slack tendons);
    slack_jacobian (B, K, K) d (slack length [m] of slack tendon k) / d command[l] (zero rows for taut tendons);
    parameter_jacobian (B, 6, P) d pose / d parameter (units of each parameter, ``parameter_names``). Stability
    (on by default; None with ``stability="off"``): stability_index (B,) the number of unstable directions (0:
    stable; -1: not assessed: not converged, for the whole batch ``stability_note``: friction, point-model
    tendons, disks, or a rod whose phases turn too fast even on 16 steps an interval; ``stability_reasons`` says
    which, ``assessed`` (B,) bool which rods have a verdict);
    lagrangian_error (B,) the check of the test (small: trustworthy); stability_margin (B,) [rad] how far the rod
    is from a change of the count (small: near a buckling load; see ``stability_reasons``); with "stable" also
    branch (B,) int8 (0: as solved, 1: the solve landed on an unstable equilibrium and a restart found this stable
    one, -1: unstable, no stable one found) and multiple_stable (B,) bool (restarts found distinct stable
    equilibria).

    With obstacles (None otherwise; tdcr_warp/physics/contact.py): contact_force (B, N+1, 3) the obstacles' point
    force on each node [N] (world frame; n jumps by it there), contact_gap (B, N+1, O) each node's gap to each
    obstacle [m] (negative: penetration), interval_gap (B, N, O) the smallest gap along each interval between two
    nodes [m] (the centre line checked between the nodes), contact_stiffness (B, O) the penalty stiffness each
    obstacle was solved with [N/m per m]; ``penetration`` (B, O) the deepest penetration of each [m], at a node or
    between two; a rigid one beyond ``contact_tolerance`` flags PENETRATION. With a constrained tip: tip_reaction (B,
    3) the force it takes [N] (world). segments (B,) int: the segments of multiple shooting each rod was solved in (1:
    single shooting; ``StaticOptions.segments``); a split rod's sensitivities are NaN (its stability verdict carries
    the Jacobi fields over the segments: tdcr_warp/physics/stability.py).

    Per tendon (B, K): tendon_tension_base (at the motor side, s = 0) and tendon_tension_end (just before its
    termination) [N]. With tendon states (displacement control or friction; None otherwise): tendon_path_length,
    the length of its deformed path [m]; tendon_free_length, the unstretched tendon that path holds [m];
    tendon_turning (with friction), the total turning of its path [rad], kinks included where they are modelled;
    tendon_tension (B, N+1, K) just distal of every node [N]; slack (B, K): a displacement-controlled tendon with
    zero tension and length to spare. With friction: slip (B, K), the slip direction each tendon was solved with
    (+1 pulled, -1 released, 0: stick-slip from ``history``); slip_state (B, N+1, K) int8 just distal of each
    node: +1 sliding toward the motor, -1 away from it, 0 stuck; tension_slots: the profile a following
    quasi-static solve starts from (``history``).
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
    stability_margin: np.ndarray | None = None
    stability_note: str = ""
    branch: np.ndarray | None = None
    multiple_stable: np.ndarray | None = None
    tip_reaction: np.ndarray | None = None
    contact_force: np.ndarray | None = None
    contact_gap: np.ndarray | None = None
    interval_gap: np.ndarray | None = None
    contact_stiffness: np.ndarray | None = None
    segments: np.ndarray | None = None

    @property
    def stable(self) -> np.ndarray | None:
        """(B,) bool: converged to an equilibrium the Jacobi test found stable (None without
        ``stability``; False also where it was not assessed, stability_index -1)."""
        return None if self.stability_index is None else self.converged & (self.stability_index == 0)

    @property
    def success(self) -> np.ndarray:
        """(B,) bool: converged, not found unstable and not through an obstacle (an unstable
        equilibrium or an unresolved contact is never a success). A rod the test could not assess
        is a success of the solve whose stability is unknown: ``assessed`` says so (False), and
        ``tdcr-warp static`` counts it apart (exit status 3)."""
        return self.converged & ((self.status & (layout.UNSTABLE | layout.PENETRATION | layout.CROSSED)) == 0)

    @property
    def assessed(self) -> np.ndarray | None:
        """(B,) bool: the rod has a stability verdict (index >= 0; else ``stability_reasons`` says why)."""
        return None if self.stability_index is None else self.stability_index >= 0

    def stability_reasons(self) -> list[str] | None:
        """One string per rod: "stable", "unstable: k directions", or why it was not assessed
        (None with ``stability="off"``)."""
        if self.stability_index is None:
            return None
        return ["stable" if i == 0 else f"unstable: {i} directions" if i > 0 else
                "not assessed: not converged" if not ok else f"not assessed: {self.stability_note}" if self.stability_note
                else "not assessed: the phases turn too fast for the grid (raise nodes)" if np.isnan(margin)
                else "not assessed: the wires' stiffness is singular here (a bifurcation point)"
                for i, ok, margin in zip(self.stability_index.tolist(), self.converged.tolist(),
                                         self.stability_margin.tolist())]

    @property
    def segments_or_one(self) -> np.ndarray:
        """(B,) ``segments``, 1 where it is not reported (the closed-form model)."""
        return np.ones(len(self.converged), dtype=int) if self.segments is None else self.segments

    @property
    def penetration(self) -> np.ndarray | None:
        """(B, O) the deepest penetration of each obstacle [m], nodes and intervals (None without obstacles)."""
        return None if self.contact_gap is None else np.maximum(penetration(self.contact_gap),
                                                                 penetration(self.interval_gap))

    @property
    def tip_position(self) -> np.ndarray:
        return self.positions[:, -1]

    @property
    def tip_rotation(self) -> np.ndarray:
        return self.rotations[:, -1]

    def failure_reasons(self) -> list[str]:
        """One string per rod: "converged" or why it failed."""
        return [describe_status(st) for st in self.status]


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
                          tip_error_estimate=zeros if opts.error_estimate else None,
                          **({} if opts.stability == "off" else {
                              "stability_index": np.full(B, -1, dtype=np.int64), "lagrangian_error": zeros + np.nan,
                              "stability_margin": zeros + np.nan, "stability_note": "the constant-curvature model"}))


class StaticProblem:
    """The device arrays of one robot batch at one shape (B rods, options, device), built once and reused by
    every solve of that shape: the tables, and per CPU thread the Model / Control / State / Work of its rods
    (Shooting). ``mode`` "reference": every tendon in tension control, frictionless (build.scene_features)."""

    def __init__(self, robot: Robot, B: int, opts: StaticOptions, device, mode: str = "solve"):
        self.robot, self.B, self.opts, self.device = robot, B, opts, device
        self.tables = Tables.of(robot, opts.nodes, opts.specialize, opts.kink_loads, mode, opts.tendon_states,
                                 opts.model == "disks")
        self.chunks = split(B, device, opts.threads)
        K = robot.n_tendons
        self.solvers = [Shooting(self.tables, lo, hi, np.zeros((hi - lo, K)), precision=opts.precision,
                                 integrator=opts.integrator, model=opts.model, device=device, rod=opts.rod,
                                 driver=opts.driver)
                        for lo, hi in self.chunks]
        self.disp = np.flatnonzero(self.tables.tmode[0] >= 0)  # the displaced tendons
        self.j_of = 6 + self.tables.tmode[0, self.disp]  # their shooting unknowns
        self.assessor = Assessor(robot, self.tables, opts)
        self.armed = armed_segments(self.tables, opts)  # multiple shooting's count (None: as needed; 1: never)
        self.contacts = chunk_contacts(robot, self.tables, self.solvers, self.chunks, self.armed)
        self.lock = threading.Lock()
        self._reference = None
        self._unloaded: tuple | None = None  # the rods' unloaded Jacobians and their cost (unloaded_jacobians)

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

    @functools.cached_property
    def tendon_compliance(self) -> np.ndarray:
        """(B, K, K) the straight rod's linear tendon model (tdcr_warp.physics.slack.tendon_compliance), once."""
        return tendon_compliance(self.robot, self.B)

    def start(self, tau: np.ndarray, avail: np.ndarray | None) -> np.ndarray:
        """Scaled straight-rod start (B, nu): the displaced tendons at the tensions of the linear
        straight-rod model (tdcr_warp.physics.slack.linear_tensions), the base wrench of all tensions."""
        t = self.tables
        react = np.zeros((len(tau), t.features.tip))  # a constrained tip's reaction starts at zero
        if avail is None:
            return np.concatenate([t.straight.guess(tau) / t.scales[:, :6], react], axis=1)
        guess, z = linear_tensions(self.robot, t, self.tendon_compliance, tau, avail)
        return np.concatenate([t.straight.guess(guess) / t.scales[:, :6], z, react], axis=1)

    def solve(self, tau: np.ndarray, initial: StaticSolution | None, displacements: np.ndarray | None = None,
              slip: np.ndarray | None = None, history: StaticSolution | None = None, *,
              sensitivities: bool = False, stability: str = "off", parameters: tuple = (),
              free: StaticSolution | None = None) -> StaticSolution:
        """One solve of the batch; with ``sensitivities`` or ``stability`` (see StaticOptions) also the rods'
        sensitivities (``parameters``: robot field names); ``free``: a held tip's rods solved free, its start."""
        opts, tables = self.opts, self.tables
        ptables = parameter_tables(self.robot, tables, parameters, opts.precision, opts.nodes, opts.specialize,
                                   opts.kink_loads, opts.tendon_states) if parameters else []
        tau, avail = self.command(tau, displacements)
        slip, profile = _slip_memory(tables, self.solvers[0].n_slots, tau, avail, slip, history)
        x0, J0 = self._first_guess(tau, avail, initial, history)
        warm = (initial or history) is not None
        if free is not None and not warm:
            x0 = np.concatenate([free.unknowns, np.zeros((self.B, tables.features.tip))], axis=1)
        J0, spent = (J0, None) if warm else unloaded_jacobians(self, avail)
        newton = {"tol": opts.tolerance, "max_iter": opts.max_iter, "max_step": opts.max_step,
                  "broyden": opts.jacobian == "broyden"}
        stiffness = None if initial is None else initial.contact_stiffness
        job = _Job(tau=tau, avail=avail, slip=slip, profile=profile, x0=x0, J0=J0, spent=spent, warm=warm,
                   newton=newton, ptables=ptables, linear=sensitivities or bool(parameters), stability=stability,
                   stiffness=stiffness, free=None if free is None or warm else x0)
        parts = parallel(lambda i: self._solve_chunk(i, job), list(range(len(self.chunks))))
        out = parts[0] if len(parts) == 1 else {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
        return _solution(tables, opts, out, job, tuple(parameters), self.assessor.unassessed)

    def _first_guess(self, tau: np.ndarray, avail: np.ndarray | None, initial: StaticSolution | None,
                     history: StaticSolution | None) -> tuple[np.ndarray, np.ndarray | None]:
        """The scaled unknowns (B, nu) Newton starts from and the Jacobian (B, nu, nu) it reuses
        (None: a fresh one): a warm start's (``initial``), a quasi-static step's last unknowns with a
        fresh Jacobian (``history``: a chain of Broyden updates goes stale as the shape and the
        stick-slip pattern move), else the straight-rod start."""
        start = initial or history
        if start is None:
            return self.start(tau, avail), None
        B, nu = self.B, self.tables.nu
        x_init = start.unknowns if start.unknowns is not None else start.base_wrench / self.tables.scale_rows(B)[:, :6]
        if x_init.shape != (B, nu) or start.jacobian.shape[1:] != (nu, nu):
            raise InputError(f"initial: warm start has shape {x_init.shape}, this problem needs ({B}, {nu})")
        return x_init, (start.jacobian if initial is not None else None)

    def _solve_chunk(self, i: int, job: _Job) -> dict:
        """Chunk i of the batch solved (host copies of its results, ``Shooting.results``): Newton from
        the job's start, a load continuation for rods far from it, the slack set settled, the
        stick-slip corrector, and on request the sensitivities, stability and stable branch."""
        lo, hi = self.chunks[i]
        sh, tables, newton, x0 = self.solvers[i], self.tables, job.newton, job.x0[lo:hi]
        avail = None if job.avail is None else job.avail[lo:hi]
        sh.set_command(job.tau[lo:hi], avail)
        sh.set_memory(job.slip[lo:hi], None)
        taut = np.ones((hi - lo, job.tau.shape[1]), dtype=bool)
        taut[:, self.disp] = x0[:, self.j_of] >= 0
        sh.set_taut(taut)
        contact = self.contacts[i] if self.contacts else None
        if contact:
            contact.reset(None if job.stiffness is None else job.stiffness[lo:hi])
        if job.J0 is not None:
            sh.host(sh.newton.J).put(job.J0[lo:hi])
        sh.solve(x0, fresh_jacobian=job.J0 is None, **newton)
        if self.opts.continuation:
            _continue(self, sh, job, lo, hi, x0)
        if job.free is not None and not sh.converged().all():
            _hold(sh, tables, lo, hi, x0, newton)
        segments = _contact_and_split(self, sh, lo, hi, contact, x0, newton, job)
        if len(self.disp):
            settle_slack(sh, taut, self.disp, self.j_of, newton)
        if job.profile is not None:
            _stick_slip(self, sh, job.slip[lo:hi], job.profile[lo:hi], x0, taut, newton)
        if job.spent is not None:  # the integrations of the unloaded Jacobians count, where they were made
            it, sn = sh.counts()
            sh.set_counts(it, sn + job.spent[lo:hi])
        res = sh.results() | {"segments": segments}
        if contact:
            res |= contact.results(self.opts.contact_tolerance, res["status"])
        if job.linear or job.stability != "off":
            rods = (sh, lo, hi, job.tau[lo:hi], taut)
            with contact.near_only(res["contact_gap"]) if contact else nullcontext():  # probes: double steps
                res |= self.assessor.assess(*rods, res, job.ptables, job.linear, job.stability)
            res = _not_linearised(res, segments > 1)
            if job.stability == "stable":
                res = self.assessor.stable_branch(*rods, res, job.ptables, job.linear, newton, self.disp, self.j_of)
        return res


@dataclass
class _Job:
    """One solve of a StaticProblem's batch, as every chunk takes it: tensions tau (B, K) [N], the
    displaced tendons' lengths avail (B, K) [m] or None, slip (B, K) and the stick-slip profile or
    None (friction), the start x0 (B, nu) and Jacobian J0 or None, the integrations spent (B,) on
    J0 in this solve or None, whether the start is warm, the Newton settings, the parameters'
    tables and what to add (``linear``: sensitivities; the stability verdict unless ``stability``
    is "off"), the obstacles' stiffness to start from (a warm start's) or None, and with a
    constrained tip (not warm) the free rods' unknowns (B, nu; zero reaction), or None."""

    tau: np.ndarray
    avail: np.ndarray | None
    slip: np.ndarray
    profile: np.ndarray | None
    x0: np.ndarray
    J0: np.ndarray | None
    spent: np.ndarray | None
    warm: bool
    newton: dict
    ptables: list
    linear: bool
    stability: str
    stiffness: np.ndarray | None = None
    free: np.ndarray | None = None


def _continue(problem: StaticProblem, sh: Shooting, job: _Job, lo: int, hi: int, x0: np.ndarray) -> None:
    """A cold solve's rods of chunk lo:hi that failed from the straight-rod start ``x0``, or whose
    load is large (``continuation_steps``), solved again along a load path. The disk model's
    start is the coupled model's answer (warm): its rods that fail from there take the path from
    the straight rod too (two-section robots at a few N, which converge from half their load)."""
    if job.warm and problem.opts.model != "disks":
        return
    straight = _straight(problem, job, lo, hi, x0)
    finite, large, steps = continuation_steps(straight, problem.opts.continuation)
    redo = finite & (~sh.converged() | (large & (not job.warm)))
    if redo.any():
        load_continuation(sh, _loads(problem.tables, job, lo, hi), straight, redo, steps, job.newton)


def _straight(problem: StaticProblem, job: _Job, lo: int, hi: int, x0: np.ndarray) -> np.ndarray:
    """(b, nu) the straight-rod start of rods lo:hi (a load path's, linear in the loads): ``x0``
    for a cold solve, worked out anew for a warm one."""
    return problem.start(job.tau, job.avail)[lo:hi] if job.warm else x0


def _loads(tables: Tables, job: _Job, lo: int, hi: int) -> tuple:
    """The loads of rods lo:hi as a load path scales them (tdcr_warp/core/homotopy.py
    ``scaled_loads``): rod rows, point force rows, tensions and, under displacement control, the
    lengths (each tendon's path along the straight rod, then the length given to it)."""
    avail = None if job.avail is None else job.avail[lo:hi]
    lengths = None if avail is None else (np.broadcast_to(tables.straight.path, job.tau.shape)[lo:hi], avail)
    return tables.rows("rod", lo, hi), tables.rows("pforce", lo, hi), job.tau[lo:hi], lengths


def _contact_and_split(problem: StaticProblem, sh: Shooting, lo: int, hi: int, contact: Contact | None,
                       x0: np.ndarray, newton: dict, job: _Job) -> np.ndarray:
    """The contact of a solved chunk settled and stiffened (tdcr_warp/physics/contact.py; a rod
    single shooting cannot carry up the climb split), its rods that may have crossed a rigid
    obstacle, warm starts included, sent along a load path from the unloaded rod
    (tdcr_warp/physics/crossing.py), then multiple shooting
    (``StaticOptions.segments``, tdcr_warp/physics/segments.py): the rods whose contact is still
    unresolved (None), or every converged rod (M), solved again in segments from their last
    shapes and stiffened on; returns (b,) the segments each rod ends with (1: single shooting)."""
    if contact:
        contact.settle(x0, newton)
        contact.stiffen(problem.opts.contact_tolerance, problem.opts.contact_steps, newton)
        uncross(contact, _loads(problem.tables, job, lo, hi), _straight(problem, job, lo, hi, x0), newton,
                problem.opts.contact_tolerance, problem.opts.contact_steps)
        lean_along(contact, problem.opts.contact_tolerance, problem.opts.contact_steps, newton)
    count, b = problem.armed, hi - lo
    ok, single = sh.converged(), np.ones(b, dtype=int)
    if count == 1 or (count is None and not contact):
        return single
    tol = problem.opts.contact_tolerance
    rods = ok if count else ok & ((contact.results(tol, sh.status(), False)["status"] & layout.PENETRATION) != 0)
    if contact:
        rods &= ~contact.split_mask()  # (split in a climb already)
        if rods.any():
            contact.split_stiffen(rods, tol, problem.opts.contact_steps, newton)
        return np.maximum(contact.split_count(), 1)
    if not rods.any():
        return single
    iters, shots = sh.counts()
    seg = Segments(sh, problem.tables.rows("rod", lo, hi), count, 0.0)
    seg.from_nodes(sh.nodes, rods)
    seg.solve_into(rods, newton["tol"], newton["max_iter"])
    it, sn = sh.counts()
    sh.set_counts(np.where(rods, it + iters, iters), np.where(rods, sn + shots, shots))
    return np.where(rods, count, 1)


def armed_segments(tables: Tables, opts: StaticOptions) -> int | None:
    """``StaticOptions.segments`` where multiple shooting covers the variant (no tendon states,
    constrained tip or disks), else 1; checked against the variant and the grid (InputError)."""
    segmentable = kernel_segmentable(opts.model, tables.features)
    if opts.segments is not None and opts.segments > opts.nodes:
        raise InputError(f"solver segments must be at most nodes = {opts.nodes}, got {opts.segments}")
    if opts.segments not in (None, 1) and not segmentable:
        raise InputError(f"solver segments = {opts.segments} (multiple shooting) needs a robot without "
                         "displacement control, friction, a constrained tip, disks or sections")
    return opts.segments if segmentable else 1


def _not_linearised(res: dict, rods: np.ndarray) -> dict:
    """``res`` with the sensitivities of ``rods`` (b,) marked not computed (NaN): their probes
    integrate base to tip, which multiple shooting split them to avoid (the stability verdict
    carries its fields over the segments: tdcr_warp/physics/stability.py)."""
    for k in ("tip_jacobian", "tip_compliance", "tension_jacobian", "slack_jacobian", "parameter_jacobian"):
        if k in res:
            res[k] = np.where(rods.reshape((-1,) + (1,) * (res[k].ndim - 1)), np.nan, res[k])
    return res


def _stick_slip(problem: StaticProblem, sh: Shooting, slip: np.ndarray, profile: np.ndarray, x0: np.ndarray,
                taut: np.ndarray, newton: dict) -> None:
    """The stick-slip corrector of a quasi-static step (friction with a history): solved again
    with the previous tension ``profile`` remembered, from the slipping predictor where it
    converged (else from x0); iterations and integrations add up."""
    ok = sh.converged()
    iters, shots = sh.counts()
    sh.set_memory(slip, profile)
    sh.solve(np.where(ok[:, None], sh.newton.x.numpy(), x0), **newton)
    if len(problem.disp):
        settle_slack(sh, taut, problem.disp, problem.j_of, newton)
    it, sn = sh.counts()
    sh.set_counts(it + iters, sn + shots)


def _hold(sh: Shooting, tables: Tables, lo: int, hi: int, x0: np.ndarray, newton: dict) -> None:
    """The rods of a chunk with a constrained tip that failed from the free rod: held by a spring
    first as soft as a tenth of the rod's tip stiffness 3 EI / L^3 (``holding_path``)."""
    rod = tables.rows("rod", lo, hi)
    soft = 10.0 * rod[:, layout.LENGTH] / (3.0 * rod[:, layout.FORCE_SCALE])  # 10 L^3 / (3 EI)
    holding_path(sh, tables.rows("tipc", lo, hi), np.broadcast_to(soft, (hi - lo,)), x0, ~sh.converged(), newton)


def _slip_memory(tables: Tables, n_slots: int, tau: np.ndarray, avail: np.ndarray | None, slip: np.ndarray | None,
                 history: StaticSolution | None) -> tuple[np.ndarray, np.ndarray | None]:
    """Friction's slip directions (B, K) (default +1) and the tension profile of ``history`` a
    stick-slip solve starts from (or None); given a history, the slip directions are the
    predictor's: each whole tendon slipping the way its motor moved since then. n_slots: the
    evaluation slots of a rod (Shooting.n_slots)."""
    B, K = tau.shape
    slip = np.ones((B, K)) if slip is None else slip
    if history is None:
        return slip, None
    if history.base_wrench.shape[0] != B:
        raise InputError(f"history: a solution of {history.base_wrench.shape[0]} rods, the batch has {B}")
    if not tables.features.friction:
        return slip, None
    if history.tension_slots is None or history.tension_slots.shape != (B, n_slots, 3 * K):
        raise InputError("history: expected a solution of this robot and solver options with friction "
                         "(its tension_slots)")
    was = history.tendon_tension_base if avail is None else history.tendon_free_length
    now = tau if avail is None else avail
    moved = np.where(np.broadcast_to(tables.tmode[0] >= 0, (B, K)), was - now, now - was)
    return np.where(moved >= 0, 1.0, -1.0), history.tension_slots


def unloaded_jacobians(problem: StaticProblem, avail: np.ndarray | None) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The first Jacobians of a problem's straight-started Broyden solve (``unloaded_jacobian``),
    made on its first such solve and kept, and the integrations spent on them now (B,) or None;
    (None, None) for plain Newton and displacement control (``avail``: its start is the rod's own).
    Where every rod has the same robot (the batch differs in its commands only) it is made once,
    for the first rod, and shared; else each chunk makes its rods'."""
    if problem.opts.jacobian != "broyden" or avail is not None:
        return None, None
    if problem._unloaded is None:
        B, K = problem.B, problem.tables.tendon.shape[1]
        x_ref = problem.start(np.zeros((B, K)), None)
        if problem.robot.batch_size == 1:
            J, spent = unloaded_jacobian(problem.solvers[0], problem.tables, x_ref[:problem.solvers[0].b], 1)
            J, spent = np.broadcast_to(J[0], (B, *J.shape[1:])), np.pad(spent, (0, B - len(spent)))
        else:
            parts = [unloaded_jacobian(sh, problem.tables, x_ref[lo:hi], hi - lo)
                     for sh, (lo, hi) in zip(problem.solvers, problem.chunks)]
            J, spent = np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])
        problem._unloaded = (J, spent)
        return J, spent
    return problem._unloaded[0], None


def unloaded_jacobian(sh: Shooting, tables: Tables, x_ref: np.ndarray, rods: int) -> tuple[np.ndarray, np.ndarray]:
    """The unloaded Jacobians of the first ``rods`` rods of a chunk: the finite-difference Jacobian
    at the straight start x_ref (b, nu) of a zero command (probes over long steps, core/solver.py
    first_jacobian), a straight-started Broyden solve's first. It depends on the rod alone, not on
    its command, its neighbours or the chunking. Measured (experiments/bench_integrations.py):
    iterations as with each rod's own first Jacobian at its own start or fewer (the report robot at
    0-30 N: 3.99 -> 3.89), and the 7 probes of a first Jacobian gone from every solve after the
    first. A rod whose unloaded Jacobian is not finite gets it anyway: its first step fails and it
    rebuilds its own. Returns (b, nu, nu) (rows past ``rods`` unset) and the integrations spent (b,):
    nu + 1 on those rods."""
    mask = np.arange(sh.b) < rods
    sh.set_command(np.zeros((sh.b, tables.tendon.shape[1])), None)
    first_jacobian(sh, x_ref, mask)
    return sh.host(sh.newton.J).get(np.float64).copy(), np.where(mask, tables.nu + 1, 0)


def _solution(tables: Tables, opts: StaticOptions, out: dict, job: _Job, parameters: tuple,
              unassessed: str) -> StaticSolution:
    """The StaticSolution of a batch from its chunks' joined results ``out``: the base wrench and
    tendon fields unscaled, NaN sensitivities for rods that did not converge, UNSTABLE flagged."""
    B = len(out["converged"])
    x = out.pop("x")
    out["base_wrench"] = x[:, :6] * tables.scale_rows(B)[:, :6]
    if tables.features.tip:
        out["tip_reaction"] = tables.tip_reaction(x)
    s = np.broadcast_to(tables.grid, (B, tables.grid.shape[1])).astype(np.float64)
    tendon = tendon_results(tables, out, x, job.tau, job.slip, job.profile is not None)
    if job.linear:
        bad = ~out["converged"]
        for k in ("tip_jacobian", "tip_compliance", "tension_jacobian", "slack_jacobian", "parameter_jacobian"):
            out[k][bad] = np.nan
        out["parameter_names"] = parameters
    if job.stability != "off":
        st = out["stability_index"]
        out["status"] = np.where(st > 0, out["status"] | layout.UNSTABLE, out["status"]).astype(out["status"].dtype)
        out["stability_note"] = unassessed
    return StaticSolution(s=s, options=opts, unknowns=x, **out, **tendon)


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
_DEFAULT_OPTIONS = StaticOptions()
_options_cache: dict = {}


def _options(options: StaticOptions | None, overrides: dict) -> StaticOptions:
    """``options`` (None: the defaults) with ``overrides``, validated once per distinct pair: the
    options are frozen, so the first call's serve every later one (the keys hold the overrides with
    their types: nodes=20.0 is validated, and rejected, on its own)."""
    base = options or _DEFAULT_OPTIONS
    if not overrides:
        return base
    try:
        key = (id(base), tuple((k, type(v), v) for k, v in overrides.items()))
        hit = _options_cache.get(key)
    except TypeError:  # an unhashable value: checked (and refused or converted) on every call
        return base.override(**overrides)
    if hit is None or hit[0] is not base:
        if len(_options_cache) >= 256:
            _options_cache.clear()
        hit = _options_cache[key] = (base, base.override(**overrides))  # holds base: its id stays its own
    return hit[1]


@functools.lru_cache(maxsize=64)
def _shape_options(opts: StaticOptions) -> StaticOptions:
    """The options a cached problem is made for: those that select kernels and arrays (not what a
    solve adds: the error estimate, sensitivities, stability)."""
    return replace(opts, error_estimate=False, sensitivities=False, stability="off")


def _problem(robot: Robot, B: int, opts: StaticOptions, device) -> tuple[StaticProblem, bool]:
    """A cached problem of this robot object and shape (locked for the caller), or a new one.
    Returns (problem, cached)."""
    if B * (opts.nodes + 1) > CACHE_NODE_RODS:
        return StaticProblem(robot, B, opts, device), False
    key = (id(robot), B, _shape_options(opts), device.alias)
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
    opts = _options(options, overrides)
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
    friction can hold it (stick) and slips where it cannot (docs/tendons.md); slip is then
    not used. options / overrides: :class:`StaticOptions` fields (nodes, integrator, model, ...).
    device: "cpu" or "cuda:0" (None: Warp's default). initial: an earlier solution of the
    same batch size to warm-start from (its unknowns and Jacobian; the disk model without one
    starts from the coupled model's solution, the limit of ever closer disks). parameters: robot fields
    to differentiate the tip pose by (``parameter_jacobian``), e.g. "youngs_modulus",
    "tendons[0].offset[1]", "tip_force[0]" (tdcr_warp.physics.sensitivity; under displacement control
    the motor's given length is held, not the displacement).
    """
    opts = _options(options, overrides)
    if robot.sections:
        check_model_support(robot, opts.model)
    if robot.sections and (opts.sensitivities or parameters or opts.stability == "stable"):
        raise InputError("a backbone with sections has no sensitivities or stable-branch search yet: drop "
                         "sensitivities / parameters / stability = 'stable'")
    if robot.tip_constraint is not None and (opts.sensitivities or parameters or opts.stability == "stable"):
        raise InputError("a constrained tip has no sensitivities or stable-branch search yet (the tip is held): "
                         "drop tip_constraint, or sensitivities / parameters / stability = 'stable'")
    slip = None if slip is None else real_array(slip, "slip", copy=False)
    tau, q = check_command(robot, tensions, displacements,
                           None if slip is None or np.ndim(slip) != 2 else max(robot.batch_size, np.shape(slip)[0]))
    B = tau.shape[0]
    sg = None if slip is None else check_slip(robot, slip, B)
    if opts.model == "constant_curvature":
        check_model_support(robot, opts.model)
        if opts.sensitivities or opts.stability == "stable" or parameters:
            raise InputError("solver model 'constant_curvature' has no sensitivities or stable-branch search: use "
                             "model 'coupled' or 'point'")
        return _constant_curvature(robot, tau, opts)
    if opts.model == "disks" and initial is None and history is None:  # from its limit as the disks get closer
        initial = solve_static(robot, tau, displacements=q, slip=sg, device=device,
                               options=replace(opts, model="coupled", sensitivities=False, stability="off",
                                               error_estimate=False))
    free = None
    if robot.tip_constraint is not None and initial is None and history is None:  # from the free rods
        free = solve_static(replace(robot, tip_constraint=None), tau, displacements=q, slip=sg, device=device,
                            options=replace(opts, sensitivities=False, stability="off", error_estimate=False))
    dev = wp.get_device(device)
    require_memory(B * (opts.nodes + 1) * 400.0, f"nodes = {opts.nodes} for {B} rods: the shapes")
    problem, locked = _problem(robot, B, opts, dev)
    try:
        sol = problem.solve(tau, initial, q, sg, history, sensitivities=opts.sensitivities,
                            stability=opts.stability, parameters=tuple(parameters or ()), free=free)
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
