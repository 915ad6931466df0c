"""Explicit Runge-Kutta steps of the rod ODE: the scheme's stages and weights, and one step over
an interval (the shooting of kernels/integration.py and the look-ahead of the spacer disks in
kernels/disks.py both step with ``interval``).

  stage_c / stage_w    where an explicit Runge-Kutta stage is evaluated and its weight
  orthonormalize       one Newton-Schulz step of R toward the nearest rotation
  orth_error           the largest entry of R^T R - I so far
  interval             one integration step over an interval (all of its stages)
"""

import functools
from types import SimpleNamespace

import warp as wp

from .rod import make_rhs
from .structs import make_structs, tendon_vectors
from .variants import STAGES, Features

__all__ = ["make_interval", "make_stages"]


@functools.cache
def make_stages(dtype, integrator: str):
    """The explicit Runge-Kutta scheme (Euler, midpoint, RK4), and keeping R a rotation."""
    zero = dtype(0.0)
    half = dtype(0.5)
    sixth = dtype(1.0 / 6.0)
    third = dtype(1.0 / 3.0)  # from Python: a literal inside a kernel would be float32
    mat33 = wp.types.matrix((3, 3), dtype)
    rk4 = integrator == "rk4"
    midpoint = integrator == "midpoint"

    @wp.func
    def stage_c(st: int):
        """Where stage st is evaluated, as a fraction of the interval."""
        if wp.static(rk4):
            return wp.where(st == 0, zero, wp.where(st == 3, dtype(1.0), half))
        if wp.static(midpoint):
            return wp.where(st == 0, zero, half)
        return zero

    @wp.func
    def stage_w(st: int):
        """The weight of stage st (RK4: 1/6, 1/3, 1/3, 1/6; midpoint: 0, 1; Euler: 1)."""
        if wp.static(rk4):
            return wp.where(st == 0 or st == 3, sixth, third)
        if wp.static(midpoint):
            return wp.where(st == 0, zero, dtype(1.0))
        return dtype(1.0)

    @wp.func
    def orthonormalize(R: mat33):
        """One Newton-Schulz step towards the nearest rotation: squares the drift."""
        return dtype(1.5) * R - dtype(0.5) * (R * (wp.transpose(R) * R))

    @wp.func
    def orth_error(R: mat33, orth: dtype):
        """max(orth, max |R^T R - I|)."""
        dev = wp.transpose(R) * R - wp.identity(3, dtype)
        for i in range(3):
            for j in range(3):
                orth = wp.max(orth, wp.abs(dev[i, j]))
        return orth

    return SimpleNamespace(stage_c=stage_c, stage_w=stage_w, orthonormalize=orthonormalize, orth_error=orth_error)


@functools.cache
def make_interval(dtype, integrator: str, model: str, dynamic: bool, rod: str, features: Features):
    """``interval``: one step of the integrator over an interval."""
    vec3 = wp.types.vector(3, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)
    K = features.tendons
    kvec, evec = tendon_vectors(dtype, K)
    st = make_structs(dtype, dynamic)
    Model, Control, Step = st.Model, st.Control, st.Step
    rhs = make_rhs(dtype, model, dynamic, rod, features).rhs
    sc = make_stages(dtype, integrator)
    stages = STAGES[integrator]

    @wp.func
    def interval(md: Model, ct: Control, sp: Step, b: int, s: dtype, h: dtype, p: vec3, R: mat33, n: vec3, m: vec3,
                 q: vec3, w: vec3, t0: kvec, E: evec, k: int, store: int):
        """The state at s + h from the state at s, the start of interval k: explicit stages, each
        from the last, y_i = y + c_i h k_(i-1), y <- y + h sum_i w_i k_i, then R orthonormalized.
        A runtime stage count keeps one call site of the right-hand side (compile time)."""
        sl = k * stages
        Ap = vec3()
        AR = mat33()
        An = vec3()
        Am = vec3()
        Aq = vec3()
        Aw = vec3()
        AE = evec()
        kE = evec()
        kp = vec3()
        kR = mat33()
        kn = vec3()
        km = vec3()
        kq = vec3()
        kw = vec3()
        for st in range(stages + 0 * k):
            ch = sc.stage_c(st) * h
            kp, kR, kn, km, kq, kw, kE = rhs(md, ct, sp, b, s + ch, p + ch * kp, R + ch * kR, n + ch * kn,
                                                m + ch * km, q + ch * kq, w + ch * kw, t0, E + ch * kE, k,
                                                sl + st, store)
            wt = sc.stage_w(st)
            Ap += wt * kp
            AR += wt * kR
            An += wt * kn
            Am += wt * km
            if wp.static(dynamic):
                Aq += wt * kq
                Aw += wt * kw
            if wp.static(K > 0):
                AE += wt * kE
        p = p + h * Ap
        R = R + h * AR
        n = n + h * An
        m = m + h * Am
        if wp.static(dynamic):
            q = q + h * Aq
            w = w + h * Aw
        if wp.static(K > 0):
            E = E + h * AE
        return p, sc.orthonormalize(R), n, m, q, w, E

    return SimpleNamespace(interval=interval)
