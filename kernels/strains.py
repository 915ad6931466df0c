"""The constitutive law: strains v (shear and extension) and u (bending and torsion), body frame,
from the internal force n and moment m [RW11]; in dynamics with strain-rate damping [T19].

  body_strains  v, u from R^T n, R^T m:  R^T n = Kse (v - v*) + Bse v_t,  R^T m = Kbt (u - u*) + Bbt u_t
  strains       the same from the world-frame n, m
  store_slot    dynamics: a slot's (v, u, q, w, v', u') at the trial point, for the next history

``rod`` = "kirchhoff": inextensible and unshearable, v = v* = (0, 0, 1) (kernels/rod.py).
Sources: [RW11] Rucker & Webster 2011 (statics), [T19] Till, Aloi & Rucker 2019 (dynamics).
"""

import functools
from types import SimpleNamespace

import warp as wp

from .layout import BBT, BSE, USTAR
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
def make_strains(dtype, dynamic: bool, kirchhoff: bool):
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)
    zero = dtype(0.0)
    one = dtype(1.0)
    st = make_structs(dtype, dynamic)
    Model, Step = st.Model, st.Step
    rows = make_rows(dtype, dynamic)
    rvec, dvec = rows.rvec, rows.dvec

    @wp.func
    def body_strains(md: Model, sp: Step, b: int, kse: vec3, kbt: vec3, rtn: vec3, rtm: vec3, slot: int):
        """v, u (body frame) from the body-frame internal force R^T n and moment R^T m by the
        constitutive law with the stiffness diagonals kse, kbt at s (kernels/backbone.py); with
        strain damping in dynamics: R^T n = Kse (v - v*) + Bse v_t with v_t = c0 v + v_h (likewise u)."""
        ustar = rvec(md, b, USTAR)
        v = vec3(zero, zero, one)
        if wp.static(dynamic):
            bse = dvec(md, b, BSE)
            bbt = dvec(md, b, BBT)
            if wp.static(not kirchhoff):
                v = wp.cw_div(rtn + kse[2] * vec3(zero, zero, one) - wp.cw_mul(bse, sp.hist[b, slot, SLOT_V]),
                              kse + sp.c0 * bse)
            u = wp.cw_div(rtm + wp.cw_mul(kbt, ustar) - wp.cw_mul(bbt, sp.hist[b, slot, SLOT_U]),
                          kbt + sp.c0 * bbt)
            return v, u
        if wp.static(not kirchhoff):
            v = wp.cw_div(rtn, kse) + v
        return v, wp.cw_div(rtm, kbt) + ustar

    @wp.func
    def strains(md: Model, sp: Step, b: int, kse: vec3, kbt: vec3, R: mat33, n: vec3, m: vec3, slot: int):
        """v, u from the world-frame n, m (see ``body_strains``)."""
        return body_strains(md, sp, b, kse, kbt, wp.transpose(R) * n, wp.transpose(R) * m, slot)

    @wp.func
    def store_slot(sp: Step, b: int, slot: int, v: vec3, u: vec3, q: vec3, w: vec3, dv: vec3, du: vec3):
        """Dynamics: the values of one slot at the trial point (``Step.ycur``)."""
        if wp.static(dynamic):
            sp.ycur[b, slot, SLOT_V] = v
            sp.ycur[b, slot, SLOT_U] = u
            sp.ycur[b, slot, SLOT_Q] = q
            sp.ycur[b, slot, SLOT_W] = w
            sp.ycur[b, slot, SLOT_DV] = dv
            sp.ycur[b, slot, SLOT_DU] = du

    return SimpleNamespace(body_strains=body_strains, strains=strains, store_slot=store_slot)
