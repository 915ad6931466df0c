"""Homotopies shared by statics and dynamics: when Newton fails (or would land on another
equilibrium) from its start, a rod is reached along a path of easier problems, each solved
from the last. Every choice is made per rod, so a rod's answer never depends on its batch
neighbours.

- ``load_continuation`` (statics): tensions and external loads scaled by lam = 1/c .. 1;
- ``holding_path`` (statics, a constrained tip): a spring to the held point, ever stiffer, then held;
- ``tension_increment`` (dynamics): tau(i-1) + lam (tau(i) - tau(i-1)) in one time step;
- ``added_damping`` (dynamics): the step of a heavily damped copy, damping + s K / c0,
  s = 1000^(1 - lam) - 1 going to 0.
"""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np
import warp as wp

from tdcr_warp.core.solver import Shooting
from tdcr_warp.kernels import layout

LARGE_LOAD = 1.5  # scaled bending load of the straight-rod start: |m(0)| L / EI + |n_xy(0)| L^2 / EI
MAX_CONTINUATION = 64
HOLDING_DECADES = 6  # a constrained tip's spring: from its first compliance down 6 decades, then held


def follow(sh: Shooting, set_load, steps: np.ndarray, mask: np.ndarray, start, newton: dict):
    """Follow a load path for the rods in ``mask``: ``set_load(lam)`` sets the problem of every
    rod at its lam (b,), rod i going through 1/steps[i], ..., 1, each solved from its last
    solution (the first from ``start``: host (b, 6) or a device array). A rod that fails on the
    way stops there, flagged. Returns the iterations and integrations each rod spent on it."""
    steps = np.maximum(np.broadcast_to(steps, mask.shape), 1)
    on_path = mask.copy()
    iters = np.zeros(sh.b, dtype=np.int64)
    shots = np.zeros(sh.b, dtype=np.int64)
    for j in range(1, int(steps[mask].max(initial=0)) + 1):
        set_load(np.minimum(j / steps, 1.0))
        sh.solve(start if j == 1 else None, mask=on_path, fresh_jacobian=j == 1, **newton)
        it, sn = sh.counts()
        iters[on_path] += it[on_path]
        shots[on_path] += sn[on_path]
        on_path &= sh.converged() & (j < steps)
        if not on_path.any():
            break
    return iters, shots


def _report(sh: Shooting, iters: np.ndarray, shots: np.ndarray) -> None:
    """The rods a path touched report its sums of iterations and integrations (``follow``'s)."""
    touched = shots > 0
    it, sn = sh.counts()
    it[touched], sn[touched] = iters[touched], shots[touched]
    sh.set_counts(it, sn)


