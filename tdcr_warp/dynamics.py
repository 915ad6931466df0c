"""Batched dynamics: BDF-alpha time stepping [Till, Aloi & Rucker 2019], one shooting
problem in s per time step, solved for all rods at once.

``Simulator(robot, tensions, dt=..., alpha=...)`` starts every rod at rest in its static
equilibrium under ``tensions``; ``step(tensions)`` advances one step (closed loop),
``simulate(schedule, steps)`` runs open loop and returns a :class:`Trajectory`. A rod whose
step fails is flagged and frozen at its last good state; the others go on.
"""

from __future__ import annotations

import math
import sys
import time
import warnings
from dataclasses import asdict, dataclass, replace

import numpy as np
import warp as wp

from .kernels import layout
from .kernels.shooting import make_history_kernel
from .robot import InputError, Robot, require_memory
from .shooting import (ShootingBatch, check_tensions, host_tables, parallel, rows, scene_features, split,
                       unknown_scales)
from .statics import StaticOptions, StaticSolution, solve_static

__all__ = ["Simulator", "StepResult", "Trajectory", "bdf_alpha_coefficients"]


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
    (failed earlier) report converged False and their frozen tip."""

    tip_position: np.ndarray
    tip_velocity: np.ndarray
    tip_acceleration: np.ndarray
    converged: np.ndarray
    iterations: np.ndarray
    residual: np.ndarray
    status: np.ndarray


@dataclass
class Trajectory:
    """Recorded open-loop run of B rods over T steps.

    time (T+1,) [s]; tip_position, tip_velocity, tip_acceleration (T+1, B, 3) (index 0 is the
    initial state); tensions (T, B, K) [N]; converged, iterations, residual [m], status (T, B);
    failed_step (B,): first failed step or -1; shape_steps (S,) and positions (S, B, N+1, 3):
    full shapes every ``shapes_every`` steps (empty if 0).
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
    failed_step: np.ndarray
    shape_steps: np.ndarray
    positions: np.ndarray

    def to_npz(self, path) -> None:
        np.savez_compressed(path, **asdict(self))


