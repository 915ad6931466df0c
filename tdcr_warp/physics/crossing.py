"""Rigid obstacles are never crossed on the way to an answer, nor reached into between nodes.

A cold solve starts its obstacles soft (tdcr_warp/physics/contact.py) so that Newton from the
straight rod meets a problem close to the free one. A load that the soft obstacle cannot hold
takes the rod part way, or all the way, through a rigid sphere or capsule; the stiffening then
pushes it out on the far side, or never sees it. The answer is an equilibrium of the rigid
contact, but not the one the robot reaches as its load grows from zero.

The check: every point of the centre line (the nodes and the samples between them,
kernels/contact.py ``crossing``) goes in a straight line from its place in the unloaded rod to
its place in the answer. Where that line passes nearer a sphere's centre or a capsule's axis
than CORE times (its radius + the rod's), the rod may have crossed it (or slid far around it).
Such a rod is solved again along a load path from the unloaded rod with its obstacles as stiff
as its answer had them, in steps that move no point by more than STEP_REACH times that radius,
each checked against the step before (a step that fails or crosses is tried again at a third of
its size), and its contact stiffened again. A rod whose path fails keeps its answer, flagged
CROSSED; a rod split into segments (multiple shooting) that may have
crossed is flagged at once. Lumens and planes need no check: a rod through their wall ends
outside, and the gaps say so.

Between nodes: the law pushes a node by the gap at its own point, so a sphere or bar can reach
in between two nodes it holds off (kernels/contact.py checks the intervals). A rod whose centre
line does so beyond the tolerance is solved again (``lean_along``) with those obstacles pushing
each node by the nearest point of its share of the centre line (OB_ALONG: the local curve
through the node with its tangent and curvature), from a tenth of the stiffness climbed back
and stiffened; a rod that fails, or whose way there crosses the obstacle, keeps its answer
(flagged PENETRATION by the check). Rods that need neither are untouched, bit for bit.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from tdcr_warp.core.homotopy import MAX_CONTINUATION, scaled_loads, unloaded_shapes
from tdcr_warp.kernels import layout
from tdcr_warp.physics.contact import Contact, penetration

__all__ = ["CORE", "STEP_REACH", "lean_along", "uncross"]

CORE = 0.5  # a straight way nearer the core than this fraction of (obstacle radius + rod radius) may cross
STEP_REACH = 0.25  # a load path's step moves no point by more than this fraction of that radius
MIN_STEP = 1e-3  # a load path fails where its step shrinks below this fraction of its first
ALONG_SOFT = 0.1  # OB_ALONG is switched on at this fraction of the stiffness, then climbed back
SOLID = (layout.SPHERE, layout.CAPSULE)


def _core(contact: Contact, start: tuple) -> np.ndarray:
    """(b, O) how near the straight ways from the shapes ``start`` (device positions and
    orientations) to the last stored shapes pass each obstacle's core (kernels/contact.py)."""
    sh = contact.sh
    core = wp.zeros_like(contact.igap)
    wp.launch(contact.kernels.crossing, dim=(sh.b, sh.n1 - 1), inputs=[sh.model, *start, sh.nodes.p, sh.nodes.R, core],
              device=sh.device)
    return sh.host(core).get(np.float64).min(axis=1)


def _solve_again(sh, x: np.ndarray, rods: np.ndarray, newton: dict) -> None:
    """``rods`` (b,) solved again from the unknowns ``x`` (b, nu), a fresh Jacobian; their
    iterations and integrations add to those they had."""
    if not rods.any():
        return
    iters, shots = sh.counts()
    sh.solve(x, mask=rods, fresh_jacobian=True, **newton)
    it, sn = sh.counts()
    sh.set_counts(np.where(rods, iters + it, iters), np.where(rods, shots + sn, shots))


def _solid(contact: Contact) -> np.ndarray:
    """(b, O) bool: the rigid spheres and capsules of each rod."""
    kind = contact.table[..., layout.OB_KIND]
    return contact.rigid[None] & np.isin(kind, SOLID)


def _steps(contact: Contact, start: tuple) -> np.ndarray:
    """(b,) the steps of a load path that move no node by more than STEP_REACH times the smallest
    reach of a solid obstacle (its radius + the rod's), from the shapes ``start`` to the last stored."""
    sh = contact.sh
    moved = np.linalg.norm(sh.host(sh.nodes.p).get(np.float64) - start[0].numpy(), axis=2).max(axis=1)
    reach = contact.table[..., layout.OB_RADIUS] + contact.table[..., layout.OB_REACH]
    smallest = np.where(_solid(contact), reach, np.inf).min(axis=1)
    return np.clip(np.ceil(moved / (STEP_REACH * smallest)), 1, MAX_CONTINUATION).astype(np.int64)