def continuation_steps(x0: np.ndarray, minimum: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which rods need a load continuation and over how many steps, from the scaled
    straight-rod start x0 (b, nu; its first 6 are n(0), m(0)): beyond ~1.5 rad of linear
    bending Newton may land on another equilibrium (a looped cantilever under a large tip
    force); steps grow with the bending
    load and the axial compression in Euler loads (sqrt(P L^2 / EI)). Returns (finite, large,
    steps) per rod."""
    with np.errstate(all="ignore"):  # absurd inputs overflow: those rods are flagged anyway
        m, nxy = x0[:, 3:6], x0[:, :2]
        load = np.sqrt(np.add.reduce(m * m, axis=1)) + np.sqrt(np.add.reduce(nxy * nxy, axis=1))  # np.linalg.norm's sums
        compression = np.sqrt(np.abs(x0[:, 2]))
        finite = np.isfinite(load) & np.isfinite(compression)
        hard = np.where(finite, np.maximum(load, compression), 0.0)
    steps = np.minimum(np.maximum(np.ceil(hard), minimum), MAX_CONTINUATION).astype(np.int64)
    return finite, load > LARGE_LOAD, steps


@contextmanager
def scaled_loads(sh: Shooting, rod0: np.ndarray, pforce0: np.ndarray, tau: np.ndarray, lengths=None):
    """Within: ``set_load(lam)`` (b,) scales the tensions and external loads (gravity, tip wrench,
    point forces) of every rod by its lam (under displacement control, ``lengths`` = (free, avail):
    the length given to each displaced tendon goes from its straight-rod path ``free`` to
    ``avail``); afterwards the rods' own tables and command are back in place."""
    md = sh.model
    own_rod, own_pf = md.rod, md.pforce
    rod = np.array(np.broadcast_to(rod0, (sh.b, rod0.shape[1])))
    md.rod = sh.dev.array(rod)
    has_points = pforce0.shape[1] > 0
    if has_points:
        md.pforce = sh.dev.array(np.broadcast_to(pforce0, (sh.b,) + pforce0.shape[1:]))

    def set_load(lam):
        r = rod.copy()
        for c in (layout.FE, layout.TIP_F, layout.TIP_M):
            r[:, c:c + 3] *= lam[:, None]
        sh.dev.put(md.rod, r)
        if has_points:
            sh.dev.put(md.pforce, pforce0 * lam[:, None, None])
        sh.set_command(tau * lam[:, None], None if lengths is None else
                       lengths[0] + lam[:, None] * (lengths[1] - lengths[0]))

    try:
        yield set_load
    finally:
        md.rod, md.pforce = own_rod, own_pf
        sh.set_command(tau, None if lengths is None else lengths[1])


def load_continuation(sh: Shooting, loads: tuple, x0: np.ndarray, mask: np.ndarray, steps: np.ndarray,
                      newton: dict) -> None:
    """Statics: tensions and external loads of the rods in ``mask`` scaled by lam (``loads`` as
    ``scaled_loads`` takes them), from the straight-rod start scaled likewise (it is linear in the
    loads). Afterwards the rods' own tables are back in place, and their iterations and
    integrations are the sums over the path."""
    with scaled_loads(sh, *loads) as set_load:
        iters, shots = follow(sh, set_load, steps, mask, x0 * (1 / steps)[:, None], newton)
    _report(sh, iters, shots)


def unloaded_shapes(sh: Shooting, loads: tuple) -> tuple:
    """The rods' shapes with every load and tension of ``loads`` (as ``scaled_loads`` takes them)
    at zero (one integration from zero unknowns): device copies of their node positions and
    orientations (b, N+1)."""
    with scaled_loads(sh, *loads) as set_load:
        set_load(np.zeros(sh.b))
        sh.probe(np.zeros((sh.b, sh.kern.nu)), shapes=True)
    return wp.clone(sh.probe.nodes.p), wp.clone(sh.probe.nodes.R)


def holding_path(sh: Shooting, tipc: np.ndarray, compliance: np.ndarray, start: np.ndarray, mask: np.ndarray,
                 newton: dict) -> None:
    """Statics, a constrained tip: the rods in ``mask`` held first by a spring of compliance
    ``compliance`` (b,) [m/N] to the held point, its compliance then shrunk 10-fold per step
    (HOLDING_DECADES of them) and last set to 0 (held), each step from the last, the first from
    ``start`` (b, nu): a tip pulled ever harder toward its place follows the path a growing tip
    force takes it along, where a straight Newton step would ask the near-inextensible rod to
    stretch. A Jacobian at every iterate; iterations and integrations add up."""
    md = sh.model
    own = md.tipc
    table = np.array(np.broadcast_to(tipc, (sh.b, tipc.shape[1])))
    md.tipc = sh.dev.array(table)
    steps = HOLDING_DECADES + 1

    def set_compliance(lam):
        t = table.copy()
        t[:, layout.TC_COMPLIANCE] = np.where(lam < 1.0, compliance * 10.0 ** (1.0 - lam * steps), 0.0)
        sh.dev.put(md.tipc, t)

    try:
        iters, shots = follow(sh, set_compliance, np.full(sh.b, steps), mask, start, newton | {"broyden": False})
    finally:
        md.tipc = own
    _report(sh, iters, shots)


def retry(sh: Shooting, set_load, failed: np.ndarray, start, newton: dict, continuation: int) -> np.ndarray:
    """Dynamics: the homotopy along ``set_load`` in ``continuation`` steps, then 4x and 16x
    finer, for the failed rods, from ``start``; returns the rods still failing."""
    for n_sub in (continuation, 4 * continuation, 16 * continuation):
        if not (failed.any() and n_sub):
            break
        follow(sh, set_load, np.full(sh.b, n_sub), failed, start, newton)
        failed = failed & ~sh.converged()
    return failed


def tension_increment(sh: Shooting, tau_prev: np.ndarray, tau_new: np.ndarray):
    """set_load of a large tension change within one time step."""
    return lambda lam: sh.set_tensions(tau_prev + lam[:, None] * (tau_new - tau_prev))


def added_damping(sh: Shooting, scratch, dyn: np.ndarray, stiffness: np.ndarray, c0: float):
    """set_load of the damping homotopy; writes the device table ``scratch`` (b, DYN_WIDTH)."""
    def set_damping(lam):
        d = np.array(dyn)
        s = np.array([1e3 ** (1 - x) - 1 for x in lam.tolist()])  # Python's pow, as a scalar path would
        d[:, layout.BSE:layout.BBT + 3] += s[:, None] * stiffness / c0
        sh.dev.put(scratch, d)
    return set_damping
