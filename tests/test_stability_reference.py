"""The device verdict (kernels/jacobi.py: the clamp's plane, phases of V U^-1) against the
independent host version (tests/stability_reference.py: the tip's plane, eigenvalues of a
unitary tracked to the clamp) on rods nobody tuned: random tensions, dead loads around the
buckling loads, helical routing, precurvature, both rod models."""

import numpy as np
import pytest
from stability_reference import host_index

import tdcr_warp as tw

E, NU, RB, L = 190e9, 0.3, 1e-3, 0.5
EI = E * np.pi * RB**4 / 4
P_CR = np.pi**2 * EI / (4 * L**2)


def rods(kind: str, rng):
    """(robot, tensions) of one family of 24 rods."""
    B = 24
    tend = [tw.Tendon(offset=(0.01 * np.cos(a), 0.01 * np.sin(a))) for a in (0.0, 2.1, 4.2)]
    F = np.zeros((B, 3))
    F[:, 2] = -rng.uniform(0.0, 6.0, B) * P_CR  # from stable to past the second pair of Euler modes
    F[:, :2] = rng.normal(0.0, 0.02, (B, 2)) * P_CR
    kw = {"length": L, "youngs_modulus": E, "poisson_ratio": NU, "radius": RB, "density": 7800.0, "gravity": (0, 0, -9.81)}
    if kind == "helix":
        tend = [tw.Tendon(offset=(0.0, 0.0), helix_radius=0.01, turns=1.0, routing="helix"),
                tw.Tendon(offset=(0.0, 0.0), helix_radius=0.01, turns=-1.0, phase=np.pi, routing="helix")]
    if kind == "precurved":
        kw["precurvature"] = (2.0, 0.0, 0.5)
    tau = rng.uniform(0.0, 3.0, (B, len(tend)))
    return tw.Robot(tendons=tend, tip_force=F, **kw), tau


@pytest.mark.parametrize("kind,rod", [("parallel", "cosserat"), ("parallel", "kirchhoff"), ("helix", "cosserat"),
                                      ("precurved", "cosserat")])
def test_device_verdict_equals_the_independent_host_test(kind, rod):
    rng = np.random.default_rng(len(kind) * 7 + len(rod))
    robot, tau = rods(kind, rng)
    opts = {"nodes": 30, "rod": rod, "tol": 1e-12, "continuation": 0}
    sol = tw.solve_static(robot, tau, **opts)
    ref, _, margin = host_index(robot, tau, **opts)
    ok = sol.converged & (ref >= 0) & (margin > 1e-3)  # away from the boundary of a count
    assert ok.sum() >= 18
    assert set(sol.stability_index[ok].tolist()) > {0}, "the family must hold unstable rods too"
    assert (sol.stability_index[ok] == ref[ok]).all(), (sol.stability_index[ok], ref[ok])
    assert (sol.stability_margin[ok] > 0).all()
