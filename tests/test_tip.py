"""Constrained tips: the tip held at a point, on a plane or along a line, its reaction an output
(extra unknowns and residuals of the shooting). Checked against the propped cantilever's closed
form, against the tip forces that put a free tip where it is held (the reaction must be that
force, the shape that shape), and for bad input. (The independent SciPy reference is compared
in tests/test_scipy_tip.py.)"""

import numpy as np
import pytest

from tdcr_warp.model.robot import InputError, Robot, TipConstraint
from tdcr_warp.physics.statics import solve_static

ROD = dict(radius=0.5e-3, youngs_modulus=60e9, density=6450.0, gravity=(-9.81, 0.0, 0.0))
W = 6450.0 * np.pi * 0.5e-3**2 * 9.81
NONE = np.zeros((1, 0))


@pytest.mark.parametrize("tip", [TipConstraint("plane", point=(0, 0, 0.2), normal=(1, 0, 0)),
                                 TipConstraint("line", point=(0, 0, 0.2), direction=(0, 0, 1))])
def test_propped_cantilever_reaction(tip):
    """Weight w, the tip held on the axis' line (free to slide along it) or on the plane through
    it across the sag: the propped cantilever, R = 3 w L / 8 (the sag is L / 60: the large
    deflection terms are ~3e-4 of R)."""
    L = 0.2
    sol = solve_static(Robot(length=L, tip_constraint=tip, **ROD), NONE, nodes=40)
    assert sol.success[0]
    assert abs(sol.tip_reaction[0, 0] / (3 * W * L / 8) - 1) < 3e-4
    assert np.abs(sol.tip_reaction[0, 1:]).max() < 1e-12 and abs(sol.tip_position[0, 0]) < 1e-12
    assert sol.stability_reasons() == ["not assessed: a constrained tip (the test covers a free tip)"]


@pytest.mark.parametrize("force", [(0.3, 0.0, 0.0), (1.0, 0.5, 0.0), (3.0, 0.0, -1.0)])
def test_point_held_where_a_tip_force_puts_it(force):
    """A free cantilever (0.3 m, 1 mm) under a tip force F bends to p; held at p instead, the tip
    takes exactly F and the rod takes the same shape, from small to past 90 degrees of bending.
    Newton from the free rod fails for the larger ones (a straight step asks the near-
    inextensible rod to stretch); the spring toward p, ever stiffer, finds them."""
    base = dict(ROD, length=0.3, radius=1e-3)
    pushed = solve_static(Robot(tip_force=force, **base), NONE, nodes=100)
    held = solve_static(Robot(tip_constraint=TipConstraint("point", point=pushed.tip_position[0]), **base), NONE,
                        nodes=100)
    assert held.success[0]
    assert np.abs(held.tip_reaction[0] - force).max() < 1e-9 * max(np.abs(force))
    assert np.abs(held.positions - pushed.positions).max() < 1e-11


def test_reactions_per_rod_and_balance():
    """Per-rod held points (a batch of 3 on a plane x = x_b): each rod's base force is its weight
    plus its reaction (global force balance), to the Newton tolerance (1e-10 m of L |r|)."""
    L = 0.2
    x = np.array([0.0, -0.005, 0.01])
    tip = TipConstraint("plane", point=np.stack([x, np.zeros(3), np.full(3, L)], axis=1), normal=(1, 0, 0))
    rob = Robot(length=L, tip_constraint=tip, **ROD)
    sol = solve_static(rob, np.zeros((3, 0)), nodes=40)
    assert sol.success.all() and np.allclose(sol.tip_position[:, 0], x, atol=1e-12)
    weight = np.array([-W * L, 0.0, 0.0])
    assert np.abs(sol.base_wrench[:, :3] - (weight + sol.tip_reaction)).max() < 1e-9 * W * L


def test_bad_tip_constraints_are_refused():
    for kwargs, message in [(dict(kind="pin", point=(0, 0, 1)), "kind must be one of"),
                            (dict(kind="plane", point=(0, 0, 1)), "normal is required"),
                            (dict(kind="point", point=(0, 0, 1), normal=(1, 0, 0)), "normal is not a field"),
                            (dict(kind="line", point=(0, 0, np.inf), direction=(0, 0, 1)), "non-finite"),
                            (dict(kind="line", point=(0, 0, 1), direction=(0, 0, 0)), "must be a non-zero")]:
        with pytest.raises(InputError, match=message):
            TipConstraint(**kwargs)
    held = Robot(length=0.2, tip_constraint=TipConstraint("point", point=(0, 0, 0.2)), **ROD)
    with pytest.raises(InputError, match="constrained tip has no sensitivities"):
        solve_static(held, NONE, sensitivities=True)
    with pytest.raises(InputError, match=r"constant_curvature.*does not support a held tip \(\[tip\]\)"):
        solve_static(held, NONE, model="constant_curvature")
