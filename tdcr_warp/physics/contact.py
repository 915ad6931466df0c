"""Contact with obstacles, on the host: rigid obstacles stiffened toward rigid contact, and what
a solve reports of contact (the law itself is kernels/contact.py).

A rigid obstacle starts at the penalty stiffness k0 of tdcr_warp.core.build.pack_obstacles. After
a solve, every rod whose deepest penetration of a rigid obstacle exceeds the tolerance
(``StaticOptions.contact_tolerance`` times the rod's radius), or that the law's rounded band
still pushes from further off the surface than that, is solved again, from its last solution,
with that obstacle's stiffness raised by the factor that the linear law says brings the
penetration to half the tolerance and the band within it (2 to 1000 per round), up to
``contact_steps`` rounds, climbing there by factors of at most 10 per solve; a solve that fails is
taken back and retried at the square root of its factor (``Contact.climb``), so a rod never
loses its last converged solution. A cold solve starts with every obstacle 1e-3 times as stiff
(close to the free problem: Newton from the straight rod converges as it does without them);
then the rods that touch climb back, the others take the stiffness at once (``Contact.settle``),
and a rod that failed restarts 1e-6 times as stiff and climbs.
Each rod's schedule is its own: a rod's answer never depends on its neighbours in the batch. A rod still beyond the tolerance, or
clamped inside an obstacle, is flagged ``PENETRATION``.

A long line contact defeats single shooting (a start error grows like exp(2 beta l), beta =
(k / 4 E I)^(1/4)): where armed (statics), a rod whose contact would grow one beyond 1e6 at the
next stiffness, or whose climb step fails twice where it grows beyond 1e3, or that ends flagged,
is split and climbs on by multiple shooting (``ContactSplitting``).
"""

from __future__ import annotations

import math
from contextlib import contextmanager

import numpy as np
import warp as wp

from tdcr_warp.core.solver import Shooting
from tdcr_warp.kernels import layout
from tdcr_warp.kernels.contact import make_contact_kernel, make_interval_kernels
from tdcr_warp.physics.segments import SEGMENT_REACH, SINGLE_REACH, SWITCH_REACH, Segments

__all__ = ["Contact", "chunk_contacts", "contact_segments", "penetration"]

MAX_FACTOR = 1e3  # the most one round of stiffening asks for
STEP, MIN_STEP, MAX_TRIES = 10.0, 1.15, 40  # climbing: the first factor per solve, the smallest, the most solves
SOFT = 1e-3  # a cold solve starts with its obstacles this many times as stiff (a failed rod: SOFT^2)
EXACT = {"broyden": False}  # a failed step's retry: a Jacobian at every iterate (the contact set moves)


def contact_growth(rod: np.ndarray, stiffness: np.ndarray, length: np.ndarray | None = None) -> np.ndarray:
    """(b,) ln of a start error's growth along a line contact, 2 beta l with beta = (k / 4 E I)^(1/4),
    the rods' rows ``rod`` (b, ROD_WIDTH) on their stiffest obstacle (``stiffness`` (b, O) [N/m^2])
    over ``length`` (b,) [m] (None: the whole rod)."""
    L, ei = rod[:, layout.LENGTH], rod[:, layout.FORCE_SCALE] * rod[:, layout.LENGTH] ** 2
    return 2.0 * (L if length is None else length) * (stiffness.max(axis=1) / (4.0 * ei)) ** 0.25


def contact_segments(rod: np.ndarray, stiffness: np.ndarray, precision: str) -> np.ndarray:
    """(b,) the segments (of equal length) that keep ``contact_growth`` within SEGMENT_REACH per
    segment wherever the rod lies on its stiffest obstacle."""
    return np.ceil(contact_growth(rod, stiffness) / math.log(SEGMENT_REACH[precision])).astype(int)


def penetration(gap: np.ndarray) -> np.ndarray:
    """(b, O) the deepest penetration of each obstacle [m] (0 where none) from the gaps (b, N+1, O)."""
    return np.maximum(0.0, -gap.min(axis=1))


