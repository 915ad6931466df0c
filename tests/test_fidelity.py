"""The fidelity ladder: each rung matches the next one where it should, specialised kernels
match the general one, and the a-posteriori error estimate bounds the true error."""

import numpy as np
import pytest

import tdcr_warp as tw

BASE = dict(length=0.5, youngs_modulus=190e9, poisson_ratio=0.3, radius=1e-3, density=7800.0)
X, Y = tw.Tendon(offset=(0.01, 0.0)), tw.Tendon(offset=(0.0, 0.01))


def test_kirchhoff_matches_cosserat_within_shear_and_extension():
    """Slender steel rod: the difference is the shear/extension compliance, measured 2.5e-6 m
    at 3 N (axial strain 3 N / EA = 5e-6 times L, plus shear)."""
    rob = tw.Robot(**BASE, tendons=[X, Y], gravity=(0, -9.81, 0))
    tau = [[2.0, 1.0]]
    cos = tw.solve_static(rob, tau, nodes=50, tol=1e-13)
    kir = tw.solve_static(rob, tau, nodes=50, tol=1e-13, rod="kirchhoff")
    EA = 190e9 * np.pi * 1e-6
    diff = np.abs(cos.tip_position - kir.tip_position).max()
    assert 1e-8 < diff < 3 * 3.0 / EA * 0.5, f"Kirchhoff vs Cosserat {diff:.2e} m"


def test_constant_curvature_matches_kirchhoff_exactly_and_cosserat_closely():
    rob = tw.Robot(**BASE, tendons=[X, Y])
    tau = [[2.0, 1.0]]
    cc = tw.solve_static(rob, tau, model="constant_curvature", nodes=100)
    kir = tw.solve_static(rob, tau, nodes=100, tol=1e-13, rod="kirchhoff")
    cos = tw.solve_static(rob, tau, nodes=100, tol=1e-13)
    assert np.abs(cc.positions - kir.positions).max() < 1e-10  # same arc, same nodes
    assert np.abs(cc.tip_position - cos.tip_position).max() < 5e-6


def test_constant_curvature_vs_point_load_model():
    """The point-load model treats the tendon pull as a tip force along the tip tangent: close to
    the arc for small tensions, not near the rod's buckling load (3 N here, Euler load 1.5 N)."""
    rob = tw.Robot(**BASE, tendons=[X])
    small = [[0.05]]
    cc = tw.solve_static(rob, small, model="constant_curvature").tip_position[0]
    pt = tw.solve_static(rob, small, model="point", nodes=50).tip_position[0]
    deflection = np.linalg.norm(cc - [0, 0, 0.5])
    assert np.linalg.norm(cc - pt) < 0.05 * deflection
    big = [[3.0]]
    cc = tw.solve_static(rob, big, model="constant_curvature").tip_position[0]
    pt = tw.solve_static(rob, big, model="point", nodes=50).tip_position[0]
    assert np.linalg.norm(cc - pt) > 0.5 * np.linalg.norm(cc - [0, 0, 0.5])


def test_point_and_coupled_identical_at_zero_tension():
    rob = tw.Robot(**BASE, tendons=[X, tw.Tendon(routing="helix", helix_radius=0.01, turns=0.5)],
                   gravity=(0, -9.81, 0), tip_force=(0.01, 0, 0))
    a = tw.solve_static(rob, [[0.0, 0.0]], model="point")
    b = tw.solve_static(rob, [[0.0, 0.0]], model="coupled")
    assert np.array_equal(a.positions, b.positions)


@pytest.mark.parametrize("scene", ["planar", "helix+gravity+point", "dynamic"])
def test_specialised_kernels_match_the_general_one(scene):
    if scene == "planar":
        rob, tau = tw.Robot(**BASE, tendons=[X]), [[3.0]]
    else:
        rob = tw.Robot(**BASE, tendons=[X, tw.Tendon(routing="helix", helix_radius=0.01, turns=0.5)],
                       gravity=(0, -9.81, 0), point_forces=[tw.PointForce(s=0.3, force=(0.0, 0.01, 0.0))],
                       damping_bending=(0.008,) * 3, drag=(0.01,) * 3)
        tau = [[1.0, 1.0]]
    if scene == "dynamic":
        runs = [tw.Simulator(rob, [[0.0, 0.0]], dt=0.005, nodes=20, specialize=sp).simulate(np.tile(tau, (10, 1)), 10)
                for sp in (True, False)]
        assert np.abs(runs[0].tip_position - runs[1].tip_position).max() < 1e-12
        return
    spec = tw.solve_static(rob, tau, specialize=True)
    gen = tw.solve_static(rob, tau, specialize=False)
    assert np.abs(spec.positions - gen.positions).max() < 1e-12


def test_midpoint_is_second_order():
    rob = tw.Robot(**BASE, tendons=[X, tw.Tendon(routing="helix", helix_radius=0.008, turns=0.5)],
                   gravity=(0, -9.81, 0))
    tau = [[2.0, 1.0]]
    ref = tw.solve_static(rob, tau, nodes=1024, tol=1e-13).tip_position
    errs = [np.linalg.norm(tw.solve_static(rob, tau, nodes=n, integrator="midpoint", tol=1e-13).tip_position - ref)
            for n in (16, 32, 64)]
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all(np.abs(orders - 2) < 0.3), (errs, orders)


@pytest.mark.parametrize("integrator,nodes", [("rk4", 10), ("rk4", 20), ("midpoint", 20), ("euler", 40)])
def test_error_estimate_bounds_the_true_error(integrator, nodes):
    cases = [(tw.Robot(**BASE, tendons=[X]), [3.0]),
             (tw.Robot(**BASE, tendons=[X, Y]), [2.0, 1.5]),
             (tw.Robot(**BASE, tendons=[tw.Tendon(routing="helix", helix_radius=0.01, turns=0.5), X]), [2.0, 1.0]),
             (tw.Robot(**BASE, tendons=[X], gravity=(0, -9.81, 0)), [1.0])]
    for rob, tau in cases:
        ref = tw.solve_static(rob, [tau], nodes=1024, tol=1e-13).tip_position[0]
        sol = tw.solve_static(rob, [tau], nodes=nodes, integrator=integrator, tol=1e-13, error_estimate=True)
        true = np.linalg.norm(sol.tip_position[0] - ref)
        est = sol.tip_error_estimate[0]
        assert true <= est, f"{integrator} N={nodes}: true {true:.2e} > estimate {est:.2e}"
        assert est < 20 * true + 1e-12, f"estimate {est:.2e} far above the error {true:.2e}"


def test_constant_curvature_refuses_scenes_it_cannot_model():
    rob = tw.Robot(**BASE, tendons=[X], gravity=(0, 0, -9.81))
    with pytest.raises(tw.InputError, match="constant_curvature.*gravity"):
        tw.solve_static(rob, [[1.0]], model="constant_curvature")


def test_presets_and_scene_key(tmp_path):
    from scenes import ROBOT

    from tdcr_warp.io.scene import load_scene
    assert tw.StaticOptions.preset("fast").rod == "kirchhoff"
    assert tw.StaticOptions.preset("accurate", nodes=64).nodes == 64
    with pytest.raises(tw.InputError, match="preset"):
        tw.StaticOptions.preset("fastest")
    scene = tmp_path / "s.toml"
    scene.write_text(ROBOT + """[[tendons]]
offset = [0.01, 0.0]
[actuation]
tensions = [[1.0]]
[solver]
preset = "fast"
precision = "float32"
""")
    opts = load_scene(scene).options
    assert (opts.nodes, opts.rod, opts.precision) == (10, "kirchhoff", "float32")
