"""Physics checks of the batched static solver against things nobody tuned.

Tolerances, and where they come from:
- CLOSED_FORM_TOL = 1e-9 m: RK4 on a 1.5 rad circle measured 3.3e-9 m at N = 50 and
  2.1e-10 m at N = 100 (error ~ N^-4); the test uses N = 100, 5x margin.
- BATCH_TOL = 1e-12 m: a rod in a mixed batch runs the same arithmetic as alone; the
  Newton stopping point may differ by the tolerance (1e-10 m) only if the iteration path
  differs, which it must not.
"""

import sys

import numpy as np
import pytest
from tdcr_warp.kernels import layout

import tdcr_warp as tw

CLOSED_FORM_TOL = 1e-9
BATCH_TOL = 1e-12

E, NU, R, L, RHO = 190e9, 0.3, 1e-3, 0.5, 7800.0
EI = E * np.pi * R**4 / 4


def four_tendons(**kw):
    offs = [(0.01, 0.0), (0.0, 0.01), (-0.01, 0.0), (0.0, -0.01)]
    return [tw.Tendon(offset=o, **kw) for o in offs]


def robot(**kw):
    base = dict(length=L, youngs_modulus=E, poisson_ratio=NU, radius=R, density=RHO)
    base.update(kw)
    return tw.Robot(**base)


def test_kernels_import_only_as_subpackage():
    assert "kernels" not in sys.modules, "kernels/ imported as a top-level package"


@pytest.mark.parametrize("axis", [0, 1])
def test_pure_tip_moment_gives_constant_curvature(axis):
    """n = 0 everywhere, so v = v* and the rod is an exact circle of radius EI / M."""
    theta = 1.5  # total bend angle [rad]
    M = theta * EI / L
    moment = np.zeros(3)
    moment[axis] = M
    sol = tw.solve_static(robot(tip_moment=moment), np.zeros((1, 0)), nodes=100)
    assert sol.converged.all()
    rho = EI / M
    lateral = rho * (1 - np.cos(theta))
    expect = np.array([lateral, 0.0, rho * np.sin(theta)]) if axis == 1 else \
        np.array([0.0, -lateral, rho * np.sin(theta)])
    err = np.abs(sol.tip_position[0] - expect).max()
    assert err < CLOSED_FORM_TOL, f"tip off the circle by {err:.3e} m"
    # every node on the circle, not only the tip
    s = sol.s[0]
    ang = s / rho
    lat = rho * (1 - np.cos(ang))
    exp_all = np.stack([lat if axis == 1 else 0 * s, -lat if axis == 0 else 0 * s, rho * np.sin(ang)], 1)
    assert np.abs(sol.positions[0] - exp_all).max() < CLOSED_FORM_TOL


def test_small_deflection_cantilever():
    """Tip force F: delta = F L^3 / (3 EI) + F L / (G A) (Timoshenko, shear factor 1 as in Kse)."""
    F = 1e-4
    sol = tw.solve_static(robot(tip_force=(F, 0, 0)), np.zeros((1, 0)), nodes=50)
    G = E / (2 * (1 + NU))
    delta = F * L**3 / (3 * EI) + F * L / (G * np.pi * R**2)
    rel = abs(sol.tip_position[0, 0] - delta) / delta
    # geometric nonlinearity is O((delta / L)^2) ~ 1e-6 here
    assert rel < 1e-5, f"tip deflection {sol.tip_position[0, 0]:.6e} m vs {delta:.6e} m (rel {rel:.2e})"


def _tip_error_vs_nodes(integrator, nodes_list, rob, tau):
    ref = tw.solve_static(rob, tau, nodes=1024, tol=1e-13).tip_position
    return [np.linalg.norm(tw.solve_static(rob, tau, nodes=n, integrator=integrator,
                                           tol=1e-13).tip_position - ref) for n in nodes_list]


@pytest.mark.parametrize("integrator,nodes,order,slack", [
    ("rk4", [8, 16, 32], 4.0, 0.3),
    ("euler", [64, 128, 256], 1.0, 0.1),
])
def test_convergence_order(integrator, nodes, order, slack):
    rob = robot(tendons=[tw.Tendon(offset=(0.01, 0.0)),
                         tw.Tendon(routing="helix", helix_radius=0.008, turns=0.5, phase=0.3)],
                gravity=(0.0, -9.81, 0.0))
    tau = [[2.0, 1.5]]
    errs = _tip_error_vs_nodes(integrator, nodes, rob, tau)
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all(np.abs(orders - order) < order * slack), f"{integrator}: errors {errs}, orders {orders}"


def _simpson(y, s):
    """Composite Simpson on a uniform grid with an even number of intervals."""
    h = s[1] - s[0]
    return h / 3 * (y[0] + y[-1] + 4 * y[1:-1:2].sum(0) + 2 * y[2:-1:2].sum(0))


