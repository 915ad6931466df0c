"""Kernel-side structs of one precision and the helpers that read the packed per-rod tables.

``make_structs(dtype, dynamic)``: Model (per-rod parameters, kernels/layout.py), Control (what
the user commands) and Step (the BDF-alpha step being solved). ``make_rows(dtype, dynamic)``:
``row`` (shared or per-rod row of a table), ``rvec`` / ``dvec`` (three columns of the rod /
dynamics table as a vector) and ``term_node`` (where a tendon ends). ``tendon_vectors``: the
per-tendon vector types.

Dynamics keeps a BDF-alpha history per *slot*: every place where the right-hand side is
evaluated (each RK stage of each interval) and both sides of every node (for the jumps).
A slot holds (v, u, q, w, v', u') in the columns SLOT_V .. SLOT_DU.
"""

import functools
from types import SimpleNamespace

import warp as wp

SLOT_V, SLOT_U, SLOT_Q, SLOT_W, SLOT_DV, SLOT_DU = 0, 1, 2, 3, 4, 5
SLOT_WIDTH = 6


def tendon_vectors(dtype, tendons: int):
    """kvec: one value per tendon; evec: the tendon states E = (Theta, ell, ell0), 3 per tendon
    (each at least of length 1: a placeholder without tendon states)."""
    return wp.types.vector(max(tendons, 1), dtype), wp.types.vector(max(3 * tendons, 1), dtype)


@functools.cache
def make_structs(dtype, dynamic: bool):
    """The kernel-side Model, Control and Step of one precision (statics or dynamics)."""
    vec3 = wp.types.vector(3, dtype)

    @wp.struct
    class Model:
        """Per-rod parameters, read-only in kernels; arrays lead with 1 (shared) or B."""

        rod: wp.array2d(dtype=dtype)  # (1|B, ROD_WIDTH)
        dyn: wp.array2d(dtype=dtype)  # (1|B, DYN_WIDTH)
        tendon: wp.array3d(dtype=dtype)  # (1|B, K, TENDON_WIDTH)
        grid: wp.array2d(dtype=dtype)  # (1|B, N+1) node arc lengths [m]
        term_node: wp.array2d(dtype=int)  # (1|B, K) node where each tendon ends
        pforce: wp.array3d(dtype=dtype)  # (1|B, P, 3) point forces [N]
        pnode: wp.array2d(dtype=int)  # (1|B, P) node of each point force
        dnext: wp.array2d(dtype=int)  # (1|B, N+1) disk model: at node 0 and each disk the next disk's node (its own at the last), else -1
        tmode: wp.array2d(dtype=int)  # (1|B, K) shooting unknown 6 + j of a displacement-controlled tendon, or -1
        route: wp.array4d(dtype=dtype)  # (1, K, S, 9) spline segments: s_i, then x and y cubic coefficients
        obst: wp.array3d(dtype=dtype)  # (1|B, O, OB_WIDTH) obstacles and the contact law (kernels/contact.py)
        tipc: wp.array2d(dtype=dtype)  # (1|B, TC_WIDTH) a constrained tip: the point and the directions held
        near: wp.array2d(dtype=int)  # (1|B, N+1) with obstacles: 1 where contact may act at a node (kernels/nodes.py)
        sect: wp.array3d(dtype=dtype)  # (1|B, S, SEC_WIDTH) with sections: the backbone along s (kernels/backbone.py)
        n_tendons: int
        n_points: int
        n_obst: int
        n_sect: int

    @wp.struct
    class Control:
        """What the user commands (tendon states: tensions of displacement-controlled tendons
        are unknowns; with friction, ``tau`` is the tension at the motor, s = 0)."""

        tau: wp.array2d(dtype=dtype)  # (B, K) tensions [N]
        avail: wp.array2d(dtype=dtype)  # (B, K) unstretched length given to a displaced tendon less its arc length [m]
        slip: wp.array2d(dtype=dtype)  # (B, K) slip direction sigma in [-1, 1] (+1: sliding toward the motor)
        stick: int  # 1: stick-slip from the previous tension profile (tau_old), every rod and tendon
        taut: wp.array2d(dtype=int)  # (B, K) displaced tendon: 1 taut (tension unknown), 0 slack (zero tension)
        tau_old: wp.array3d(dtype=dtype)  # (B, S, K) previous tension at every evaluation slot [N]
        dtau_old: wp.array3d(dtype=dtype)  # (B, S, K) its arc-length derivative [N/m]

    @wp.struct
    class Step:
        """The BDF-alpha time step being solved (statics: c0 only, never read)."""

        c0: dtype  # y_t = c0 y + y_h [1/s]
        tprof: wp.array3d(dtype=dtype)  # (B, S, 3K) friction, at every slot of the trial point: tension,
        # tau' and the slip state (+1 toward the motor, -1 away, 0 stuck)
        if dynamic:
            hist: wp.array3d(dtype=vec3)  # (B, S, SLOT_WIDTH) history y_h per slot
            ycur: wp.array3d(dtype=vec3)  # (B, S, SLOT_WIDTH) values at the trial point

    return SimpleNamespace(Model=Model, Control=Control, Step=Step)


@functools.cache
def make_rows(dtype, dynamic: bool):
    """row, rvec, dvec and term_node for the Model of one precision."""
    vec3 = wp.types.vector(3, dtype)
    Model = make_structs(dtype, dynamic).Model

    @wp.func
    def row(b: int, table: wp.array2d(dtype=dtype)):
        """The row of rod b in a table shared by the batch (1 row) or per rod (B rows): a
        compare, not an integer division (which cost ~1/3 of a coupled right-hand side)."""
        return wp.min(b, table.shape[0] - 1)

    @wp.func
    def row(b: int, table: wp.array3d(dtype=dtype)):
        return wp.min(b, table.shape[0] - 1)

    @wp.func
    def row(b: int, table: wp.array2d(dtype=int)):
        return wp.min(b, table.shape[0] - 1)

    @wp.func
    def rvec(md: Model, b: int, c: int):
        """Columns c .. c+2 of rod b's row of the rod table (layout.KSE, ...)."""
        i = row(b, md.rod)
        return vec3(md.rod[i, c], md.rod[i, c + 1], md.rod[i, c + 2])

    @wp.func
    def dvec(md: Model, b: int, c: int):
        """Columns c .. c+2 of rod b's row of the dynamics table (layout.RHOJ, ...)."""
        i = row(b, md.dyn)
        return vec3(md.dyn[i, c], md.dyn[i, c + 1], md.dyn[i, c + 2])

    @wp.func
    def term_node(md: Model, b: int, k: int):
        """The node where tendon k ends."""
        return md.term_node[row(b, md.term_node), k]

    return SimpleNamespace(row=row, rvec=rvec, dvec=dvec, term_node=term_node)