class ContactState:
    """The contact of one chunk of rods: its Shooting's own per-rod obstacle table, and what the
    last stored shapes say of it."""

    def __init__(self, sh: Shooting, table: np.ndarray, rod: np.ndarray, rigid: np.ndarray, reach: np.ndarray):
        self.sh = sh
        b, n1 = sh.b, sh.n1
        self.start_table = np.array(np.broadcast_to(table, (b,) + table.shape[1:]))
        self.rigid = rigid  # (O,) bool
        self.reach = np.broadcast_to(reach, (b,))  # the rods' radii [m]
        self.per_len = np.broadcast_to(rod[:, layout.FORCE_SCALE] / rod[:, layout.LENGTH], (b,))  # E I / L^3
        self.rod = rod
        self.table = self.start_table.copy()
        self.crossed = np.zeros(b, dtype=bool)  # tdcr_warp/physics/crossing.py
        sh.model.obst = sh.dev.array(self.table)
        self.kernel = make_contact_kernel(sh.dev.wdtype, sh.dynamic)
        self.kernels = make_interval_kernels(sh.dev.wdtype, sh.dynamic)
        self.force = wp.zeros((b, n1), dtype=sh.kern.vec3, device=sh.device)
        self.gap = wp.zeros((b, n1, table.shape[1]), dtype=sh.dev.wdtype, device=sh.device)
        self.pressing = wp.zeros_like(self.gap)
        self.igap = wp.zeros((b, n1 - 1, table.shape[1]), dtype=sh.dev.wdtype, device=sh.device)

    def reset(self, stiffness: np.ndarray | None) -> None:
        """A cold start: every obstacle SOFT times its stiffness (``settle`` climbs back); a warm
        one: the rigid obstacles at ``stiffness`` (b, O) [N/m^2] (the warm start's: its schedule
        need not be climbed again), a compliant one at its own."""
        self.table = self.start_table.copy()
        self.segs = self.count = None  # every rod by single shooting again
        self.crossed = np.zeros(self.sh.b, dtype=bool)  # tdcr_warp/physics/crossing.py
        k = self.table[..., layout.OB_STIFF]
        if stiffness is not None and stiffness.shape == self.table.shape[:2]:
            self.table[..., layout.OB_STIFF] = np.where(self.rigid[None], stiffness, k)
        self.goal = self.table[..., layout.OB_STIFF].copy()
        if stiffness is None:
            self.table[..., layout.OB_STIFF] = k * SOFT
        self.sh.dev.put(self.sh.model.obst, self.table)

    def goal_stiffness(self) -> np.ndarray:
        """(b, O) every obstacle's stiffness before any schedule [N/m^2] (rigid ones: their base k0)."""
        return self.start_table[..., layout.OB_STIFF].copy()

    def measure(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The contact force (b, N+1, 3) [N], the gap to each obstacle (b, N+1, O) [m] at the
        nodes of the last stored shapes, and the gap where the obstacle can push (b, N+1, O) [m]
        (the gap the law sees: the node's, or its share's with OB_ALONG; in dynamics FAR at a node
        leaving at 1 / (2 damping) or faster, whose depth no stiffness sets: the schedule looks at
        this one, the PENETRATION flag at the gap)."""
        sh, out = self.sh, self.sh.nodes
        vel = out.q if sh.dynamic else out.p  # statics: no velocities (the kernel reads none)
        wp.launch(self.kernel, dim=(sh.b, sh.n1), inputs=[sh.model, out.p, out.R, out.m, vel, self.force, self.gap,
                                                          self.pressing], device=sh.device)
        return tuple(sh.host(a).get(np.float64) for a in (self.force, self.gap, self.pressing))

    def measure_intervals(self) -> np.ndarray:
        """(b, N, O) the smallest gap to each obstacle along every interval of the last stored
        shapes [m] (kernels/contact.py: the centre line between the nodes, not only at them)."""
        sh, out = self.sh, self.sh.nodes
        wp.launch(self.kernels.intervals, dim=(sh.b, sh.n1 - 1), inputs=[sh.model, out.p, out.R, self.igap],
                  device=sh.device)
        return sh.host(self.igap).get(np.float64)

    def half_band(self) -> np.ndarray:
        """(b, O) half the width of the law's rounded band, eps / 2 = E I / (2 L^3 k) [m]: a node
        nearer an obstacle than that is pushed."""
        return 0.5 * self.per_len[:, None] / self.table[..., layout.OB_STIFF]

    def band(self, gap: np.ndarray) -> np.ndarray:
        """(b, O) ``half_band`` for the obstacles that touch (0 elsewhere): how far off the surface
        a node may still be pushed."""
        half = self.half_band()
        return np.where(gap.min(axis=1) < half, half, 0.0)

    @contextmanager
    def near_only(self, gap: np.ndarray):
        """Within: contact counts only at the nodes of each rod nearer an obstacle than its radius
        plus the law's half band in ``gap`` (b, N+1, O) [m], the solved shapes' gaps; elsewhere a
        node carries no force, and the probes of those shapes (the stability verdict's and the
        sensitivities', which move a node by far less than a radius) take their double steps
        over it."""
        near = (gap < (self.reach[:, None] + self.half_band())[:, None, :]).any(axis=2)
        mirror = self.sh.host(self.sh.model.near)
        mirror.put(near.astype(np.int32))
        try:
            yield
        finally:
            mirror.put(np.ones(near.shape, dtype=np.int32))

    def restore(self) -> None:
        """Dynamics, before a step: the stiffness each rod had at its stiffest since the start
        (a step's stiffening is kept, a step's softening is not)."""
        k = self.table[..., layout.OB_STIFF]
        self.goal = np.maximum(self.goal, k)
        if not np.array_equal(k, self.goal):
            self.table[..., layout.OB_STIFF] = self.goal
            self.sh.dev.put(self.sh.model.obst, self.table)

    def results(self, tolerance: float, status: np.ndarray, between: bool = True) -> dict[str, np.ndarray]:
        """What a solve reports of contact, and ``status`` with PENETRATION where a rigid
        obstacle is penetrated beyond the tolerance at a node or between two (or the base is
        inside one), CROSSED where one was crossed on the way (``crossed``). ``between`` False:
        the nodes alone decide PENETRATION (what stiffening and splitting can mend; the schedule's
        own decisions), and ``interval_gap`` is not measured (None)."""
        force, gap, _pressing = self.measure()
        igap = self.measure_intervals() if between else None
        limit = tolerance * self.reach[:, None]
        deepest = penetration(gap) if igap is None else np.maximum(penetration(gap), penetration(igap))
        bad = (((deepest > limit) | (self.band(gap) > limit)) & self.rigid[None]).any(axis=1)
        bad |= (gap[:, 0] < -limit).any(axis=1)
        return {"contact_force": force, "contact_gap": gap, "interval_gap": igap,
                "contact_stiffness": self.table[..., layout.OB_STIFF].copy(),
                "status": np.where(bad, status | layout.PENETRATION, status) | np.where(self.crossed, layout.CROSSED, 0)}


class ContactSplitting(ContactState):
    """The rods of one chunk's contact that single shooting cannot carry up the stiffness climb,
    split: solved by multiple shooting (tdcr_warp/physics/segments.py) from then on, each in as
    many segments as its own contact needs (``split_rods``), and its own shooting per rod
    (``_solve``)."""

    segs: dict | None = None  # {M: Segments}: multiple shooting in M segments
    count: np.ndarray | None = None  # (b,) int: the segments each rod is split into (0: single shooting)
    armed: bool = False  # split the rods single shooting cannot carry
    fixed: int | None = None  # the count of every split (None: as many as each rod needs)
    c0: float = 0.0  # BDF-alpha's c0 [1/s] of the split rods' unknowns (0: statics)

    def arm(self, segments: int | None, c0: float = 0.0) -> None:
        """Split the rods single shooting cannot carry up a climb (``StaticOptions.segments``:
        None: into as many segments as each needs; M: into M; 1: never), their unknowns scaled
        with BDF-alpha's c0 [1/s] (0: statics)."""
        self.armed, self.fixed, self.c0 = segments != 1, segments, c0

    def split_mask(self) -> np.ndarray:
        """(b,) bool: the rods multiple shooting solves."""
        return self.split_count() > 0

    def split_count(self) -> np.ndarray:
        """(b,) int: the segments each rod is split into (0: single shooting)."""
        return np.zeros(self.sh.b, dtype=int) if self.count is None else self.count

    def _last(self) -> tuple:
        """The last solution of every rod: its single-shooting unknowns, and a split rod's segments'."""
        return self.sh.host(self.sh.newton.x).get(), {M: seg.state() for M, seg in (self.segs or {}).items()}

    def _solve(self, start: tuple, rods: np.ndarray, newton: dict) -> None:
        """Solve ``rods`` (b,) from ``start`` (a ``_last``), each by its own shooting."""
        single = rods & ~self.split_mask()
        if single.any():
            self.sh.solve(start[0], mask=single, fresh_jacobian=True, **newton)
        for M, seg in (self.segs or {}).items():
            mine = rods & (self.count == M)
            if mine.any():
                if M in start[1]:
                    seg.restore(start[1][M], mine)
                seg.solve_into(mine, newton["tol"], newton["max_iter"])

    def _need(self, stiffness: np.ndarray) -> np.ndarray:
        """(b,) the segments each rod needs at ``stiffness`` (b, O) (``contact_segments``, or the
        count armed; within 2..N)."""
        sh = self.sh
        if self.fixed:
            need = np.full(sh.b, self.fixed)
        else:
            need = contact_segments(np.broadcast_to(self.rod, (sh.b, self.rod.shape[1])), stiffness, self.precision)
        return np.clip(need, 2, sh.n1 - 1)

    @property
    def precision(self) -> str:
        return "float64" if self.sh.dev.wdtype == wp.float64 else "float32"

    def growth(self, stiffness: np.ndarray) -> np.ndarray:
        """(b,) ``contact_growth`` at ``stiffness`` (b, O) over the length of each rod that
        touches an obstacle in its last stored shape (nodes within the law's half band at that
        stiffness: a soft band may reach nodes that the stiffer law leaves free, a whole wire
        floating on a narrow tube's axis)."""
        sh = self.sh
        _f, _g, gap = self.measure()
        touching = (gap < 0.5 * self.per_len[:, None, None] / stiffness[:, None, :]).any(axis=2)  # (b, N+1)
        length = touching.sum(axis=1) * np.broadcast_to(self.rod[:, layout.LENGTH], (sh.b,)) / (sh.n1 - 1)
        return contact_growth(np.broadcast_to(self.rod, (sh.b, self.rod.shape[1])), stiffness, length)

    def _split_ahead(self, rods: np.ndarray, stiffness: np.ndarray) -> None:
        """Before a climb to ``stiffness`` (b, O): ``rods`` (b,) whose present contact would grow
        a start error beyond SINGLE_REACH along its length are split, and split rods that need
        more segments there split again (``split_rods``, sized for STEP times that stiffness)."""
        split = self.split_mask()
        beyond = self.growth(stiffness) > math.log(SINGLE_REACH[self.precision])
        grow = rods & ((~split & beyond) | (split & (self._need(stiffness * STEP) > self.split_count())))
        if grow.any():
            self.split_rods(grow, stiffness * STEP)

    def split_rods(self, rods: np.ndarray, stiffness: np.ndarray) -> None:
        """``rods`` (b,) solved by multiple shooting from now on, from their last shapes, each in
        as many segments as its contact at ``stiffness`` (b, O) [N/m^2] needs (or the count armed)."""
        need = self._need(stiffness)
        if self.segs is None:
            self.segs, self.count = {}, np.zeros(self.sh.b, dtype=int)
        for M in np.unique(need[rods]).tolist():
            mine = rods & (need == M)
            if M not in self.segs:
                self.segs[M] = Segments(self.sh, self.rod, M, self.c0)
            self.segs[M].from_nodes(self.sh.nodes, mine)
            self.count[mine] = M


class Contact(ContactSplitting):
    """The schedule of one chunk's contact: its rigid obstacles climbed, settled, softened and
    stiffened toward rigid contact (see the module), splitting the rods single shooting cannot
    carry where armed."""

    def _count(self, rods: np.ndarray, iters: np.ndarray, shots: np.ndarray) -> None:
        it, sn = self.sh.counts()
        iters[rods] += it[rods]
        shots[rods] += sn[rods]

    def climb(self, rods: np.ndarray, goal: np.ndarray, newton: dict, iters: np.ndarray, shots: np.ndarray) -> None:
        """The obstacles of ``rods`` from their stiffness to ``goal`` (b, O), each rod from its last
        solution by factors of up to STEP, with Broyden's updates; a step that fails is taken back
        (stiffness and solution) and tried again with a Jacobian at every iterate, and if that
        fails too at the square root of its factor, down to MIN_STEP, where the rod stays. Where
        armed, a rod single shooting cannot carry is split first (``_split_ahead``), or after two
        failures takes the same step again by multiple shooting."""
        sh, ok = self.sh, rods.copy()
        step, exact = np.full(sh.b, STEP), np.zeros(sh.b, dtype=bool)
        for _ in range(MAX_TRIES):
            k = self.table[..., layout.OB_STIFF]
            ok &= (goal > k * (1 + 1e-12)).any(axis=1) & (step >= MIN_STEP)
            if not ok.any():
                return
            prev, old = self._last(), self.table.copy()
            if self.armed:
                self._split_ahead(ok, np.where(ok[:, None], np.minimum(goal, k * step[:, None]), k))
                prev = self._last()
            self.table[..., layout.OB_STIFF] = np.where(ok[:, None], np.minimum(goal, k * step[:, None]), k)
            sh.dev.put(sh.model.obst, self.table)
            for group, how in ((ok & ~exact, newton), (ok & exact, newton | EXACT)):
                if group.any():
                    self._solve(prev, group, how)
                    self._count(group, iters, shots)
            failed = ok & ~sh.converged()
            exact &= ~(ok & ~failed)  # a step taken: the next starts with Broyden again
            if failed.any():
                self.table[failed] = old[failed]
                sh.dev.put(sh.model.obst, self.table)
                self._solve(prev, failed, newton)
                self._count(failed, iters, shots)
                again = failed & exact
                if self.armed:  # failed twice where single shooting is at risk: again by multiple shooting
                    tried = k * np.where(failed, step, 1.0)[:, None]
                    risk = self.growth(tried) > math.log(SWITCH_REACH[self.precision])
                    grow = again & risk & (~self.split_mask() | (self._need(tried) > self.split_count()))
                    if grow.any():
                        self.split_rods(grow, tried * STEP)
                        again &= ~grow
                step[again] = np.sqrt(step[again])
                exact |= failed

    def settle(self, x0: np.ndarray, newton: dict) -> None:
        """After the first solve: the rods that touch nothing take their obstacles' stiffness as it
        is (their shape does not change), those that touch ``climb`` to it; a rod that failed is
        solved again from ``x0`` with its obstacles SOFT times softer still, and climbs. A warm
        start (already at the stiffness): the rods it failed for ``soften`` from x0."""
        sh = self.sh
        if np.array_equal(self.table[..., layout.OB_STIFF], self.goal):
            failed = ~sh.converged()
            if failed.any():  # too far for the stiff contact
                self.soften(failed, x0, newton)
            return
        iters, shots = sh.counts()
        ok = sh.converged()
        _f, _g, gap = self.measure()
        touching = (gap.min(axis=1) < self.half_band()).any(axis=1)
        quiet = ok & ~touching
        self.table[quiet, :, layout.OB_STIFF] = self.goal[quiet]
        sh.dev.put(sh.model.obst, self.table)
        self.climb(ok & touching, self.goal, newton, iters, shots)
        failed = ~ok
        if failed.any():
            self.table[failed, :, layout.OB_STIFF] = self.goal[failed] * SOFT * SOFT
            sh.dev.put(sh.model.obst, self.table)
            sh.solve(x0, mask=failed, fresh_jacobian=True, **newton)  # (a cold start: no rod is split yet)
            self._count(failed, iters, shots)
            self.climb(failed & sh.converged(), self.goal, newton, iters, shots)
        sh.set_counts(iters, shots)

    def soften(self, failed: np.ndarray, x0: np.ndarray, newton: dict) -> np.ndarray:
        """The rods ``failed`` (b,) solved again from ``x0`` with their obstacles SOFT times as stiff,
        then climbed back toward their stiffness (a rod that cannot climb all the way keeps the
        last stiffness it converged at: ``results`` judges its penetration, ``restore`` puts the
        stiffness back); returns the rods still failing. Iterations add up."""
        sh = self.sh
        iters, shots = sh.counts()
        goal = self.table[..., layout.OB_STIFF].copy()
        self.table[failed, :, layout.OB_STIFF] *= SOFT
        sh.dev.put(sh.model.obst, self.table)
        sh.solve(x0, mask=failed, fresh_jacobian=True, **newton)
        self._count(failed, iters, shots)
        self.climb(failed & sh.converged(), goal, newton, iters, shots)
        sh.set_counts(iters, shots)
        return failed & ~sh.converged()

    def split_stiffen(self, rods: np.ndarray, tolerance: float, steps: int, newton: dict) -> None:
        """``rods`` (b,) solved again by multiple shooting from their last shapes (``split_rods``)
        and stiffened on (``stiffen``); iterations and integrations add up."""
        iters, shots = self.sh.counts()
        self.split_rods(rods, self.table[..., layout.OB_STIFF] * STEP)
        self._solve(self._last(), rods, newton)
        self._count(rods, iters, shots)
        self.sh.set_counts(iters, shots)
        self.stiffen(tolerance, steps, newton, rods)

    def stiffen(self, tolerance: float, steps: int, newton: dict, rods: np.ndarray | None = None) -> None:
        """Rigid obstacles stiffened until each rod's penetration is within ``tolerance`` radii
        (see the module; only ``rods`` (b,) bool where given); iterations and integrations add up
        over the schedule."""
        sh = self.sh
        rods = np.ones(sh.b, dtype=bool) if rods is None else rods
        iters, shots = sh.counts()
        limit = tolerance * self.reach[:, None]
        for _ in range(steps):
            _f, _g, gap = self.measure()
            pen, band = penetration(gap), self.band(gap)
            over = ((pen > limit) | (band > limit)) & self.rigid[None] & (sh.converged() & rods)[:, None]
            if not over.any():
                break
            factor = np.where(over, np.clip(np.maximum(2.0 * pen, band) / limit, 2.0, MAX_FACTOR), 1.0)
            k = self.table[..., layout.OB_STIFF].copy()
            self.climb(over.any(axis=1), k * factor, newton, iters, shots)
            if np.array_equal(k, self.table[..., layout.OB_STIFF]):
                break  # no rod could stiffen further
        sh.set_counts(iters, shots)


def chunk_contacts(robot, tables, solvers: list[Shooting], chunks: list[tuple[int, int]],
                   segments: int | None = 1, c0: float = 0.0) -> list[Contact]:
    """The Contact of each chunk's Shooting (none without obstacles), armed with ``segments`` and
    c0 (``Contact.arm``; 1: never split)."""
    if not tables.features.contact:
        return []
    rigid = np.array([ob.rigid for ob in robot.obstacles], dtype=bool)
    radius = robot.radius
    contacts = [Contact(sh, tables.rows("obst", lo, hi), tables.rows("rod", lo, hi), rigid,
                        radius[lo:hi] if len(radius) > 1 else radius)
                for sh, (lo, hi) in zip(solvers, chunks)]
    for contact in contacts:
        contact.arm(segments, c0)
    return contacts
