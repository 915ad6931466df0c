"""The Warp solver's tendon physics (displacement control, friction, the kink switch) against
the independent SciPy solver of tests/scipy_reference.py, which was written from the equations
and shares no code with it. Tolerances: RK4 at N = 80 on these shapes is within ~1e-9 m of the
converged answer (tests/test_statics.py), the reference's integrator (rtol 1e-10) within ~1e-10."""

import numpy as np
import pytest
from scipy_reference import solve_reference

import tdcr_warp as tw

POS_TOL = 2e-8  # m
TENSION_TOL = 1e-6  # relative


def scene(control: str, mu: float, slip: float):
    """A helical tendon ending at mid-length and a straight one to the tip, a wire compliance,
    gravity and a tip force: the dict of the reference and the Warp robot with the same numbers."""
    common = dict(length=0.5, youngs_modulus=190e9, poisson_ratio=0.3, radius=1e-3, density=7800.0)
    loads = dict(gravity=(0.0, -9.81, 0.0), tip_force=(0.05, 0.0, 0.02))
    t1 = dict(offset=(0.004, 0.0), helix_radius=0.006, turns=0.75, length=0.3, friction=mu, slip=slip)
    t2 = dict(offset=(0.0, -0.01), friction=mu, slip=slip, compliance=1e-4, pretension=0.5)
    ref = dict(common, **loads, precurvature=(0, 0, 0), tip_moment=(0, 0, 0), point_forces=[],
               tendons=[dict(t1, tension=3.0), dict(t2, tension=2.0)])
    if control == "displacement":
        ref["tendons"][1].update(control="displacement", displacement=0.002)
        ref["tendons"][1].pop("tension")
    tendons = [tw.Tendon(offset=t1["offset"], routing="helix", helix_radius=0.006, turns=0.75, length=0.3,
                         friction=mu),
               tw.Tendon(offset=t2["offset"], friction=mu, compliance=1e-4, pretension=0.5, control=control)]
    return ref, tw.Robot(tendons=tendons, **common, **loads)


@pytest.mark.parametrize("control, mu, slip, model, kinks", [
    ("displacement", 0.25, 1.0, "coupled", True),
    ("displacement", 0.25, -1.0, "coupled", False),
    ("tension", 0.3, 1.0, "point", True),
])
def test_tendon_physics_agrees_with_the_scipy_reference(control, mu, slip, model, kinks):
    ref_rod, rb = scene(control, mu, slip)
    # the point model has no distributed tendon load, so no kinks: tensions do not jump either
    ref = solve_reference(ref_rod, model=model, kink_loads=kinks and model == "coupled")
    assert ref["success"]
    tau = [3.0, 2.0] if control == "tension" else [3.0, 0.0]
    q = None if control == "tension" else [0.0, 0.002]
    sol = tw.solve_static(rb, tau, displacements=q, slip=[slip, slip], nodes=80, model=model, kink_loads=kinks,
                          tol=1e-12)
    assert sol.converged.all()
    assert np.abs(sol.tip_position[0] - ref["tip_position"]).max() < POS_TOL
    for name in ("tendon_tension_base", "tendon_tension_end"):
        assert np.allclose(getattr(sol, name)[0], ref[name], rtol=TENSION_TOL, atol=1e-12), name
    # our Theta is the turning the capstan law sees: kink angles count only where kinks are modelled
    turning = ref["tendon_turning"] - (0 if kinks and model == "coupled" else ref["tendon_kink_angle"])
    assert np.allclose(sol.tendon_turning[0], turning, rtol=TENSION_TOL, atol=1e-12)
    assert np.abs(sol.tendon_free_length[0] - ref["tendon_unstretched_length"]).max() < POS_TOL
