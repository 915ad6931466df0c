"""A backbone whose cross-section and material vary along its length: :class:`Section` s.

Each section runs from the end of the one before (the first from the base, s = 0) to its ``end``
[m]. Its outer and inner radius, Young's and shear modulus and density are linear in s from
their value at its start to their value at its end (a taper), and may jump between sections. A
field is a number (constant in the section) or a pair (start, end). The cross-section is a tube
(a solid rod where the inner radius is 0): A = pi (ro^2 - ri^2), I = pi (ro^4 - ri^4) / 4,
J = 2 I; Kse = diag(G A, G A, E A), Kbt = diag(E I, E I, G J) (docs/physics.md, "A backbone
that varies along s").

The sections are shared by a batch of rods (every rod's length ends at the last section's end).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tdcr_warp.model.checks import InputError, real_array

__all__ = ["SEC_COLUMNS", "Section", "check_sections", "section_properties", "section_table"]

# Columns of a packed section row (kernels/layout.py SEC_*): its start and end [m], then the
# value at the start and the slope d/ds of the outer radius, inner radius, E, G and density.
SEC_COLUMNS = ("start", "end", "ro", "dro", "ri", "dri", "E", "dE", "G", "dG", "rho", "drho")


def _pair(value, name: str) -> np.ndarray:
    """A number or a (start, end) pair as (2,) float64, finite."""
    a = real_array(value, name).reshape(-1)
    if a.size == 1:
        a = np.repeat(a, 2)
    if a.size != 2:
        raise InputError(f"{name}: expected a number or a pair [at start, at end], got {np.shape(value)}")
    if not np.isfinite(a).all():
        raise InputError(f"{name}: non-finite value {a.tolist()}")
    a.flags.writeable = False
    return a


@dataclass(frozen=True)
class Section:
    """One section of the backbone: from the previous section's end (or the base) to ``end``
    [m]. radius, inner_radius [m], youngs_modulus [Pa], shear_modulus [Pa] (or poisson_ratio
    [-]: G = E / (2 (1 + nu))), density [kg/m^3]: a number, or [at its start, at its end]."""

    end: float
    radius: object
    youngs_modulus: object
    density: object
    inner_radius: object = 0.0
    poisson_ratio: object = None
    shear_modulus: object = None

    def __post_init__(self):
        end = real_array(self.end, "section end").reshape(-1)
        if end.size != 1 or not np.isfinite(end[0]) or end[0] <= 0:
            raise InputError(f"section end: expected one positive arc length [m], got {self.end!r}")
        object.__setattr__(self, "end", float(end[0]))
        for name in ("radius", "inner_radius", "youngs_modulus", "density"):
            object.__setattr__(self, name, _pair(getattr(self, name), f"section {name}"))
        if (self.poisson_ratio is None) == (self.shear_modulus is None):
            raise InputError("section: give exactly one of poisson_ratio and shear_modulus, got "
                             f"poisson_ratio = {self.poisson_ratio!r}, shear_modulus = {self.shear_modulus!r}")
        if self.poisson_ratio is not None:
            nu = _pair(self.poisson_ratio, "section poisson_ratio")
            if np.any((nu <= -1) | (nu >= 0.5)):
                raise InputError(f"section poisson_ratio must be in (-1, 0.5), got {nu.tolist()}")
            object.__setattr__(self, "poisson_ratio", nu)
        else:
            object.__setattr__(self, "shear_modulus", _pair(self.shear_modulus, "section shear_modulus"))
        self._check_ranges()

    def _check_ranges(self) -> None:
        """Positive moduli, a hollow section's wall of positive thickness, density >= 0."""
        for name, ok, what in (("youngs_modulus", self.youngs_modulus > 0, "positive"),
                               ("shear_modulus", None if self.shear_modulus is None else self.shear_modulus > 0,
                                "positive"),
                               ("inner_radius", self.inner_radius >= 0, ">= 0"),
                               ("radius", self.radius > self.inner_radius, "greater than inner_radius"),
                               ("density", self.density >= 0, ">= 0")):
            if ok is not None and not ok.all():
                raise InputError(f"section {name} must be {what}, got {getattr(self, name).tolist()}"
                                 + (f" (inner_radius {self.inner_radius.tolist()})" if name == "radius" else ""))

    @property
    def shear(self) -> np.ndarray:
        """G at the section's start and end [Pa]: given, or E / (2 (1 + nu)) at each end. (With a
        Poisson ratio, G is linear between the ends' values, as E is.)"""
        if self.shear_modulus is not None:
            return self.shear_modulus
        return self.youngs_modulus / (2.0 * (1.0 + self.poisson_ratio))


def check_sections(sections: tuple, length: np.ndarray) -> tuple:
    """``sections`` as a tuple of Section, their ends increasing, the last at every rod's length."""
    sections = tuple(sections)
    for i, sec in enumerate(sections):
        if not isinstance(sec, Section):
            raise InputError(f"sections[{i}]: expected Section, got {type(sec).__name__}")
    ends = [sec.end for sec in sections]
    for i in range(1, len(ends)):
        if ends[i] <= ends[i - 1]:
            raise InputError(f"sections[{i}].end = {ends[i]!r} m must be greater than sections[{i - 1}].end = "
                             f"{ends[i - 1]!r} m (the ends increase along the rod)")
    if sections and np.any(np.abs(length - ends[-1]) > 1e-12 * ends[-1]):
        raise InputError(f"sections[{len(ends) - 1}].end = {ends[-1]!r} m must be the rod length (length = "
                         f"{np.unique(length).tolist()} m)")
    return sections


def section_table(sections: tuple) -> np.ndarray:
    """(S, len(SEC_COLUMNS)) the packed sections (start, end, then value at the start and slope)."""
    rows = []
    start = 0.0
    for sec in sections:
        h = sec.end - start
        row = [start, sec.end]
        for pair in (sec.radius, sec.inner_radius, sec.youngs_modulus, sec.shear, sec.density):
            row += [pair[0], (pair[1] - pair[0]) / h]
        rows.append(row)
        start = sec.end
    return np.array(rows, dtype=np.float64).reshape(-1, len(SEC_COLUMNS))


def section_properties(table: np.ndarray, s) -> dict[str, np.ndarray]:
    """Host evaluation at arc lengths ``s`` (right limits at a section's start): area A, second
    moment I, Kse and Kbt diagonals (..., 3), mass per length rho A."""
    s = np.asarray(s, dtype=np.float64)
    j = np.clip(np.searchsorted(table[:, 1], s, side="right"), 0, len(table) - 1)
    row = table[j]
    x = s - row[..., 0]
    ro, ri, E, G, rho = (row[..., c] + row[..., c + 1] * x for c in (2, 4, 6, 8, 10))
    area = math.pi * (ro**2 - ri**2)
    inertia = math.pi * (ro**4 - ri**4) / 4.0
    kse = np.stack([G * area, G * area, E * area], axis=-1)
    kbt = np.stack([E * inertia, E * inertia, 2.0 * G * inertia], axis=-1)
    return {"area": area, "inertia": inertia, "kse": kse, "kbt": kbt, "rho_area": rho * area}
