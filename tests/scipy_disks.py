"""Independent reference solver (plain NumPy/SciPy) for the static spacer-disk tendon model.

Not part of the package and not a test file: a helper for the tests. Written only from the
equations below; it shares no code with the Warp solver or with tests/scipy_reference.py.

Model
-----
* Cosserat rod (shear and extension), base clamped at p(0) = 0, R(0) = I, leaving along +z.
  G = E / (2 (1 + nu)), A = pi r^2, I = pi r^4 / 4, J = 2 I, Kse = diag(GA, GA, EA),
  Kbt = diag(EI, EI, GJ), v* = e3, u* = 0, weight per length f = density A gravity (world).
* State y = [p (3), R (9, row-major), n (3), m (3)]; n, m internal force/moment, WORLD frame.
  Between disks the rod carries no tendon load:
      p' = R v,  R' = R hat(u),  n' = -f,  m' = -p' x n,
      v = e3 + Kse^-1 R^T n,  u = Kbt^-1 R^T m.
* Disks at 0 < s_1 < ... < s_D <= L. Tendon k has a constant body-frame offset r_k = (x_k, y_k, 0),
  a tension tau_k >= 0 (the same along the tendon: no friction) and ends at disk d_k (its
  `length` is that disk's arc length). Holes: h_0k = r_k in the grounded base plate,
  h_jk = p(s_j) + R(s_j) r_k. The tendon is straight between consecutive holes, chord directions
  u_jk = (h_jk - h_(j-1)k) / |h_jk - h_(j-1)k|, j = 1..d_k.
* Point loads at disk j from tendon k (j <= d_k), acting at the hole:
      F_jk = tau_k (u_(j+1)k - u_jk)  (j < d_k),   F_jk = -tau_k u_jk  (j = d_k),
  integrating base -> tip: n <- n - F_jk, m <- m - (R r_k) x F_jk. The first chord's pull at the
  base goes into the ground. A lumped disk mass adds the force disk_mass * gravity at p(s_j) of every
  disk, a point force F at a disk n <- n - F. Tip: n(L+) = tip_force, m(L+) = tip_moment, after
  the jumps of a disk sitting at s = L.

Method (global shooting)
------------------------
Unknowns x = [n(0) / (EI/L^2), m(0) / (EI/L), and for every tendon k and disk j <= d_k a guessed
hole g_jk / L]. From the guessed holes (with g_0k = r_k) every disk's tendon loads are known, so
the rod is integrated base -> tip segment by segment (scipy.integrate.solve_ivp, DOP853) with the
jumps applied at the disks. Residual: the scaled tip wrench error and g_jk - (p(s_j) + R(s_j) r_k)/L
for every guessed hole. scipy.optimize.root solves it ("hybr", "lm" if that fails) with the exact
Jacobian: the 18 x 18 transition matrix of each segment is integrated with the state (variational
equations) and chained through the jumps and the loads' dependence on the guessed holes.

A rod is a dict (SI units): length, youngs_modulus, poisson_ratio, radius, density (0),
gravity (3, zero), tip_force (3, zero), tip_moment (3, zero), disks (list of s), disk_mass (0),
tendons: list of {offset (x, y), length, tension}, point_forces: list of {s, force (3,)} with s a
disk position.
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import root

__all__ = ["solve_disks"]

_E3 = np.array([0.0, 0.0, 1.0])
_STATE_SIZE = 18
_SAMPLES_PER_SEGMENT = 20
_CONVERGED_RESIDUAL = 1e-9
_POSITION_MATCH = 1e-9  # relative to L: a tendon end or point force "is at" a disk
_IDENTITY = np.eye(3)


def _hat(w):
    """Skew matrix of w (3,): _hat(w) @ x = w x x."""
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


_HAT_BASIS = np.array([_hat(axis) for axis in _IDENTITY])  # hat(e_l), l = 0, 1, 2


def _cross(a, b):
    """a x b for 3-vectors (np.cross is slow on tiny arrays)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _vector3(value):
    return np.asarray((0.0, 0.0, 0.0) if value is None else value, dtype=float).reshape(3).copy()


