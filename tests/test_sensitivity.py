"""Sensitivities from the converged shooting problem (tdcr_warp/physics/sensitivity.py): the tip
Jacobians of the commands, the tip compliance and parameter Jacobians, against closed forms of
a straight cantilever, central differences of full solves and of the independent SciPy solver."""

import numpy as np
import pytest
import scipy_reference as sr

import tdcr_warp as tw

E, NU, RB, L, RHO = 190e9, 0.3, 1e-3, 0.5, 7800.0
EI = E * np.pi * RB**4 / 4
GA = E / (2 * (1 + NU)) * np.pi * RB**2
EA = E * np.pi * RB**2
GJ = E / (2 * (1 + NU)) * np.pi * RB**4 / 2
OFF = 0.01
FOUR = [(OFF, 0.0), (0.0, OFF), (-OFF, 0.0), (0.0, -OFF)]
TIGHT = 1e-13  # full solves for central differences: L |r| below this [m]


def robot(tendons=(), **kw):
    base = dict(length=L, youngs_modulus=E, poisson_ratio=NU, radius=RB, density=RHO)
    return tw.Robot(tendons=tuple(tendons), **(base | kw))


def rel(a, b):
    return np.abs(a - b).max() / np.abs(b).max()


def cantilever_compliance() -> np.ndarray:
    """Tip compliance of a straight Cosserat cantilever (linear theory, exact for it: the
    moment is linear in s, so RK4 integrates it exactly). Pose [x, y, z, theta]: a force F_x
    bends by F L^3 / 3EI and shears by F L / GA, and tilts the tip about +y by F L^2 / 2EI;
    a moment M_y tilts by M L / EI and moves the tip by M L^2 / 2EI; axial F L / EA; torsion
    M L / GJ. Symmetric (Maxwell-Betti)."""
    C = np.zeros((6, 6))
    C[0, 0] = C[1, 1] = L**3 / (3 * EI) + L / GA
    C[2, 2] = L / EA
    C[0, 4] = C[4, 0] = L**2 / (2 * EI)
    C[1, 3] = C[3, 1] = -L**2 / (2 * EI)
    C[3, 3] = C[4, 4] = L / EI
    C[5, 5] = L / GJ
    return C


def test_compliance_of_a_straight_cantilever_is_the_closed_form():
    sol = tw.solve_static(robot(), nodes=20, sensitivities=True, tol=1e-12)
    C = sol.tip_compliance[0]
    exact = cantilever_compliance()
    assert sol.converged.all()
    for i, j in zip(*np.nonzero(exact)):  # every term, the small axial one (8e-7 m/N) too
        assert abs(C[i, j] / exact[i, j] - 1) < 1e-6, (i, j, C[i, j], exact[i, j])
    mask = exact == 0
    assert np.abs(C[mask]).max() < 1e-9 * np.abs(exact).max()
    assert np.abs(C - C.T).max() < 1e-10 * np.abs(C).max()
    # the shear term alone (8e-6 of the bending one): Cosserat less Kirchhoff
    kirch = tw.solve_static(robot(), nodes=20, sensitivities=True, tol=1e-12, rod="kirchhoff").tip_compliance[0]
    assert abs((C[0, 0] - kirch[0, 0]) / (L / GA) - 1) < 1e-3
    assert kirch[2, 2] == 0.0  # inextensible


def _central(solve, h):
    """Central difference of the tip pose [p, theta] of full solves at -h, +h."""
    lo, hi = solve(-h), solve(+h)
    assert lo.converged.all() and hi.converged.all()
    dp = (hi.tip_position - lo.tip_position) / (2 * h)
    W = np.einsum("bij,bkj->bik", hi.tip_rotation - lo.tip_rotation, 0.5 * (hi.tip_rotation + lo.tip_rotation))
    th = 0.5 * np.stack([W[:, 2, 1] - W[:, 1, 2], W[:, 0, 2] - W[:, 2, 0], W[:, 1, 0] - W[:, 0, 1]], -1) / (2 * h)
    return np.concatenate([dp, th], axis=1)


