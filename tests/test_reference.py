"""The Warp solver against the independent SciPy solver (tests/scipy_reference.py).

Tolerance: tip within 1e-6 of the tip deflection |p(L) - L e3| (relative), and within 1e-9 m.
RK4 at N = 100 has a discretisation error near 1e-12 m on these rods; the reference runs
DOP853 at rtol 1e-11. Every case is solved by both the coupled and the point-load model.
"""

import numpy as np
import pytest
from scipy_reference import solve_reference

import tdcr_warp as tw

BASE = dict(length=0.5, youngs_modulus=190e9, poisson_ratio=0.3, radius=1e-3, density=7800.0)

CASES = {
    "one tendon": dict(tendons=[dict(offset=(0.01, 0.0), tension=3.0)]),
    "one tendon + gravity": dict(tendons=[dict(offset=(0.01, 0.0), tension=3.0)], gravity=(0, 0, -9.81)),
    "two tendons": dict(tendons=[dict(offset=(0.01, 0.0), tension=2.0), dict(offset=(0.0, 0.01), tension=1.0)]),
    "lateral gravity": dict(tendons=[dict(offset=(0.01, 0.0), tension=1.0)], gravity=(0, -9.81, 0)),
    "helical tendon": dict(tendons=[dict(offset=(0.0, 0.0), helix_radius=0.01, turns=0.5, phase=0.3,
                                         tension=1.5)], gravity=(0, 0, -9.81)),
    "tip force": dict(tip_force=(0.05, -0.02, -0.1), tip_moment=(0.0, 0.0, 0.003)),
    "two sections + point force": dict(
        tendons=[dict(offset=(0.008, 0.0), length=0.25, tension=2.0), dict(offset=(0.0, 0.01), tension=1.0),
                 dict(offset=(0.0, 0.0), helix_radius=0.009, turns=1.0, tension=0.8)],
        point_forces=[dict(s=0.4, force=(0.0, 0.02, 0.01))], gravity=(0, 0, -9.81),
        precurvature=(0.5, 0.0, 0.0)),
}


def to_robot(d: dict):
    tendons = [tw.Tendon(offset=t.get("offset", (0, 0)), routing="helix" if t.get("helix_radius") else "straight",
                         helix_radius=t.get("helix_radius", 0.0), turns=t.get("turns", 0.0),
                         phase=t.get("phase", 0.0), length=t.get("length")) for t in d.get("tendons", [])]
    points = [tw.PointForce(s=p["s"], force=p["force"]) for p in d.get("point_forces", [])]
    kw = {k: d[k] for k in ("gravity", "tip_force", "tip_moment", "precurvature") if k in d}
    robot = tw.Robot(**BASE, tendons=tendons, point_forces=points, **kw)
    tensions = np.array([[t["tension"] for t in d.get("tendons", [])]])
    return robot, tensions


@pytest.mark.parametrize("model", ["coupled", "point"])
@pytest.mark.parametrize("name", list(CASES))
def test_tip_agrees_with_scipy_reference(name, model):
    d = dict(BASE, **CASES[name])
    ref = solve_reference(d, model=model)
    robot, tensions = to_robot(d)
    sol = tw.solve_static(robot, tensions, model=model, nodes=100, tol=1e-13)
    assert sol.converged.all()
    deflection = np.linalg.norm(ref["tip_position"] - [0, 0, d["length"]])
    assert deflection > 1e-4, "case does not bend the rod"
    err = np.linalg.norm(sol.tip_position[0] - ref["tip_position"])
    assert err < 1e-6 * deflection and err < 1e-9, f"{name}/{model}: tip off by {err:.2e} m ({err / deflection:.1e} rel)"
    assert np.abs(sol.tip_rotation[0] - ref["tip_rotation"]).max() < 1e-8
    assert np.abs(sol.base_wrench[0] - np.concatenate([ref["n0"], ref["m0"]])).max() < 1e-7