class Simulator:
    """Holds the batch state of B rods and advances it in time.

    robot: the batch (its damping_shear, damping_bending and drag are the dynamic
    parameters); tensions: (B, K) [N], the static start; dt [s] > 0; alpha in [-0.48, 0]
    (0: BDF2; negative values damp high frequencies). options / overrides: solver settings
    (:class:`StaticOptions`: nodes, integrator, model, precision, tol, max_iter, ...).
    initial: a static solution of the same rods (possibly under other tip loads) to start
    from at rest, instead of solving the statics under ``tensions``.
    """

    def __init__(self, robot: Robot, tensions, *, dt: float, alpha: float = 0.0,
                 options: StaticOptions | None = None, device: str | None = None,
                 initial: StaticSolution | None = None, **overrides):
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
            raise InputError(f"dt must be a positive number of seconds, got {dt!r}")
        if not (isinstance(alpha, (int, float)) and -0.5 < alpha <= 0.0):
            raise InputError(f"alpha must be in (-0.5, 0], got {alpha!r}")
        self.robot = robot
        self.opts = replace(options or StaticOptions(), **overrides)
        self.dt, self.alpha = float(dt), float(alpha)
        self.coef = bdf_alpha_coefficients(self.dt, self.alpha)
        sec = robot.section()
        self._warn_single_shooting(robot, sec)
        tau = check_tensions(robot, tensions)
        self.B = tau.shape[0]
        self.dev = wp.get_device(device)
        static = initial if initial is not None else solve_static(robot, tau, options=self.opts,
                                                                  device=self.dev)
        if static.base_wrench.shape[0] != self.B:
            raise InputError(f"initial: {static.base_wrench.shape[0]} rods, the batch has {self.B}")
        if not static.converged.all():
            bad = np.flatnonzero(~static.converged)
            raise InputError(f"the static start did not converge for rods {bad[:10].tolist()} "
                             f"({static.failure_reasons()[bad[0]]})")
        host = host_tables(robot, self.opts.nodes)
        if host["grid"].shape[1] != static.s.shape[1]:
            raise InputError("initial: its node count differs from the simulation's")
        self.grid = np.broadcast_to(host["grid"], (self.B, host["grid"].shape[1]))
        dyn = robot.pack_dynamics()
        self.chunks = split(self.B, self.dev, self.opts.threads)
        if self.opts.model == "constant_curvature":
            raise InputError("dynamics needs a rod model: solver model 'coupled' or 'point'")
        features = scene_features(robot, self.opts.specialize)
        self.batches = [ShootingBatch(host={k: rows(v, lo, hi) for k, v in host.items()}, tau=tau[lo:hi],
                                      precision=self.opts.precision, integrator=self.opts.integrator,
                                      model=self.opts.model, device=self.dev, dyn=rows(dyn, lo, hi),
                                      rod=self.opts.rod, features=features)
                        for lo, hi in self.chunks]
        self._advance = make_history_kernel(self.batches[0].wdtype)
        # host tables for the damping homotopy of failing steps: each chunk's dynamics rows and
        # its shear/bending stiffness (added as damping s K / c0); the device table is built on demand
        stiff = np.concatenate(np.broadcast_arrays(sec["kse"], sec["kbt"]), axis=1)  # (1|B, 6)
        self._dyn = [np.broadcast_to(rows(dyn, lo, hi), (hi - lo, layout.DYN_WIDTH)) for lo, hi in self.chunks]
        self._stiff = [np.broadcast_to(rows(stiff, lo, hi), (hi - lo, 6)) for lo, hi in self.chunks]
        self._damped = [None] * len(self.chunks)
        self._yprev = [wp.zeros_like(bt.args.ycur) for bt in self.batches]
        x0 = static.base_wrench * unknown_scales(robot, self.B)
        for (lo, hi), bt, yp in zip(self.chunks, self.batches, self._yprev):
            bt.evaluate(x0[lo:hi])  # c0 = 0, empty history: the static slots
            self._launch_advance(bt, yp, np.ones(hi - lo, dtype=np.int32), at_rest=True)
            bt.args.c0 = bt.wdtype(self.coef[0])
            bt.x.assign(bt.xt)
        self._x_prev = [None] * len(self.batches)
        self._tau_prev = tau
        self.alive = np.ones(self.B, dtype=bool)
        self.failed_step = np.full(self.B, -1)
        self.steps_done = 0
        self._have_jacobian = False
        self.tip_position = static.tip_position.copy()
        self.tip_velocity = np.zeros((self.B, 3))
        self.tip_acceleration = np.zeros((self.B, 3))
        self._vel_hist = np.zeros((self.B, 3))  # BDF-alpha history of the tip velocity (0 at rest)
        self._vel_prev = np.zeros((self.B, 3))

    def _warn_single_shooting(self, robot: Robot, sec: dict) -> None:
        """Warn where dt is below what single shooting resolves: a start error grows along the rod
        by exp(L (rho A c0^2 / (EI + c0 Bbt))^(1/4) / sqrt 2), beyond the precision's reach past 1e6
        (float64) or 1e4 (float32) (README, robustness envelope). Steps there may fail (flagged)."""
        limit = math.log(1e6 if self.opts.precision == "float64" else 1e4)
        ei = sec["kbt"][:, :2].min(axis=1)
        bbt = robot.damping_bending[:, :2].min(axis=1)
        rho_a = robot.density * sec["area"]
        c_ratio = self.coef[0] * self.dt  # c0 = c_ratio / dt

        def growth(dt):  # inf where the numbers overflow (absurdly small dt)
            c0 = np.float64(c_ratio) / dt
            with np.errstate(over="ignore", invalid="ignore"):
                g = robot.length * (rho_a * c0**2 / (ei + c0 * bbt)) ** 0.25 / math.sqrt(2)
            return np.where(np.isfinite(g), g, np.inf)

        g = np.atleast_1d(growth(self.dt))
        worst = int(np.argmax(g))
        if g[worst] <= limit:
            return
        lo, hi = math.log(self.dt), max(math.log(self.dt), math.log(1e3))  # growth falls as dt grows
        for _ in range(100):  # bisect log dt
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if np.max(growth(math.exp(mid))) > limit else (lo, mid)
        amp = f"1e{g[worst] / math.log(10):.0f}" if math.isfinite(g[worst]) else "beyond float64"
        warnings.warn(f"dt = {self.dt:g} s is below the single-shooting limit of {int(np.sum(g > limit))} rod(s) "
                      f"(rod {worst}: amplification {amp}; dt >= {math.exp(hi):.1e} s stays inside): steps may "
                      "fail, and are then flagged", stacklevel=3)

    def _retry(self, bt: ShootingBatch, set_load, failed: np.ndarray, x: np.ndarray, newton: dict) -> np.ndarray:
        """Homotopies along ``set_load`` (continuation steps, then 4x and 16x finer) for the failed
        rods, from x; returns the rods still failing."""
        for n_sub in (self.opts.continuation, 4 * self.opts.continuation, 16 * self.opts.continuation):
            if not (failed.any() and n_sub):
                break
            bt.homotopy(set_load, n_sub, failed, x, newton)
            failed = failed & ((bt.status.numpy() & layout.CONVERGED) == 0)
        return failed

    def _damping_homotopy(self, bt: ShootingBatch, i: int, failed: np.ndarray, x: np.ndarray,
                          newton: dict) -> np.ndarray:
        """Chunk i's failed rods reached from heavily damped copies of themselves: s K / c0 added
        to the shear and bending damping, s = 1000^(1 - lam) - 1 going to 0 (lam = 1: the exact
        step). Returns the rods still failing; the chunk's own dynamics table is back in place."""
        own = bt.args.dyn
        if self._damped[i] is None:
            self._damped[i] = bt.array(self._dyn[i])
        bt.args.dyn = self._damped[i]

        def set_damping(lam):
            d = np.array(self._dyn[i])
            d[:, layout.BSE:layout.BBT + 3] += (1e3 ** (1 - lam) - 1) * self._stiff[i] / self.coef[0]
            bt.put(self._damped[i], d)

        try:
            return self._retry(bt, set_damping, failed, x, newton)
        finally:
            bt.args.dyn = own

    def _launch_advance(self, bt: ShootingBatch, yprev, ok: np.ndarray, at_rest: bool = False) -> None:
        c0, c1, c2, d1 = (bt.wdtype(c) for c in self.coef)
        wp.launch(self._advance, dim=bt.args.ycur.shape, device=self.dev,
                  inputs=[bt.args.ycur, yprev, bt.args.hist, bt.array(ok, np.int32), c0, c1, c2, d1,
                          int(at_rest)])

    def step(self, tensions) -> StepResult:
        """Advance every live rod by dt under ``tensions`` (B, K) [N]."""
        tau = check_tensions(self.robot, tensions)
        if tau.shape[0] != self.B:
            raise InputError(f"tensions: {tau.shape[0]} rows for {self.B} rods")
        o = self.opts
        keep = self._have_jacobian

        def run(i):
            (lo, hi), bt, yp = self.chunks[i], self.batches[i], self._yprev[i]
            bt.set_tensions(tau[lo:hi])
            # Newton start: linear extrapolation of the base wrench over the last two steps
            # (the shooting residual amplifies a start error by up to ~1e4 at small dt).
            x = bt.x.numpy().astype(np.float64)
            x_pred = 2.0 * x - self._x_prev[i] if self.steps_done > 0 else x
            self._x_prev[i] = x
            newton = dict(tol=o.tolerance, max_iter=o.max_iter, max_step=o.max_step, broyden=o.jacobian == "broyden")
            alive = self.alive[lo:hi]
            bt.solve(x_pred, None, mask=alive, keep_jacobian=keep, **newton)
            failed = alive & ((bt.status.numpy() & layout.CONVERGED) == 0)
            # A large tension change in one step: reach it by a homotopy in the tension increment,
            # each sub-problem from the last (same time step, same history).
            tau_prev, tau_new = self._tau_prev[lo:hi], tau[lo:hi]
            failed = self._retry(bt, lambda lam: bt.set_tensions(tau_prev + lam * (tau_new - tau_prev)), failed, x,
                                 newton)
            if failed.any():
                # A lightly damped rod that moves fast: single shooting amplifies start errors, so
                # the step is reached from a heavily damped copy of itself, which hardly moves from
                # x(i) and is better conditioned.
                bt.set_tensions(tau_new)
                failed = self._damping_homotopy(bt, i, failed, x, newton)
            if failed.any():  # last resort: plain Newton (a fresh Jacobian at every iterate) from x(i)
                bt.solve(x, None, mask=failed, **(newton | dict(broyden=False, max_iter=2 * o.max_iter)))
            status = bt.status.numpy().copy()
            ok = ((status & layout.CONVERGED) != 0) & alive
            self._launch_advance(bt, yp, ok.astype(np.int32))
            p = bt.out.p.numpy()[:, -1].astype(np.float64)
            R = bt.out.R.numpy()[:, -1].astype(np.float64)
            q = bt.out.q.numpy()[:, -1].astype(np.float64)
            return (ok, status, bt.iters.numpy().copy(), bt.resnorm.numpy().astype(np.float64), p,
                    np.einsum("bij,bj->bi", R, q))

        parts = parallel(run, list(range(len(self.chunks))))
        self._tau_prev = tau
        self._have_jacobian = True
        ok, status, iters, resid, p, v = (np.concatenate(x) for x in zip(*parts))
        newly_failed = self.alive & ~ok
        self.failed_step[newly_failed] = self.steps_done
        self.alive &= ok
        self.steps_done += 1
        c0, c1, c2, d1 = self.coef
        acc = c0 * v + self._vel_hist
        okb = ok[:, None]
        self.tip_position = np.where(okb, p, self.tip_position)
        self._vel_hist = np.where(okb, c1 * v + c2 * self._vel_prev + d1 * acc, self._vel_hist)
        self._vel_prev = np.where(okb, v, self._vel_prev)
        self.tip_velocity = np.where(okb, v, self.tip_velocity)
        self.tip_acceleration = np.where(okb, acc, self.tip_acceleration)
        resid = np.where(ok, resid, np.inf)
        return StepResult(self.tip_position.copy(), self.tip_velocity.copy(), self.tip_acceleration.copy(),
                          ok, iters, resid, status)

    def tip_state(self) -> dict[str, np.ndarray]:
        """State at the last two nodes of the last evaluation: rotations (B, 2, 3, 3), n, m
        (B, 2, 3) world frame, q (B, 2, 3) body frame, and the last interval h (B,) [m]."""
        f64 = np.float64
        cat = {name: np.concatenate([getattr(bt.out, name).numpy()[:, -2:].astype(f64) for bt in self.batches])
               for name in ("R", "n", "m", "q")}
        cat["h"] = self.grid[:, -1] - self.grid[:, -2]
        return cat

    def shapes(self) -> np.ndarray:
        """Current positions along s, (B, N+1, 3) [m] (frozen rods: their last trial)."""
        return np.concatenate([bt.out.p.numpy().astype(np.float64) for bt in self.batches])

    def simulate(self, schedule, steps: int, *, shapes_every: int = 0, progress: bool = False) -> Trajectory:
        """Open loop: ``schedule`` is (B, steps, K) or (steps, K) [N], or a callable of the
        step index returning (B, K)."""
        if not isinstance(steps, int) or steps < 1:
            raise InputError(f"steps must be a positive integer, got {steps!r}")
        K = self.robot.n_tendons
        if callable(schedule):
            get = schedule
        else:
            sched = np.asarray(schedule, dtype=np.float64)
            if sched.ndim == 2:
                sched = np.broadcast_to(sched[None], (self.B,) + sched.shape)
            if sched.shape != (self.B, steps, K):
                raise InputError(f"schedule: expected shape ({self.B}, {steps}, {K}) or ({steps}, {K}), "
                                 f"got {np.shape(schedule)}")

            def get(i):
                return sched[:, i]

        T, B = steps, self.B
        require_memory(T * B * (8.0 * (9 + K) + 9) + (T // shapes_every if shapes_every else 0) * B * 24.0
                       * self.grid.shape[1], f"steps = {T} for {B} rod(s): the trajectory")
        tip = np.zeros((T + 1, B, 3))
        vel = np.zeros((T + 1, B, 3))
        acc = np.zeros((T + 1, B, 3))
        tip[0], vel[0], acc[0] = self.tip_position, self.tip_velocity, self.tip_acceleration
        taus = np.zeros((T, B, K))
        conv = np.zeros((T, B), dtype=bool)
        iters = np.zeros((T, B), dtype=np.int32)
        resid = np.zeros((T, B))
        status = np.zeros((T, B), dtype=np.int32)
        shape_steps, shapes = [], []
        if shapes_every:
            shape_steps.append(0)
            shapes.append(self.shapes())
        bar = _Progress(T, B) if progress else None
        for i in range(T):
            taus[i] = check_tensions(self.robot, get(i), name=f"schedule step {i}")
            r = self.step(taus[i])
            tip[i + 1], vel[i + 1], acc[i + 1] = r.tip_position, r.tip_velocity, r.tip_acceleration
            conv[i], iters[i], resid[i], status[i] = r.converged, r.iterations, r.residual, r.status
            if shapes_every and (i + 1) % shapes_every == 0:
                shape_steps.append(i + 1)
                shapes.append(self.shapes())
            if bar:
                bar.update(i + 1, int((~self.alive).sum()))
        if bar:
            bar.close()
        n1 = self.batches[0].out.p.shape[1]
        return Trajectory(time=self.dt * np.arange(T + 1), tip_position=tip, tip_velocity=vel,
                          tip_acceleration=acc, tensions=taus, converged=conv, iterations=iters,
                          residual=resid, status=status, failed_step=self.failed_step.copy(),
                          shape_steps=np.array(shape_steps, dtype=np.int32),
                          positions=np.array(shapes) if shapes else np.zeros((0, B, n1, 3)))


class _Progress:
    """A one-line progress bar on stderr: done/total units, rod-units/s, ETA, failed rods.
    ``start``: units already done before this run (resumed), left out of the rate."""

    def __init__(self, total: int, rods: int, unit: str = "steps", rate_unit: str = "rod-steps/s", start: int = 0):
        self.total, self.rods, self.t0, self.start = total, rods, time.perf_counter(), start
        self.unit, self.rate_unit = unit, rate_unit
        self.shown = -1.0

    def update(self, done: int, failed: int, note: str = "") -> None:
        now = time.perf_counter()
        if done < self.total and now - self.shown < 0.2:
            return
        self.shown = now
        el = now - self.t0
        rate = (done - self.start) * self.rods / el if el > 0 else 0.0
        eta = el / (done - self.start) * (self.total - done) if done > self.start else 0.0
        filled = int(30 * done / self.total)
        sys.stderr.write(f"\r[{'#' * filled}{'.' * (30 - filled)}] {done}/{self.total} {self.unit}{note} "
                         f"{rate:,.0f} {self.rate_unit} ETA {eta:5.1f} s failed {failed}")
        sys.stderr.flush()

    def close(self) -> None:
        sys.stderr.write("\n")