def test_tension_wrench_and_parameter_jacobians_match_central_differences_of_full_solves():
    """A bent robot under gravity, a tip load and four tendons at mixed tensions."""
    rb = robot([tw.Tendon(offset=o) for o in FOUR], gravity=(0, 0, -9.81), tip_force=(0.02, -0.01, -0.05))
    tau = np.array([[3.0, 0.5, 0.0, 1.2], [0.2, 2.0, 1.0, 0.0]])
    params = ["youngs_modulus", "tendons[0].offset[1]", "density", "radius", "tendons[0].angle"]
    opts = dict(nodes=30, tol=TIGHT)
    sol = tw.solve_static(rb, tau, sensitivities=True, parameters=params, **opts)
    assert sol.converged.all() and sol.parameter_names == tuple(params)
    for k in range(4):
        def solve(h, k=k):
            t = tau.copy()
            t[:, k] += h
            return tw.solve_static(rb, np.maximum(t, 0.0) if h < 0 and (tau[:, k] == 0).any() else t, **opts)
        if (tau[:, k] == 0).any():  # a one-sided check at tau = 0 (tensions stay >= 0)
            got = (solve(1e-4).tip_position - sol.tip_position) / 1e-4
            assert rel(sol.tip_jacobian[:, :3, k], got) < 1e-3
            continue
        assert rel(sol.tip_jacobian[:, :, k], _central(solve, 1e-4)) < 1e-6
    for i, (field, h) in enumerate((("tip_force", 1e-4), ("tip_moment", 1e-6))):
        for c in range(3):
            def solve(d, field=field, c=c):
                v = np.array(getattr(rb, field)[0])
                v[c] += d
                return tw.solve_static(tw.Robot(**{**_fields(rb), field: v}), tau, **opts)
            assert rel(sol.tip_compliance[:, :, 3 * i + c], _central(solve, h)) < 1e-6, (field, c)
    steps = {"youngs_modulus": 1e-5 * E, "tendons[0].offset[1]": 1e-6, "density": 8.0, "radius": 1e-8,
             "tendons[0].angle": 1e-4}
    for p, name in enumerate(params):
        def solve(d, name=name):
            return tw.solve_static(_set(rb, name, d), tau, **opts)
        assert rel(sol.parameter_jacobian[:, :, p], _central(solve, steps[name])) < 1e-6, name


def _fields(rb):
    return dict(length=rb.length, youngs_modulus=rb.youngs_modulus, poisson_ratio=rb.poisson_ratio,
                radius=rb.radius, density=rb.density, tendons=rb.tendons, gravity=rb.gravity,
                tip_force=rb.tip_force, tip_moment=rb.tip_moment)


def _set(rb, name, d):
    """The robot with parameter ``name`` moved by d (an independent edit of the dataclasses)."""
    from dataclasses import replace
    if name.startswith("tendons[0].offset"):
        c = int(name[-2])
        off = np.array(rb.tendons[0].offset[0])
        off[c] += d
        return replace(rb, tendons=(replace(rb.tendons[0], offset=off),) + rb.tendons[1:])
    if name == "tendons[0].angle":  # the offset turned about the backbone by d
        x, y = np.array(rb.tendons[0].offset[0])
        off = (x * np.cos(d) - y * np.sin(d), x * np.sin(d) + y * np.cos(d))
        return replace(rb, tendons=(replace(rb.tendons[0], offset=off),) + rb.tendons[1:])
    return replace(rb, **{name: getattr(rb, name) + d})


def test_displacement_jacobian_matches_central_differences():
    """Three tendons at 120 degrees under displacement control (compliant wires), one slack."""
    ang = np.array([0.0, 2.0, 4.0]) * np.pi / 3
    tend = [tw.Tendon(offset=(OFF * np.cos(a), OFF * np.sin(a)), control="displacement", compliance=2e-4,
                      pretension=0.5) for a in ang]
    rb = robot(tend, gravity=(0, 0, -9.81))
    q = np.array([[0.004, 0.001, 0.0], [0.002, -0.003, 0.001]])
    opts = dict(nodes=30, tol=TIGHT)
    sol = tw.solve_static(rb, displacements=q, sensitivities=True, **opts)
    assert sol.converged.all() and sol.slack[1, 1]
    for k in range(3):
        def solve(h, k=k):
            d = q.copy()
            d[:, k] += h
            return tw.solve_static(rb, displacements=d, **opts)
        cd = _central(solve, 1e-6)
        assert rel(sol.tip_jacobian[0, :, k], cd[0]) < 1e-6, k
        if k == 1:  # a slack tendon moves nothing
            assert np.abs(sol.tip_jacobian[1, :, k]).max() == 0 and np.abs(cd[1]).max() < 1e-9
        else:
            assert rel(sol.tip_jacobian[1, :, k], cd[1]) < 1e-6, k


