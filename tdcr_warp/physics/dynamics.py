"""Batched dynamics: BDF-alpha time stepping [Till, Aloi & Rucker 2019], one shooting
problem in s per time step, solved for all rods at once.

``Simulator(robot, tensions, dt=..., alpha=...)`` starts every rod at rest in its static
equilibrium under ``tensions``; ``step(tensions)`` advances one step (closed loop),
``simulate(schedule, steps)`` runs open loop and returns a :class:`Trajectory`. A rod whose
step fails is flagged and frozen at its last good state; the others go on.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import asdict, dataclass

import numpy as np
import warp as wp

from tdcr_warp.core.build import Tables
from tdcr_warp.core.homotopy import added_damping, retry, tension_increment
from tdcr_warp.core.launch import Replay
from tdcr_warp.core.parallel import parallel, split
from tdcr_warp.core.progress import Progress
from tdcr_warp.core.solver import Shooting
from tdcr_warp.kernels import layout
from tdcr_warp.kernels.energy import make_energy_kernels
from tdcr_warp.kernels.history import make_history_kernels
from tdcr_warp.kernels.segments import segmentable
from tdcr_warp.model.options import StaticOptions, check_model_support
from tdcr_warp.model.robot import InputError, Robot, check_command, check_tensions, real_array, require_memory
from tdcr_warp.physics.contact import chunk_contacts, penetration
from tdcr_warp.physics.segments import SWITCH_REACH, Segments, segments_needed, single_shooting_warning
from tdcr_warp.physics.slack import available_lengths, settle_slack
from tdcr_warp.physics.statics import StaticSolution, armed_segments, reference_lengths, solve_static

__all__ = ["Simulator", "StepResult", "Trajectory", "bdf_alpha_coefficients", "bending_layer_ratio"]

# (alpha, limit), descending: the largest h / l_b (``bending_layer_ratio``, rounded up in its 4th
# digit) at which the undamped wire released from a tendon's pull kept its energy over 600 steps at
# every alpha from there down to the next row's (experiments/bdf_alpha_energy.py, docs/solver.md);
# below -0.49 the last.
LAYER_LIMITS = ((-0.3, 1.233), (-0.47, 0.6815), (-0.49, 0.3542))


def bdf_alpha_coefficients(dt: float, alpha: float) -> tuple[float, float, float, float]:
    """c0, c1, c2, d1 of BDF-alpha: y_t = c0 y + y_h, y_h = c1 y(i) + c2 y(i-1) + d1 y_t(i)."""
    c0 = (1.5 + alpha) / (dt * (1.0 + alpha))
    c1 = -2.0 / dt
    c2 = (0.5 + alpha) / (dt * (1.0 + alpha))
    d1 = alpha / (1.0 + alpha)
    return c0, c1, c2, d1


@dataclass
class StepResult:
    """One time step of B rods. tip_position, tip_velocity, tip_acceleration: (B, 3) world
    frame [m, m/s, m/s^2]; converged, iterations, residual [m], status: (B,). Frozen rods
    (failed earlier) report converged False and their frozen tip. penetration (B,): the deepest
    penetration of any obstacle [m] (0 without obstacles); beyond ``contact_tolerance`` radii the
    status has PENETRATION (the rod goes on)."""

    tip_position: np.ndarray
    tip_velocity: np.ndarray
    tip_acceleration: np.ndarray
    converged: np.ndarray
    iterations: np.ndarray
    residual: np.ndarray
    status: np.ndarray
    penetration: np.ndarray


@dataclass
class Trajectory:
    """Recorded open-loop run of B rods over T steps.

    time (T+1,) [s]; tip_position, tip_velocity, tip_acceleration (T+1, B, 3) (index 0 is the
    initial state); tensions (T, B, K) [N]; converged, iterations, residual [m], status,
    penetration [m] (T, B) (the deepest into any obstacle; 0 without); failed_step (B,): first failed step or -1; shape_steps (S,), positions (S, B, N+1, 3) [m]
    and rotations (S, B, N+1, 3, 3): full shapes every ``shapes_every`` steps (empty if 0).
    """

    time: np.ndarray
    tip_position: np.ndarray
    tip_velocity: np.ndarray
    tip_acceleration: np.ndarray
    tensions: np.ndarray
    converged: np.ndarray
    iterations: np.ndarray
    residual: np.ndarray
    status: np.ndarray
    penetration: np.ndarray
    failed_step: np.ndarray
    shape_steps: np.ndarray
    positions: np.ndarray
    rotations: np.ndarray

    def to_npz(self, path) -> None:
        np.savez_compressed(path, **asdict(self))


def bending_layer_ratio(robot: Robot, h: float, dt: float, alpha: float) -> np.ndarray:
    """(1 or B,) h / l_b: an interval h [m] of the grid over the length l_b = ((EI + c0 Bbt) /
    (rho A c0^2))^(1/4) [m] over which one step's inertia bends the rod (the boundary layer of its
    problem in s; the softer bending axis). Beyond a limit that shrinks as alpha -> -0.5
    (``LAYER_LIMITS``) undamped motion gains energy."""
    c0 = bdf_alpha_coefficients(dt, alpha)[0]
    sec = robot.section()
    soft = (sec["kbt"][:, :2] + c0 * robot.damping_bending[:, :2]).min(axis=1)
    return h * math.sqrt(c0) * (robot.density * sec["area"] / soft) ** 0.25  # (no c0^2: dt = 1e-300 is valid)


def layer_warning(robot: Robot, grid: np.ndarray, dt: float, alpha: float) -> str | None:
    """Why undamped motion may gain energy at this grid (1 or B, N+1) [m], dt and alpha (its
    intervals beyond ``LAYER_LIMITS``, with the nodes that stay inside), or None."""
    limit = next((lim for a, lim in LAYER_LIMITS if a <= alpha), LAYER_LIMITS[-1][1])
    ratio = float(np.max(bending_layer_ratio(robot, float(np.diff(grid, axis=1).max()), dt, alpha)))
    if ratio <= limit:
        return None
    need = f"{math.ceil((grid.shape[1] - 1) * ratio / limit):.3g}"
    return (f"alpha = {alpha:g} at dt = {dt:g} s: the grid's intervals are {ratio:.2f} of the bending layer l_b, "
            f"beyond {limit:g} where undamped motion was measured to keep its energy (docs/solver.md): it may gain "
            f"energy (the energy monitor flags such steps ENERGY); nodes >= {need} stays inside")


def _check_stepping(dt, alpha) -> None:
    """An InputError unless dt [s] > 0 and alpha in (-0.5, 0]."""
    if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
        raise InputError(f"dt must be a positive number of seconds, got {dt!r}")
    if not (isinstance(alpha, (int, float)) and -0.5 < alpha <= 0.0):
        raise InputError(f"alpha must be in (-0.5, 0], got {alpha!r}")


def _static_start(robot: Robot, tau: np.ndarray, displacements, initial: StaticSolution | None, opts: StaticOptions,
                  device) -> tuple[StaticSolution, Tables, np.ndarray]:
    """The static equilibrium the rods start from at rest (``initial``, else solved under ``tau`` and
    ``displacements``; every rod converged, or an InputError), the robot's tables and the
    solution's scaled shooting unknowns (B, nu)."""
    B = tau.shape[0]
    static = initial if initial is not None else solve_static(robot, tau, options=opts, device=device,
                                                              displacements=displacements)
    if static.base_wrench.shape[0] != B:
        raise InputError(f"initial: {static.base_wrench.shape[0]} rods, the batch has {B}")
    bad = np.flatnonzero(~static.converged | ((static.status & layout.PENETRATION) != 0))
    if len(bad):
        raise InputError(f"the static start did not converge for rods {bad[:10].tolist()} "
                         f"({static.failure_reasons()[bad[0]]})")
    tables = Tables.of(robot, opts.nodes, opts.specialize, opts.kink_loads)
    if tables.grid.shape[1] != static.s.shape[1]:
        raise InputError("initial: its node count differs from the simulation's")
    x0 = static.unknowns if static.unknowns is not None else static.base_wrench / tables.scale_rows(B)
    if x0.shape[1] != tables.nu:
        raise InputError(f"initial: {x0.shape[1]} shooting unknowns, this robot needs {tables.nu}")
    return static, tables, x0


