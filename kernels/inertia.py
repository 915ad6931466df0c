"""Inertia and damping of the dynamic right-hand side [T19], in BDF-alpha form: a time derivative
is y_t = c0 y + y_h, with y_h the history of the slot being evaluated (``Step.hist``).

  inertia_loads   the velocity kinematics q', w' and the inertial (and drag) load per length
  damped_system   the strain-rate damping's share of the system for (v', u')

The damping of the strains themselves, R^T n = Kse (v - v*) + Bse v_t, is part of the
constitutive law (kernels/strains.py ``body_strains``).
Sources: [T19] Till, Aloi & Rucker 2019.
"""

import functools
from types import SimpleNamespace

import warp as wp

from .layout import BBT, BSE, DRAG, RHOA, RHOJ
from .structs import (
    SLOT_DU,
    SLOT_DV,
    SLOT_Q,
    SLOT_U,
    SLOT_V,
    SLOT_W,
    make_rows,
    make_structs,
)


@functools.cache
def make_inertia(dtype, drag: bool):
    """``drag``: square-law drag of the surrounding fluid."""
    vec3 = wp.types.vector(3, dtype)
    st = make_structs(dtype, True)
    Model, Step = st.Model, st.Step
    rows = make_rows(dtype, True)
    row, dvec = rows.row, rows.dvec

    @wp.func
    def inertia_loads(md: Model, sp: Step, b: int, slot: int, v: vec3, u: vec3, q: vec3, w: vec3, lam_n: vec3):
        """q' and w' (body-frame velocities along s) and the load terms moved to the left of
        n' = R lam_n, m' = R lam_m - p' x n: lam_n gains rho A (w x q + q_t) and the drag
        C q |q|, lam_m = w x (rho J w) + rho J w_t. Returns q', w', lam_n, lam_m."""
        rho_a = md.dyn[row(b, md.dyn), RHOA]
        rho_j = dvec(md, b, RHOJ)
        vt = sp.c0 * v + sp.hist[b, slot, SLOT_V]
        ut = sp.c0 * u + sp.hist[b, slot, SLOT_U]
        qt = sp.c0 * q + sp.hist[b, slot, SLOT_Q]
        wt = sp.c0 * w + sp.hist[b, slot, SLOT_W]
        dq = vt - wp.cross(u, q) + wp.cross(w, v)
        dw = ut - wp.cross(u, w)
        lam_n = lam_n + rho_a * (wp.cross(w, q) + qt)
        if wp.static(drag):
            lam_n = lam_n + wp.cw_mul(dvec(md, b, DRAG), wp.cw_mul(q, vec3(wp.abs(q[0]), wp.abs(q[1]),
                                                                          wp.abs(q[2]))))
        lam_m = wp.cross(w, wp.cw_mul(rho_j, w)) + wp.cw_mul(rho_j, wt)
        return dq, dw, lam_n, lam_m

    return SimpleNamespace(inertia_loads=inertia_loads)


@functools.cache
def make_damping(dtype):
    """The strain-rate damping in the system for (v', u') of the coupled model."""
    vec3 = wp.types.vector(3, dtype)
    st = make_structs(dtype, True)
    Model, Step = st.Model, st.Step
    dvec = make_rows(dtype, True).dvec

    @wp.func
    def damped_system(md: Model, sp: Step, b: int, slot: int, kse: vec3, kbt: vec3, c: vec3, d: vec3):
        """The diagonal stiffness of the (v', u') system and its right-hand side with strain-rate
        damping: Kse + c0 Bse and c - Bse v'_h (likewise Kbt, d)."""
        kse = kse + sp.c0 * dvec(md, b, BSE)
        kbt = kbt + sp.c0 * dvec(md, b, BBT)
        c = c - wp.cw_mul(dvec(md, b, BSE), sp.hist[b, slot, SLOT_DV])
        d = d - wp.cw_mul(dvec(md, b, BBT), sp.hist[b, slot, SLOT_DU])
        return kse, kbt, c, d

    return SimpleNamespace(damped_system=damped_system)
