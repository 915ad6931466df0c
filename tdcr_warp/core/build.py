"""From a host ``Robot`` to the device: the only host file that knows the column layout of
the packed tables (kernels/layout.py).

``Tables`` are the packed per-rod tables of a robot at one node count (host NumPy, leading
dimension 1 or B), computed once. ``put_model`` uploads the rows of one chunk of rods as a
``Model`` (read-only in kernels), ``make_control`` the tensions, ``make_state`` the per-node
solution and ``make_work`` the Newton scratch; all are allocated once per batch shape and
reused across solves and time steps.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import warp as wp

from tdcr_warp.kernels import layout
from tdcr_warp.kernels.structs import SLOT_WIDTH
from tdcr_warp.kernels.variants import ALL, Features
from tdcr_warp.model.backbone import section_properties
from tdcr_warp.model.options import check_model_support
from tdcr_warp.model.robot import InputError, Robot, route_table

PRECISIONS = {"float64": (wp.float64, np.float64), "float32": (wp.float32, np.float32)}


def make_grid(length: np.ndarray, tendon_len: np.ndarray, point_s: np.ndarray, nodes: int,
              knots: np.ndarray | None = None):
    """Arc-length nodes holding every tendon termination and point load, and the ``knots``
    (1, Q) of tendons routed through points (where their r'' has a kink: RK4 keeps its order
    only if no interval straddles one).

    Returns grid (Bg, N+1), term_node (Bg, K), point_node (Bg, P); Bg is 1 unless one of the
    inputs varies per rod. Intervals are shared out over the segments in proportion to
    their length (at least one each).
    """
    K, P = tendon_len.shape[1], point_s.shape[1]
    knots = np.zeros((1, 0)) if knots is None else knots
    bg = max(length.shape[0], tendon_len.shape[0], point_s.shape[0])
    keys = np.concatenate([np.broadcast_to(length[:, None], (bg, 1)),
                           np.broadcast_to(tendon_len, (bg, K)),
                           np.broadcast_to(point_s, (bg, P)),
                           np.broadcast_to(knots, (bg, knots.shape[1]))], axis=1)
    uniq, inverse = np.unique(keys, axis=0, return_inverse=True)
    rows = [_grid_row(row[0], row[1:], nodes) for row in uniq]
    grid = np.stack([r[0] for r in rows])[inverse.ravel()]
    marks = np.stack([r[1] for r in rows])[inverse.ravel()]
    return grid, marks[:, :K].astype(np.int32), marks[:, K:K + P].astype(np.int32)


def _grid_row(L: float, breaks: np.ndarray, nodes: int):
    tol = 1e-12 * L
    pts = np.unique(np.concatenate([breaks, [L]]))
    pts = pts[np.concatenate([[True], np.diff(pts) > tol])]
    pts = pts[pts > tol]
    if len(pts) > nodes:
        raise InputError(f"solver nodes = {nodes} is fewer than the {len(pts)} segments set by "
                         "tendon terminations, point loads, the knots of tendons routed through points and the "
                         "spacer disks (model 'disks')")
    seg = np.diff(np.concatenate([[0.0], pts]))
    ideal = nodes * seg / L
    count = np.maximum(1, np.floor(ideal)).astype(int)
    while count.sum() < nodes:
        count[np.argmax(ideal - count)] += 1
    while count.sum() > nodes:
        count[np.argmax(np.where(count > 1, count - ideal, -np.inf))] -= 1
    starts = np.concatenate([[0.0], pts[:-1]])
    grid = np.concatenate([np.linspace(a, b, c, endpoint=False) for a, b, c in zip(starts, pts, count)]
                          + [[L]])
    node_of = np.concatenate([[0], np.cumsum(count)])
    ends = np.concatenate([[0.0], pts])
    marks = np.array([node_of[np.argmin(np.abs(ends - b))] for b in breaks], dtype=np.int64)
    return grid, marks


def check_disk_model(robot: Robot, tendon_len: np.ndarray) -> None:
    """The disk model needs disks, no friction or obstacles (check_model_support), and every tendon ending at a
    disk."""
    if not len(robot.disks):
        raise InputError("model = 'disks' needs the robot's disks ([robot] disks = a count per section or "
                         "a list of arc lengths)")
    check_model_support(robot, "disks")
    tol = 1e-9 * float(robot.length.max())
    off = np.abs(tendon_len[..., None] - robot.disks).min(axis=-1) > tol if tendon_len.size else np.zeros((1, 0), bool)
    if off.any():
        b, k = np.argwhere(off)[0]
        raise InputError(f"tendons[{k}] ends at s = {float(tendon_len[b, k])!r} m (rod {b}), not at a disk: the "
                         f"disk model needs every tendon to end at one (disks at {robot.disks.tolist()} m)")


def disk_nodes(grid: np.ndarray, disks: np.ndarray) -> np.ndarray:
    """(Bg, N+1) per node: from node 0 and from every disk the node of the next disk (its own
    node at the last disk), -1 at the other nodes."""
    out = np.full(grid.shape, -1, dtype=np.int32)
    for row, g in zip(out, grid):
        at = np.abs(g[:, None] - disks[None]).argmin(axis=0)
        chain = np.concatenate([[0], at])
        row[chain[:-1]] = chain[1:]
        row[chain[-1]] = chain[-1]
    return out


RIGID_START = 1e-2  # a rigid obstacle's first stiffness: a load of E I / L^3 per length sinks 1% of the radius


def pack_obstacles(robot: Robot) -> np.ndarray:
    """(1|B, O, layout.OB_WIDTH): each obstacle's geometry, its penalty stiffness (a rigid one's
    first, k0 = E I / (L^3 0.01 r): stiffened by tdcr_warp.physics.contact), the rod's radius,
    the contact's damping and OB_ALONG 0 (the law at the node's point; tdcr_warp.physics.crossing
    sets it for the rods that need it)."""
    if not robot.obstacles:
        return np.zeros((1, 0, layout.OB_WIDTH))
    k0 = robot.section()["kbt"][:, 0] / (robot.length**3 * RIGID_START * robot.radius)
    rows = [_columns([ob.geometry(), (k0 if ob.rigid else ob.stiffness)[:, None], robot.radius[:, None],
                      ob.damping[:, None], np.zeros((1, 1))],
                     layout.OB_WIDTH) for ob in robot.obstacles]
    b = max(r.shape[0] for r in rows)
    return np.stack([np.broadcast_to(r, (b, layout.OB_WIDTH)) for r in rows], axis=1)


def _columns(cols: list[np.ndarray], width: int) -> np.ndarray:
    b = max(c.shape[0] for c in cols)
    out = np.concatenate([np.broadcast_to(c, (b, c.shape[1])) for c in cols], axis=1)
    assert out.shape[1] == width
    return out


def pack_rod(robot: Robot) -> np.ndarray:
    """Per-rod parameter rows, shape (1 or B, layout.ROD_WIDTH). With sections, the stiffness at the
    base (the scales) and in FE the gravitational acceleration (the kernels weigh rho A(s) g)."""
    sec = robot.section()
    fe = robot.gravity if robot.sections else (robot.density * sec["area"])[:, None] * robot.gravity
    L, EI = robot.length[:, None], sec["kbt"][:, :1]
    return _columns([sec["kse"], sec["kbt"], robot.precurvature, fe, robot.tip_force, robot.tip_moment, L,
                     EI / (L * L), EI / L], layout.ROD_WIDTH)


def pack_sections(robot: Robot, grid: np.ndarray) -> np.ndarray:
    """(Bg, S, layout.SEC_WIDTH) the sections of each grid row, their ends the nodes they fall on
    (exactly: the kernels find a section's end among the nodes); (1, 1, SEC_WIDTH) of zeros without."""
    table = robot.section_rows
    if not len(table):
        return np.zeros((1, 1, layout.SEC_WIDTH))
    out = np.repeat(table[None], grid.shape[0], axis=0)
    for row, g in zip(out, grid):
        ends = g[np.abs(g[:, None] - table[None, :, layout.SEC_END]).argmin(axis=0)]
        row[:, layout.SEC_END] = ends
        row[1:, layout.SEC_START] = ends[:-1]
    return out


def weight_moments(robot: Robot) -> tuple[np.ndarray, np.ndarray]:
    """(1,) a robot's sections' mass int_0^L rho A ds [kg] and its first moment int_0^L s rho A ds
    [kg m], by 3-point Gauss-Legendre per section (exact: rho A is of degree 3 in s)."""
    x, w = np.polynomial.legendre.leggauss(3)
    table = robot.section_rows
    a, b = table[:, :1], table[:, 1:2]
    s = 0.5 * (a + b) + 0.5 * (b - a) * x
    wt = 0.5 * (b - a) * w
    rho_a = section_properties(table, s)["rho_area"]
    return np.array([np.sum(wt * rho_a)]), np.array([np.sum(wt * s * rho_a)])


def pack_dynamics(robot: Robot) -> np.ndarray:
    """Dynamics rows, shape (1 or B, layout.DYN_WIDTH)."""
    sec = robot.section()
    rho_a = (robot.density * sec["area"])[:, None]
    rho_j = (robot.density * sec["inertia"])[:, None] * np.array([1.0, 1.0, 2.0])
    return _columns([rho_a, rho_j, robot.damping_shear, robot.damping_bending, robot.drag], layout.DYN_WIDTH)


def slack_slopes(robot: Robot) -> np.ndarray:
    """(1|B, K) the slope of a displacement-controlled tendon's taut residual at zero tension on
    a straight rod, per scaled unknown: (EI / L^2) (r^2 / EI + 1 / EA + c) L / L = r^2 / L^2 +
    EI / (EA L^2) + c EI / L^2 (bending shortens the path by r theta, compression by L tau / EA,
    the wire stretches by c L tau). The slack branch continues with it (kernels/rod.py)."""
    if not robot.tendons:
        return np.zeros((1, 0))
    r0 = np.linalg.norm(robot.tendon_routing(0.0)[0], axis=-1)
    sec = robot.section()
    L = robot.length[:, None]
    ei, ea = sec["kbt"][:, :1], sec["kse"][:, 2:3]
    return r0**2 / L**2 + ei / (ea * L**2) + robot.tendon_columns("compliance") * ei / L**2


def pack_tendons(robot: Robot) -> np.ndarray:
    """Tendon rows, shape (1 or B, K, layout.TENDON_WIDTH): routing (Robot.routing_parameters),
    friction, compliance and the slack slope."""
    names = (layout.T_X0, layout.T_Y0, layout.T_A, layout.T_W, layout.T_PHASE, layout.T_DX, layout.T_DY)
    cols = dict(zip(names, robot.routing_parameters()))
    cols[layout.T_MU] = robot.tendon_columns("friction")
    cols[layout.T_COMPLIANCE] = robot.tendon_columns("compliance")
    cols[layout.T_SLACK_SLOPE] = slack_slopes(robot)
    b = max(c.shape[0] for c in cols.values())
    K = robot.n_tendons
    return np.stack([np.broadcast_to(cols[c], (b, K)) for c in range(layout.TENDON_WIDTH)], axis=-1)


MODES = ("solve", "reference")


def scene_features(robot: Robot, tendon: np.ndarray, specialize: bool, kink_loads: bool = True,
                   mode: str = "solve", lengths: bool = False, disks: bool = False) -> Features:
    """The physics this batch contains (all of the optional terms when ``specialize`` is off).
    Tendon states (path lengths, friction) are structure, not options: friction when a tendon
    has mu > 0, one unknown per displacement-controlled tendon. ``mode`` "reference": every
    tendon in tension control without friction, integrating the tendon lengths (the reference
    state of displacement control); ``lengths``: integrate them anyway. ``disks``: the disk model,
    whose tendon states (always) hold each tendon's last hole and chord too: 4 x the tendon count
    (kernels/disks.py). Obstacles, like the tendon states, are structure: contact compiles in
    only where the robot has them."""
    friction = mode == "solve" and robot.has_friction
    displaced = len(robot.displaced) if mode == "solve" else 0
    states = robot.n_tendons if (friction or displaced or lengths or mode == "reference" or disks) else 0
    states *= 4 if disks else 1
    spline = any(t.routing == "points" for t in robot.tendons)
    tendons = dict(kinks=kink_loads, friction=friction, tendons=states, displaced=displaced, spline=spline,
                   contact=len(robot.obstacles) > 0, sections=bool(robot.sections),
                   tip=0 if robot.tip_constraint is None or mode != "solve" else robot.tip_constraint.count)
    if not specialize:
        return ALL._replace(**tendons)
    heavy = any(np.any(sec.density > 0) for sec in robot.sections) if robot.sections else np.any(robot.density > 0)
    return Features(gravity=bool(np.any(robot.gravity != 0) and heavy),
                    point_loads=len(robot.point_forces) > 0 or (disks and robot.disk_mass > 0),
                    helix=spline or bool(np.any(tendon[..., [layout.T_A, layout.T_DX, layout.T_DY]] != 0)),
                    drag=bool(np.any(robot.drag != 0)), **tendons)


@dataclass(frozen=True)
class Tables:
    """The packed host tables of one robot at one node count (leading dimension 1 or B).

    rod, dyn, tendon, pforce: see kernels/layout.py; grid (1|B, N+1) [m]; term_node (1|B, K)
    and pnode (1|B, P): node indices; dnext (1|B, N+1): the disk model's next disk from node 0
    and every disk (``disk_nodes``; (1, 1) of -1 in the other models); obst (1|B, O, OB_WIDTH): the
    obstacles (``pack_obstacles``); tipc (1|B, TC_WIDTH): a constrained tip (zeros: none); sect (1|B, S, SEC_WIDTH): the
    backbone's sections (``pack_sections``); tendon_len (1|B, K): termination arc lengths [m] (the
    kernels' tendon lengths are relative to them); route (1, K, S, 9): the spline segments of tendons routed
    through points (robot.route_table); tmode (1, K): the shooting unknown 6 + j of each
    displacement-controlled tendon (-1: tension control); features: the physics the robot
    contains; straight: its Newton start. Derived from the rod table: ``scales`` and ``stiffness``.
    """

    rod: np.ndarray
    dyn: np.ndarray
    tendon: np.ndarray
    grid: np.ndarray
    term_node: np.ndarray
    pforce: np.ndarray
    pnode: np.ndarray
    dnext: np.ndarray
    tmode: np.ndarray
    route: np.ndarray
    tendon_len: np.ndarray
    obst: np.ndarray
    tipc: np.ndarray
    sect: np.ndarray
    features: Features
    straight: StraightRod

    @classmethod
    def of(cls, robot: Robot, nodes: int, specialize: bool = True, kink_loads: bool = True,
           mode: str = "solve", lengths: bool = False, disks: bool = False) -> "Tables":
        """``disks``: the tables of the disk model (a node at every disk, the disks' weights)."""
        tendon_len = robot.tendon_lengths() if robot.tendons else np.zeros((1, 0))
        if disks:
            check_disk_model(robot, tendon_len)
        point_s, point_f = robot.pack_point_forces(disk_weights=disks)
        knots = ([t.points[1:-1, 0] for t in robot.tendons if t.routing == "points"] + ([robot.disks] if disks else [])
                 + ([robot.section_rows[:-1, layout.SEC_END]] if robot.sections else []))
        grid, term_node, point_node = make_grid(robot.length, tendon_len, point_s, nodes,
                                                np.concatenate(knots)[None] if knots else None)
        dnext = disk_nodes(grid, robot.disks) if disks else np.full((1, 1), -1, dtype=np.int32)
        tendon = pack_tendons(robot)
        features = scene_features(robot, tendon, specialize, kink_loads, mode, lengths, disks)
        tmode = np.full((1, robot.n_tendons), -1, dtype=np.int32)
        if features.displaced:
            tmode[0, list(robot.displaced)] = np.arange(features.displaced)
        return cls(rod=pack_rod(robot), dyn=pack_dynamics(robot), tendon=tendon, grid=grid, term_node=term_node,
                   pforce=point_f, pnode=point_node, dnext=dnext, tmode=tmode, route=route_table(robot), tendon_len=tendon_len,
                   obst=pack_obstacles(robot), features=features, sect=pack_sections(robot, grid),
                   tipc=np.zeros((1, layout.TC_WIDTH)) if not features.tip else robot.tip_constraint.table(), straight=StraightRod.of(robot))

    @property
    def disks(self) -> bool:
        """Whether these are the disk model's tables (a disk chain in ``dnext``)."""
        return bool(self.dnext.max() >= 0)

    @property
    def nu(self) -> int:
        """Shooting unknowns per rod: n(0), m(0), a tension per displacement-controlled tendon and
        the reaction of a constrained tip."""
        return 6 + self.features.displaced + self.features.tip

    def rows(self, name: str, lo: int, hi: int) -> np.ndarray:
        """Rows lo:hi of table ``name``; a shared table (leading 1) stays as it is."""
        t = getattr(self, name)
        return t[lo:hi] if t.shape[0] > 1 else t

    @functools.cached_property
    def scales(self) -> np.ndarray:
        """(1|B, nu) the kernels' force and moment scales [EI/L^2 x 3, EI/L x 3, EI/L^2 per
        displaced tendon]: the scaled unknowns are [n(0), m(0), tensions] / scales (taken once
        from the rod table: every solve uses them)."""
        f, m = self.rod[:, layout.FORCE_SCALE], self.rod[:, layout.MOMENT_SCALE]
        return np.stack([f, f, f, m, m, m] + [f] * (self.features.displaced + self.features.tip), axis=1)

    def scale_rows(self, B: int) -> np.ndarray:
        return np.broadcast_to(self.scales, (B, self.nu))

    def tip_reaction(self, x: np.ndarray) -> np.ndarray:
        """(B, 3) the force a constrained tip takes [N] (world) from the scaled unknowns x (B, nu)."""
        B, first = x.shape[0], 6 + self.features.displaced
        lam = x[:, first:] * self.scale_rows(B)[:, first:]
        basis = self.tipc[:, layout.TC_BASIS:layout.TC_BASIS + 9].reshape(-1, 3, 3)[:, :lam.shape[1]]
        return np.einsum("bi,bij->bj", lam, np.broadcast_to(basis, (B,) + basis.shape[1:]))

    @property
    def stiffness(self) -> np.ndarray:
        """(1|B, 6) the Kse and Kbt diagonals [N, N m^2]."""
        return self.rod[:, layout.KSE:layout.KBT + 3]


_YZX, _ZXY = [1, 2, 0], [2, 0, 1]


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b over the last axis, the same arithmetic as np.cross at a fraction of its overhead."""
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1], a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


@dataclass(frozen=True)
class StraightRod:
    """What the Newton start of a robot needs, computed once: the base wrench of the straight
    rod under its external loads (gravity, tip wrench: ``external``, point forces: ``points``,
    (1|B, 6)), and per tendon the tangent at its end (dr + e3, (1|B, K, 3)), its length
    (1|B, K, 1) and the lever arm s_end e3 + r (1|B, K, 3); ``path``: each tendon's path length
    on the straight rod (1|B, K) [m] (the start of a displacement-controlled tendon)."""

    external: np.ndarray
    points: np.ndarray | None
    tangent: np.ndarray
    tangent_norm: np.ndarray
    arm: np.ndarray
    path: np.ndarray

    @classmethod
    def of(cls, robot: Robot) -> "StraightRod":
        e3 = np.array([0.0, 0.0, 1.0])
        L = robot.length
        if robot.sections:  # the weight and its moment about the base
            mass, moment = weight_moments(robot)
            n0 = robot.tip_force + mass[:, None] * robot.gravity
            m_weight = _cross(moment[:, None] * e3, robot.gravity)
        else:
            fe = (robot.density * robot.section()["area"])[:, None] * robot.gravity
            n0 = robot.tip_force + fe * L[:, None]
            m_weight = _cross(0.5 * (L**2)[:, None] * e3, fe)
        m0 = robot.tip_moment + _cross(L[:, None] * e3, robot.tip_force) + m_weight
        K = robot.n_tendons
        t = arm = norm = np.zeros((1, K, 3))
        path = np.zeros((1, K))
        if K:
            tl = robot.tendon_lengths()
            r, dr, _ = robot.tendon_routing(tl)
            t = dr + e3
            norm = np.linalg.norm(t, axis=-1, keepdims=True)
            arm = tl[..., None] * e3 + r
            # |r'(s) + e3|: constant along straight, helical and linear routes; by Simpson's rule
            # over [0, l] where a route runs through points
            path = tl * np.linalg.norm(t, axis=-1)
            if any(td.routing == "points" for td in robot.tendons):
                frac = np.linspace(0.0, 1.0, 65)
                rates = np.stack([np.linalg.norm(robot.tendon_routing(tl * f)[1] + e3, axis=-1) for f in frac])
                wts = np.r_[1.0, np.tile([4.0, 2.0], 31), 4.0, 1.0] / (3.0 * 64)
                path = tl * np.tensordot(wts, rates, axes=1)
        points = None
        if robot.point_forces:
            ps, pf = robot.pack_point_forces()
            points = np.concatenate(np.broadcast_arrays(pf.sum(axis=1), _cross(ps[..., None] * e3, pf).sum(axis=1)),
                                    axis=1)
        return cls(external=np.concatenate(np.broadcast_arrays(n0, m0), axis=1), points=points, tangent=t,
                   tangent_norm=norm, arm=arm, path=path)

    @functools.cached_property
    def _lever(self) -> np.ndarray:
        """(1|B, K, 6) each lever arm's components as a x F takes them (``_cross``): a x F =
        [a_y, a_z, a_x] F[z, x, y] - [a_z, a_x, a_y] F[y, z, x]."""
        return np.concatenate((self.arm[..., _YZX], self.arm[..., _ZXY]), axis=-1)

    def guess(self, tensions: np.ndarray) -> np.ndarray:
        """n(0), m(0) (B, 6) of the straight rod under tensions (B, K): the Newton start. The
        external wrench, then each tendon's force F and moment arm x F, then the point forces
        are added in that order (a running sum, the arithmetic of adding them one by one)."""
        B, K = tensions.shape
        terms = np.empty((B, K + 1 + (self.points is not None), 6))
        terms[:, 0] = self.external
        if K:
            F = terms[:, 1:K + 1, :3]
            np.divide(-tensions[..., None] * self.tangent, self.tangent_norm, out=F)
            arms = self._lever * F[..., _ZXY + _YZX]
            np.subtract(arms[..., :3], arms[..., 3:], out=terms[:, 1:K + 1, 3:])
        if self.points is not None:
            terms[:, -1] = self.points
        return np.add.accumulate(terms, axis=1)[:, -1]


def _pad(a: np.ndarray, shape_min: tuple) -> np.ndarray:
    """Kernels take at least one column; empty tendon/point tables become zero-filled."""
    if a.shape[1] > 0:
        return a
    return np.zeros((a.shape[0],) + shape_min, dtype=a.dtype)


class Device:
    """Uploads to one device at one precision."""

    def __init__(self, device, precision: str):
        self.device = device
        self.wdtype, self.ndtype = PRECISIONS[precision]

    def array(self, a: np.ndarray, ndtype=None) -> wp.array:
        a = np.ascontiguousarray(a, dtype=ndtype or self.ndtype)
        return wp.array(a, dtype=wp.dtype_from_numpy(a.dtype), device=self.device)

    def put(self, dest: wp.array, values: np.ndarray) -> None:
        """Copy host values into an existing device array (of any vector/matrix dtype)."""
        scalar = np.int32 if dest.dtype in (wp.int32, int) else self.ndtype
        dest.assign(np.ascontiguousarray(values, dtype=scalar))


def put_model(kern, dev: Device, tables: Tables, lo: int, hi: int):
    """The kernel ``Model`` of rods lo:hi (shared tables stay shared)."""
    md = kern.Model()
    md.rod = dev.array(tables.rows("rod", lo, hi))
    md.dyn = dev.array(tables.rows("dyn", lo, hi))
    md.tendon = dev.array(_pad(tables.rows("tendon", lo, hi), (1, layout.TENDON_WIDTH)))
    md.grid = dev.array(tables.rows("grid", lo, hi))
    md.term_node = dev.array(_pad(tables.rows("term_node", lo, hi), (1,)), np.int32)
    md.pforce = dev.array(_pad(tables.rows("pforce", lo, hi), (1, 3)))
    md.pnode = dev.array(_pad(tables.rows("pnode", lo, hi), (1,)), np.int32)
    md.dnext = dev.array(tables.rows("dnext", lo, hi), np.int32)
    md.tmode = dev.array(_pad(tables.tmode, (1,)), np.int32)
    md.route = dev.array(tables.route if tables.route.shape[1] else np.zeros((1, 1, 1, 9)))
    md.obst = dev.array(_pad(tables.rows("obst", lo, hi), (1, layout.OB_WIDTH)))
    md.tipc = dev.array(tables.rows("tipc", lo, hi))
    md.near = dev.array(np.ones((hi - lo, tables.grid.shape[1]) if tables.features.contact else (1, 1)), np.int32)
    md.sect = dev.array(tables.rows("sect", lo, hi))
    md.n_sect = tables.sect.shape[1] if tables.features.sections else 0
    md.n_tendons = tables.tendon.shape[1]
    md.n_points = tables.pforce.shape[1]
    md.n_obst = tables.obst.shape[1]
    return md


def make_control(kern, dev: Device, tau: np.ndarray, n_slots: int):
    """The kernel ``Control``: tensions (b, K) [N]; with tendon states also the available
    unstretched lengths of displaced tendons (b, K) [m], slip directions (b, K) (+1) and the
    stick-slip memory (b, S, K), off and zero until set (``set_command``, ``set_memory``)."""
    b, K = tau.shape
    ct = kern.Control()
    ct.tau = dev.array(pad_tensions(tau))
    shape = (b, K) if kern.tstate else (1, 1)
    ct.avail = dev.array(np.zeros(shape))
    ct.slip = dev.array(np.ones(shape))
    ct.stick = 0
    ct.taut = dev.array(np.ones(shape), np.int32)
    memory = (b, n_slots, K) if kern.friction else (1, 1, 1)
    ct.tau_old = dev.array(np.zeros(memory))
    ct.dtau_old = dev.array(np.zeros(memory))
    return ct


def pad_tensions(tau: np.ndarray) -> np.ndarray:
    """Tensions (b, K) as the Control's ``tau`` holds them (a zero column where K = 0)."""
    return _pad(tau, (1,))


def make_step(kern, dev: Device, b: int, n_slots: int, dynamic: bool):
    """The kernel ``Step``: the BDF-alpha constant and the history of every slot (dynamics),
    and with friction the tension profile of the trial point at every slot (b, S, 3K)."""
    sp = kern.Step()
    sp.c0 = dev.wdtype(0.0)
    prof = (b, n_slots, 3 * kern.K) if kern.friction else (1, 1, 1)
    sp.tprof = wp.zeros(prof, dtype=dev.wdtype, device=dev.device)
    if dynamic:
        sp.hist = wp.zeros((b, n_slots, SLOT_WIDTH), dtype=kern.vec3, device=dev.device)
        sp.ycur = wp.zeros((b, n_slots, SLOT_WIDTH), dtype=kern.vec3, device=dev.device)
    return sp


def make_state(kern, dev: Device, b: int, n1: int, dynamic: bool):
    """The kernel ``Nodes`` of the solution: p, R, n, m (and q, w in dynamics) at every node."""
    out = kern.Nodes()
    d = dev.device
    out.p = wp.zeros((b, n1), dtype=kern.vec3, device=d)
    out.R = wp.zeros((b, n1), dtype=kern.mat33, device=d)
    out.n = wp.zeros((b, n1), dtype=kern.vec3, device=d)
    out.m = wp.zeros((b, n1), dtype=kern.vec3, device=d)
    if dynamic:
        out.q = wp.zeros((b, n1), dtype=kern.vec3, device=d)
        out.w = wp.zeros((b, n1), dtype=kern.vec3, device=d)
    out.orth = wp.zeros(b, dtype=dev.wdtype, device=d)
    if kern.tstate:
        out.tend = wp.zeros((b, kern.K, layout.TO_WIDTH), dtype=dev.wdtype, device=d)
        out.taun = wp.zeros((b, n1, kern.K), dtype=dev.wdtype, device=d)
    return out


def make_work(kern, dev: Device, b: int):
    """The kernel ``Newton`` scratch and outcome of b rods."""
    nw = kern.Newton()
    d = dev.device
    for name in ("x", "r", "xt"):
        setattr(nw, name, wp.zeros(b, dtype=kern.vecu, device=d))
    nw.J = wp.zeros(b, dtype=kern.matu, device=d)
    nw.res = wp.zeros((b, kern.width), dtype=kern.vecu, device=d)
    for name in ("active", "need_jac", "flags", "status", "iters", "n_shoot"):
        setattr(nw, name, wp.zeros(b, dtype=int, device=d))
    nw.lam = wp.zeros(b, dtype=dev.wdtype, device=d)
    nw.resnorm = wp.zeros(b, dtype=dev.wdtype, device=d)
    nw.n_active = wp.zeros(1, dtype=int, device=d)
    return nw