def _product_matrix(body_vector):
    """Matrix (3, 9) of the linear map R (row-major) -> R b for the fixed vector b."""
    return (_IDENTITY[:, :, None] * body_vector[None, None, :]).reshape(3, 9)


def _transpose_product_matrix(world_vector):
    """Matrix (3, 9) of the linear map R (row-major) -> R^T a for the fixed vector a."""
    return (_IDENTITY[:, None, :] * world_vector[None, :, None]).reshape(3, 9)


class _DiskRod:
    """Parsed rod: stiffness, loads, disks, tendons and the layout of the unknowns.

    hole_slot[k, j] is the index in x of the guessed hole of tendon k at disk j (0-based),
    -1 beyond the tendon's end; ends[k] = d_k, the number of disks tendon k runs through.
    """

    def __init__(self, rod: dict):
        self.length = length = float(rod["length"])
        youngs = float(rod["youngs_modulus"])
        shear = youngs / (2.0 * (1.0 + float(rod["poisson_ratio"])))
        radius = float(rod["radius"])
        area = np.pi * radius**2
        inertia = np.pi * radius**4 / 4.0
        self.shear_compliance = 1.0 / np.array([shear * area, shear * area, youngs * area])
        self.bending_compliance = 1.0 / np.array([youngs * inertia, youngs * inertia, shear * 2.0 * inertia])
        self.force_scale = youngs * inertia / length**2
        self.moment_scale = youngs * inertia / length
        gravity = _vector3(rod.get("gravity"))
        self.weight_per_length = float(rod.get("density", 0.0) or 0.0) * area * gravity
        self.tip_force = _vector3(rod.get("tip_force"))
        self.tip_moment = _vector3(rod.get("tip_moment"))
        self._parse_disks(rod.get("disks") or [])
        self.disk_loads = np.tile(float(rod.get("disk_mass", 0.0) or 0.0) * gravity, (len(self.disks), 1))
        for load in rod.get("point_forces") or []:
            self.disk_loads[self.disk_index(load["s"], "point force")] += _vector3(load["force"])
        self._parse_tendons(rod.get("tendons") or [])

    def _parse_disks(self, disks):
        self.disks = np.asarray(disks, dtype=float).reshape(-1)
        if self.disks.size and (self.disks[0] <= 0.0 or np.any(np.diff(self.disks) <= 0.0)):
            raise ValueError(f"disks must be strictly increasing arc lengths > 0, got {self.disks}")
        if self.disks.size and self.disks[-1] > self.length * (1.0 + _POSITION_MATCH):
            raise ValueError(f"last disk at s = {self.disks[-1]} lies beyond the rod length {self.length}")
        self.disks = np.minimum(self.disks, self.length)

    def _parse_tendons(self, tendons):
        count = len(tendons)
        self.offsets = np.zeros((count, 3))
        self.tensions = np.zeros(count)
        self.ends = np.zeros(count, dtype=int)
        self.hole_slot = np.full((count, len(self.disks)), -1, dtype=int)
        slot = 6
        for k, tendon in enumerate(tendons):
            self.offsets[k, :2] = np.asarray(tendon["offset"], dtype=float).reshape(2)
            self.tensions[k] = float(tendon["tension"])
            if self.tensions[k] < 0.0:
                raise ValueError(f"tendon {k}: tension must be >= 0, got {self.tensions[k]}")
            self.ends[k] = self.disk_index(tendon.get("length", self.length), f"tendon {k} end") + 1
            self.hole_slot[k, : self.ends[k]] = slot + 3 * np.arange(self.ends[k])
            slot += 3 * self.ends[k]
        self.unknown_count = slot

    def disk_index(self, s, what):
        """0-based index of the disk at arc length s; ValueError if there is none."""
        gaps = np.abs(self.disks - float(s))
        if gaps.size == 0 or gaps.min() > _POSITION_MATCH * self.length:
            raise ValueError(f"{what} at s = {s} is not at a disk (disks: {self.disks})")
        return int(np.argmin(gaps))

    def initial_guess(self):
        """Unknowns of the straight rod: holes at (x_k, y_k, s_j), base wrench from global balance."""
        length = self.length
        weight = self.weight_per_length * length
        base_force = self.tip_force + weight + self.disk_loads.sum(axis=0) - self.tensions.sum() * _E3
        base_moment = (self.tip_moment + np.cross(length * _E3, self.tip_force)
                       + np.cross(0.5 * length * _E3, weight)
                       + np.cross(self.disks[:, None] * _E3, self.disk_loads).sum(axis=0)
                       - (self.tensions[:, None] * np.cross(self.offsets, _E3)).sum(axis=0))
        guess = np.zeros(self.unknown_count)
        guess[0:3] = base_force / self.force_scale
        guess[3:6] = base_moment / self.moment_scale
        for k, end in enumerate(self.ends):
            for j in range(end):
                slot = self.hole_slot[k, j]
                guess[slot : slot + 3] = (self.offsets[k] + self.disks[j] * _E3) / length
        return guess