def test_tension_jacobian_matches_the_scipy_reference_solver():
    """Central differences of the independent SciPy solver (tests/scipy_reference.py) on a
    helical tendon and a straight one, with gravity."""
    rb = robot([tw.Tendon(offset=(OFF, 0.0)), tw.Tendon(routing="helix", helix_radius=OFF, turns=0.5)],
               gravity=(0, 0, -9.81))
    tau = np.array([[2.0, 1.0]])
    sol = tw.solve_static(rb, tau, nodes=60, tol=TIGHT, sensitivities=True)

    def ref(t):
        tend = [dict(offset=(OFF, 0.0)), dict(helix_radius=OFF, turns=0.5)]
        d = dict(length=L, youngs_modulus=E, poisson_ratio=NU, radius=RB, density=RHO, precurvature=(0, 0, 0),
                 gravity=(0, 0, -9.81), tip_force=(0, 0, 0), tip_moment=(0, 0, 0), point_forces=[],
                 tendons=[dict(tt, tension=float(x)) for tt, x in zip(tend, t)])
        return sr.solve_reference(d)["tip_position"]

    h = 1e-4
    for k in range(2):
        e = np.eye(2)[k] * h
        cd = (ref(tau[0] + e) - ref(tau[0] - e)) / (2 * h)
        assert rel(sol.tip_jacobian[0, :3, k], cd) < 1e-6, k


def test_position_compliance_is_symmetric_for_conservative_loads():
    """Dead tip force, gravity and frictionless tendons of fixed tension are conservative (the
    tendons' potential is tau times the path length), so d p / d F is a Hessian inverse:
    symmetric at any equilibrium. Friction makes it not."""
    rb = robot([tw.Tendon(offset=o) for o in FOUR], gravity=(0, 0, -9.81), tip_force=(0.05, 0.0, -0.1))
    sol = tw.solve_static(rb, [[4.0, 1.0, 0.0, 0.5]], nodes=30, tol=1e-12, sensitivities=True)
    C = sol.tip_compliance[0, :3, :3]
    assert np.abs(C - C.T).max() < 1e-7 * np.abs(C).max()
    fr = robot([tw.Tendon(offset=o, friction=0.3) for o in FOUR], gravity=(0, 0, -9.81), tip_force=(0.05, 0.0, -0.1))
    Cf = tw.solve_static(fr, [[4.0, 1.0, 0.0, 0.5]], nodes=30, tol=1e-12, sensitivities=True).tip_compliance[0, :3, :3]
    assert np.abs(Cf - Cf.T).max() > 1e-4 * np.abs(Cf).max()


def test_unconverged_rods_get_nan_and_bad_parameters_a_clear_message():
    rb = robot([tw.Tendon(offset=(OFF, 0.0))])
    sol = tw.solve_static(rb, [[1.0], [400.0]], nodes=20, max_iter=2, continuation=0, sensitivities=True)
    assert sol.converged[0] and not sol.converged[1]
    assert np.isfinite(sol.tip_jacobian[0]).all() and np.isnan(sol.tip_jacobian[1]).all()
    for bad, words in (("stiffness", "must be one of"), ("tendons[3].offset[0]", "1 tendons"),
                       ("tip_force", "name a component"), ("tendons[0].offset[2]", "out of range"),
                       ("tendons[0].angle[0]", "is a scalar")):
        with pytest.raises(tw.InputError, match=words):
            tw.solve_static(rb, [1.0], parameters=[bad])
    with pytest.raises(tw.InputError, match="constant_curvature"):
        tw.solve_static(rb, [1.0], model="constant_curvature", sensitivities=True)
