"""Batched sliding-mode control of the tip (report section 4, with its bugs fixed).

Tip states X1 = p(L), X2 = R(L) q(L) (world frame). Error e = X_d - X1, sliding surface
S = e_t + C e, exponential reaching law S_t = -eps sw(S) - k S with sw = sgn ("smc") or
sat(S / phi) ("boundary_layer"). Written X2_t = a_c + b_c tau, the command is
b_c tau = C e_t + Xdd_d - a_c + eps sw(S) + k S, allocated into tensions 0 <= tau <= tau_max by
a bounded least-squares problem per rod (so K tendons reach targets off the tendon planes).
With ``command = "displacement"`` the controller commands motor displacements instead (what
hardware accepts): the same law on the model X2_t = a_c + b_c q, allocated within the motor's
range, the tension limit and the slack of each tendon (tdcr_warp/apps/allocation.py). It tracks the
tip across the base axis (x, y); the height follows on the surface the robot reaches (moving it
off that surface would take co-contraction: on examples/displacement_control.toml a 0.1 mm
squeeze of the rod costs about 3 N on each tendon of a pair).

Input models (a_c, b_c):
- "jacobian" (default): a quasi-static first-mode model of the tip,
  X2_t = w^2 (p_s(tau) - X1) - 2 zeta w X2 with p_s(tau) ~ p_s(tau0) + J (tau - tau0), where
  J = d p_tip / d tau comes from the batched statics (its tip Jacobian, refreshed every
  ``model_every`` steps), w is the Euler-Bernoulli first bending frequency and zeta the modal
  damping of the strain damping Bbt. Commanding displacements, J = d p_s / d q and the
  tendons held by their motors stiffen the rod: w^2 = k_tip / m_1 with k_tip the lateral tip
  stiffness of the statics (its tip compliance) and m_1 = 3 EI / (L^3 w_1^2) (0.243 rho A L)
  the first mode's mass; the damping term keeps 2 zeta w_1 (the wires add no damping).
- "alpha": the report's model, a_c = (n'(L) + rho A g - R C q|q|) / (rho A) and
  b_c = -[alpha_1 .. alpha_K] / (rho A) with alpha_i = hat(p_i')^2 p_i'' / |p_i'|^3 + p_i' / |p_i'|
  (p_i the tendon path at the tip).
Every gain, target and bound is per rod.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from tdcr_warp.apps.allocation import allocate_displacements
from tdcr_warp.core.progress import Progress
from tdcr_warp.model.options import COMMANDS, StaticOptions
from tdcr_warp.model.robot import InputError, Robot, real_array, require_memory
from tdcr_warp.model.tippath import TipPath
from tdcr_warp.physics.dynamics import Simulator
from tdcr_warp.physics.statics import reference_lengths, solve_static

__all__ = ["ControlRun", "TipController", "allocate", "control_metrics", "run_closed_loop", "sliding_command",
           "static_target"]

METHODS = ("smc", "boundary_layer", "integral")
INPUT_MODELS = ("jacobian", "alpha")
LATERAL = np.array([1.0, 1.0, 0.0])  # the axes a displacement command tracks (x, y: across the base axis)


def per_rod(name: str, value, B: int, tail: tuple[int, ...], bound: bool = False) -> np.ndarray:
    """``value`` as (B,) + tail: a number, shape ``tail`` (shared) or per rod; an InputError
    names ``name`` for any other shape or a non-finite entry (``bound``: an upper bound, +inf
    allowed)."""
    arr = real_array(value, name)
    if arr.shape == () and tail:
        arr = np.full(tail, float(arr))
    if arr.shape == tail:
        arr = np.broadcast_to(arr, (B,) + tail)
    if arr.shape != (B,) + tail:
        raise InputError(f"{name}: expected a number, shape {tail} or {(B,) + tail}, got shape {np.shape(value)}")
    if not (np.isfinite(arr) | (bound & (arr == np.inf))).all():
        raise InputError(f"{name}: non-finite value in {value!r}")
    return np.array(arr)


def _hat(x: np.ndarray) -> np.ndarray:
    z = np.zeros(x.shape[:-1])
    return np.stack([np.stack([z, -x[..., 2], x[..., 1]], -1), np.stack([x[..., 2], z, -x[..., 0]], -1),
                     np.stack([-x[..., 1], x[..., 0], z], -1)], -2)


def allocate(Bc: np.ndarray, v: np.ndarray, tau_max: np.ndarray, tau0: np.ndarray, sweeps: int = 60) -> np.ndarray:
    """Per rod: min |Bc tau - v|^2 + lam |tau|^2 over 0 <= tau <= tau_max, by projected
    coordinate descent (convex; warm-started at tau0). Bc (B, 3, K), v (B, 3) -> (B, K)."""
    Q = np.einsum("bik,bil->bkl", Bc, Bc)
    lam = 1e-9 * np.trace(Q, axis1=1, axis2=2)[:, None] + 1e-300
    K = Q.shape[1]
    Q = Q + lam[:, :, None] * np.eye(K)
    g = np.einsum("bik,bi->bk", Bc, v)
    tau = np.clip(tau0, 0.0, tau_max).copy()
    diag = np.einsum("bkk->bk", Q)
    if tau.shape[0] == 1:
        return _sweeps_one_rod(Q, g, diag, tau_max, tau, sweeps)
    columns = [(Q[:, k], g[:, k], diag[:, k], tau_max[:, k], tau[:, k]) for k in range(K)]  # views, taken once
    for _ in range(sweeps):
        for q, gk, dk, hi, tk in columns:
            r = gk - np.einsum("bl,bl->b", q, tau) + dk * tk
            np.clip(r / dk, 0.0, hi, out=tk)
    return tau


def _sweeps_one_rod(Q: np.ndarray, g: np.ndarray, diag: np.ndarray, tau_max: np.ndarray, tau: np.ndarray,
                    sweeps: int) -> np.ndarray:
    """``allocate``'s sweeps for a batch of one rod (a control loop's latency), with the batch's
    arithmetic: each sum of products by the same np.einsum, the rest in Python floats (which round
    as NumPy's elementwise operations do) and np.clip's rule max(x, 0) then min(x, tau_max), a NaN
    kept. ``tau`` (1, K) is updated in place and returned. A sweep that changes nothing ends them
    (every later one would repeat it)."""
    rows = [(Q[:, k], float(g[0, k]), float(diag[0, k]), float(tau_max[0, k])) for k in range(Q.shape[1])]
    cur = tau[0].tolist()
    for _ in range(sweeps):
        before = cur.copy()
        for k, (q, gk, dk, hi) in enumerate(rows):
            x = (gk - np.einsum("bl,bl->b", q, tau).item() + dk * cur[k]) / dk
            x = x if x > 0.0 or math.isnan(x) else 0.0
            x = x if x < hi or math.isnan(x) else hi
            cur[k] = tau[0, k] = x
        if cur == before:
            break
    return tau


def sliding_command(e: np.ndarray, e_t: np.ndarray, ac: np.ndarray, *, C: np.ndarray, k: np.ndarray,
                    eps: np.ndarray, phi: np.ndarray, method: str, xdd_d: np.ndarray | float = 0.0,
                    Ci: np.ndarray | None = None, ie: np.ndarray | None = None):
    """S = e_t + C e (method "integral": + Ci ie, ie the integral of e) and the input v = b_c tau
    that makes S_t = -eps sw(S) - k S on the plant X2_t = a_c + b_c tau:
    v = C e_t (+ Ci e) + Xdd_d - a_c + eps sw(S) + k S. sw = sgn ("smc") or sat(S / phi).
    Shapes (B, 3); eps, phi (B,)."""
    S = e_t + C * e
    v = C * e_t + xdd_d - ac
    if method == "integral":
        S, v = S + Ci * ie, v + Ci * e
    sw = np.sign(S) if method == "smc" else np.clip(S / phi[:, None], -1.0, 1.0)
    return S, v + eps[:, None] * sw + k * S


def _gains(B: int, K: int, gain_c, gain_k, epsilon, phi, tension_max, gain_i) -> tuple[np.ndarray, ...]:
    """The checked per-rod gains C, k (B, 3) [1/s], eps (B,) [m/s^2], phi (B,) [m/s], the tension
    bound (B, K) [N] and the integral gain Ci (B, 3) [1/s^2] (default C^2 / 4)."""
    C = per_rod("gain_c", gain_c, B, (3,))
    k = per_rod("gain_k", gain_k, B, (3,))
    eps = per_rod("epsilon", epsilon, B, ())
    ph = per_rod("phi", phi, B, ())
    tau_max = per_rod("tension_max", tension_max, B, (K,), bound=True)
    Ci = C**2 / 4 if gain_i is None else per_rod("gain_i", gain_i, B, (3,))
    if (Ci < 0).any():
        raise InputError(f"gain_i must be >= 0, got {Ci[Ci < 0][0]!r}")
    for name, arr in (("gain_c", C), ("gain_k", k), ("tension_max", tau_max)):
        if (arr <= 0).any():
            raise InputError(f"{name} must be positive, got {arr[arr <= 0][0]!r}")
    if (eps < 0).any() or (ph <= 0).any():
        raise InputError("epsilon must be >= 0 and phi > 0")
    return C, k, eps, ph, tau_max, Ci


def first_mode(robot: Robot, B: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The first bending mode of each rod as a clamped Euler-Bernoulli beam, (B,) each: omega
    [rad/s], its damping ratio zeta from the bending damping, rho A [kg/m] and the modal mass
    3 EI / (L^3 omega^2) [kg] (0.243 rho A L)."""
    sec = robot.section()
    EI = np.broadcast_to(sec["kbt"][:, 0], (B,))
    rho_a = np.broadcast_to(robot.density * sec["area"], (B,))
    L = np.broadcast_to(robot.length, (B,))
    omega = 1.8751**2 * np.sqrt(EI / (rho_a * L**4))
    zeta = omega * np.broadcast_to(robot.damping_bending[:, 0], (B,)) / (2 * EI)
    return omega, zeta, rho_a, 3 * EI / (L**3 * omega**2)


def motor_range(robot: Robot, u: np.ndarray, displacement_range) -> tuple[np.ndarray, np.ndarray]:
    """The motors' range q_lo, q_hi (B, K) [m] (default +- L / 20), checked against the start's
    displacements u (B, K) [m]."""
    B, K = u.shape
    L = np.broadcast_to(robot.length[:, None], (B, K))
    try:
        lo, hi = (-L / 20, L / 20) if displacement_range is None else displacement_range
    except (TypeError, ValueError):
        raise InputError(f"displacement_range must be (lo, hi) [m], got {displacement_range!r}") from None
    q_lo, q_hi = (per_rod(f"displacement_range[{i}]", v, B, (K,)) for i, v in enumerate((lo, hi)))
    if (q_lo >= q_hi).any():
        raise InputError(f"displacement_range: lo must be below hi, got {displacement_range!r}")
    if ((u < q_lo) | (u > q_hi)).any():
        b, k = np.argwhere((u < q_lo) | (u > q_hi))[0]
        raise InputError(f"the start's displacement[{b}][{k}] = {u[b, k]!r} m is outside displacement_range "
                         f"[{q_lo[b, k]!r}, {q_hi[b, k]!r}]")
    return q_lo, q_hi


def alpha_model(sim: Simulator, rho_a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The report's input model at the simulator's current state: a_c = (n'(L) + rho A g - R C q|q|) /
    (rho A) (B, 3) and b_c = -[alpha_1 .. alpha_K] / (rho A) (B, 3, K), alpha_i = hat(p_i')^2 p_i'' /
    |p_i'|^3 + p_i' / |p_i'| (p_i the tendon path at the tip, from the last two nodes); rho_a (B,) [kg/m]."""
    st = sim.tip_state()
    robot, B = sim.robot, sim.B
    sec = robot.section()
    kse = np.broadcast_to(sec["kse"], (B, 3))
    kbt = np.broadcast_to(sec["kbt"], (B, 3))
    R = st["R"][:, 1]
    v = np.einsum("bji,bj->bi", R, st["n"][:, 1]) / kse + [0, 0, 1]
    u = np.einsum("bji,bj->bi", R, st["m"][:, 1]) / kbt
    u_prev = np.einsum("bji,bj->bi", st["R"][:, 0], st["m"][:, 0]) / kbt
    v_prev = np.einsum("bji,bj->bi", st["R"][:, 0], st["n"][:, 0]) / kse + [0, 0, 1]
    h = st["h"][:, None]
    du, dv = (u - u_prev) / h, (v - v_prev) / h
    dn = (st["n"][:, 1] - st["n"][:, 0]) / h
    q = st["q"][:, 1]
    drag = np.broadcast_to(robot.drag, (B, 3))
    g = np.broadcast_to(robot.gravity, (B, 3))
    ra = rho_a[:, None]
    ac = (dn + ra * g - np.einsum("bij,bj->bi", R, drag * q * np.abs(q))) / ra
    r_tip = np.broadcast_to(robot.tendon_routing(np.broadcast_to(robot.length, (B,)))[0], (B, robot.n_tendons, 3))
    cols = []
    for i in range(robot.n_tendons):
        r = r_tip[:, i]
        ps = np.einsum("bij,bj->bi", R, np.cross(u, r) + v)
        pss = np.einsum("bij,bj->bi", R, np.cross(u, np.cross(u, r)) + np.cross(u, v) + np.cross(du, r) + dv)
        nps = np.linalg.norm(ps, axis=1)[:, None]
        alpha = np.einsum("bij,bj->bi", _hat(ps) @ _hat(ps), pss) / nps**3 + ps / nps
        cols.append(-alpha / ra)
    return ac, np.stack(cols, axis=-1)


def held_integral(ie: np.ndarray, e: np.ndarray, dt: float, bc: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The error integral ie (B, 3) [m s] advanced by e dt where the allocated command u (B, K)
    delivers the input v = b_c u (B, 3) to within 10 % (elsewhere held: no wind-up)."""
    miss = np.linalg.norm(np.einsum("bik,bk->bi", bc, u) - v, axis=1)
    delivered = miss <= 0.1 * np.linalg.norm(v, axis=1) + 1e-12
    return np.where(delivered[:, None], ie + dt * e, ie)


class TipController:
    """Sliding-mode tip controller for the B rods of a :class:`Simulator`.

    target (3,) or (B, 3) [m], or a :class:`~tdcr_warp.model.tippath.TipPath` (a desired trajectory:
    its velocity and acceleration enter the sliding surface and the law); gain_c, gain_k:
    diagonals (3,) or (B, 3) [1/s]; epsilon [m/s^2]
    and phi [m/s] (boundary layer): float or (B,); tension_max [N]: float, (K,) or (B, K).
    command "tension" | "displacement" (every tendon under displacement control; the input model
    "jacobian"): what the controller sets; displacement_range (lo, hi) [m], each a float, (K,)
    or (B, K): the motors' range (default +- L / 20), with tension_max the bound the allocation
    keeps on the tensions the displacements make.
    method "smc" | "boundary_layer" | "integral" (the boundary layer on S = e_t + C e + Ci int e:
    the integral removes the steady error a wrong model leaves; gain_i = Ci, default C^2 / 4,
    critically damped; docs/physics.md has the Lyapunov argument; the integral is held while the
    allocation cannot deliver the command: no wind-up); input_model "jacobian" | "alpha". model_robot: the robot
    the controller believes in (its statics, frequency and damping), default the simulated one;
    give the nominal robot to test robustness to plant uncertainty.
    """

    def __init__(self, sim: Simulator, target, *, method: str = "boundary_layer", input_model: str = "jacobian",
                 gain_c=20.0, gain_k=20.0, epsilon=0.005, phi=1e-3, tension_max=8.0, model_every: int = 5,
                 model_robot: Robot | None = None, gain_i=None, command: str = "tension",
                 displacement_range=None):
        if method not in METHODS:
            raise InputError(f"control method must be one of {METHODS}, got {method!r}")
        if input_model not in INPUT_MODELS:
            raise InputError(f"control input_model must be one of {INPUT_MODELS}, got {input_model!r}")
        if command not in COMMANDS:
            raise InputError(f"control command must be one of {COMMANDS}, got {command!r}")
        B, K = sim.B, sim.robot.n_tendons
        if K == 0:
            raise InputError("control needs at least one tendon")
        self.sim, self.method, self.input_model, self.command = sim, method, input_model, command
        self.path = target if isinstance(target, TipPath) else TipPath.constant(per_rod("target", target, B, (3,)))
        self.target = self.desired(sim.steps_done * sim.dt)[0]  # where the path starts (B, 3)
        self.C, self.k, self.eps, self.phi, self.tau_max, self.Ci = _gains(B, K, gain_c, gain_k, epsilon, phi,
                                                                           tension_max, gain_i)
        self.ie = np.zeros((B, 3))  # the integral of the tip error [m s] (method "integral")
        self.model_unstable = np.zeros(B, dtype=bool)  # a linearisation landed on an unstable equilibrium
        self.model_every = model_every
        self._static = None
        self._J = None
        self._p0 = None
        self._u_lin = None
        self.steps = 0
        robot = self.model_robot = model_robot or sim.robot
        if robot.n_tendons != K:
            raise InputError(f"model_robot has {robot.n_tendons} tendons, the plant {K}")
        self.u = sim.displacements if command == "displacement" else np.zeros((B, K))  # the last command
        self.omega, self.zeta, self.rho_a, self.m_mode = first_mode(robot, B)
        self.static_opts = StaticOptions(nodes=sim.opts.nodes, integrator=sim.opts.integrator,
                                         model=sim.opts.model, precision=sim.opts.precision, threads=sim.opts.threads,
                                         sensitivities=True)
        if command == "displacement":
            self._displacement_setup(robot, displacement_range)

    def _displacement_setup(self, robot: Robot, displacement_range) -> None:
        """Checks of displacement commands; the motors' range q_lo, q_hi (B, K) [m]."""
        for name, rb in (("the plant", self.sim.robot), ("model_robot", robot)):
            bad = [k for k in range(rb.n_tendons) if k not in set(rb.displaced)]
            if bad:
                raise InputError(f"command = 'displacement': tendon(s) {bad} of {name} are under tension control "
                                 "(give every tendon control = 'displacement')")
        if self.input_model != "jacobian":
            raise InputError("command = 'displacement' needs input_model = 'jacobian' (the statics' d tip / d q)")
        self.q_lo, self.q_hi = motor_range(robot, self.u, displacement_range)
        self._reference = reference_lengths(robot, options=self.static_opts, device=self.sim.dev)
        self._lin = None
        self._warm = None

    def surface(self, e: np.ndarray, e_t: np.ndarray) -> np.ndarray:
        """The sliding variable S (B, 3) of the errors e, e_t (and the current error integral)."""
        S = e_t + self.C * e
        return S + self.Ci * self.ie if self.method == "integral" else S

    def desired(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The desired tip position, velocity and acceleration (B, 3) at time t [s]."""
        B = self.sim.B
        try:
            return tuple(np.broadcast_to(a, (B, 3)) for a in self.path(t))
        except ValueError:
            raise InputError(f"tip path: expected (3,) or ({B}, 3) per quantity for {B} rods, got "
                             f"{[np.shape(a) for a in self.path(t)]}") from None

    def _linearise(self, u: np.ndarray) -> None:
        """p_s(u) and J = d p_s / d u at the command u (tensions or displacements): one batched
        static solve with its tip Jacobian (tdcr_warp/physics/sensitivity.py: probes of the converged
        shooting problem, no extra solves); commanding displacements, also the tensions, their
        Jacobian, the slack set and each slack tendon's spare length."""
        disp = self.command == "displacement"
        base = solve_static(self.model_robot, np.zeros_like(u) if disp else u, displacements=u if disp else None,
                            options=self.static_opts, device=self.sim.dev, initial=self._static)
        if disp and not base.converged.all():  # those rods keep their last model
            bad = np.flatnonzero(~base.converged)
            if self._static is None:
                raise InputError(f"the controller's model did not converge for rods {bad[:10].tolist()} at the "
                                 f"command {u[bad[0]].tolist()} ({base.failure_reasons()[bad[0]]})")
            base = base.replaced(bad, self._static.rows(bad))
            u = u.copy()
            u[bad] = self._u_lin[bad]
        self._static, self._J, self._p0, self._u_lin = base, base.tip_jacobian[:, :3], base.tip_position, u.copy()
        self.model_unstable |= base.converged & ~base.success
        if disp:
            gap = np.where(base.slack, self._reference - u - base.tendon_free_length, 0.0)
            self._lin = {"q": self._u_lin, "tension": base.tendon_tension_base, "tension_jacobian": base.tension_jacobian,
                         "slack_jacobian": base.slack_jacobian,
                         "slack": base.slack, "gap": np.maximum(gap, 0.0)}
            C = base.tip_compliance
            self._w2 = 2.0 / ((C[:, 0, 0] + C[:, 1, 1]) * self.m_mode)  # the held tendons' stiffness

    def plant(self) -> tuple[np.ndarray, np.ndarray]:
        """a_c (B, 3) and b_c (B, 3, K) of X2_t = a_c + b_c tau at the current state."""
        X1, X2 = self.sim.tip_position, self.sim.tip_velocity
        if self.input_model == "jacobian":
            if self._J is None or self.steps % self.model_every == 0:
                self._linearise(self.u)
            w2 = (self._w2 if self.command == "displacement" else self.omega**2)[:, None]
            bc = w2[:, :, None] * self._J
            ac = w2 * (self._p0 - np.einsum("bik,bk->bi", self._J, self._u_lin) - X1) \
                - (2 * self.zeta * self.omega)[:, None] * X2
            return ac, bc
        return alpha_model(self.sim, self.rho_a)

    def __call__(self) -> np.ndarray:
        """The command (B, K) for the next step, tensions [N] or displacements [m] (``command``),
        from the simulator's current tip state."""
        ac, bc = self.plant()
        p_d, v_d, a_d = self.desired(self.sim.steps_done * self.sim.dt)
        e = p_d - self.sim.tip_position
        e_t = v_d - self.sim.tip_velocity
        _, v = sliding_command(e, e_t, ac, C=self.C, k=self.k, eps=self.eps, phi=self.phi, method=self.method,
                               xdd_d=a_d, Ci=self.Ci, ie=self.ie)
        disp = self.command == "displacement"
        if disp:
            bc, v = bc * LATERAL[:, None], v * LATERAL
            self.u, self._warm = allocate_displacements(bc, v, self.u, self._lin, self.q_lo, self.q_hi, self.tau_max,
                                                        self._warm)
        else:
            self.u = allocate(bc, v, self.tau_max, self.u)
        if self.method == "integral":
            self.ie = held_integral(self.ie, e * LATERAL if disp else e, self.sim.dt, bc, self.u, v)
        self.steps += 1
        return self.u


@dataclass
class ControlRun:
    """Closed-loop record: time (T+1,), tip_position, tip_velocity, error = desired - tip_position
    (T+1, B, 3) [m, m/s, m], sliding (T+1, B, 3) [m/s], tensions (T, B, K) [N] (commanding
    displacements: the tensions at the motors at the end of each step), converged (T, B),
    penetration (T, B) [m] (the deepest into any obstacle; 0 without obstacles), target
    (B, 3) (where the desired path starts), desired (T+1, B, 3) [m] (the desired tip);
    displacements (T, B, K) [m]: the commanded motor displacements (empty when tensions are);
    shape_steps (S,), positions (S, B, N+1, 3) [m] and rotations (S, B, N+1, 3, 3): the shapes
    every ``shapes_every`` steps (empty if 0); model_unstable (B,): the controller's model was
    linearised about an equilibrium the stability verdict found unstable at least once (its
    Jacobian then describes a shape the robot would leave)."""

    time: np.ndarray
    tip_position: np.ndarray
    tip_velocity: np.ndarray
    error: np.ndarray
    sliding: np.ndarray
    tensions: np.ndarray
    converged: np.ndarray
    target: np.ndarray
    penetration: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    desired: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 3)))
    displacements: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 0)))
    shape_steps: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int32))
    positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 0, 3)))
    rotations: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 0, 3, 3)))
    model_unstable: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    def to_npz(self, path) -> None:
        np.savez_compressed(path, **asdict(self))