def _rhs(model, y):
    """Derivative of the state y (18,) between disks."""
    rotation = y[3:12].reshape(3, 3)
    force, moment = y[12:15], y[15:18]
    shear_strain = _E3 + model.shear_compliance * (rotation.T @ force)
    curvature = model.bending_compliance * (rotation.T @ moment)
    position_rate = rotation @ shear_strain
    return np.concatenate([position_rate, (rotation @ _hat(curvature)).ravel(),
                           -model.weight_per_length, -_cross(position_rate, force)])


def _rate_matrix(model, y):
    """Jacobian (18, 18) of _rhs at y (the variational equations' matrix)."""
    rotation = y[3:12].reshape(3, 3)
    force, moment = y[12:15], y[15:18]
    shear_strain = _E3 + model.shear_compliance * (rotation.T @ force)
    curvature = model.bending_compliance * (rotation.T @ moment)
    shear_by_rotation = model.shear_compliance[:, None] * _transpose_product_matrix(force)
    curvature_by_rotation = model.bending_compliance[:, None] * _transpose_product_matrix(moment)
    # R hat(w) (row-major) is linear in w with columns (R hat(e_l)).ravel()
    rotated_hats = (rotation @ _HAT_BASIS).transpose(1, 2, 0).reshape(9, 3)
    # dR' / dR for fixed u: the map R -> R hat(u), row-major
    rotation_by_rotation = (_IDENTITY[:, None, :, None] * _hat(curvature).T[None, :, None, :]).reshape(9, 9)
    matrix = np.zeros((_STATE_SIZE, _STATE_SIZE))
    matrix[0:3, 3:12] = _product_matrix(shear_strain) + rotation @ shear_by_rotation
    matrix[0:3, 12:15] = rotation @ (model.shear_compliance[:, None] * rotation.T)
    matrix[3:12, 3:12] = rotation_by_rotation + rotated_hats @ curvature_by_rotation
    matrix[3:12, 15:18] = rotated_hats @ (model.bending_compliance[:, None] * rotation.T)
    # m' = hat(n) p': chain through p', plus the explicit dependence on n
    matrix[15:18] = _hat(force) @ matrix[0:3]
    matrix[15:18, 12:15] -= _hat(rotation @ shear_strain)
    return matrix


def _segment(model, y, start, end, rtol, atol, sample_count):
    """Integrate the state and its 18 x 18 transition matrix over [start, end].

    Returns (y(end), transition matrix, sample arc lengths, sample positions); sample_count
    points in [start, end), none when sample_count is 0.
    """
    def rhs(_, state):
        current = state[:_STATE_SIZE]
        transition = state[_STATE_SIZE:].reshape(_STATE_SIZE, _STATE_SIZE)
        return np.concatenate([_rhs(model, current), (_rate_matrix(model, current) @ transition).ravel()])

    initial = np.concatenate([y, np.eye(_STATE_SIZE).ravel()])
    solution = solve_ivp(rhs, (start, end), initial, method="DOP853", rtol=rtol, atol=atol,
                         dense_output=sample_count > 0)
    if not solution.success:
        raise RuntimeError(f"solve_ivp failed on [{start}, {end}]: {solution.message}")
    final = solution.y[:, -1]
    samples = np.linspace(start, end, sample_count, endpoint=False)
    positions = solution.sol(samples)[:3].T if sample_count > 0 else np.zeros((0, 3))
    return final[:_STATE_SIZE], final[_STATE_SIZE:].reshape(_STATE_SIZE, _STATE_SIZE), samples, positions


