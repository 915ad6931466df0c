"""Batched description of tendon-driven continuum robots (host side, NumPy).

Every field is either shared by the batch or given per rod: a scalar field takes a float or
an array of shape (B,); a vector field takes shape (3,) (or (2,) for tendon offsets) or
(B, 3). Builders validate their input and raise :class:`InputError` naming the field, the
rod and the value, so that no bad number reaches a kernel.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field

import numpy as np

from tdcr_warp.model.backbone import SEC_COLUMNS, Section, check_sections, section_properties, section_table
from tdcr_warp.model.checks import InputError, as_field, check_values, real_array, require_memory
from tdcr_warp.model.world import Obstacle, TipConstraint

__all__ = ["InputError", "Obstacle", "PointForce", "Robot", "Section", "Tendon", "TipConstraint", "check_command",
           "check_displacements", "check_slip", "check_tensions", "real_array", "require_memory", "route_table"]

MAX_DISKS = 100_000  # spacer disks of a robot: each is a grid node, and StaticOptions.nodes <= 100000


def _batch(fields: dict[str, np.ndarray]) -> int:
    sizes = {k: v.shape[0] for k, v in fields.items() if v.shape[0] > 1}
    if len(set(sizes.values())) > 1:
        raise InputError(f"per-rod fields disagree on the batch size: {sizes}")
    return max(sizes.values(), default=1)


CONTROLS = ("tension", "displacement")
ROUTINGS = ("straight", "helix", "linear", "points")


def cubic_spline(s: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Coefficients (M-1, 4) of the not-a-knot cubic spline through (s_i, y_i): on [s_i, s_i+1],
    y = a + b t + c t^2 + d t^3 with t = s - s_i; y, y', y'' continuous, and the third
    derivative too at the second and the last-but-one knot (the end slopes, which set the pull
    of a tendon where it ends, are then as accurate as the inside; a natural spline's y'' = 0
    at the ends costs O(h) there). Two points: a line; three: a parabola."""
    h = np.diff(s)
    M = len(s)
    if M == 2:
        c = np.zeros(2)
    elif M == 3:
        c = np.full(3, ((y[2] - y[1]) / h[1] - (y[1] - y[0]) / h[0]) / (h[0] + h[1]))
    else:
        A = np.zeros((M, M))
        rhs = np.zeros(M)
        A[0, :3] = -h[1], h[0] + h[1], -h[0]
        A[-1, -3:] = -h[-1], h[-2] + h[-1], -h[-2]
        for i in range(1, M - 1):
            A[i, i - 1], A[i, i], A[i, i + 1] = h[i - 1], 2.0 * (h[i - 1] + h[i]), h[i]
            rhs[i] = 3.0 * ((y[i + 1] - y[i]) / h[i] - (y[i] - y[i - 1]) / h[i - 1])
        c = np.linalg.solve(A, rhs)
    b = (y[1:] - y[:-1]) / h - h * (2.0 * c[:-1] + c[1:]) / 3.0
    d = (c[1:] - c[:-1]) / (3.0 * h)
    return np.stack([y[:-1], b, c[:-1], d], axis=1)