class _Readings:
    """What a Simulator's state says after its last step, read from its chunks (``parts``)."""

    def tip_state(self) -> dict[str, np.ndarray]:
        """State at the last two nodes of the last evaluation: rotations (B, 2, 3, 3), n, m
        (B, 2, 3) world frame, q (B, 2, 3) body frame, and the last interval h (B,) [m]."""
        f64 = np.float64
        cat = {name: np.concatenate([getattr(c.sh.nodes, name).numpy()[:, -2:].astype(f64) for c in self.parts])
               for name in ("R", "n", "m", "q")}
        cat["h"] = self.grid[:, -1] - self.grid[:, -2]
        return cat

    def tendons(self) -> dict[str, np.ndarray]:
        """Per rod and tendon (B, K) after the last step (tendon states only): tension_base,
        tension_end [N], path_length [m], turning [rad] and, with friction, slip: the slip
        direction that step used (the next one takes it from this step's motion)."""
        if not self.tables.features.tendons:
            raise InputError("tendons(): this robot has no tendon states (no displacement control or friction)")
        td = np.concatenate([c.sh.tendon_table() for c in self.parts])
        out = {"tension_base": td[..., layout.TO_BASE], "tension_end": td[..., layout.TO_END],
               "path_length": td[..., layout.TO_PATH], "turning": td[..., layout.TO_TURN]}
        if self.tables.features.friction:
            out["slip"] = self.last_slip.copy()
        return out

    def contact(self) -> dict[str, np.ndarray]:
        """With obstacles, after the last step: contact_force (B, N+1, 3) the obstacles' point force
        on each node [N] (world frame, with the contact's damping at the nodes' velocities) and
        contact_gap (B, N+1, O) each node's gap to each obstacle [m] (negative: penetration)."""
        if not self.tables.features.contact:
            raise InputError("contact(): this robot has no obstacles")
        found = [c.contact.measure() for c in self.parts]
        return {"contact_force": np.concatenate([f for f, _, _ in found]),
                "contact_gap": np.concatenate([g for _, g, _ in found])}

    def tip_reaction(self) -> np.ndarray:
        """(B, 3) the force the constrained tip takes after the last step [N] (world frame)."""
        if not self.tables.features.tip:
            raise InputError("tip_reaction(): this robot's tip is free (no tip_constraint)")
        return self.tables.tip_reaction(np.concatenate([c.sh.host(c.sh.newton.x).get(np.float64) for c in self.parts]))

    def velocities(self) -> np.ndarray:
        """(B, N+1, 3) the nodes' velocities R q after the last step [m/s] (world frame)."""
        R, q = (np.concatenate([getattr(c.sh.nodes, a).numpy().astype(np.float64) for c in self.parts])
                for a in ("R", "q"))
        return np.einsum("bnij,bnj->bni", R, q)

    def energy(self) -> dict[str, np.ndarray]:
        """After the last step, per rod (B,) [J]: ``energy`` the mechanical energy H (kinetic, elastic,
        gravity's and the dead point loads' potentials and, in the coupled model, each tendon's
        tension times its path length: kernels/energy.py) and ``motion`` its kinetic plus elastic
        part (frozen rods: their last trial)."""
        found = np.concatenate([c.monitor.measure() for c in self.parts])
        return {"energy": found[:, 0], "motion": found[:, 1]}

    def shapes(self) -> tuple[np.ndarray, np.ndarray]:
        """Current positions (B, N+1, 3) [m] and rotations (B, N+1, 3, 3) along s (frozen rods:
        their last trial)."""
        return (np.concatenate([c.sh.nodes.p.numpy().astype(np.float64) for c in self.parts]),
                np.concatenate([c.sh.nodes.R.numpy().astype(np.float64) for c in self.parts]))