def _tendon_loads(model, x):
    """Tendon point forces from the guessed holes, (K, D, 3), and their derivatives (K, D, 3, N)."""
    tendon_count, disk_count = model.hole_slot.shape
    forces = np.zeros((tendon_count, disk_count, 3))
    derivatives = np.zeros((tendon_count, disk_count, 3, model.unknown_count))
    for k, end in enumerate(model.ends):
        slots = model.hole_slot[k, :end]
        holes = model.length * x[slots[:, None] + np.arange(3)]
        chords = np.diff(np.vstack([model.offsets[k], holes]), axis=0)
        chord_lengths = np.linalg.norm(chords, axis=1)
        if np.any(chord_lengths == 0.0):
            raise RuntimeError(f"tendon {k}: two consecutive guessed holes coincide")
        directions = chords / chord_lengths[:, None]
        direction_derivatives = np.zeros((end, 3, model.unknown_count))
        for j in range(end):
            # d(unit chord) / d(chord) = (I - u u^T) / |chord|; holes are unknowns scaled by L
            unit = directions[j]
            projection = (_IDENTITY - np.outer(unit, unit)) * (model.length / chord_lengths[j])
            direction_derivatives[j, :, slots[j] : slots[j] + 3] += projection
            if j > 0:
                direction_derivatives[j, :, slots[j - 1] : slots[j - 1] + 3] -= projection
        next_directions = np.vstack([directions[1:], np.zeros((1, 3))])
        next_derivatives = np.concatenate([direction_derivatives[1:], np.zeros((1, 3, model.unknown_count))])
        forces[k, :end] = model.tensions[k] * (next_directions - directions)
        derivatives[k, :end] = model.tensions[k] * (next_derivatives - direction_derivatives)
    return forces, derivatives


def _disk_jump(model, disk, y, sensitivity, forces, derivatives):
    """Apply the point loads of a disk to y and to sensitivity = dy/dx (18, N); returns copies."""
    y, sensitivity = y.copy(), sensitivity.copy()
    rotation = y[3:12].reshape(3, 3)
    y[12:15] -= model.disk_loads[disk]
    for k, end in enumerate(model.ends):
        if disk >= end:
            continue
        force, d_force = forces[k, disk], derivatives[k, disk]
        arm = rotation @ model.offsets[k]
        d_arm = _product_matrix(model.offsets[k]) @ sensitivity[3:12]
        y[12:15] -= force
        y[15:18] -= _cross(arm, force)
        sensitivity[12:15] -= d_force
        sensitivity[15:18] += _hat(force) @ d_arm - _hat(arm) @ d_force
    return y, sensitivity


def _hole_residuals(model, disk, x, y, sensitivity, residual, jacobian):
    """Fill the residual rows g_jk - (p + R r_k) / L of the tendons through this disk."""
    position, rotation = y[0:3], y[3:12].reshape(3, 3)
    for k, end in enumerate(model.ends):
        if disk >= end:
            continue
        rows = slice(model.hole_slot[k, disk], model.hole_slot[k, disk] + 3)
        hole = position + rotation @ model.offsets[k]
        d_hole = sensitivity[0:3] + _product_matrix(model.offsets[k]) @ sensitivity[3:12]
        residual[rows] = x[rows] - hole / model.length
        jacobian[rows] = -d_hole / model.length
        jacobian[rows, rows] += _IDENTITY


