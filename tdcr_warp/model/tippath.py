"""Desired tip trajectories for the tip controller: X_d(t), its velocity and acceleration, per rod.

Shapes (each field shared by the batch or given per rod):
- ``TipPath.constant(target)``: a fixed point (velocity and acceleration 0);
- ``TipPath.circle(centre, radius, frequency, axis="z", phase=0)``: a circle about ``axis``
  through ``centre`` [m] of ``radius`` [m], ``frequency`` revolutions per second (negative:
  clockwise), starting at angle ``phase`` [rad] from the first in-plane axis;
- ``TipPath.line(start, end, speed)``: from ``start`` to ``end`` [m] at ``speed`` [m/s], then
  held at ``end``;
- ``TipPath.waypoints(times, points)``: a cubic spline through ``points`` (M, 3) or (B, M, 3) [m]
  at ``times`` (M,) [s] (strictly increasing), at rest at both ends (clamped), held before the
  first and after the last;
- ``TipPath(fn)``: any callable ``fn(t) -> (p, v, a)``, each (3,) or (B, 3).

In a scene: ``[control] path = { shape = "circle", centre = [0.0, 0.0, 0.4998], radius = 0.01,
frequency = 1.0 }`` (or ``shape = "line"`` with start, end, speed; ``shape = "waypoints"`` with
times, points), in place of ``target``.
"""

from __future__ import annotations

import numpy as np

from tdcr_warp.model.robot import InputError, real_array

__all__ = ["TipPath", "path_from_table"]

AXES = {"x": (1, 2, 0), "y": (2, 0, 1), "z": (0, 1, 2)}  # (first in-plane, second in-plane, normal)


def _vector(name: str, value) -> np.ndarray:
    a = real_array(value, name)
    if a.shape[-1:] != (3,) or a.ndim > 2 or not np.isfinite(a).all():
        raise InputError(f"{name}: expected finite [x, y, z] in m (or one per rod), got {value!r}")
    return a


def _positive(name: str, value, allow_negative: bool = False) -> np.ndarray:
    a = real_array(value, name)
    if a.ndim > 1 or not np.isfinite(a).all() or not ((a != 0) if allow_negative else (a > 0)).all():
        raise InputError(f"{name}: expected a {'non-zero' if allow_negative else 'positive'} finite number "
                         f"(or one per rod), got {value!r}")
    return a


class TipPath:
    """A desired tip trajectory: ``path(t)`` -> (p, v, a), each (B or 1, 3) [m, m/s, m/s^2]."""

    def __init__(self, fn):
        if not callable(fn):
            raise InputError(f"a tip path needs a callable fn(t) -> (p, v, a), got {fn!r}")
        self._fn = fn

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        out = self._fn(float(t))
        if not (isinstance(out, tuple) and len(out) == 3):
            raise InputError(f"tip path at t = {t}: expected (position, velocity, acceleration), got {out!r}")
        arrays = []
        for name, v in zip(("position", "velocity", "acceleration"), out):
            a = np.atleast_2d(real_array(v, f"tip path {name} at t = {t}"))
            if a.shape[-1] != 3 or a.ndim != 2 or not np.isfinite(a).all():
                raise InputError(f"tip path {name} at t = {t}: expected finite (3,) or (B, 3), got {v!r}")
            arrays.append(a)
        return tuple(arrays)

    @classmethod
    def constant(cls, target) -> "TipPath":
        p = np.atleast_2d(_vector("target", target))
        zero = np.zeros_like(p)
        return cls(lambda t: (p, zero, zero))

    @classmethod
    def circle(cls, centre, radius, frequency, axis: str = "z", phase=0.0) -> "TipPath":
        if axis not in AXES:
            raise InputError(f"circle axis must be one of {tuple(AXES)}, got {axis!r}")
        c = np.atleast_2d(_vector("centre", centre))
        r = _positive("radius", radius).reshape(-1, 1)
        w = 2 * np.pi * _positive("frequency", frequency, allow_negative=True).reshape(-1, 1)
        ph = real_array(phase, "phase").reshape(-1, 1)
        if not np.isfinite(ph).all():
            raise InputError(f"phase: expected finite numbers [rad], got {phase!r}")
        i, j, _ = AXES[axis]
        e1, e2 = np.eye(3)[i], np.eye(3)[j]

        def at(t):
            a = w * t + ph
            cos, sin = np.cos(a), np.sin(a)
            p = c + r * (cos * e1 + sin * e2)
            v = r * w * (-sin * e1 + cos * e2)
            acc = -r * w**2 * (cos * e1 + sin * e2)
            return p, v, acc
        return cls(at)

    @classmethod
    def line(cls, start, end, speed) -> "TipPath":
        p0, p1 = np.atleast_2d(_vector("start", start)), np.atleast_2d(_vector("end", end))
        s = _positive("speed", speed).reshape(-1, 1)
        d = p1 - p0
        length = np.linalg.norm(d, axis=1, keepdims=True)
        if (length == 0).any():
            raise InputError("line: start and end are the same point")
        u, T = d / length, length / s

        def at(t):
            moving = t < T
            p = np.where(moving, p0 + u * s * t, p1)
            return p, np.where(moving, u * s, 0.0), np.zeros_like(p)
        return cls(at)

    @classmethod
    def waypoints(cls, times, points) -> "TipPath":
        from scipy.interpolate import CubicSpline

        t = real_array(times, "times")
        if t.ndim != 1 or len(t) < 2 or not np.isfinite(t).all() or not (np.diff(t) > 0).all():
            raise InputError(f"times: expected at least 2 finite, strictly increasing times [s], got {times!r}")
        P = real_array(points, "points")
        if P.ndim == 2:
            P = P[None]
        if P.ndim != 3 or P.shape[1:] != (len(t), 3) or not np.isfinite(P).all():
            raise InputError(f"points: expected finite ({len(t)}, 3) or (B, {len(t)}, 3) in m, got shape {P.shape}")
        spline = CubicSpline(t, P, axis=1, bc_type="clamped")
        d1, d2 = spline.derivative(1), spline.derivative(2)

        def at(tt):
            inside = t[0] <= tt <= t[-1]
            tc = min(max(tt, t[0]), t[-1])
            p = spline(tc)
            return (p, d1(tc), d2(tc)) if inside else (p, np.zeros_like(p), np.zeros_like(p))
        return cls(at)


def path_from_table(table) -> TipPath:
    """A ``[control].path`` table of a scene as a TipPath (errors name the key)."""
    if not isinstance(table, dict):
        raise InputError(f"[control].path must be a table with a shape, got {table!r}")
    keys = {"circle": {"centre", "radius", "frequency", "axis", "phase"}, "line": {"start", "end", "speed"},
            "waypoints": {"times", "points"}}
    shape = table.get("shape")
    if shape not in keys:
        raise InputError(f"[control].path.shape must be one of {tuple(keys)}, got {shape!r}")
    args = {k: v for k, v in table.items() if k != "shape"}
    unknown = set(args) - keys[shape]
    if unknown:
        raise InputError(f"unknown key {sorted(unknown)[0]!r} in [control].path of shape {shape!r} "
                         f"(known: {', '.join(sorted(keys[shape]))})")
    try:
        return getattr(TipPath, shape)(**args)
    except TypeError as e:  # a missing argument
        raise InputError(f"[control].path ({shape}): {e}") from None
    except InputError as e:
        raise InputError(f"[control].path: {e}") from None