def run_closed_loop(sim: Simulator, controller: TipController, steps: int, *, progress=False,
                    shapes_every: int = 0) -> ControlRun:
    """Run ``steps`` steps of the controller on the simulated plant; ``shapes_every`` > 0 also
    keeps the shapes every that many steps (and at the start). ``progress``: True for a
    progress bar, or a callable ``progress(step, steps)`` called after every step."""
    B, K = sim.B, sim.robot.n_tendons
    n1 = sim.grid.shape[1]
    disp = controller.command == "displacement"
    require_memory(steps * B * (8.0 * (13 + (2 if disp else 1) * K) + 1)
                   + (steps // shapes_every if shapes_every else 0) * B * 96.0 * n1,
                   f"steps = {steps} for {B} rod(s): the closed-loop record")
    tip = np.zeros((steps + 1, B, 3))
    vel = np.zeros((steps + 1, B, 3))
    S = np.zeros((steps + 1, B, 3))
    taus = np.zeros((steps, B, K))
    qs = np.zeros((steps if disp else 0, B, K))
    conv = np.zeros((steps, B), dtype=bool)
    pen = np.zeros((steps, B))
    desired = np.zeros((steps + 1, B, 3))
    tip[0], vel[0] = sim.tip_position, sim.tip_velocity
    t0 = sim.steps_done * sim.dt
    p_d, v_d, _ = controller.desired(t0)
    desired[0] = p_d
    S[0] = controller.surface(p_d - tip[0], v_d - vel[0])
    shape_steps, shapes = ([0], [sim.shapes()]) if shapes_every else ([], [])
    bar = Progress(steps, B) if progress is True else None
    for i in range(steps):
        if disp:
            qs[i] = controller()
            r = sim.step(displacements=qs[i])
            taus[i] = sim.tendons()["tension_base"]
        else:
            taus[i] = controller()
            r = sim.step(taus[i])
        tip[i + 1], vel[i + 1], conv[i], pen[i] = r.tip_position, r.tip_velocity, r.converged, r.penetration
        p_d, v_d, _ = controller.desired(t0 + (i + 1) * sim.dt)
        desired[i + 1] = p_d
        S[i + 1] = controller.surface(p_d - tip[i + 1], v_d - vel[i + 1])
        if shapes_every and (i + 1) % shapes_every == 0:
            shape_steps.append(i + 1)
            shapes.append(sim.shapes())
        if bar:
            bar.update(i + 1, int((~sim.alive).sum()))
        elif callable(progress):
            progress(i + 1, steps)
    if bar:
        bar.close()
    return ControlRun(time=sim.dt * np.arange(steps + 1), tip_position=tip, tip_velocity=vel,
                      error=desired - tip, sliding=S, tensions=taus, converged=conv, penetration=pen,
                      target=controller.target.copy(), desired=desired, displacements=qs, shape_steps=np.array(shape_steps, dtype=np.int32),
                      positions=np.array([p for p, _ in shapes]) if shapes else np.zeros((0, B, n1, 3)),
                      rotations=np.array([R for _, R in shapes]) if shapes else np.zeros((0, B, n1, 3, 3)),
                      model_unstable=controller.model_unstable.copy())


def control_metrics(run: ControlRun, tension_max: np.ndarray, band: float = 5e-4) -> dict[str, np.ndarray]:
    """Per-rod metrics: final and RMS tip error [m], settling time into ``band`` [s] (inf if
    never), overshoot [m] (largest excursion past the target along the initial error), chatter
    index: mean |tau(k) - 2 tau(k-1) + tau(k-2)| summed over tendons [N] over the second half of
    the run, the switching part of the tension history while holding (a smooth ramp scores ~0);
    the fraction of steps where a tension
    reverses direction; and the mean |tau(k) - tau(k-1)| [N]), saturation fraction, peak and
    mean tension [N]; for tracking, the largest error over the second half of the run
    ``max_error`` [m] and the ``lag`` [s]: the delay of the desired path (a whole number of steps,
    at most a quarter of the run) that best matches the tip over the second half (0 for a fixed
    target); ``max_penetration`` [m]: the deepest any node sank into an obstacle over the run (0
    without obstacles)."""
    err = np.linalg.norm(run.error, axis=2)  # (T+1, B)
    T = err.shape[0] - 1
    outside = err > band
    last_out = T - np.argmax(outside[::-1], axis=0)  # index of the last sample outside the band
    settle = np.where(outside.any(axis=0), run.time[np.minimum(last_out + 1, T)], 0.0)
    settle = np.where(outside[-1], np.inf, settle)
    d0 = run.error[0] / np.maximum(np.linalg.norm(run.error[0], axis=1, keepdims=True), 1e-300)
    overshoot = np.maximum(0.0, -np.einsum("tbi,bi->tb", run.error, d0).min(axis=0))
    dtau = np.diff(run.tensions, axis=0)
    d2tau = np.diff(run.tensions[T // 2:], n=2, axis=0)  # the second half: the held phase
    chatter = np.abs(d2tau).sum(axis=2).mean(axis=0) if len(d2tau) else np.zeros(err.shape[1])
    rate = np.abs(dtau).sum(axis=2).mean(axis=0) if T > 1 else np.zeros(err.shape[1])
    flips = (np.sign(dtau[1:]) * np.sign(dtau[:-1]) < 0).any(axis=2).mean(axis=0) if T > 2 else np.zeros(err.shape[1])
    tmax = np.broadcast_to(tension_max, run.tensions.shape[1:])
    sat = ((run.tensions <= 0.0) | (run.tensions >= tmax[None] * (1 - 1e-12))).mean(axis=(0, 2))
    half = slice(T // 2, None)
    desired = run.tip_position + run.error
    shifts = range(0, max(1, T // 4) + 1)
    miss = np.stack([((desired[T // 2 - k:T + 1 - k] - run.tip_position[half]) ** 2).sum(axis=2).mean(axis=0)
                     for k in shifts])  # (shifts, B)
    lag = np.argmin(miss, axis=0) * (run.time[1] - run.time[0] if T else 0.0)
    return {"final_error": err[-1], "rms_error": np.sqrt((err[1:] ** 2).mean(axis=0)),
            "max_error": err[half].max(axis=0), "lag": lag, "settling_time": settle,
            "overshoot": overshoot, "chatter": chatter, "reversal_fraction": flips, "tension_rate": rate, "saturation_fraction": sat,
            "peak_tension": run.tensions.max(axis=(0, 2)), "mean_tension": run.tensions.mean(axis=0),
            "max_penetration": run.penetration.max(axis=0) if run.penetration.size else np.zeros(err.shape[1])}


# The unit of each control_metrics entry ("1": a fraction of the steps; tension_rate is per step).
METRIC_UNITS = {"final_error": "m", "rms_error": "m", "max_error": "m", "lag": "s", "settling_time": "s", "overshoot": "m", "chatter": "N",
                "reversal_fraction": "1", "tension_rate": "N", "saturation_fraction": "1", "peak_tension": "N",
                "mean_tension": "N", "max_penetration": "m"}


def static_target(robot: Robot, tensions, **kw) -> np.ndarray:
    """The static tip under ``tensions`` (and ``displacements``, among ``kw`` for solve_static):
    a reachable target."""
    sol = solve_static(robot, tensions, **kw)
    if not sol.converged.all():
        raise InputError("the static target did not converge")
    return sol.tip_position