class _Path:
    """The load path of ``uncross``: each rod's load fraction lam climbs from 0 to 1 in steps of
    its own, at most 1 / ``steps``, each step's contact stiffened to the tolerance (so that a point
    pressed on an obstacle stays near its surface); a step that fails or crosses (``_core`` against the last
    accepted shape) is taken back and tried at a third of its size, one that succeeds lets the next
    grow by half (a rod's path is its own: its answer never depends on its neighbours)."""

    def __init__(self, contact: Contact, start: tuple, steps: np.ndarray, rods: np.ndarray):
        self.contact, self.sh = contact, contact.sh
        self.solid = _solid(contact)
        self.lam, self.most = np.zeros(self.sh.b), 1.0 / steps
        self.dlam = self.most.copy()
        self.last = start
        self.on, self.done, self.failed = rods.copy(), np.zeros(self.sh.b, dtype=bool), np.zeros(self.sh.b, dtype=bool)

    def run(self, set_load, x0: np.ndarray, newton: dict, stiffen: tuple) -> None:
        """Walk every rod to lam = 1 or until its steps shrink below MIN_STEP (failed); each step's
        contact stiffened (``stiffen`` = (tolerance, steps): the contact's) before it is checked."""
        sh = self.sh
        x = x0 * self.most[:, None]  # the straight-rod start is linear in the loads
        iters, shots = np.zeros(sh.b, dtype=np.int64), np.zeros(sh.b, dtype=np.int64)
        while self.on.any():
            target = np.where(self.on, np.minimum(self.lam + self.dlam, 1.0), self.lam)
            set_load(target)
            sh.solve(x, mask=self.on, fresh_jacobian=True, **newton)
            self.contact.stiffen(*stiffen, newton, self.on & sh.converged())
            it, sn = sh.counts()
            iters[self.on] += it[self.on]
            shots[self.on] += sn[self.on]
            ok = self.on & sh.converged() & ~((_core(self.contact, self.last) < CORE) & self.solid).any(axis=1)
            self._accept(ok, target, x)
            bad = self.on & ~ok
            self.dlam[bad] /= 3.0
            self.failed |= bad & (self.dlam < MIN_STEP * self.most)
            self.on &= ~(self.failed | self.done)
        sh.set_counts(iters, shots)

    def _accept(self, ok: np.ndarray, target: np.ndarray, x: np.ndarray) -> None:
        """The rods ``ok`` took their step to ``target``: their shapes and unknowns become the last."""
        sh = self.sh
        self.lam[ok] = target[ok]
        self.dlam[ok] = np.minimum(1.5 * self.dlam[ok], self.most[ok])
        self.done |= ok & (self.lam >= 1.0)
        x[ok] = sh.host(sh.newton.x).get()[ok]
        for mine, now in zip(self.last, (sh.nodes.p, sh.nodes.R)):
            kept = sh.host(mine)
            shapes = kept.get()
            shapes[ok] = sh.host(now).get()[ok]
            kept.put(shapes)


def uncross(contact: Contact, loads: tuple, x0: np.ndarray, newton: dict, tolerance: float, steps: int) -> None:
    """The rods of a solve's chunk that may have crossed a rigid sphere or capsule (see the
    module) solved again along a load path (``_Path``), stiffened at every step (``tolerance``,
    ``steps``: the contact's); a rod whose path fails keeps its answer and is marked ``contact.crossed``.
    ``loads`` = (rod rows, point force rows, tensions, lengths or None): the chunk's loads, as
    ``scaled_loads`` takes them."""
    sh = contact.sh
    solid = _solid(contact)
    if not solid.any():
        return
    start = unloaded_shapes(sh, loads)
    suspect = sh.converged() & ((_core(contact, start) < CORE) & solid).any(axis=1)
    split = suspect & contact.split_mask()
    contact.crossed |= split
    rods = suspect & ~split
    if not rods.any():
        return
    answer, (iters, shots) = sh.host(sh.newton.x).get(), sh.counts()
    walk = _Path(contact, start, _steps(contact, start), rods)
    with scaled_loads(sh, *loads) as set_load:
        walk.run(set_load, x0, newton, (tolerance, steps))
    it, sn = sh.counts()
    sh.set_counts(np.where(rods, iters + it, iters), np.where(rods, shots + sn, shots))
    _solve_again(sh, answer, walk.failed, newton)  # the answer as it was, flagged
    contact.crossed |= walk.failed


def lean_along(contact: Contact, tolerance: float, steps: int, newton: dict) -> None:
    """The converged rods whose centre line reaches into a rigid sphere or capsule between two
    nodes beyond ``tolerance`` radii solved again from their answers with those obstacles pushing
    each node by the nearest point of its share of the centre line (OB_ALONG, kernels/contact.py
    ``pressed``), ALONG_SOFT times as stiff, climbed back (``Contact.climb``) and stiffened
    (``steps``: the contact's); a rod that fails, or whose way there crosses the obstacle
    (``_core``), keeps its answer. The other rods are untouched (bit for bit)."""
    sh = contact.sh
    solid = _solid(contact)
    if not solid.any():
        return
    limit = tolerance * contact.reach[:, None]
    reaching = (penetration(contact.measure_intervals()) > limit) & solid & (contact.table[..., layout.OB_ALONG] == 0)
    rods = sh.converged() & reaching.any(axis=1)
    if not rods.any():
        return
    answer, table = sh.host(sh.newton.x).get(), contact.table.copy()
    before = (wp.clone(sh.nodes.p), wp.clone(sh.nodes.R))
    contact.table[..., layout.OB_ALONG] = np.where(rods[:, None] & solid, 1.0, table[..., layout.OB_ALONG])
    contact.table[rods, :, layout.OB_STIFF] *= ALONG_SOFT  # the law's point moves: from softer, climbed back
    sh.dev.put(sh.model.obst, contact.table)
    _solve_again(sh, answer, rods, newton)
    iters, shots = sh.counts()
    contact.climb(rods & sh.converged(), table[..., layout.OB_STIFF], newton, iters, shots)
    sh.set_counts(iters, shots)
    contact.stiffen(tolerance, steps, newton, rods & sh.converged())
    failed = rods & ~(sh.converged() & ~((_core(contact, before) < CORE) & solid).any(axis=1))
    if failed.any():  # the answer as it was
        contact.table[failed] = table[failed]
        sh.dev.put(sh.model.obst, contact.table)
        _solve_again(sh, answer, failed, newton)
