"""What surrounds the rods: rigid or compliant obstacles the backbone touches (host side).

An :class:`Obstacle` is one of

  kind         fields                                              the rod stays
  -----------  --------------------------------------------------  ------------------------------
  "plane"      point, normal                                        on the side the normal points to
  "sphere"     center, radius                                       outside
  "capsule"    start, end, radius (a cylinder with round ends)      outside
  "tube"       start, end, radius (a straight lumen)                inside, between its ends
  "bent_tube"  start, direction, toward, bend_radius, angle,        inside, along the arc
               radius (a lumen along a circular arc: it leaves
               ``start`` along ``direction``, bending toward
               ``toward`` with its centre line of radius
               ``bend_radius``, over ``angle`` rad)

A :class:`TipConstraint` holds a rod's tip at a point, on a plane or along a line (free to
rotate): the reaction force it takes is a solve's output.

Points and directions [m] are world-frame, (3,) or (B, 3); lengths and angles, a number or
(B,): a sweep may move or resize each obstacle per rod. ``stiffness`` None (default): rigid,
the solver stiffens the contact until the penetration is within tolerance
(``StaticOptions.contact_tolerance``); a number [N/m per m of rod]: a compliant obstacle
(tissue) of that penalty stiffness, solved as it is. ``damping`` [s/m] (default 0), in
dynamics: the Hunt-Crossley factor of the contact force, F = k w phi(delta) max(0, 1 + damping
d delta/dt) n (kernels/contact.py): it dissipates as the rod presses in and vanishes with the
penetration, so the force stays continuous at first touch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from tdcr_warp.kernels import layout
from tdcr_warp.model.checks import InputError, as_field, check_values

__all__ = ["KINDS", "Obstacle", "TipConstraint"]

KINDS = {"plane": ("point", "normal"), "sphere": ("center", "radius"), "capsule": ("start", "end", "radius"),
         "tube": ("start", "end", "radius"),
         "bent_tube": ("start", "direction", "toward", "bend_radius", "angle", "radius")}
CODES = {"plane": layout.PLANE, "sphere": layout.SPHERE, "capsule": layout.CAPSULE, "tube": layout.TUBE,
         "bent_tube": layout.BENT_TUBE}
VECTORS = ("point", "normal", "center", "start", "end", "direction", "toward")
SCALARS = ("radius", "bend_radius", "angle", "stiffness", "damping")


def _unit(name: str, v: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    check_values(name, norm[:, 0], norm[:, 0] > 0, "a non-zero vector (its length)")
    out = v / norm
    out.flags.writeable = False
    return out


@dataclass(frozen=True)
class Obstacle:
    """One obstacle (the module's table lists the kinds and their fields)."""

    kind: str
    point: object = None
    normal: object = None
    center: object = None
    start: object = None
    end: object = None
    direction: object = None
    toward: object = None
    radius: object = None
    bend_radius: object = None
    angle: object = None
    stiffness: object = None
    damping: object = 0.0

    def __post_init__(self):
        if self.kind not in KINDS:
            raise InputError(f"obstacle kind must be one of {tuple(KINDS)}, got {self.kind!r}")
        need = KINDS[self.kind]
        for f in fields(self):
            name, value = f.name, getattr(self, f.name)
            if name in ("kind", "stiffness", "damping"):
                continue
            if name in need and value is None:
                raise InputError(f"{self.kind} obstacle: {name} is required ({', '.join(need)})")
            if name not in need and value is not None:
                raise InputError(f"{self.kind} obstacle: {name} is not a field of it (its fields: {', '.join(need)})")
        for name in need + ("damping",) + (("stiffness",) if self.stiffness is not None else ()):
            tail = (3,) if name in VECTORS else ()
            object.__setattr__(self, name, as_field(f"{self.kind} {name}", getattr(self, name), tail))
        self._check_sizes()

    def _check_sizes(self) -> None:
        """Positive sizes, unit directions, a tube longer than zero, a bend wider than the lumen."""
        k = self.kind
        for name in ("radius", "bend_radius", "stiffness"):
            v = getattr(self, name)
            if v is not None:
                check_values(f"{k} {name}", v, v > 0, "positive")
        check_values(f"{k} damping", self.damping, self.damping >= 0, "zero or positive")
        if k == "plane":
            object.__setattr__(self, "normal", _unit(f"{k} normal", self.normal))
        if k in ("capsule", "tube"):
            span = np.linalg.norm(self.end - self.start, axis=-1)
            check_values(f"{k} end - start (its length)", span, span > 0, "positive")
        if k == "bent_tube":
            d = _unit(f"{k} direction", self.direction)
            t = self.toward - np.sum(self.toward * d, axis=-1, keepdims=True) * d
            object.__setattr__(self, "direction", d)
            object.__setattr__(self, "toward", _unit(f"{k} toward (its part across direction)", t))
            check_values(f"{k} angle", self.angle, (self.angle > 0) & (self.angle <= 2 * math.pi), "in (0, 2 pi]")
            check_values(f"{k} bend_radius", self.bend_radius, self.bend_radius > self.radius,
                         "larger than its radius")

    @property
    def rigid(self) -> bool:
        return self.stiffness is None

    def batch_fields(self, prefix: str) -> dict[str, np.ndarray]:
        """Its fields that may be given per rod, named ``prefix.field``."""
        return {f"{prefix}.{n}": getattr(self, n) for n in VECTORS + SCALARS if getattr(self, n) is not None}

    def geometry(self) -> np.ndarray:
        """(1|B, OB_STIFF) its row of the kernels' obstacle table up to the contact law."""
        cols = {layout.OB_KIND: np.full((1, 1), float(CODES[self.kind]))}
        slots = {"plane": ("point", "normal", None), "sphere": ("center", None, None),
                 "capsule": ("start", "end", None), "tube": ("start", "end", None),
                 "bent_tube": ("start", "direction", "toward")}[self.kind]
        for col, name in zip((layout.OB_A, layout.OB_B, layout.OB_C), slots):
            cols[col] = np.zeros((1, 3)) if name is None else getattr(self, name)
        for col, name in ((layout.OB_RADIUS, "radius"), (layout.OB_BEND, "bend_radius"), (layout.OB_ANGLE, "angle")):
            v = getattr(self, name)
            cols[col] = np.zeros((1, 1)) if v is None else v[:, None]
        b = max(c.shape[0] for c in cols.values())
        return np.concatenate([np.broadcast_to(cols[c], (b, cols[c].shape[1])) for c in sorted(cols)], axis=1)


TIP_KINDS = {"point": (), "plane": ("normal",), "line": ("direction",)}


@dataclass(frozen=True)
class TipConstraint:
    """The tip held at ``point`` (kind "point"), on the plane through it with unit ``normal``
    ("plane") or on the line through it along ``direction`` ("line"); each (3,) or (B, 3) [m].
    The tip is free to rotate: the constraint takes a force only, across what it leaves free."""

    kind: str
    point: object
    normal: object = None
    direction: object = None

    def __post_init__(self):
        if self.kind not in TIP_KINDS:
            raise InputError(f"tip constraint kind must be one of {tuple(TIP_KINDS)}, got {self.kind!r}")
        for name in ("normal", "direction"):
            given = getattr(self, name) is not None
            if given != (name in TIP_KINDS[self.kind]):
                raise InputError(f"tip constraint {self.kind}: {name} is {'not a field of it' if given else 'required'}")
        object.__setattr__(self, "point", as_field("tip constraint point", self.point, (3,)))
        for name in TIP_KINDS[self.kind]:
            object.__setattr__(self, name, _unit(f"tip constraint {name}", as_field(f"tip constraint {name}",
                                                                                   getattr(self, name), (3,))))

    @property
    def count(self) -> int:
        """The reaction's unknowns: 3 at a point, 2 across a line, 1 along a plane's normal."""
        return {"point": 3, "line": 2, "plane": 1}[self.kind]

    def batch_fields(self, prefix: str) -> dict[str, np.ndarray]:
        return {f"{prefix}.{n}": getattr(self, n) for n in ("point", "normal", "direction")
                if getattr(self, n) is not None}

    def table(self) -> np.ndarray:
        """(1|B, TC_WIDTH): the point, the directions held and compliance 0 (kernels/layout.py)."""
        if self.kind == "point":
            basis = np.eye(3).reshape(1, 9)
        elif self.kind == "plane":
            basis = np.concatenate([self.normal, np.zeros((len(self.normal), 6))], axis=1)
        else:
            d = self.direction
            helper = np.where(np.abs(d[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
            e1 = np.cross(d, helper)
            e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
            basis = np.concatenate([e1, np.cross(d, e1), np.zeros((len(d), 3))], axis=1)
        b = max(len(self.point), len(basis))
        return np.concatenate([np.broadcast_to(self.point, (b, 3)), np.broadcast_to(basis, (b, 9)), np.zeros((b, 1))],
                              axis=1)