def _shoot(model, x, rtol, atol, sample_count=0):
    """Integrate base -> tip for the unknowns x; residual, Jacobian, disk and tip states, samples."""
    count = model.unknown_count
    forces, derivatives = _tendon_loads(model, x)
    y = np.concatenate([np.zeros(3), _IDENTITY.ravel(), model.force_scale * x[0:3],
                        model.moment_scale * x[3:6]])
    sensitivity = np.zeros((_STATE_SIZE, count))
    sensitivity[12:15, 0:3] = model.force_scale * _IDENTITY
    sensitivity[15:18, 3:6] = model.moment_scale * _IDENTITY
    residual, jacobian = np.zeros(count), np.zeros((count, count))
    disk_states, sample_s, sample_p = [], [], []
    reaches_tip = model.disks.size > 0 and model.disks[-1] == model.length
    bounds = list(model.disks) + ([] if reaches_tip else [model.length])
    start = 0.0
    for index, end in enumerate(bounds):
        y, transition, s_values, positions = _segment(model, y, start, end, rtol, atol, sample_count)
        sensitivity = transition @ sensitivity
        sample_s.append(s_values)
        sample_p.append(positions)
        start = end
        if index < model.disks.size:
            disk_states.append(y.copy())
            _hole_residuals(model, index, x, y, sensitivity, residual, jacobian)
            y, sensitivity = _disk_jump(model, index, y, sensitivity, forces, derivatives)
    residual[0:3] = (y[12:15] - model.tip_force) / model.force_scale
    jacobian[0:3] = sensitivity[12:15] / model.force_scale
    residual[3:6] = (y[15:18] - model.tip_moment) / model.moment_scale
    jacobian[3:6] = sensitivity[15:18] / model.moment_scale
    if sample_count > 0:
        sample_s.append([model.length])
        sample_p.append(y[None, 0:3])
    return {"residual": residual, "jacobian": jacobian, "tip_state": y,
            "disk_states": np.array(disk_states).reshape(-1, _STATE_SIZE),
            "s": np.concatenate(sample_s), "p": np.concatenate(sample_p).reshape(-1, 3)}


def _outputs(model, x, rtol, atol):
    """Result dict of solve_disks at the converged unknowns x."""
    shot = _shoot(model, x, rtol, atol, sample_count=_SAMPLES_PER_SEGMENT)
    positions = shot["disk_states"][:, 0:3]
    rotations = shot["disk_states"][:, 3:12].reshape(-1, 3, 3)
    holes = positions[None] + np.einsum("dij,kj->kdi", rotations, model.offsets)
    path_lengths = np.zeros(len(model.ends))
    for k, end in enumerate(model.ends):
        holes[k, end:] = np.nan
        chain = np.vstack([model.offsets[k], holes[k, :end]])
        path_lengths[k] = np.linalg.norm(np.diff(chain, axis=0), axis=1).sum()
    tip = shot["tip_state"]
    return {"tip": tip[0:3].copy(), "R_tip": tip[3:12].reshape(3, 3).copy(),
            "n0": model.force_scale * x[0:3], "m0": model.moment_scale * x[3:6],
            "disk_positions": positions, "holes": holes, "path_lengths": path_lengths,
            "s": shot["s"], "p": shot["p"], "residual": float(np.linalg.norm(shot["residual"]))}


def solve_disks(rod: dict, *, rtol: float = 1e-12, atol: float = 1e-14) -> dict:
    """Solve the static spacer-disk tendon model of `rod` (see the module docstring).

    Returns a dict: tip (3,), R_tip (3, 3), n0, m0 (3,) base wrench (world), disk_positions (D, 3),
    holes (K, D, 3) (NaN beyond a tendon's end), path_lengths (K,) (sum of the tendon's chords from
    the base hole), s, p: samples along the rod, residual: norm of the scaled residual.
    Raises RuntimeError if neither "hybr" nor "lm" brings the residual below 1e-9.
    """
    model = _DiskRod(rod)

    def equations(x):
        shot = _shoot(model, x, rtol, atol)
        return shot["residual"], shot["jacobian"]

    start = model.initial_guess()
    attempts = (("hybr", {"xtol": 1e-13}), ("lm", {"xtol": 1e-13, "ftol": 1e-13}))
    best_x, best_norm, messages = start, np.inf, []
    for method, options in attempts:
        solution = root(equations, start, jac=True, method=method, options=options)
        norm = float(np.linalg.norm(solution.fun))
        messages.append(f"{method}: residual {norm:.3e} ({solution.message})")
        if norm < best_norm:
            best_x, best_norm = solution.x, norm
        if norm <= _CONVERGED_RESIDUAL:
            break
    if best_norm > _CONVERGED_RESIDUAL:
        raise RuntimeError("spacer-disk reference did not converge; " + "; ".join(messages))
    return _outputs(model, best_x, rtol, atol)