@dataclass(frozen=True)
class Tendon:
    """One tendon. Routing in the body (disk) frame:

    r(s) = offset + (offset_end - offset) s / length + helix_radius [cos(2 pi turns s / length + phase), sin(...)]

    offset: (2,) or (B, 2) [m]; helix_radius, turns, phase [m, -, rad]: float or (B,);
    length: termination arc length [m] (None: the rod length), float or (B,).
    ``routing`` is "straight" (constant offset), "helix" (a rotating offset), "linear" (the
    offset moves in a straight line from ``offset`` at the base to ``offset_end`` at the
    termination: converging or diverging routes) or "points": a general path through
    ``points`` [(s, x, y), ...] [m] (s from 0 to the termination, increasing), a not-a-knot
    cubic spline in x(s) and y(s) (continuous r, r', r'', which the coupled model needs).

    The tendon itself: ``control`` "tension" (commanded in N) or "displacement" (commanded as
    a motor displacement q in m, pull positive: the motor takes in q of unstretched tendon,
    relative to the reference state where every tendon holds its ``pretension`` [N]);
    ``compliance`` 1 / (E_t A_t) of the wire [1/N] (0: inextensible); ``friction`` the
    coefficient mu of tendon-disk friction (capstan law, 0: frictionless). Float or (B,) each.
    """

    offset: object = (0.0, 0.0)
    routing: str = "straight"
    helix_radius: object = 0.0
    turns: object = 0.0
    phase: object = 0.0
    length: object = None
    offset_end: object = None
    control: str = "tension"
    compliance: object = 0.0
    pretension: object = 0.0
    friction: object = 0.0
    points: object = None
    spline: np.ndarray | None = field(init=False, default=None, repr=False, compare=False)  # "points": (M-1, 9)

    def __post_init__(self):
        if self.routing not in ROUTINGS:
            raise InputError(f"tendon routing must be one of {ROUTINGS}, got {self.routing!r}")
        if self.control not in CONTROLS:
            raise InputError(f"tendon control must be one of {CONTROLS}, got {self.control!r}")
        for name in ("offset", "helix_radius", "turns", "phase", "compliance", "pretension", "friction"):
            tail = (2,) if name == "offset" else ()
            object.__setattr__(self, name, as_field(f"tendon {name}", getattr(self, name), tail))
        for name, what in (("compliance", "compliance [1/N]"), ("pretension", "pretension [N]"),
                           ("friction", "friction coefficient mu")):
            check_values(f"tendon {name}", getattr(self, name), getattr(self, name) >= 0, f">= 0 (a {what})")
        if self.length is not None:
            object.__setattr__(self, "length", as_field("tendon length", self.length, ()))
            check_values("tendon length", self.length, self.length > 0, "positive")
        if self.routing == "linear":
            if self.offset_end is None:
                raise InputError("tendon offset_end is required with routing = 'linear'")
            object.__setattr__(self, "offset_end", as_field("tendon offset_end", self.offset_end, (2,)))
        elif self.offset_end is not None:
            raise InputError(f"tendon offset_end is only used with routing = 'linear', got routing = {self.routing!r}")
        if self.routing == "helix":
            check_values("tendon helix_radius", self.helix_radius, self.helix_radius >= 0, ">= 0")
        else:
            check_values(f"tendon helix_radius ({self.routing} routing)", self.helix_radius, self.helix_radius == 0, "0")
        if self.routing == "points":
            pts = real_array(self.points, "tendon points")
            if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] < 2:
                raise InputError(f"tendon points: expected two or more (s, x, y) rows, got shape {pts.shape}")
            if not np.isfinite(pts).all():
                raise InputError(f"tendon points: non-finite value in {pts.tolist()}")
            if pts[0, 0] != 0.0:
                raise InputError(f"tendon points: the first s must be 0 (the base), got {float(pts[0, 0])!r}")
            steps = np.diff(pts[:, 0])
            if (steps <= 0).any():
                i = int(np.argmax(steps <= 0))
                raise InputError(f"tendon points must be increasing in s: s = {float(pts[i + 1, 0])!r} follows "
                                 f"{float(pts[i, 0])!r}")
            if self.length is not None and np.any(np.abs(self.length - pts[-1, 0]) > 1e-12 * pts[-1, 0]):
                raise InputError(f"tendon points end at s = {float(pts[-1, 0])!r}, the tendon's length is "
                                 f"{self.length}")
            pts.flags.writeable = False
            object.__setattr__(self, "points", pts)
            s = pts[:, 0]  # the spline, solved once (every routing evaluation reads it)
            seg = np.concatenate([s[:-1, None], cubic_spline(s, pts[:, 1]), cubic_spline(s, pts[:, 2])], axis=1)
            seg.flags.writeable = False
            object.__setattr__(self, "spline", seg)
            if np.any(self.offset != 0):
                raise InputError("tendon offset must be (0, 0) with routing = 'points' (the points give the path)")
        elif self.points is not None:
            raise InputError(f"tendon points are only used with routing = 'points', got routing = {self.routing!r}")