class Simulator(_Readings):
    """Holds the batch state of B rods and advances it in time.

    robot: the batch (its damping_shear, damping_bending and drag are the dynamic
    parameters); tensions: (B, K) [N], the static start; dt [s] > 0; alpha in (-0.5, 0]: the
    scheme's own damping of oscillations, largest at 0 (BDF2) and vanishing as alpha -> -0.5
    (the trapezoidal rule); per period at omega dt = 0.5 the amplitude ratio is 0.878 at 0,
    0.932 at -0.2, 0.991 at -0.45 (tests/test_dynamics.py). Near -0.5 the grid must resolve the
    step's bending layer (``bending_layer_ratio`` within ``LAYER_LIMITS``, else a warning): the
    energy monitor (``energy_tolerance``) flags a step of unforced motion that gains mechanical
    energy (status ENERGY; the rod fails there), and ``energy()`` reads each rod's energy.
    options / overrides: solver settings (:class:`StaticOptions`: nodes, integrator, model,
    precision, tol, max_iter, ...).
    initial: a static solution of the same rods (possibly under other tip loads) to start
    from at rest, instead of solving the statics under ``tensions``.

    Tendons under displacement control take ``displacements`` (B, K) [m] (in ``step`` too),
    with one tension unknown each and the slack complementarity settled every step, as in
    statics. Friction: the slip direction of a tendon follows its sliding velocity, smoothed,
    sigma = tanh(-d ell / dt / slip_speed) with ell its path length (from the last two steps;
    shortening: sliding toward the motor, +1); the static start uses slip +1. Below
    ``slip_speed`` [m/s] friction fades like viscous friction: dynamics has no static stick.

    segments (a solver option): multiple shooting (tdcr_warp/physics/segments.py: each rod split
    into that many segments in every step; 1: never); None (default): single shooting, and where
    dt is beyond its comfortable reach a rod whose step fails it (and its retries) is split into
    as many segments as dt needs from then on (not yet with tendon states or a held tip); a rod
    whose static start was split (a long line contact) stays split, and one whose contact grows
    too long for single shooting is split as statics splits it (docs/contact.md, "In motion").

    Obstacles and a held tip act in every step as in statics (docs/contact.md, "In motion"): the
    contact damped by each obstacle's ``damping``, a rigid one stiffened where a step presses a rod
    in beyond ``contact_tolerance`` radii (else PENETRATION in that step's status); ``contact()``,
    ``velocities()`` and ``tip_reaction()`` read the state after a step.
    """

    def __init__(self, robot: Robot, tensions=None, *, dt: float, alpha: float = 0.0,
                 options: StaticOptions | None = None, device: str | None = None,
                 initial: StaticSolution | None = None, displacements=None, slip_speed: float = 1e-3,
                 **overrides):
        _check_stepping(dt, alpha)
        self.robot = robot
        self.opts = (options or StaticOptions()).override(**overrides)
        self.dt, self.alpha = float(dt), float(alpha)
        self.coef = bdf_alpha_coefficients(self.dt, self.alpha)
        if not (isinstance(slip_speed, (int, float)) and math.isfinite(slip_speed) and slip_speed > 0):
            raise InputError(f"slip_speed must be a positive speed [m/s], got {slip_speed!r}")
        self.slip_speed = float(slip_speed)
        tau, q = check_command(robot, tensions, displacements)
        self.B = tau.shape[0]
        self.dev = wp.get_device(device)
        self._command = _Commands(robot, self.opts, self.dev, self.B, np.zeros_like(tau) if q is None else q)
        check_model_support(robot, self.opts.model, dynamic=True)
        static, self.tables, x0 = _static_start(robot, tau, displacements, initial, self.opts, self.dev)
        layer = layer_warning(robot, self.tables.grid, self.dt, self.alpha)
        if layer:
            warnings.warn(layer, stacklevel=2)
        self.segments, self.split_all = _segment_count(self, self.opts.segments), self.opts.segments is not None
        self.grid = np.broadcast_to(self.tables.grid, (self.B, self.tables.grid.shape[1]))
        self.path = static.tendon_path_length
        self.chunks = split(self.B, self.dev, self.opts.threads)
        _, avail = self._command(tau, displacements)
        self.slip = self.last_slip = np.ones((self.B, robot.n_tendons))  # the static start: pulled
        self.parts = [_Chunk(self, self.tables, lo, hi, tau[lo:hi], x0[lo:hi], static,
                             None if avail is None else avail[lo:hi]) for lo, hi in self.chunks]
        if self.tables.features.contact:
            inside = np.flatnonzero(np.concatenate([c.inside() for c in self.parts]))
            if len(inside):
                raise InputError(f"the start of rods {inside[:10].tolist()} is inside an obstacle (beyond "
                                 f"contact_tolerance = {self.opts.contact_tolerance} radii)")
        self._tau_prev = tau
        self.alive = np.ones(self.B, dtype=bool)
        self.failed_step = np.full(self.B, -1)
        self.steps_done = 0
        self._read_tips()

    def _slip(self) -> np.ndarray:
        """Slip directions from the tendons' path-length rates over the last step."""
        path = np.concatenate([c.sh.tendon_table()[..., layout.TO_PATH] for c in self.parts])
        rate = (path - self.path) / self.dt
        self.path = path
        return np.tanh(-rate / self.slip_speed)

    def step(self, tensions=None, displacements=None) -> StepResult:
        """Advance every live rod by dt under ``tensions`` (B, K) [N] (and ``displacements``
        (B, K) [m] of the displacement-controlled tendons; None: the last ones)."""
        tau, avail = self._command(tensions, displacements)
        first = self.steps_done == 0
        slip = self.slip if self.tables.features.friction else None

        def run(i):
            lo, hi = self.chunks[i]
            return self.parts[i].step(tau[lo:hi], self._tau_prev[lo:hi], self.alive[lo:hi], first,
                                      None if avail is None else avail[lo:hi], None if slip is None else slip[lo:hi])

        parts = parallel(run, list(range(len(self.chunks))))
        self._tau_prev = tau
        if self.tables.features.friction:
            self.last_slip, self.slip = self.slip, self._slip()
        ok, status, iters, resid, pen = parts[0] if len(parts) == 1 else (np.concatenate(x) for x in zip(*parts))
        newly_failed = self.alive & ~ok
        self.failed_step[newly_failed] = self.steps_done
        self.alive &= ok
        self.steps_done += 1
        self._read_tips()
        resid = np.where(ok, resid, np.inf)
        return StepResult(self.tip_position.copy(), self.tip_velocity.copy(), self.tip_acceleration.copy(),
                          ok, iters, resid, status, pen)

    @property
    def displacements(self) -> np.ndarray:
        """(B, K) the motor displacements held now [m] (zero for tendons under tension control)."""
        return self._command.q.copy()

    def _read_tips(self) -> None:
        tips = [c.tips() for c in self.parts]
        self.tip_position, self.tip_velocity, self.tip_acceleration = tips[0] if len(tips) == 1 else (
            np.concatenate([t[j] for t in tips]) for j in range(3))

    def simulate(self, schedule, steps: int, *, shapes_every: int = 0, progress: bool = False,
                 displacements=None) -> Trajectory:
        """Open loop: ``schedule`` is (B, steps, K) or (steps, K) [N], or a callable of the
        step index returning (B, K); ``displacements`` likewise [m] for the tendons under
        displacement control (None: they stay where they are)."""
        if not isinstance(steps, int) or steps < 1:
            raise InputError(f"steps must be a positive integer, got {steps!r}")
        K = self.robot.n_tendons
        get = _schedule(schedule, steps, "schedule", self.B, K)
        disp_at = None if displacements is None else _schedule(displacements, steps, "displacements", self.B, K)
        rec = _Recording(self, steps, shapes_every)
        bar = Progress(steps, self.B) if progress else None
        for i in range(steps):
            rec.taus[i] = check_tensions(self.robot, get(i), name=f"schedule step {i}")
            rec.add(i, self.step(rec.taus[i], None if disp_at is None else disp_at(i)))
            if bar:
                bar.update(i + 1, int((~self.alive).sum()))
        if bar:
            bar.close()
        return rec.trajectory()