def test_global_balance_coupled():
    """Backbone and tendons as one body: the base cut carries n(0) plus the tendon tensions,
    and balances gravity, the tip wrench and a point force (moments about the origin)."""
    tip_f = np.array([0.05, -0.02, 0.1])
    tip_m = np.array([0.0, 0.0, 0.002])
    pf = np.array([0.0, 0.08, 0.0])
    rob = robot(tendons=[tw.Tendon(offset=(0.01, 0.0)), tw.Tendon(offset=(0.0, 0.01), length=0.25),
                         tw.Tendon(routing="helix", helix_radius=0.009, turns=1.0, phase=1.0)],
                gravity=(0.0, 0.0, -9.81), tip_force=tip_f, tip_moment=tip_m,
                point_forces=[tw.PointForce(s=0.375, force=pf)])
    tau = np.array([[2.0, 1.0, 1.5]])
    sol = tw.solve_static(rob, tau, nodes=400, tol=1e-13)
    assert sol.converged.all()
    rhoAg = RHO * np.pi * R**2 * np.array([0.0, 0.0, -9.81])
    n0, m0 = sol.base_wrench[0, :3], sol.base_wrench[0, 3:]
    # tendon tangents at the base (R(0) = I): pb = u x r + r' + v
    sec = rob.section()
    v0 = n0 / sec["kse"][0] + [0, 0, 1]
    u0 = m0 / sec["kbt"][0]
    r_base, dr_base, _ = rob.tendon_routing(0.0)
    pull_f, pull_m = np.zeros(3), np.zeros(3)
    for k in range(3):
        r, dr = r_base[0, k], dr_base[0, k]
        pb = np.cross(u0, r) + dr + v0
        t = pb / np.linalg.norm(pb)
        pull_f += tau[0, k] * t
        pull_m += np.cross(r, tau[0, k] * t)
    p = sol.positions[0]
    k_pf = np.argmin(np.abs(sol.s[0] - 0.375))
    force = rhoAg * L + tip_f + pf
    moment = (_simpson(np.cross(p, rhoAg), sol.s[0]) + np.cross(p[-1], tip_f) + tip_m
              + np.cross(p[k_pf], pf))
    assert np.abs(n0 + pull_f - force).max() < 1e-9, (n0 + pull_f, force)
    assert np.abs(m0 + pull_m - moment).max() < 1e-9, (m0 + pull_m, moment)


def test_global_balance_point_model():
    """Point model: the backbone alone balances gravity, tip wrench and termination loads."""
    rob = robot(tendons=[tw.Tendon(offset=(0.01, 0.0)), tw.Tendon(offset=(0.0, -0.01), length=0.3)],
                gravity=(0.0, -9.81, 0.0))
    tau = np.array([[1.0, 0.5]])
    sol = tw.solve_static(rob, tau, nodes=400, model="point", tol=1e-13)
    assert sol.converged.all()
    rhoAg = RHO * np.pi * R**2 * np.array([0.0, -9.81, 0.0])
    force, moment = rhoAg * L, _simpson(np.cross(sol.positions[0], rhoAg), sol.s[0])
    offsets = [np.array([0.01, 0, 0]), np.array([0, -0.01, 0])]
    sec = rob.section()
    for k, lk in enumerate([0.5, 0.3]):
        j = np.argmin(np.abs(sol.s[0] - lk))
        Rj, nj, mj = sol.rotations[0, j], sol.n[0, j], sol.m[0, j]
        v = Rj.T @ nj / sec["kse"][0] + [0, 0, 1]
        u = Rj.T @ mj / sec["kbt"][0]
        pb = np.cross(u, offsets[k]) + v
        F = -tau[0, k] * Rj @ pb / np.linalg.norm(pb)
        force = force + F
        moment = moment + np.cross(sol.positions[0, j] + Rj @ offsets[k], F)
    assert np.abs(sol.base_wrench[0, :3] - force).max() < 1e-9
    assert np.abs(sol.base_wrench[0, 3:] - moment).max() < 1e-9


def test_mixed_batch_equals_each_rod_alone():
    B = 5
    rng = np.random.default_rng(3)
    per_rod = dict(
        length=rng.uniform(0.3, 0.6, B), youngs_modulus=rng.uniform(50e9, 200e9, B),
        radius=rng.uniform(0.8e-3, 1.2e-3, B), gravity=rng.normal(0, 5, (B, 3)),
        precurvature=np.c_[rng.uniform(-1, 1, B), np.zeros(B), np.zeros(B)],
    )
    tendons = [tw.Tendon(offset=np.c_[rng.uniform(0.005, 0.012, B), np.zeros(B)]),
               tw.Tendon(routing="helix", helix_radius=0.008, turns=rng.uniform(0, 1, B)),
               tw.Tendon(offset=(0.0, -0.01), length=0.2)]
    tau = rng.uniform(0, 3, (B, 3))
    batch = tw.solve_static(robot(tendons=tendons, **per_rod), tau, threads=2)
    assert batch.converged.all()
    for b in range(B):
        one = robot(tendons=[tw.Tendon(offset=tendons[0].offset[b]),
                             tw.Tendon(routing="helix", helix_radius=0.008, turns=tendons[1].turns[b]),
                             tw.Tendon(offset=(0.0, -0.01), length=0.2)],
                    **{k: v[b] for k, v in per_rod.items()})
        alone = tw.solve_static(one, tau[b:b + 1])
        err = np.abs(alone.positions[0] - batch.positions[b]).max()
        assert err < BATCH_TOL, f"rod {b}: batch differs from alone by {err:.3e} m"


