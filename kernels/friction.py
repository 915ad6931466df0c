"""Tendon tensions along s: capstan friction and stick-slip.

  tension_of           the tension of tendon k (from the tendon states, or the command)
  tensions             the tension of every tendon at a point of state E, and tau' = g kappa + h
  blend                the C1 switch of tau' between stick and slip
  slip_state           +1 sliding toward the motor, -1 away, 0 stuck
  store_profile        the tension profile at an interval's slot (for the next stick-slip solve)
  store_node_profile   the same at a node's slot (tau' recorded as 0)

The friction load on the backbone, sum tau' t, comes with the tendon rates
(kernels/tendons.py ``tendon_rates``), where the path's turning rate kappa is known.
"""

import functools
from types import SimpleNamespace

import warp as wp

from .layout import T_MU
from .structs import make_rows, make_structs, tendon_vectors


@functools.cache
def make_tensions(dtype, dynamic: bool, tendons: int, friction: bool):
    """``tendons`` = K > 0: per-tendon states along s; ``friction``: capstan friction (else the
    tension of a tendon is the same all along it)."""
    zero = dtype(0.0)
    one = dtype(1.0)
    K = tendons
    kvec, evec = tendon_vectors(dtype, K)
    st = make_structs(dtype, dynamic)
    Model, Control = st.Model, st.Control
    row = make_rows(dtype, dynamic).row

    @wp.func
    def blend(z: dtype, width: dtype):
        """0 for z <= 0, 1 above width, a C1 smoothstep between (a step at 0 when width = 0)."""
        if width <= zero:
            return wp.where(z > zero, one, zero)
        c = wp.clamp(z / width, zero, one)
        return c * c * (dtype(3.0) - dtype(2.0) * c)

    @wp.func
    def tensions(md: Model, ct: Control, b: int, t0: kvec, E: evec, slot: int, h_step: dtype, curv: dtype):
        """Tension of every tendon at the point of state E, and its arc-length derivative as
        tau' = g kappa + h (kappa: the turning rate of the tendon path). Capstan friction: the
        tension at s is t0 exp(-sigma mu Theta(s)); with ``stick`` it is the previous profile
        tau_old clamped to the band t0 exp(-mu Theta) .. t0 exp(+mu Theta) that friction can
        hold (outside it the tendon slips: toward the motor at the lower edge, away at the
        upper one). tau' jumps where the slip front lies; so that the shooting residual stays
        continuous as the front crosses an evaluation point, the derivative (the friction load,
        not the tension) switches from stick to slip over about one interval h_step beyond the
        band's edge: a C1 blend in ln(tau_old / edge) over the width 2 h_step (|tau_old'| /
        tau_old + mu curv), curv: the rod's curvature |u| (h_step = 0: a sharp switch). Inside
        the band the tendon sticks exactly: a quasi-static step starts where the last one left
        its profile, on the band's edge, with a smooth residual."""
        tau = t0
        g = kvec()
        h = kvec()
        if wp.static(friction):
            it = row(b, md.tendon)
            for k in range(md.n_tendons):
                mu = md.tendon[it, k, T_MU]
                th = E[k]
                if ct.stick != 0:
                    lo = t0[k] * wp.exp(-mu * th)
                    hi = t0[k] * wp.exp(mu * th)
                    old = ct.tau_old[b, slot, k]
                    dold = ct.dtau_old[b, slot, k]
                    tau[k] = wp.clamp(old, lo, hi)
                    wu = wp.where(old >= hi, one, zero)
                    wl = wp.where(old <= lo, one, zero)
                    if old > zero and lo > zero:
                        width = dtype(2.0) * h_step * (wp.abs(dold) / old + mu * curv)
                        wu = blend(wp.log(old / hi), width)
                        wl = blend(wp.log(lo / old), width)
                        tot = wu + wl
                        if tot > one:
                            wu = wu / tot
                            wl = wl / tot
                    g[k] = mu * tau[k] * (wu - wl)
                    h[k] = (one - wu - wl) * dold * (tau[k] / wp.max(old, dtype(1e-30)))
                else:
                    sg = ct.slip[b, k]
                    tau[k] = t0[k] * wp.exp(-sg * mu * th)
                    g[k] = -sg * mu * tau[k]
        return tau, g, h

    @wp.func
    def tension_of(ct: Control, b: int, k: int, tau: kvec):
        """The tension of tendon k: tau[k] with tendon states, else the command."""
        if wp.static(K > 0):
            return tau[k]
        return ct.tau[b, k]

    return SimpleNamespace(blend=blend, tensions=tensions, tension_of=tension_of)


@functools.cache
def make_profiles(dtype, dynamic: bool, tendons: int):
    """What a friction solve records of its tension profile (``Step.tprof``), per evaluation slot."""
    zero = dtype(0.0)
    one = dtype(1.0)
    K = tendons
    kvec, evec = tendon_vectors(dtype, K)
    st = make_structs(dtype, dynamic)
    Model, Step = st.Model, st.Step
    row = make_rows(dtype, dynamic).row

    @wp.func
    def slip_state(md: Model, b: int, k: int, g: dtype, tau: dtype):
        """+1 sliding toward the motor (tau' = -mu kappa tau), -1 away from it, 0 stuck (the
        friction load more than half of the way to the slip branch's)."""
        ratio = g / wp.max(md.tendon[row(b, md.tendon), k, T_MU] * tau, dtype(1e-30))
        if ratio < dtype(-0.5):
            return one
        if ratio > dtype(0.5):
            return -one
        return zero

    @wp.func
    def store_profile(md: Model, sp: Step, b: int, slot: int, tau: kvec, g: kvec, h: kvec, dE: evec):
        """Tension, tau' = g kappa + h and slip state of every tendon at an interval's ``slot``."""
        for k in range(md.n_tendons):
            sp.tprof[b, slot, k] = tau[k]
            sp.tprof[b, slot, K + k] = g[k] * dE[k] + h[k]
            sp.tprof[b, slot, 2 * K + k] = slip_state(md, b, k, g[k], tau[k])

    @wp.func
    def store_node_profile(md: Model, sp: Step, b: int, slot: int, tau: kvec, g: kvec):
        """Tension and slip state of every tendon at a node's ``slot`` (tau' recorded as 0)."""
        for k in range(md.n_tendons):
            sp.tprof[b, slot, k] = tau[k]
            sp.tprof[b, slot, K + k] = zero
            sp.tprof[b, slot, 2 * K + k] = slip_state(md, b, k, g[k], tau[k])

    return SimpleNamespace(slip_state=slip_state, store_profile=store_profile, store_node_profile=store_node_profile)