def _segment_count(sim: Simulator, segments: int | None) -> int:
    """The segments of multiple shooting (1: none): ``segments``, or (None) as many as dt needs
    where single shooting is at risk and the variant allows them (no tendon states or held tip
    yet: else 1, warned where dt is beyond single shooting)."""
    f, n_int = sim.tables.features, sim.tables.grid.shape[1] - 1
    allowed = segmentable(sim.opts.model, f)
    if segments is None:
        need = segments_needed(sim.robot, sim.opts.precision, sim.dt, sim.coef[0] * sim.dt)
        segments = min(need, n_int) if allowed and need > 1 else 1
        if allowed and need > n_int:
            warnings.warn(f"dt = {sim.dt:g} s needs {need} segments, more than the grid's {n_int} intervals: "
                          "raise nodes", stacklevel=3)
    if not (isinstance(segments, int) and 1 <= segments <= n_int):
        raise InputError(f"segments must be an integer from 1 to the interval count {n_int}, got {segments!r}")
    if segments > 1 and not allowed:
        raise InputError("segments > 1 (multiple shooting) needs a robot without displacement control, friction "
                         "or a constrained tip (not built yet)")
    warning = segments == 1 and single_shooting_warning(sim.robot, sim.opts.precision, sim.dt, sim.coef[0] * sim.dt)
    if warning:
        warnings.warn(warning, stacklevel=3)
    return segments