def test_shared_parameter_equals_tiled():
    B = 70  # enough rods for the CPU thread split to engage
    tau = np.linspace(0, 3, B)[:, None] * [1.0, 0.0, 0.5, 0.0]
    shared = tw.solve_static(robot(tendons=four_tendons(), gravity=(0, 0, -9.81)), tau)
    tiled = tw.solve_static(robot(tendons=four_tendons(), gravity=np.tile([0, 0, -9.81], (B, 1)),
                                  youngs_modulus=np.full(B, E)), tau, threads=1)
    assert np.array_equal(shared.positions, tiled.positions)


def test_rotation_stays_orthonormal_at_large_deflection():
    rob = robot(tendons=four_tendons())
    sol = tw.solve_static(rob, [[40.0, 20.0, 0.0, 0.0]], nodes=20)
    assert sol.converged.all()
    R_tip = sol.tip_rotation[0]
    assert np.degrees(np.arccos(np.clip(R_tip[2, 2], -1, 1))) > 60, "case is not a large deflection"
    assert sol.orthogonality_error.max() < 1e-10, sol.orthogonality_error


def test_warm_start_reuses_solution_and_jacobian():
    """A warm start takes the given solution and Jacobian: no probes, only Newton's iterations
    (a cold start is as cheap now: the robot's unloaded Jacobian, made by the first solve)."""
    rob = robot(tendons=four_tendons(), gravity=(0, 0, -9.81))
    tau = np.array([[2.0, 0.5, 0.0, 0.0]] * 4)
    first = tw.solve_static(rob, tau, stability="off")
    nearby = tau + 0.01
    warm = tw.solve_static(rob, nearby, initial=first, stability="off")
    cold = tw.solve_static(rob, nearby, stability="off")
    assert warm.converged.all() and cold.converged.all()
    assert np.abs(warm.tip_position - cold.tip_position).max() < 1e-9
    assert (warm.integrations == warm.iterations).all() and (cold.integrations == cold.iterations).all()


def test_failed_rods_are_flagged_not_hidden():
    rob = robot(tendons=four_tendons(), gravity=(0, -9.81, 0))
    sol = tw.solve_static(rob, [[3.0, 1.0, 0, 0], [30.0, 0, 0, 0]], max_iter=1)
    assert not sol.converged.any()
    assert all(s & layout.MAX_ITER for s in sol.status)
    assert sol.failure_reasons()[0] == "iteration cap reached"


def test_converged_results_are_finite_and_within_tolerance():
    rng = np.random.default_rng(7)
    B = 200
    rob = robot(tendons=four_tendons(), gravity=(0, 0, -9.81),
                youngs_modulus=rng.uniform(20e9, 200e9, B))
    sol = tw.solve_static(rob, rng.uniform(0, 5, (B, 4)))
    ok = sol.converged
    assert ok.mean() > 0.99, f"only {ok.mean():.1%} converged"
    for name in ("positions", "rotations", "n", "m", "base_wrench"):
        assert np.isfinite(getattr(sol, name)[ok]).all(), name
    assert (sol.residual[ok] < 1e-10).all()


def test_float32_agrees_with_float64_within_its_precision():
    rob = robot(tendons=four_tendons(), gravity=(0, 0, -9.81))
    tau = [[3.0, 0.0, 1.0, 0.0], [1.0, 2.0, 0.0, 0.0]]
    f64 = tw.solve_static(rob, tau)
    f32 = tw.solve_static(rob, tau, precision="float32")
    assert f32.converged.all()
    err = np.abs(f32.tip_position - f64.tip_position).max()
    assert err < 1e-5, f"float32 tip off by {err:.3e} m"


@pytest.mark.parametrize("bad,match", [
    (dict(length=-1.0), "length must be positive"),
    (dict(poisson_ratio=0.5), "poisson_ratio"),
    (dict(radius=[1e-3, 0.0]), r"radius must be positive, got 0.0 \(rod 1\)"),
    (dict(youngs_modulus=np.nan), "youngs_modulus: non-finite"),
    (dict(gravity=(0, 9.81)), "gravity: expected"),
])
def test_bad_robot_fields_name_field_and_value(bad, match):
    with pytest.raises(tw.InputError, match=match):
        robot(**bad)


def test_bad_tensions_and_options():
    rob = robot(tendons=four_tendons())
    with pytest.raises(tw.InputError, match=r"tensions\[0\]\[2\].*-1.0"):
        tw.solve_static(rob, [[0, 0, -1.0, 0]])
    with pytest.raises(tw.InputError, match="shape"):
        tw.solve_static(rob, [[1.0, 0.0]])
    with pytest.raises(tw.InputError, match="integrator"):
        tw.solve_static(rob, [[1.0, 0, 0, 0]], integrator="rk45")
    with pytest.raises(tw.InputError, match=r"tendons\[0\]\.length must be <= the rod length, got 0.9"):
        robot(tendons=[tw.Tendon(offset=(0.01, 0), length=0.9)])
