"""Elastic stability of a solved static equilibrium: the Jacobi (conjugate-point) test.

A rod clamped at s = 0 with a free, loaded tip is stable when the second variation of its
energy is positive definite. For conservative loads (dead forces and gravity; tendons of
constant tension without friction, whose potential is tau times the path length) the number of
negative directions of the second variation (its index) equals the number of conjugate points
of the clamp: the arc lengths sigma in (0, L) where a Jacobi field (a solution of the
linearised equilibrium equations) that satisfies the tip's boundary condition has zero
position and rotation at sigma (the rod [sigma, L] clamped at sigma would buckle). The clamp
is the end that moves, so every crossing has the same sign (the Legendre condition: the
stiffness, and the tendons' convex path-length terms, are positive definite), and the index
counts crossings with their multiplicity (a round rod buckles in two planes at once).

The fields come from the shooting problem itself, on the device (kernels/jacobi.py): the
solution and the 6 finite-difference probes of its base wrench are integrated side by side, so
their differences are the Jacobi fields that vanish at the clamp (U(0) = 0), with U the change of
position and rotation and V the conjugate momenta: the change of the total internal force
n + sum tau t and of the total moment less half the rotation crossed with it (the term of the
rotations' second order). U^T V stays symmetric along s (the plane is Lagrangian):
``lagrangian_error`` measures it, a check of the whole construction. With P = V U^-1 and its
eigenvalues p = cot(phi), a phase phi passes a multiple of pi at each conjugate point, forwards
only; the tip, free, adds the negative eigenvalues of P(L) (the Morse index theorem for a
clamped-free interval). So, with the phases tracked node by node from the clamp as continuous
lifts, index = sum_k floor((phi_k(L) - NEUTRAL) / pi + 1/2). A phase within NEUTRAL of an
odd multiple of pi/2 at the tip is a zero mode (the elastica of a round rod turned about the
load), neutral rather than unstable. The tests hold an independent host version of the test
(tests/stability_reference.py), built the other way round from the tip's plane, and compare.

Displacement control adds the stiffness of the wires: the second variation gains sum kappa
(d ell)^2. With J the shooting Jacobian, the index is that under tension control at the same
tensions less the count of positive eigenvalues of the Schur complement of the taut tendons'
length residuals (Haynsworth inertia additivity; the complement is -(A Q^-1 A^T + c l) up to a
positive factor). Not assessed (index -1): friction (not conservative) and the point model's
tendon loads (follower forces). The disk model's chords are conservative (a tendon's energy is
its tension times the sum of its chords' lengths); with a single disk each chord runs from the
fixed base plate to it, a point load of that disk's position alone, whose stiffness jumps V at the
disk (kernels/jacobi.py, ``shear``: followed as a path of planes so that the phases move with it).
With more disks a chord's pull depends on the positions of both holes it joins, a coupling of the
fields at two disks that a sweep from the clamp leaves out: not assessed.

A rod solved in segments (multiple shooting) has its fields carried over the segments by the same
kernel (``restart_nodes``): at every node a pass reaches the probes restart from the solution and
an orthonormal basis of the fields (the same plane), at each segment's start the solution from the
solved shape.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from tdcr_warp.core.build import Tables
from tdcr_warp.core.launch import Mirror, Replay
from tdcr_warp.kernels import layout
from tdcr_warp.physics.segments import segment_bounds
from tdcr_warp.physics.sensitivity import AXIAL_STRAIN, PROBE_REL

__all__ = ["NEUTRAL", "Verdict", "restart_nodes", "wires_stabilised"]

WIRE_TOL = 1e-6  # relative size of a positive eigenvalue of the wires' Schur complement
NEUTRAL = 1e-6  # rad: a tip phase this close to an odd multiple of pi/2 is a zero mode, not unstable
# The passes of the verdict, coarse to fine: double steps where the grid allows
# (tdcr_warp.core.solver.verdict_strides), the full grid, then SUBSTEPS steps an interval. A rod
# goes on to the next pass unless its count is trusted: no phase moved more than JUMP_MAX between
# two steps (the nearest matching of the phases from step to step is unambiguous only for moves
# well under pi / 2: the full grid at N = 20 miscounted heavily loaded precurved rods whose phases
# moved 1.2-1.6 rad, experiments/verdict_passes.py) and, for double steps, a margin of at least
# REFINE_MARGIN with fields Lagrangian to within LAG_TRUST times it (their asymmetry measures the
# integration error, and the phases' with it). A rod trusted by no pass is not assessed (index -1,
# margin NaN: "the phases turn too fast for the grid"). Small moves do not show a phase that turned
# by about pi in a step, which only few steps across the rod allow: a pass takes at least MIN_STEPS
# (measured against 16 steps an interval on the same solution: with 4 steps across a rod loaded to
# 12 P_cr, 15 of 126 trusted counts were wrong, with 8 steps none, at N = 4, 8 and 20).
REFINE_MARGIN = 1e-3  # rad: the double steps' margin
LAG_TRUST = 0.1
JUMP_MAX = 0.25 * np.pi  # rad
SUBSTEPS = (2, 4, 8, 16)  # steps an interval of the passes after the full grid
MIN_STEPS = 8  # steps across the rod of a pass at least
STRIDE_ARG = 8  # the position of ``stride`` among the verdict kernel's arguments


def passes(strides: tuple[int, ...], n_int: int) -> tuple[int, ...]:
    """The verdict's passes, coarse to fine, on a grid of n_int intervals: ``strides`` (the grid's,
    tdcr_warp.core.solver.verdict_strides) then SUBSTEPS steps an interval (-m), those that take at
    least MIN_STEPS steps across the rod."""
    steps = {s: (n_int + s - 1) // s if s > 0 else -s * n_int for s in strides + tuple(-m for m in SUBSTEPS)}
    return tuple(s for s, n in steps.items() if n >= MIN_STEPS)


class Verdict:
    """The stability verdict of the rods of one Shooting ``sh`` at its solution, on the device
    (kernels/jacobi.py): its arrays allocated once and its launch recorded once and replayed
    (tdcr_warp.core.launch)."""

    def __init__(self, sh, tables: Tables, precision: str, strides: tuple[int, ...]):
        k, dev, b = sh.kern, sh.device, sh.b
        wdt = sh.dev.wdtype
        self.tables = tables
        self.mask = wp.zeros(b, dtype=int, device=dev)
        nt = k.nu + 1
        fd = self.fields = k.Fields()  # the trajectories' states and work matrices, per rod
        fd.p, fd.R, fd.n, fd.m = (wp.empty((b, nt), dtype=t, device=dev) for t in (k.vec3, k.mat33, k.vec3, k.vec3))
        fd.E = wp.empty((b, nt), dtype=k.evec, device=dev)
        fd.wk = wp.empty((b, 5, 6, 6), dtype=wdt, device=dev)  # U, V, two work matrices, a disk's jump of V
        self.index = wp.zeros(b, dtype=int, device=dev)
        self.margin = wp.zeros(b, dtype=wdt, device=dev)
        self.lag = wp.zeros(b, dtype=wdt, device=dev)
        self.jac = wp.zeros(b, dtype=k.matu, device=dev)
        self.jumps = wp.zeros(b, dtype=wdt, device=dev)
        self.restarts = wp.zeros((b, tables.grid.shape[1]), dtype=int, device=dev)
        self.host = {"restarts": Mirror(self.restarts, np.float64)}  # (set per call: the rods' segments)
        names = ("mask", "index", "margin", "lag", "jac", "jumps")
        self.host |= {name: Mirror(getattr(self, name), np.float64) for name in names}
        self.strides = passes(strides, tables.grid.shape[1] - 1)
        self.args = [sh.model, sh.control, sh.step, sh.newton.x, self.mask, wdt(PROBE_REL[precision]),
                     wdt(AXIAL_STRAIN[precision]), wdt(NEUTRAL), 1, fd, self.jac, self.index,
                     self.margin, self.lag, self.jumps, sh.nodes, self.restarts]
        self.launch = Replay(k.verdict, b, dev)

    def _run(self, mask: np.ndarray, stride: int) -> np.ndarray:
        """The verdict of the rods in ``mask`` by one pass (``stride`` intervals a step; -m: m
        steps an interval): the rods whose count that pass cannot vouch for."""
        self.host["mask"].put(mask.astype(np.int32))
        self.args[STRIDE_ARG] = stride
        self.launch(*self.args)
        # a negative count (phases that ran backwards: the Legendre condition broken by steps too
        # long for the fields, e.g. a rod under a tension of 1600 P_cr on 40 intervals) is no count
        trusted = (self.host["jumps"].get(np.float64) <= JUMP_MAX) & (self.host["index"].get(np.int64) >= 0)
        if stride >= 2:
            margin = self.host["margin"].get(np.float64)
            trusted &= (margin >= REFINE_MARGIN) & (self.host["lag"].get(np.float64) <= LAG_TRUST * margin)
        return mask & ~trusted

    def __call__(self, converged: np.ndarray, taut: np.ndarray | None, segments: np.ndarray) -> dict[str, np.ndarray]:
        """Per rod: ``stability_index`` (0 stable, -1 not converged), ``lagrangian_error``,
        ``stability_margin`` (the smallest distance [rad] of a tip phase from the boundary of
        the count; NaN where no pass could be trusted, index -1) and the shooting Jacobian
        ``unknowns_jacobian`` at x* (forward differences, over the steps of the pass that decided).
        taut (b, K) or None: the taut displaced tendons (the wires' correction, ``wires_stabilised``).
        segments (b,) int: the segments each rod was solved in (``restart_nodes``; a split rod has
        no Jacobian here: NaN)."""
        split = segments > 1
        self.host["restarts"].put(restart_nodes(segments, self.restarts.shape[1] - 1))
        todo = converged.astype(bool)
        for stride in self.strides:
            todo = self._run(todo, stride)
            if not todo.any():
                break
        index = np.where(converged & ~todo, self.host["index"].get(np.int64), -1)
        lag = np.where(converged, self.host["lag"].get(np.float64), np.nan)
        margin = np.where(converged & ~todo, self.host["margin"].get(np.float64), np.nan)
        jac = np.where(split[:, None, None], np.nan, self.host["jac"].get(np.float64))
        if taut is not None and taut.any():
            wires = wires_stabilised(jac, self.tables, taut, converged)
            index = np.where(converged & (wires >= 0) & (index >= 0), index - wires, -1)
        return {"stability_index": index, "lagrangian_error": lag, "stability_margin": margin,
                "unknowns_jacobian": jac}


def restart_nodes(segments: np.ndarray, n_int: int) -> np.ndarray:
    """(b, n_int + 1) int32, per node of a rod solved in segments (b,) > 1 (kernels/jacobi.py,
    ``restart``): 1 where the probes restart from the solution with an orthonormal basis of the
    fields (every node: fields that grow along the rod stay resolved), 2 at the later segments'
    starts, where the solution also restarts from the solved shape; 0 for the rods of single
    shooting (their fields run base to tip undisturbed)."""
    out = np.zeros((len(segments), n_int + 1), dtype=np.int32)
    for count in np.unique(segments[segments > 1]):
        rods = segments == count
        out[rods] = 1
        out[np.ix_(rods, segment_bounds(n_int, int(count))[1:-1])] = 2
    return out


def wires_stabilised(J: np.ndarray, tables: Tables, taut: np.ndarray, rods: np.ndarray) -> np.ndarray:
    """Per rod, the positive eigenvalues of the Schur complement of the taut displaced tendons'
    rows and columns in the scaled shooting Jacobian J (b, nu, nu): the unstable directions the
    wires' stiffness removes (eigenvalues above WIRE_TOL times the straight rod's slope, the
    scale of the complement: an indeterminate tension, inextensible rod and wire, has none). Rods
    outside ``rods`` (bool, b) are skipped (0); a rod whose base-wrench block of J is singular (a
    bifurcation point) gets -1: its complement, and so its verdict, is undefined."""
    disp = np.flatnonzero(tables.tmode[0] >= 0)
    j_of = 6 + tables.tmode[0, disp]
    out = np.zeros(J.shape[0], dtype=np.int64)
    slope = np.broadcast_to(tables.tendon[..., layout.T_SLACK_SLOPE], (J.shape[0], tables.tendon.shape[1]))[:, disp]
    for i in np.flatnonzero(rods & taut[:, disp].any(axis=1)):
        sel = j_of[taut[i, disp]]
        A, Bm = J[i, :6, :6], J[i, :6][:, sel]
        C, D = J[i, sel][:, :6], J[i][np.ix_(sel, sel)]
        try:
            S = D - C @ np.linalg.solve(A, Bm)
        except np.linalg.LinAlgError:
            out[i] = -1
            continue
        out[i] = int((np.linalg.eigvalsh(0.5 * (S + S.T)) > WIRE_TOL * slope[i, sel - 6].min()).sum())
    return out