def _schedule(values, steps: int, name: str, B: int, K: int):
    """The command of step i as a function: ``values`` (B, steps, K), (steps, K) or a callable."""
    if callable(values):
        return values
    sched = real_array(values, name, copy=False)
    if sched.ndim == 2:
        sched = np.broadcast_to(sched[None], (B,) + sched.shape)
    if sched.shape != (B, steps, K):
        raise InputError(f"{name}: expected shape ({B}, {steps}, {K}) or ({steps}, {K}), got {np.shape(values)}")
    return lambda i: sched[:, i]


class _Commands:
    """The commands of a Simulator's steps: the checked tensions and, under displacement control,
    the displacements held (the last ones given) and the unstretched length they give each tendon."""

    def __init__(self, robot: Robot, opts: StaticOptions, device, B: int, q: np.ndarray):
        self.robot, self.opts, self.device, self.B = robot, opts, device, B
        self.q = q  # (B, K) [m] the displacements held when a step gives none
        self._reference = None

    def __call__(self, tensions, displacements) -> tuple[np.ndarray, np.ndarray | None]:
        """Checked tensions (B, K) [N] and the lengths given to displaced tendons (B, K) [m] (or None;
        no displacements: the last ones)."""
        rb = self.robot
        tau, q = check_command(rb, tensions, displacements, self.B)
        if tau.shape[0] != self.B:
            raise InputError(f"tensions: {tau.shape[0]} rows for {self.B} rods")
        if not rb.displaced:
            return tau, None
        self.q = self.q if q is None else q
        if self._reference is None:
            self._reference = reference_lengths(rb, options=self.opts, device=self.device)
        return available_lengths(rb, self._reference, tau, self.q)


