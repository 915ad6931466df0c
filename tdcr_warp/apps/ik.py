"""Batched inverse kinematics: tip targets -> tendon commands within bounds.

Per rod, a bounded Levenberg-Marquardt iteration on the analytic tip Jacobian of the statics
(``solve_static(..., sensitivities=True)``): the step d minimises |J d - e|^2 + lam |d|^2 within
the command bounds (``box_least_squares``), e the tip error [m] (with an orientation target
also L times the rotation error [rad]); a step that reduces |e| is taken and lam shrinks, one
that does not is refused and lam grows. A rod is done when |e| < tol (reached), when no step
within the bounds reduces |e| (unreachable: the point returned is the closest the iteration
found, a local minimum of the distance over the bounded commands; no step: the projected
gradient vanishes, or a step is refused whose predicted gain is below the statics' tolerance,
where the statics' rounding decides), or when its statics fail.

The commands are tensions [N] (tension control, lower bound 0, upper ``tension_max``) and motor
displacements [m] (displacement control, within ``displacement_range``). The start is the
constant-curvature solution: the arc of length L whose tip comes closest to the target, and the
tensions whose moment bends the straight rod to its curvature.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np

from tdcr_warp.apps.control import per_rod
from tdcr_warp.model.options import StaticOptions
from tdcr_warp.model.robot import InputError, Robot, real_array
from tdcr_warp.physics.statics import StaticSolution, solve_static

__all__ = ["IKResult", "solve_ik"]

REACHED, UNREACHABLE, FAILED, CAPPED = "reached", "unreachable", "statics failed", "iteration cap"
LAM0, LAM_MAX = 1e-6, 1e6  # Levenberg-Marquardt damping, relative to the mean diagonal of J^T J
KKT_TOL = 1e-7  # |projected gradient| / (|J| |e|) of a bounded local minimum


@dataclass
class IKResult:
    """Per rod: command (B, K) tensions [N] / displacements [m] (by each tendon's control);
    tip_position (B, 3) [m], tip_rotation (B, 3, 3) at it; position_error (B,) |target - tip|
    [m]; orientation_error (B,) [rad] (0 without an orientation target); success (B,) bool
    (reached, on an equilibrium not found unstable: steps onto unstable ones are refused);
    reason: per rod "reached", "unreachable" (the closest point found is returned), "statics
    failed" or "iteration cap"; iterations (B,) Jacobian evaluations; solution: the statics at
    the returned commands."""

    command: np.ndarray
    tip_position: np.ndarray
    tip_rotation: np.ndarray
    position_error: np.ndarray
    orientation_error: np.ndarray
    success: np.ndarray
    reason: list
    iterations: np.ndarray
    solution: StaticSolution

    def to_npz(self, path) -> None:
        out = {k: v for k, v in asdict(self).items() if isinstance(v, np.ndarray)}
        np.savez_compressed(path, reason=np.array(self.reason), **out)


def box_least_squares(A: np.ndarray, b: np.ndarray, lo: np.ndarray, hi: np.ndarray, damping) -> np.ndarray:
    """Per rod: min |A x - b|^2 + lam |x|^2 over lo <= x <= hi, lam = damping trace(A^T A) / K
    (damping: float or (B,)). A convex quadratic program, solved exactly by a primal active set
    from x = clip(0): solve for the free variables with the others held at their bounds, move
    toward that point as far as the bounds allow (a variable that blocks joins the bounded set),
    and once the point is feasible free the bounded variable whose multiplier has the wrong sign
    (the largest); done when none has (at most 6 K + 6 passes). Exact linear solves: an
    ill-conditioned direction (co-contraction of tendons) is resolved like the others.
    A (B, M, K), b (B, M), lo, hi (B, K) -> (B, K)."""
    Q = np.einsum("bik,bil->bkl", A, A)
    B, K = lo.shape
    lam = np.broadcast_to(damping, (B,)) * np.trace(Q, axis1=1, axis2=2) / K + 1e-300
    Q = Q + lam[:, None, None] * np.eye(K)
    g = np.einsum("bik,bi->bk", A, b)
    eye = np.eye(K, dtype=bool)
    rows = np.arange(B)
    x = np.clip(np.zeros((B, K)), lo, hi)
    bound = np.zeros((B, K), dtype=bool)
    upper = np.zeros((B, K), dtype=bool)  # a bounded variable: at hi (else at lo)
    going = np.ones(B, dtype=bool)
    for _ in range(6 * K + 6):
        free = ~bound
        M = np.where(free[:, :, None] & free[:, None, :], Q, np.where(eye, 1.0, 0.0))
        rhs = np.where(bound, x, g - np.einsum("bkl,bl->bk", Q, np.where(bound, x, 0.0)))
        d = np.where(going[:, None] & free, np.linalg.solve(M, rhs[..., None])[..., 0] - x, 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            room = np.where(d > 0, (hi - x) / d, np.where(d < 0, (lo - x) / d, np.inf))
        block = room.argmin(axis=1)
        alpha = np.clip(room[rows, block], 0.0, 1.0)
        x = np.clip(x + alpha[:, None] * d, lo, hi)
        blocked = going & (alpha < 1.0)
        r, c = rows[blocked], block[blocked]
        bound[r, c] = True
        upper[r, c] = d[r, c] > 0
        x[r, c] = np.where(upper[r, c], hi[r, c], lo[r, c])  # exactly on the bound it met
        w = g - np.einsum("bkl,bl->bk", Q, x)  # minus the gradient
        wrong = np.where(bound, np.maximum(np.where(upper, -w, w), 0.0), 0.0)
        worst = wrong.argmax(axis=1)
        free_one = going & ~blocked & (wrong[rows, worst] > 0)
        bound[rows[free_one], worst[free_one]] = False
        going &= blocked | free_one
        if not going.any():
            break
    return x


def rotation_error(R_target: np.ndarray, R: np.ndarray) -> np.ndarray:
    """(B, 3) the world-frame rotation vector taking R to R_target (the log of R_target R^T)."""
    D = np.einsum("bij,bkj->bik", R_target, R)
    w = np.stack([D[:, 2, 1] - D[:, 1, 2], D[:, 0, 2] - D[:, 2, 0], D[:, 1, 0] - D[:, 0, 1]], axis=1)
    s = 0.5 * np.linalg.norm(w, axis=1)
    c = 0.5 * (np.trace(D, axis1=1, axis2=2) - 1.0)
    ang = np.arctan2(s, c)
    scale = np.where(s > 1e-12, ang / np.maximum(s, 1e-300), 1.0)  # ang / sin(ang), 1 at 0
    return 0.5 * scale[:, None] * w


def constant_curvature_seed(robot: Robot, target: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Tensions (B, K) of the arc of length L bending toward the target's azimuth whose tip
    comes closest to it (searched over 256 curvatures in [0, 2 pi / L)): the bending moment
    EI kappa, allocated to the tension-controlled tendons within their bounds (tendons under
    displacement control start at their bounded 0)."""
    B, K = lo.shape
    L = np.broadcast_to(robot.length, (B,))
    phi = np.arctan2(target[:, 1], target[:, 0])
    d, z = np.hypot(target[:, 0], target[:, 1]), target[:, 2]
    k = np.linspace(1e-9, 2 * np.pi * (1 - 1 / 256), 256)[None] / L[:, None]  # (B, 256)
    kl = k * L[:, None]
    dist = np.hypot((1 - np.cos(kl)) / k - d[:, None], np.sin(kl) / k - z[:, None])
    kappa = k[np.arange(B), dist.argmin(axis=1)]
    ei = np.broadcast_to(robot.section()["kbt"][:, 0], (B,))
    need = (ei * kappa)[:, None] * np.stack([-np.sin(phi), np.cos(phi)], axis=1)  # moment about x, y
    r = np.broadcast_to(robot.tendon_routing(0.0)[0], (B, K, 3))
    A = np.stack([-r[..., 1], r[..., 0]], axis=1)  # tendon k pulls with moment tau (-r_y, r_x)
    disp = np.zeros(K, dtype=bool)
    disp[list(robot.displaced)] = True
    A[:, :, disp] = 0.0
    x0 = np.clip(np.zeros((B, K)), lo, hi)
    return np.where(disp, x0, box_least_squares(A, need, np.where(disp, x0, lo), np.where(disp, x0, hi), 1e-9))


def _target_rotations(target_rotation, B: int) -> np.ndarray:
    """The orientation targets (B, 3, 3), or an InputError where one is not a rotation matrix."""
    Rt = per_rod("target_rotation", target_rotation, B, (3, 3))
    bad = np.abs(np.einsum("bji,bjk->bik", Rt, Rt) - np.eye(3)).max(axis=(1, 2)) > 1e-6
    if bad.any() or (np.linalg.det(Rt) < 0).any():
        raise InputError(f"target_rotation[{int(np.flatnonzero(bad | (np.linalg.det(Rt) < 0))[0])}] is not a "
                         "rotation matrix (orthonormal, det +1)")
    return Rt


def _command_bounds(disp: np.ndarray, L: np.ndarray, tension_max, displacement_range) -> tuple[np.ndarray, np.ndarray]:
    """The bounds lo, hi (B, K) of every command: [0, tension_max] [N] for a tendon under tension
    control, ``displacement_range`` [m] (default +- L / 20) for one under displacement control
    (``disp`` (K,) bool); L (B,) [m]."""
    B, K = len(L), len(disp)
    tmax = per_rod("tension_max", tension_max, B, (K,), bound=True)
    if (tmax[:, ~disp] <= 0).any():
        raise InputError(f"tension_max must be positive, got {tmax[:, ~disp][tmax[:, ~disp] <= 0][0]!r}")
    try:
        dlo, dhi = (-L / 20, L / 20) if displacement_range is None else displacement_range
    except (TypeError, ValueError):
        raise InputError(f"displacement_range must be (lo, hi) [m], got {displacement_range!r}") from None
    dlo, dhi = (per_rod("displacement_range", v, B, ()) for v in (dlo, dhi))
    if not (dlo < dhi).all():
        raise InputError(f"displacement_range must be finite (lo, hi) with lo < hi [m], got {displacement_range!r}")
    return np.where(disp, dlo[:, None], 0.0), np.where(disp, dhi[:, None], tmax)


def _bounded_minimum(J: np.ndarray, e: np.ndarray, cmd: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(B,) bool: the command is a bounded local minimum of |e| (KKT: no descent direction within
    the bounds lo, hi), so the target is unreachable; J (B, M, K) the error's Jacobian, e (B, M)."""
    g = np.einsum("bik,bi->bk", J, e)  # -gradient of |e|^2 / 2
    free = np.where(cmd <= lo, np.maximum(g, 0.0), np.where(cmd >= hi, np.minimum(g, 0.0), g))
    return np.linalg.norm(free, axis=1) <= KKT_TOL * np.linalg.norm(J, axis=(1, 2)) * np.linalg.norm(e, axis=1)


def _no_step_left(J, e, step, cmd, lam, better, statics_tol: float) -> np.ndarray:
    """(B,) bool: no step is left to try: the damping passed LAM_MAX, the step vanished, or a
    refused step (not ``better``) had a predicted gain |e| - |e - J step| within the statics'
    tolerance [m] (its refusal is the statics' rounding, not the model's error)."""
    gain = np.linalg.norm(e, axis=1) - np.linalg.norm(e - np.einsum("bik,bk->bi", J, step), axis=1)
    tiny = np.abs(step).max(axis=1) <= 1e-15 * (1 + np.abs(cmd).max(axis=1))
    return (lam > LAM_MAX) | tiny | (~better & (gain <= statics_tol))


def solve_ik(robot: Robot, target, *, target_rotation=None, tension_max=np.inf, displacement_range=None,
             tol: float = 1e-9, max_iter: int = 40, initial=None, options: StaticOptions | None = None,
             device: str | None = None, **overrides) -> IKResult:
    """Commands that put each rod's tip at ``target`` (3,) or (B, 3) [m] (and its frame at
    ``target_rotation`` (3, 3) or (B, 3, 3), optional), within 0 <= tension <= tension_max
    (float, (K,) or (B, K) [N]) and displacement_range (lo, hi) [m] (default +- L / 20).
    tol [m]: the position error (and L times the orientation error) to reach; initial: a start
    (B, K) of commands (default: the constant-curvature seed). options / overrides: the
    statics (``StaticOptions``; its tol defaults to 1e-3 tol, so that the tip is exact to well
    below the target's tolerance)."""
    K = robot.n_tendons
    if K == 0:
        raise InputError("inverse kinematics needs at least one tendon")
    if not (isinstance(tol, (int, float)) and np.isfinite(tol) and tol > 0):
        raise InputError(f"ik tol must be a positive number [m], got {tol!r}")
    if not (isinstance(max_iter, int) and max_iter >= 1):
        raise InputError(f"ik max_iter must be a positive integer, got {max_iter!r}")
    tgt = real_array(target, "target", copy=False)
    B = max(robot.batch_size, tgt.shape[0] if tgt.ndim == 2 else 1)
    tgt = per_rod("target", tgt, B, (3,))
    Rt = None if target_rotation is None else _target_rotations(target_rotation, B)
    disp = np.zeros(K, dtype=bool)
    disp[list(robot.displaced)] = True
    L = np.broadcast_to(robot.length, (B,))
    lo, hi = _command_bounds(disp, L, tension_max, displacement_range)
    opts = (options or StaticOptions()).override(**overrides)
    opts = replace(opts, sensitivities=True, tol=opts.tol if opts.tol is not None else 1e-3 * tol)
    cmd = constant_curvature_seed(robot, tgt, lo, hi) if initial is None else np.clip(
        per_rod("initial", initial, B, (K,)), lo, hi)

    def solve(c, warm):
        return solve_static(robot, np.where(disp, 0.0, c), displacements=np.where(disp, c, 0.0) if disp.any() else None,
                            options=opts, device=device, initial=warm)

    def error(sol):
        e = tgt - sol.tip_position
        if Rt is None:
            return e, np.zeros(B)
        eth = rotation_error(Rt, sol.tip_rotation)
        return np.concatenate([e, L[:, None] * eth], axis=1), np.linalg.norm(eth, axis=1)

    sol = solve(cmd, None)
    e, eo = error(sol)
    lam = np.full(B, LAM0)
    done = np.zeros(B, dtype=bool)
    reason = np.full(B, CAPPED, dtype=object)
    iters = np.zeros(B, dtype=np.int64)
    for _ in range(max_iter):
        failed = ~done & ~sol.converged
        reason[failed], done[failed] = FAILED, True
        hit = ~done & sol.success & (np.linalg.norm(e[:, :3], axis=1) < tol) & (L * eo < tol)
        reason[hit], done[hit] = REACHED, True
        if done.all():
            break
        J = sol.tip_jacobian[:, :3] if Rt is None else np.concatenate(
            [sol.tip_jacobian[:, :3], L[:, None, None] * sol.tip_jacobian[:, 3:]], axis=1)
        J = np.where(done[:, None, None], 0.0, np.nan_to_num(J))
        kkt = ~done & _bounded_minimum(J, e, cmd, lo, hi)
        reason[kkt], done[kkt] = UNREACHABLE, True
        if done.all():
            break
        step = box_least_squares(J, np.where(done[:, None], 0.0, e), lo - cmd, hi - cmd, lam)
        trial = np.where(done[:, None], cmd, cmd + step)
        iters += ~done
        new = solve(trial, sol)
        en, eon = error(new)
        better = ~done & new.success & (np.linalg.norm(en, axis=1) < np.linalg.norm(e, axis=1))
        cmd = np.where(better[:, None], trial, cmd)
        sol = sol.replaced(np.flatnonzero(better), new.rows(better))
        e, eo = np.where(better[:, None], en, e), np.where(better, eon, eo)
        lam = np.where(better, lam / 3.0, np.where(done, lam, lam * 10.0))
        stuck = ~done & _no_step_left(J, e, step, cmd, lam, better, opts.tol)
        reason[stuck], done[stuck] = UNREACHABLE, True
    hit = (reason == CAPPED) & sol.success & (np.linalg.norm(e[:, :3], axis=1) < tol) & (L * eo < tol)
    reason[hit] = REACHED
    pe = np.linalg.norm(tgt - sol.tip_position, axis=1)
    success = (reason == REACHED) & sol.success
    return IKResult(command=cmd, tip_position=sol.tip_position.copy(), tip_rotation=sol.tip_rotation.copy(),
                    position_error=pe, orientation_error=eo, success=success, reason=[str(r) for r in reason],
                    iterations=iters, solution=sol)
