"""The backbone's stiffness along s: constant per rod (the rod table), or from sections whose
radii and moduli are linear in s (Features.sections, the ``sect`` table of kernels/layout.py).

  section_of   the section holding s: the one ending there (before = 1) or starting there
  along        the stiffness, its slope and the weight per length at s in an interval of the grid
  backbone     Kse, Kbt, their s-derivatives and rho A at s in section j (tube: A = pi (ro^2 - ri^2),
               I = pi (ro^4 - ri^4) / 4, J = 2 I)
  stiffness    Kse, Kbt at s on one side of it (the rod table's without sections)
  boundary     1 where a section ends at s (before the tip), else 0

A section's end is a node of the grid (tdcr_warp/core/build.py), so an integration step lies in
one section, evaluated by the section its interval starts in, and a jump of stiffness lies at a
node, where n and m are continuous and the strains jump with the stiffness (kernels/nodes.py).
"""

import functools
import math
from types import SimpleNamespace

import warp as wp

from .layout import FE, KBT, KSE, SEC_E, SEC_END, SEC_G, SEC_RHO, SEC_RI, SEC_RO, SEC_START
from .structs import make_rows, make_structs

__all__ = ["make_backbone"]


@functools.cache
def make_backbone(dtype, dynamic: bool, sections: bool):
    vec3 = wp.types.vector(3, dtype)
    Model = make_structs(dtype, dynamic).Model
    rows = make_rows(dtype, dynamic)
    row, rvec = rows.row, rows.rvec
    pi = dtype(math.pi)
    quarter_pi = dtype(math.pi / 4.0)
    two = dtype(2.0)

    @wp.func
    def section_of(md: Model, b: int, s: dtype, before: int):
        """The section of s: the first whose end lies beyond s (before = 0), or at or beyond it
        (before = 1: a section's end belongs to it)."""
        i = row(b, md.sect)
        j = int(0)
        while j < md.n_sect - 1:
            e = md.sect[i, j, SEC_END]
            if e > s or (before != 0 and e == s):
                break
            j = j + 1
        return j

    @wp.func
    def backbone(md: Model, b: int, s: dtype, j: int):
        """Kse, Kbt, Kse', Kbt' (diagonals) and rho A at s, evaluated in section j."""
        i = row(b, md.sect)
        x = s - md.sect[i, j, SEC_START]
        ro = md.sect[i, j, SEC_RO] + md.sect[i, j, SEC_RO + 1] * x
        dro = md.sect[i, j, SEC_RO + 1]
        ri = md.sect[i, j, SEC_RI] + md.sect[i, j, SEC_RI + 1] * x
        dri = md.sect[i, j, SEC_RI + 1]
        E = md.sect[i, j, SEC_E] + md.sect[i, j, SEC_E + 1] * x
        dE = md.sect[i, j, SEC_E + 1]
        G = md.sect[i, j, SEC_G] + md.sect[i, j, SEC_G + 1] * x
        dG = md.sect[i, j, SEC_G + 1]
        rho = md.sect[i, j, SEC_RHO] + md.sect[i, j, SEC_RHO + 1] * x
        A = pi * (ro * ro - ri * ri)
        dA = two * pi * (ro * dro - ri * dri)
        ro2 = ro * ro
        ri2 = ri * ri
        I = quarter_pi * (ro2 * ro2 - ri2 * ri2)
        dI = pi * (ro2 * ro * dro - ri2 * ri * dri)
        kse = vec3(G * A, G * A, E * A)
        dkse = vec3(dG * A + G * dA, dG * A + G * dA, dE * A + E * dA)
        kbt = vec3(E * I, E * I, two * G * I)
        dkbt = vec3(dE * I + E * dI, dE * I + E * dI, two * (dG * I + G * dI))
        return kse, kbt, dkse, dkbt, rho * A

    @wp.func
    def along(md: Model, b: int, s: dtype, k: int):
        """Kse, Kbt, Kse', Kbt' at s in interval k (in the section the interval starts in), and the
        weight per length rho A g (the rod table's FE, or with sections rho A(s) times FE = g)."""
        if wp.static(sections):
            kse, kbt, dkse, dkbt, rho_a = backbone(md, b, s, section_of(md, b, md.grid[row(b, md.grid), k], 0))
            return kse, kbt, dkse, dkbt, rho_a * rvec(md, b, FE)
        return rvec(md, b, KSE), rvec(md, b, KBT), vec3(), vec3(), rvec(md, b, FE)

    @wp.func
    def stiffness(md: Model, b: int, s: dtype, before: int):
        """Kse, Kbt at s: on the side of the section ending at s (before = 1) or starting there."""
        if wp.static(sections):
            kse, kbt, dkse, dkbt, rhoa = backbone(md, b, s, section_of(md, b, s, before))
            return kse, kbt
        return rvec(md, b, KSE), rvec(md, b, KBT)

    @wp.func
    def boundary(md: Model, b: int, s: dtype):
        """1 where a section ends at s and another begins, else 0."""
        jump = int(0)
        if wp.static(sections):
            if section_of(md, b, s, 1) != section_of(md, b, s, 0):
                jump = 1
        return jump

    return SimpleNamespace(section_of=section_of, backbone=backbone, along=along, stiffness=stiffness,
                           boundary=boundary)