class _Recording:
    """An open-loop run of a Simulator being recorded over T steps: the arrays of a
    :class:`Trajectory`, from the simulator's state at the start (index 0)."""

    def __init__(self, sim: Simulator, T: int, shapes_every: int):
        B, K, n1 = sim.B, sim.robot.n_tendons, sim.grid.shape[1]
        require_memory(T * B * (8.0 * (10 + K) + 9) + (T // shapes_every if shapes_every else 0) * B * 96.0
                       * n1, f"steps = {T} for {B} rod(s): the trajectory")
        self.sim, self.shapes_every = sim, shapes_every
        self.tip = np.zeros((T + 1, B, 3))
        self.vel = np.zeros((T + 1, B, 3))
        self.acc = np.zeros((T + 1, B, 3))
        self.tip[0], self.vel[0], self.acc[0] = sim.tip_position, sim.tip_velocity, sim.tip_acceleration
        self.taus = np.zeros((T, B, K))
        self.conv = np.zeros((T, B), dtype=bool)
        self.iters = np.zeros((T, B), dtype=np.int32)
        self.resid = np.zeros((T, B))
        self.status = np.zeros((T, B), dtype=np.int32)
        self.pen = np.zeros((T, B))
        self.shape_steps, self.shapes = [], []
        if shapes_every:
            self.shape_steps.append(0)
            self.shapes.append(sim.shapes())

    def add(self, i: int, r: StepResult) -> None:
        """Step i's outcome (and the shapes every ``shapes_every`` steps; its tensions go to ``taus``)."""
        self.tip[i + 1], self.vel[i + 1], self.acc[i + 1] = r.tip_position, r.tip_velocity, r.tip_acceleration
        self.conv[i], self.iters[i], self.resid[i], self.status[i] = r.converged, r.iterations, r.residual, r.status
        self.pen[i] = r.penetration
        if self.shapes_every and (i + 1) % self.shapes_every == 0:
            self.shape_steps.append(i + 1)
            self.shapes.append(self.sim.shapes())

    def trajectory(self) -> Trajectory:
        """The recorded run."""
        sim, shapes = self.sim, self.shapes
        B, n1, T = sim.B, sim.grid.shape[1], len(self.taus)
        return Trajectory(time=sim.dt * np.arange(T + 1), tip_position=self.tip, tip_velocity=self.vel,
                          tip_acceleration=self.acc, tensions=self.taus, converged=self.conv, iterations=self.iters,
                          residual=self.resid, status=self.status, penetration=self.pen, failed_step=sim.failed_step.copy(),
                          shape_steps=np.array(self.shape_steps, dtype=np.int32),
                          positions=np.array([p for p, _ in shapes]) if shapes else np.zeros((0, B, n1, 3)),
                          rotations=np.array([R for _, R in shapes]) if shapes else np.zeros((0, B, n1, 3, 3)))


class _EnergyMonitor:
    """The energy monitor of a chunk's rods (energy_tolerance > 0): the mechanical energy H of
    each after a step (kernels/energy.py) against its reference, the last state after which the
    actuators did work (at rest: the static start). Watched: the rods whose loads are
    conservative while the command is held: no obstacles, friction, displacement control, held
    tip or dead tip moment (not conservative in 3D), and in the coupled model kink_loads on (the
    published model without them is not)."""

    def __init__(self, sim: Simulator, tables: Tables, sh: Shooting, lo: int, hi: int):
        f, o = tables.features, sim.opts
        self.sim, self.sh = sim, sh
        self._energy = Replay(make_energy_kernels(sh.dev.wdtype, f.helix, f.spline).energy, sh.b, sim.dev)
        self.out = wp.zeros((sh.b, 2), dtype=wp.float64, device=sim.dev)
        rows = np.broadcast_to(tables.rows("rod", lo, hi), (sh.b, layout.ROD_WIDTH))
        on = o.energy_tolerance > 0 and not (f.contact or f.friction or f.displaced or f.tip)
        on = on and (o.kink_loads or o.model != "coupled")
        self.watched = on & (rows[:, layout.TIP_M:layout.TIP_M + 3] == 0).all(axis=1)
        self.point, self.tolerance = o.model != "coupled", o.energy_tolerance
        self.eps = 100 * np.finfo(sh.dev.ndtype).eps  # the round-off of H
        self.reference = self.measure() if self.watched.any() else None  # H and T + U_el

    def measure(self) -> np.ndarray:
        """(b, 2) per rod the mechanical energy H and its kinetic plus elastic part [J] of the
        last evaluated state."""
        sh = self.sh
        self._energy(sh.model, sh.control.tau, sh.nodes.p, sh.step.ycur, sh.n_slots - 2 * sh.n1,
                     int(self.sim.opts.model == "coupled"), self.out)
        return sh.host(self.out).get(np.float64)

    def check(self, ok: np.ndarray, status: np.ndarray, tau: np.ndarray, tau_prev: np.ndarray):
        """After a step: a converged, watched rod whose command is the last step's (in the point
        model: no tension; the tendons' pull is not conservative there) and whose H rose above its
        reference by more than energy_tolerance times its kinetic plus elastic energy (the larger
        of now and at the reference; plus the round-off of H) is flagged ENERGY and fails. Any
        other converged rod takes its energy as the new reference (a command changed: the
        actuators did work). Returns ok, status (b,)."""
        (h, motion), (h_ref, motion_ref) = self.measure().T, self.reference.T
        held = self.watched & (tau == tau_prev).all(axis=1)
        if self.point:
            held &= ~tau.any(axis=1)
        scale = np.maximum(motion, motion_ref)
        gained = (h - h_ref > self.tolerance * scale + self.eps * (np.abs(h) + 2 * scale)) & held & ok
        if gained.any():
            ok = ok & ~gained
            status = np.where(gained, status | layout.ENERGY, status)
        renew = ok & ~held
        self.reference[renew, 0], self.reference[renew, 1] = h[renew], motion[renew]
        return ok, status


class _Chunk:
    """The rods lo:hi of a Simulator: their shooting problem and, on the device, the BDF-alpha
    history of every slot, the previous solution, the tip kinematics and the step outcome; with
    obstacles their Contact, at the stiffness of the static start ``static`` and stiffened
    further in any step that presses a rod in beyond the tolerance."""

    def __init__(self, sim: Simulator, tables: Tables, lo: int, hi: int, tau: np.ndarray, x0: np.ndarray,
                 static: StaticSolution, avail: np.ndarray | None):
        o = sim.opts
        self.sim = sim
        self.sh = sh = Shooting(tables, lo, hi, tau, precision=o.precision, integrator=o.integrator,
                                model=o.model, device=sim.dev, dynamic=True, rod=o.rod, driver=o.driver)
        self.hk = make_history_kernels(sh.dev.wdtype, tables.nu)
        self.disp = np.flatnonzero(tables.tmode[0] >= 0)
        self.j_of = 6 + tables.tmode[0, self.disp]
        self.taut = np.ones((hi - lo, tau.shape[1]), dtype=bool)
        self.taut[:, self.disp] = x0[:, self.j_of] >= 0
        sh.set_command(tau, avail)
        sh.set_taut(self.taut)
        sh.set_memory(np.ones(tau.shape), None)
        b, d = sh.b, sim.dev
        self.dyn = np.broadcast_to(tables.rows("dyn", lo, hi), (b, tables.dyn.shape[1]))
        self.stiffness = np.broadcast_to(tables.rows("stiffness", lo, hi), (b, 6))
        self.damped = None  # device table of the damping homotopy, made on first use
        self.yprev = wp.zeros_like(sh.step.ycur)
        self.x_prev = wp.zeros_like(sh.newton.x)
        self.x_start = wp.zeros_like(sh.newton.x)
        self.ok = wp.ones(b, dtype=int, device=d)
        self.tip = [wp.array(static.tip_position[lo:hi], dtype=wp.vec3d, device=d)] + [
            wp.zeros(b, dtype=wp.vec3d, device=d) for _ in range(4)]
        self.newton = dict(tol=o.tolerance, max_iter=o.max_iter, max_step=o.max_step,
                           broyden=o.jacobian == "broyden")
        self._end = Replay(self.hk.end_step, sh.b, sim.dev)
        self.contact = next(iter(chunk_contacts(sim.robot, tables, [sh], [(lo, hi)], armed_segments(tables, o),
                                                sim.coef[0])), None)  # (split as statics does)
        if self.contact:  # the rigid obstacles as stiff as the start's solve left them (else at their base)
            stiffness = static.contact_stiffness
            self.contact.reset(self.contact.goal_stiffness() if stiffness is None else stiffness[lo:hi])
        sh.evaluate(x0)  # c0 = 0, empty history: the static slots
        wp.copy(sh.newton.x, sh.x_in)
        self.segs, self.count = _chunk_segments(self, static.segments_or_one[lo:hi], static, lo)
        self._end_step(at_rest=True)
        sh.step.c0 = sh.dev.wdtype(sim.coef[0])
        self.monitor = _EnergyMonitor(sim, tables, sh, lo, hi)

    @property
    def split(self) -> np.ndarray:
        """(b,) bool: the rods stepped by multiple shooting."""
        return self.count > 0

    def inside(self) -> np.ndarray:
        """(b,) bool: the last evaluated shapes penetrate an obstacle beyond the tolerance."""
        none = np.zeros(self.sh.b, dtype=np.int32)
        return self.contact.results(self.sim.opts.contact_tolerance, none, False)["status"] != 0

    def _end_step(self, at_rest: bool = False) -> None:
        sh, out = self.sh, self.sh.nodes
        self._end(sh.step.ycur, self.yprev, sh.step.hist, out.p, out.R, out.q, self.ok, *self.sim.coef, int(at_rest),
                  *self.tip, sh.newton.x, self.x_prev, self.x_start)

    def tips(self):
        """Host copies of the tip position, velocity and acceleration (b, 3) each."""
        return [self.sh.host(a).get(np.float64) for a in self.tip[:3]]

    def step(self, tau: np.ndarray, tau_prev: np.ndarray, alive: np.ndarray, first: bool, avail: np.ndarray | None,
             slip: np.ndarray | None):
        """One time step of the live rods (``alive`` (b,)) under tau (b, K) [N] (tau_prev: the last
        step's) and avail (b, K) [m] or None, with friction's slip (b, K) or None: Newton from the
        extrapolated start (``first``: a fresh Jacobian), the slack set settled, the failed rods
        retried (then split, where segments are armed; split rods step by multiple shooting),
        contact stiffened where it must be, the history advanced. Returns (converged, status,
        iterations, residual, penetration) (b,) each."""
        sh, newton = self.sh, self.newton
        sh.set_command(tau, avail)
        if self.contact:
            self.contact.restore()
        if slip is not None:
            sh.set_memory(slip, None)
        split, single = self.split & alive, alive & ~self.split
        grown = self.segs.get(self.sim.segments)  # where a rod that single shooting fails goes
        if single.any():
            if grown:
                grown.from_nodes(sh.nodes, single)  # the last step's shapes: a start if single shooting fails
            sh.solve(self.x_start, mask=None if single.all() else single, fresh_jacobian=first, **newton)
        if len(self.disp):
            settle_slack(sh, self.taut, self.disp, self.j_of, newton)
        failed = single & ~sh.converged()
        if failed.any():
            failed &= self._retry(failed, tau, tau_prev, avail)
        if failed.any() and grown:  # beyond single shooting and its retries: split from now on
            self.count[failed] = grown.M
            split = split | failed
        for M, seg in self.segs.items():  # multiple shooting: the Newton on the host, the segments on the device
            if (split & (self.count == M)).any():
                seg.solve_into(split & (self.count == M), newton["tol"], newton["max_iter"])
        status, pen = sh.status(), np.zeros(sh.b)
        if self.contact:
            tol = self.sim.opts.contact_tolerance
            _climb_anew(self, alive, tol)
            self.contact.stiffen(tol, self.sim.opts.contact_steps, newton, alive)
            found = self.contact.results(tol, sh.status())
            status = found["status"]
            pen = np.maximum(penetration(found["contact_gap"]), penetration(found["interval_gap"])).max(axis=1)
        ok = ((status & layout.CONVERGED) != 0) & alive
        if self.monitor.watched.any():
            ok, status = self.monitor.check(ok, status, tau, tau_prev)
        sh.host(self.ok).put(ok)
        self._end_step()
        return ok, status, sh.host(sh.newton.iters).get(), sh.host(sh.newton.resnorm).get(np.float64), pen

    def _retry(self, failed: np.ndarray, tau: np.ndarray, tau_prev: np.ndarray, avail: np.ndarray | None) -> np.ndarray:
        """The rods ``failed`` (b,) of this step solved again: a homotopy in the tension increment,
        then from a heavily damped copy of themselves, then by plain Newton; each only for the rods
        the one before left failing. Returns the rods still failing."""
        sh, o, newton = self.sh, self.sim.opts, self.newton
        # A large tension change in one step: reach it by a homotopy in the tension increment,
        # each sub-problem from the last (same time step, same history).
        failed = retry(sh, tension_increment(sh, tau_prev, tau), failed, self.x_prev, newton, o.continuation)
        if failed.any() and self.contact:
            # A stiff contact struck within one step: reached from a soft one, stiffened back.
            sh.set_command(tau, avail)
            failed = self.contact.soften(failed, self.x_prev, newton)
        if failed.any():
            # A lightly damped rod that moves fast: single shooting amplifies start errors, so
            # the step is reached from a heavily damped copy of itself, which hardly moves from
            # x(i) and is better conditioned.
            sh.set_command(tau, avail)
            failed = self._damping_homotopy(failed)
        if failed.any():  # last resort: plain Newton (a fresh Jacobian at every iterate) from x(i)
            sh.solve(self.x_prev, mask=failed, **(newton | dict(broyden=False, max_iter=2 * o.max_iter)))
        return failed & ~sh.converged()

    def _damping_homotopy(self, failed: np.ndarray) -> np.ndarray:
        """The failed rods reached from heavily damped copies of themselves: s K / c0 added to
        the shear and bending damping, s = 1000^(1 - lam) - 1 going to 0 (lam = 1: the exact
        step). Returns the rods still failing; the rods' own dynamics table is back in place."""
        sh = self.sh
        own = sh.model.dyn
        if self.damped is None:
            self.damped = sh.dev.array(self.dyn)
        sh.model.dyn = self.damped
        try:
            return retry(sh, added_damping(sh, self.damped, self.dyn, self.stiffness, self.sim.coef[0]), failed,
                         self.x_prev, self.newton, self.sim.opts.continuation)
        finally:
            sh.model.dyn = own


def _climb_anew(chunk: _Chunk, alive: np.ndarray, tol: float) -> None:
    """In a chunk's step, where its contact is armed (``segments``, as in statics): a live rod
    (``alive`` (b,)) that single shooting leaves deeper than the tolerance, in a contact along
    which a start error grows beyond SWITCH_REACH (a line contact grown too long for it:
    stiffening from there fails, split or not), is solved again from the last step's state with
    its obstacles SOFT times as stiff and climbs back, split on the way where single shooting
    cannot carry it, as a cold static solve does (``Contact.soften``)."""
    sh, c = chunk.sh, chunk.contact
    rods = alive & sh.converged() & ~chunk.split
    if c.armed and rods.any():
        rods &= (c.results(tol, sh.status(), False)["status"] & layout.PENETRATION) != 0
        rods &= c.growth(c.table[..., layout.OB_STIFF]) > math.log(SWITCH_REACH[c.precision])
        if rods.any():
            c.soften(rods, chunk.x_prev, chunk.newton)


def _chunk_segments(chunk: _Chunk, start: np.ndarray, static: StaticSolution, lo: int) -> tuple[dict, np.ndarray]:
    """Multiple shooting of a chunk: {M: Segments} and (b,) the segments of each rod (0: single
    shooting). With ``segments`` = M every rod is split into M; with None a rod is split (into as
    many as dt needs) once single shooting fails it, and stays split. A rod the static start split
    (a long line contact; ``start`` (b,) its counts) keeps as many (at least dt's), solved again at
    rest from the static shape (single shooting from its base wrench cannot hold it; the static n
    is proximal of each node's point loads, a segment starts distal of them) for its shape and
    static slots. Each rod's count is its own: a batch's rods do not change one another's answers."""
    sim, sh, hi = chunk.sim, chunk.sh, lo + chunk.sh.b
    held = start > 1
    count = np.where(held, np.maximum(start, sim.segments), sim.segments if sim.split_all and sim.segments > 1 else 0)
    counts = set(np.unique(count[count > 1]).tolist()) | ({sim.segments} if sim.segments > 1 else set())
    segs = {M: Segments(sh, sim.tables.rows("rod", lo, hi), M, sim.coef[0]) for M in sorted(counts)}
    for M, seg in segs.items():
        mine = held & (count == M)
        seg.from_nodes(sh.nodes, ~mine)  # (single shooting's shapes: a start where a step splits a rod)
        if mine.any():
            seg.from_states(static.positions[lo:hi], static.rotations[lo:hi], static.n[lo:hi], static.m[lo:hi],
                            mine)
            ok = seg.solve(mine, chunk.newton["tol"], chunk.newton["max_iter"])[0]
            if not ok[mine].all():
                raise InputError(f"the static start of rods {(lo + np.flatnonzero(mine & ~ok))[:10].tolist()} "
                                 "(split into segments) did not converge again at rest in dynamics")
    if chunk.contact:  # its stiffening solves a split rod by its segments (the same dict and counts)
        chunk.contact.segs, chunk.contact.count = segs, count
    return segs, count