@dataclass(frozen=True)
class PointForce:
    """A point force ``force`` [N] (world frame, (3,) or (B, 3)) applied at arc length ``s`` [m]."""

    s: object
    force: object

    def __post_init__(self):
        object.__setattr__(self, "s", as_field("point force s", self.s, ()))
        object.__setattr__(self, "force", as_field("point force force", self.force, (3,)))
        check_values("point force s", self.s, self.s > 0, "positive")


@dataclass(frozen=True)
class Robot:
    """A batch of B tendon-driven rods clamped at the origin, leaving along +z.

    length [m], youngs_modulus [Pa], poisson_ratio [-], radius [m], density [kg/m^3]: float or (B,). precurvature u*
    [1/m] (body frame), gravity [m/s^2], tip_force [N], tip_moment [N m] (world frame): (3,) or (B, 3). tendons:
    sequence of :class:`Tendon`; point_forces: sequence of :class:`PointForce`. disks, disk_mass: the spacer disks
    of the tendon model "disks" (``_set_disk_fields``). obstacles: :class:`Obstacle` s, tip_constraint: a
    :class:`TipConstraint` or None (tdcr_warp.model.world). sections: :class:`Section` s along s
    (tdcr_warp.model.backbone; then the four backbone numbers are those at the base: ``_set_sections``).
    """

    length: object = 0.5
    youngs_modulus: object = None
    poisson_ratio: object = None
    radius: object = None
    density: object = None
    precurvature: object = (0.0, 0.0, 0.0)
    tendons: tuple = ()
    gravity: object = (0.0, 0.0, 0.0)
    tip_force: object = (0.0, 0.0, 0.0)
    tip_moment: object = (0.0, 0.0, 0.0)
    point_forces: tuple = ()
    damping_shear: object = (0.0, 0.0, 0.0)
    damping_bending: object = (0.0, 0.0, 0.0)
    drag: object = (0.0, 0.0, 0.0)
    disk_radius: object = None
    disks: object = ()
    disk_mass: object = 0.0
    obstacles: tuple = ()
    tip_constraint: object = None
    sections: tuple = ()
    batch_size: int = field(init=False)
    section_rows: np.ndarray = field(init=False, repr=False, compare=False)  # (S, 12): backbone.section_table

    def __post_init__(self):
        _set_sections(self)
        for name in SCALARS:
            object.__setattr__(self, name, as_field(name, getattr(self, name), ()))
        for name in VECTORS:
            object.__setattr__(self, name, as_field(name, getattr(self, name), (3,)))
        _check_ranges(self)
        object.__setattr__(self, "tendons", _items("tendons", self.tendons, Tendon))
        object.__setattr__(self, "point_forces", _items("point_forces", self.point_forces, PointForce))
        _set_world(self)
        object.__setattr__(self, "batch_size", _batch(_per_rod_fields(self)))
        with np.errstate(all="ignore"):
            object.__setattr__(self, "_section", self._compute_section())
        _check_stiffness(self)
        _check_within_length(self)
        _set_disk_fields(self)

    @property
    def n_tendons(self) -> int:
        return len(self.tendons)

    def tendon_lengths(self) -> np.ndarray:
        """Termination arc lengths, shape (1 or B, K) [m]."""
        cols = [self.length if t.length is None else t.length for t in self.tendons]
        return _stack_cols(cols)

    def section(self) -> dict[str, np.ndarray]:
        """Cross-section and stiffness per rod (leading 1 or B): A, I, Kse, Kbt (computed once, read-only); with
        sections, those at the base."""
        return self._section

    def _compute_section(self) -> dict[str, np.ndarray]:
        if self.sections:
            at = section_properties(self.section_rows, np.zeros(1))
            sec = {k: at[k] for k in ("area", "inertia", "kse", "kbt")}
        else:
            E, nu, r = self.youngs_modulus, self.poisson_ratio, self.radius
            G = E / (2.0 * (1.0 + nu))
            A = math.pi * r**2
            Ixx = math.pi * r**4 / 4.0
            kse = np.stack(np.broadcast_arrays(G * A, G * A, E * A), axis=-1)
            kbt = np.stack(np.broadcast_arrays(E * Ixx, E * Ixx, G * 2.0 * Ixx), axis=-1)
            sec = {"area": A, "inertia": Ixx, "kse": kse, "kbt": kbt}
        for v in sec.values():
            v.flags.writeable = False
        return sec

    def routing_parameters(self) -> tuple[np.ndarray, ...]:
        """Per tendon x0, y0, a [m], w [rad/m], phase [rad], dx, dy [-], each (1|B, K), of the routing
        r(s) = [x0 + dx s + a cos(w s + phase), y0 + dy s + a sin(w s + phase), 0]."""
        if not self.tendons:
            return tuple(np.zeros((1, 0)) for _ in range(7))
        lengths = self.tendon_lengths()
        cols = []
        for k, t in enumerate(self.tendons):
            w = 2.0 * math.pi * t.turns / lengths[:, k]
            slope = np.zeros((1, 2)) if t.offset_end is None else (t.offset_end - t.offset) / lengths[:, k, None]
            cols.append(np.broadcast_arrays(t.offset[:, 0], t.offset[:, 1], t.helix_radius, w, t.phase,
                                            slope[:, 0], slope[:, 1]))
        b = max(np.broadcast(*c).shape[0] for c in cols)
        return tuple(np.stack([np.broadcast_to(c[i], (b,)) for c in cols], axis=1) for i in range(7))

    def tendon_columns(self, name: str) -> np.ndarray:
        """A scalar tendon field (e.g. "friction", "compliance", "pretension") as (1 or B, K)."""
        if not self.tendons:
            return np.zeros((1, 0))
        return _stack_cols([getattr(t, name) for t in self.tendons])

    @property
    def has_friction(self) -> bool:
        """Whether any tendon of any rod has friction (mu > 0)."""
        return any(bool(np.any(t.friction > 0)) for t in self.tendons)

    @property
    def displaced(self) -> tuple[int, ...]:
        """The tendons under displacement control, in order (each adds one shooting unknown)."""
        return tuple(k for k, t in enumerate(self.tendons) if t.control == "displacement")

    def tendon_routing(self, s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Body-frame routing r(s), r', r'' of every tendon at s [m] (a number, (B,) or (B, K)), each (1|B, K, 3)."""
        if self.n_tendons == 0:
            z = np.zeros((1, 0, 3))
            return z, z, z
        x0, y0, a, w, ph, dx, dy = self.routing_parameters()
        s = np.asarray(s, dtype=np.float64)
        s = s[:, None] if s.ndim == 1 else s
        ang = w * s + ph
        c, sn, z = np.cos(ang), np.sin(ang), np.zeros_like(ang)
        r = np.stack([x0 + dx * s + a * c, y0 + dy * s + a * sn, z], axis=-1)
        dr = np.stack([dx - a * w * sn, dy + a * w * c, z], axis=-1)
        ddr = np.stack([-a * w * w * c, -a * w * w * sn, z], axis=-1)
        for k, t in enumerate(self.tendons):
            if t.routing == "points":
                g = t.spline
                sk = np.broadcast_to(s, r.shape[:-1])[..., k]
                i = np.clip(np.searchsorted(g[:, 0], sk, side="right") - 1, 0, len(g) - 1)
                u = sk - g[i, 0]
                for c0, out in ((1, 0), (5, 1)):
                    A, Bc, C, D = (g[i, c0 + j] for j in range(4))
                    r[..., k, out] = A + u * (Bc + u * (C + u * D))
                    dr[..., k, out] = Bc + u * (2 * C + 3 * u * D)
                    ddr[..., k, out] = 2 * C + 6 * u * D
        return r, dr, ddr

    def pack_point_forces(self, disk_weights: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Point-force arc lengths (1 or B, P) [m], forces (1 or B, P, 3) [N] (and the disks' weights)."""
        forces = list(self.point_forces) + ([PointForce(s, self.disk_mass * self.gravity) for s in self.disks]
                                            if disk_weights and self.disk_mass > 0 else [])
        if not forces:
            return np.zeros((1, 0)), np.zeros((1, 0, 3))
        s = _stack_cols([pf.s for pf in forces])
        f = [pf.force for pf in forces]
        b = max(x.shape[0] for x in f)
        return s, np.stack([np.broadcast_to(x, (b, 3)) for x in f], axis=1)


def route_table(robot: Robot) -> np.ndarray:
    """(1, K, S, 9) the spline segments of "points" tendons, S the most of any (zeros elsewhere: they add nothing)."""
    segs = [t.spline if t.routing == "points" else np.zeros((0, 9)) for t in robot.tendons]
    S = max([len(g) for g in segs] + [1])
    out = np.zeros((1, len(segs), S, 9))
    for k, g in enumerate(segs):
        out[0, k, :len(g)] = g
        if len(g):
            out[0, k, len(g):, 0] = np.inf  # never selected
    return out


SCALARS = ("length", "youngs_modulus", "poisson_ratio", "radius", "density")  # Robot's fields: () or (B,)
VECTORS = ("precurvature", "gravity", "tip_force", "tip_moment", "damping_shear", "damping_bending", "drag")


def _items(name: str, items, kind: type) -> tuple:
    """``items`` as a tuple, each a ``kind`` (an InputError naming the first that is not)."""
    items = tuple(items)
    for i, it in enumerate(items):
        if not isinstance(it, kind):
            raise InputError(f"{name}[{i}]: expected {kind.__name__}, got {type(it).__name__}")
    return items


DEFAULTS = {"youngs_modulus": 190e9, "poisson_ratio": 0.3, "radius": 1e-3, "density": 7800.0}


def _set_sections(robot: Robot) -> None:
    """Without sections: the default backbone numbers where none is given. With sections: the
    sections checked, and youngs_modulus, poisson_ratio, radius and density the first section's at
    the base (a value given must be that one: the sections give the backbone)."""
    table = np.zeros((0, len(SEC_COLUMNS)))
    if robot.sections:
        sections = check_sections(robot.sections, as_field("length", robot.length, ()))
        object.__setattr__(robot, "sections", sections)
        table = section_table(sections)
        first = sections[0]
        E0, G0 = float(first.youngs_modulus[0]), float(first.shear[0])
        base = {"youngs_modulus": E0, "poisson_ratio": E0 / (2.0 * G0) - 1.0, "radius": float(first.radius[0]),
                "density": float(first.density[0])}
        for name, value in base.items():
            given = getattr(robot, name)
            if given is not None and np.any(np.abs(as_field(name, given, ()) - value) > 1e-12 * abs(value)):
                raise InputError(f"{name} = {given!r} with sections: the sections give the backbone (here "
                                 f"{value!r} at the base); leave {name} unset")
            object.__setattr__(robot, name, value)
    else:
        for name, value in DEFAULTS.items():
            if getattr(robot, name) is None:
                object.__setattr__(robot, name, value)
    table.flags.writeable = False
    object.__setattr__(robot, "section_rows", table)


def _check_ranges(robot: Robot) -> None:
    """The robot's own numbers in range: positive sizes and modulus, density and damping >= 0,
    Poisson's ratio in (-1, 0.5)."""
    for name in ("length", "youngs_modulus", "radius"):
        check_values(name, getattr(robot, name), getattr(robot, name) > 0, "positive")
    check_values("density", robot.density, robot.density >= 0, ">= 0")
    for name in ("damping_shear", "damping_bending", "drag"):
        check_values(name, getattr(robot, name), getattr(robot, name) >= 0, ">= 0")
    nu = robot.poisson_ratio
    check_values("poisson_ratio", nu, (nu > -1) & (nu < 0.5), "in (-1, 0.5)")


def _set_world(robot: Robot) -> None:
    """obstacles: a tuple of Obstacle; tip_constraint: a TipConstraint or None."""
    object.__setattr__(robot, "obstacles", _items("obstacles", robot.obstacles, Obstacle))
    tip = robot.tip_constraint
    if tip is not None and not isinstance(tip, TipConstraint):
        raise InputError(f"tip_constraint: expected TipConstraint or None, got {type(tip).__name__}")


def _per_rod_fields(robot: Robot) -> dict[str, np.ndarray]:
    """Every field of the robot, its tendons and point forces that may be given per rod."""
    out = {n: getattr(robot, n) for n in SCALARS + VECTORS}
    for i, t in enumerate(robot.tendons):
        for n in ("offset", "helix_radius", "turns", "phase", "length", "offset_end", "compliance",
                  "pretension", "friction"):  # (points are shared by the batch)
            if getattr(t, n) is not None:
                out[f"tendons[{i}].{n}"] = getattr(t, n)
    for j, pf in enumerate(robot.point_forces):
        out[f"point_forces[{j}].s"] = pf.s
        out[f"point_forces[{j}].force"] = pf.force
    for j, ob in enumerate(robot.obstacles):
        out |= ob.batch_fields(f"obstacles[{j}]")
    if robot.tip_constraint is not None:
        out |= robot.tip_constraint.batch_fields("tip_constraint")
    return out


def _check_stiffness(robot: Robot) -> None:
    """The stiffnesses derived from the inputs finite and positive (each input may be in range
    while their product overflows or vanishes)."""
    with np.errstate(all="ignore"):
        sec = robot.section()
        derived = {"bending stiffness E I (from youngs_modulus, radius)": sec["kbt"][:, 0],
                   "axial stiffness E A (from youngs_modulus, radius)": sec["kse"][:, 2],
                   "scaled moment scale E I / L (from youngs_modulus, radius, length)":
                       np.broadcast_to(sec["kbt"][:, 0], np.broadcast_shapes(sec["kbt"][:, 0].shape, robot.length.shape))
                       / robot.length}
    for name, val in derived.items():
        ok = np.isfinite(val) & (val > 0) & (val < 1e300)
        check_values(name, np.asarray(val), ok, "finite and positive (the inputs are out of range)")


def _check_within_length(robot: Robot) -> None:
    """Tendon terminations, point forces and the last route point within the rod."""
    L = robot.length
    for i, t in enumerate(robot.tendons):
        if t.length is not None:
            ok = np.broadcast_to(t.length <= L * (1 + 1e-12), np.broadcast_shapes(t.length.shape, L.shape))
            check_values(f"tendons[{i}].length", np.broadcast_to(t.length, ok.shape), ok, "<= the rod length")
    for j, pf in enumerate(robot.point_forces):
        ok = np.broadcast_to(pf.s <= L * (1 + 1e-12), np.broadcast_shapes(pf.s.shape, L.shape))
        check_values(f"point_forces[{j}].s", np.broadcast_to(pf.s, ok.shape), ok, "<= the rod length")
    for i, t in enumerate(robot.tendons):
        if t.routing == "points" and t.length is None and np.any(np.abs(t.points[-1, 0] - L) > 1e-12 * L):
            raise InputError(f"tendons[{i}].points end at s = {float(t.points[-1, 0])!r}, the tendon runs to "
                             f"the tip at {float(L.max())!r} (set its length, or end the points there)")


def _set_disk_fields(robot: Robot) -> None:
    """disk_radius: every route inside it (None: unchecked). disks: the spacer disks' arc lengths
    [m] (shared, increasing, in (0, L]), or an integer D: D evenly spaced disks in each section
    (a section ends where a tendon ends, the last at the tip); the tendon model "disks" routes
    the tendons straight between them. disk_mass [kg]: each disk's weight in that model."""
    if robot.disk_radius is not None:
        object.__setattr__(robot, "disk_radius", as_field("disk_radius", robot.disk_radius, ()))
        check_values("disk_radius", robot.disk_radius, robot.disk_radius > 0, "positive")
        _check_inside_disks(robot)
    d = robot.disks
    if isinstance(d, numbers.Integral) and not isinstance(d, bool):
        if d < 1:
            raise InputError(f"disks: expected a positive count per section or a list of arc lengths, got {d!r}")
        ends = [float(robot.length.max())] + [float(x) for t in robot.tendons if t.length is not None
                                              for x in np.unique(t.length)]
        ends = np.unique(ends)
        if d * len(ends) > MAX_DISKS:
            raise InputError(f"disks = {d!r} per section in {len(ends)} section(s) is more than {MAX_DISKS:,} disks "
                             "(each disk is a node of the grid, and solver nodes <= 100000)")
        starts = np.concatenate([[0.0], ends[:-1]])
        d = np.concatenate([np.linspace(a, b, d + 1)[1:] for a, b in zip(starts, ends)])
    arr = real_array(d, "disks").reshape(-1) if np.ndim(d) <= 1 else None
    if arr is None or arr.size > MAX_DISKS:
        raise InputError(f"disks: expected a list of at most {MAX_DISKS:,} arc lengths, got shape {np.shape(d)}")
    if not np.isfinite(arr).all() or (arr <= 0).any() or (arr > robot.length.min() * (1 + 1e-12)).any():
        raise InputError(f"disks: every arc length must be in (0, {float(robot.length.min())!r}] m, got {arr.tolist()}")
    if (np.diff(arr) <= 0).any():
        raise InputError(f"disks: arc lengths must increase, got {arr.tolist()}")
    arr.flags.writeable = False
    object.__setattr__(robot, "disks", arr)
    mass = as_field("disk_mass", robot.disk_mass, ())
    if mass.shape[0] != 1:
        raise InputError(f"disk_mass: expected one number (shared by the batch), got shape {mass.shape[1:]}")
    check_values("disk_mass", mass, mass >= 0, ">= 0 [kg]")
    object.__setattr__(robot, "disk_mass", float(mass[0]))


def _check_inside_disks(robot: Robot) -> None:
    """Every tendon route within disk_radius of the axis (129 samples along each tendon)."""
    if not robot.tendons:
        return
    frac = np.linspace(0.0, 1.0, 129)
    lengths = robot.tendon_lengths()
    rad = np.stack([np.linalg.norm(robot.tendon_routing(lengths * f)[0], axis=-1) for f in frac])
    excess = rad - np.broadcast_to(robot.disk_radius, lengths.shape)[None] * (1 + 1e-12)
    if (excess > 0).any():
        j, b, k = np.unravel_index(np.argmax(excess), excess.shape)  # the worst sample
        raise InputError(f"tendons[{k}] routing leaves the disk: |r| = {rad[j, b, k]:.6g} m at s = "
                         f"{float(lengths[b, k] * frac[j]):.6g} m (rod {b}), beyond disk_radius = "
                         f"{float(np.broadcast_to(robot.disk_radius, (b + 1,))[b])!r} m")


def _stack_cols(cols: list[np.ndarray]) -> np.ndarray:
    b = max(c.shape[0] for c in cols)
    return np.stack([np.broadcast_to(c, (b,)) for c in cols], axis=1)


def _tendon_rows(value, name: str, K: int) -> np.ndarray:
    """``value`` as a 2-D float64 array of K columns ((K,) is one row), or an InputError."""
    a = real_array(value, name)
    if a.ndim == 1 and a.shape[0] == K:
        a = a[None]
    if a.ndim != 2 or a.shape[1] != K:
        raise InputError(f"{name}: expected shape (B, {K}) for {K} tendons, got {a.shape}")
    return a


def check_tensions(robot: Robot, tensions, name: str = "tensions") -> np.ndarray:
    """Tensions as a (B, K) float64 array, each finite and >= 0, or an InputError."""
    tau = _tendon_rows(tensions, name, robot.n_tendons)
    if robot.batch_size > 1 and tau.shape[0] == 1:
        tau = np.repeat(tau, robot.batch_size, axis=0)
    if robot.batch_size > 1 and tau.shape[0] != robot.batch_size:
        raise InputError(f"{name}: {tau.shape[0]} rows for a robot batch of {robot.batch_size} rods")
    bad = ~np.isfinite(tau) | (tau < 0)
    if bad.any():
        b, k = np.argwhere(bad)[0]
        raise InputError(f"{name}[{b}][{k}] must be a finite number >= 0 (tendons only pull), "
                         f"got {float(tau[b, k])!r}")
    return tau


def _rows(robot: Robot, value, name: str, B: int) -> np.ndarray:
    """A (B, K) float64 array of finite numbers from a (K,) or (B, K) input."""
    K = robot.n_tendons
    a = _tendon_rows(value, name, K)
    if a.shape[0] not in (1, B):
        raise InputError(f"{name}: {a.shape[0]} rows for {B} rods")
    a = np.array(np.broadcast_to(a, (B, K)))
    bad = ~np.isfinite(a)
    if bad.any():
        b, k = np.argwhere(bad)[0]
        raise InputError(f"{name}[{b}][{k}]: non-finite value {float(a[b, k])!r}")
    return a


def check_displacements(robot: Robot, displacements, B: int, name: str = "displacements") -> np.ndarray:
    """Motor displacements as (B, K) [m] (pull positive; (K,) is shared): nonzero only for
    tendons under displacement control."""
    q = _rows(robot, displacements, name, B)
    tension_controlled = [k for k, t in enumerate(robot.tendons) if t.control != "displacement"]
    bad = q[:, tension_controlled] != 0
    if bad.any():
        b, j = np.argwhere(bad)[0]
        k = tension_controlled[j]
        raise InputError(f"{name}[{b}][{k}] = {float(q[b, k])!r}: tendon {k} is under tension control "
                         "(set its control = 'displacement' to command it by displacement)")
    return q


def check_command(robot: Robot, tensions, displacements, B: int | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Tensions (B, K) (None: zeros) and displacements (B, K) or None, checked together: a
    tension only on a tendon under tension control, displacements only on a robot with some
    under displacement control (check_tensions, check_displacements). B (None): the robot's
    batch, or the rows of a (B, K) command."""
    tensions, displacements = (None if a is None else real_array(a, name, copy=False)
                               for a, name in ((tensions, "tensions"), (displacements, "displacements")))
    if B is None:
        B = max([robot.batch_size] + [np.shape(a)[0] for a in (tensions, displacements)
                                      if a is not None and np.ndim(a) == 2])
    tau = check_tensions(robot, np.zeros((B, robot.n_tendons)) if tensions is None else tensions)
    disp = list(robot.displaced)
    bad = tau[:, disp] != 0
    if bad.any():
        b, j = np.argwhere(bad)[0]
        raise InputError(f"tensions[{b}][{disp[j]}] = {float(tau[b, disp[j]])!r}: tendon {disp[j]} is under "
                         "displacement control (command it with displacements)")
    if displacements is None:
        return tau, None
    if not disp:
        raise InputError("displacements: no tendon of this robot is under displacement control")
    return tau, check_displacements(robot, displacements, tau.shape[0])


def check_slip(robot: Robot, slip, B: int, name: str = "slip") -> np.ndarray:
    """Slip directions (B, K), each +1 (the tendon slides toward the motor: being pulled) or -1
    (sliding away: being released)."""
    sg = _rows(robot, slip, name, B)
    bad = (sg != 1) & (sg != -1)
    if bad.any():
        b, k = np.argwhere(bad)[0]
        raise InputError(f"{name}[{b}][{k}] must be +1 (pulled) or -1 (released), got {float(sg[b, k])!r}")
    return sg
