"""A backbone whose cross-section and material vary along s (tdcr_warp.model.backbone): closed forms,
convergence order, the stability verdict against a stepped column's buckling load, a soft arm under its
own weight, and the refusals (the SciPy reference: tests/test_reference.py)."""

import math

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.optimize import brentq

import tdcr_warp as tw
from scipy_reference import solve_reference
from tdcr_warp.model.robot import InputError

E, NU, RHO = 190e9, 0.3, 7800.0
NONE = np.zeros((1, 0))


def steel(end, radius, inner=0.0, youngs=E):
    return tw.Section(end=end, radius=radius, inner_radius=inner, youngs_modulus=youngs, poisson_ratio=NU,
                      density=RHO)


@pytest.mark.parametrize("rod", ["cosserat", "kirchhoff"])
def test_hollow_section_equals_solid_rod_of_equal_stiffness(rod):
    """A uniform tube (ro, ri) against a solid rod of radius sqrt(ro^2 + ri^2) and modulus E (ro^2 - ri^2) /
    (ro^2 + ri^2): equal E A, E I, G A, G J, so equal shapes; the tube's E I is E pi (ro^4 - ri^4) / 4."""
    ro, ri, L = 1e-3, 0.6e-3, 0.5
    tube = tw.Robot(length=L, sections=[steel(L, ro, ri)], tip_force=(0.02, -0.01, -0.5), gravity=(0, -9.81, 0))
    r2 = ro**2 + ri**2
    rho = RHO * (ro**2 - ri**2) / r2  # equal mass per length too
    solid = tw.Robot(length=L, radius=math.sqrt(r2), youngs_modulus=E * (ro**2 - ri**2) / r2, poisson_ratio=NU,
                     density=rho, tip_force=(0.02, -0.01, -0.5), gravity=(0, -9.81, 0))
    assert tube.section()["kbt"][0, 0] == pytest.approx(E * math.pi * (ro**4 - ri**4) / 4, rel=1e-15)
    assert tube.section()["kse"][0, 2] == pytest.approx(solid.section()["kse"][0, 2], rel=1e-14)
    a = tw.solve_static(tube, NONE, nodes=100, tol=1e-13, rod=rod)
    b = tw.solve_static(solid, NONE, nodes=100, tol=1e-13, rod=rod)
    assert a.converged.all() and b.converged.all()
    assert np.linalg.norm(a.tip_position[0] - [0, 0, L]) > 1e-2  # it bends
    assert np.abs(a.tip_position - b.tip_position).max() < 1e-12


def test_tapered_cantilever_against_linear_theory():
    """Radius linear from r0 to r1, a small tip force F across: w = F int_0^L (L - s)^2 / (E I(s)) ds
    + F int_0^L ds / (G A(s)) (bending and shear; the load keeps w / L at 4.5e-5, so the geometric
    nonlinearity, of order (w / L)^2 = 2e-9, stays below the 1e-9 asserted: measured 4e-11 in all)."""
    L, r0, r1, F = 0.4, 2e-3, 1e-3, 1e-3
    rob = tw.Robot(length=L, sections=[steel(L, (r0, r1))], tip_force=(F, 0, 0))
    sol = tw.solve_static(rob, NONE, nodes=200, tol=1e-13)
    radius = lambda s: r0 + (r1 - r0) * s / L  # noqa: E731
    G = E / (2 * (1 + NU))
    bend = quad(lambda s: (L - s)**2 / (E * math.pi * radius(s)**4 / 4), 0, L, epsabs=0, epsrel=1e-13)[0]
    shear = quad(lambda s: 1 / (G * math.pi * radius(s)**2), 0, L, epsabs=0, epsrel=1e-13)[0]
    w = F * (bend + shear)
    assert 1e-6 < w / L < 1e-4
    err = abs(sol.tip_position[0, 0] - w) / w
    assert err < 1e-9, err


def jump_arcs(M, L, a, EI1, EI2):
    """The tip of a rod bent by a tip moment M about y: arcs of curvature M / EI1 on [0, a] and
    M / EI2 on [a, L], tangent continuous (x, z plane)."""
    k1, k2 = M / EI1, M / EI2
    t1 = k1 * a
    p1 = np.array([1 - math.cos(t1), 0, math.sin(t1)]) / k1
    t2 = t1 + k2 * (L - a)
    return p1 + np.array([math.cos(t1) - math.cos(t2), 0, math.sin(t2) - math.sin(t1)]) / k2


@pytest.mark.parametrize("rod", ["cosserat", "kirchhoff"])
def test_stiffness_jump_under_tip_moment_gives_exact_arcs(rod):
    """A jump of radius and modulus at mid-length under a tip moment: n = 0, so each piece is an exact
    arc of curvature M / EI; the tip to 1e-9 m."""
    L, a, M = 0.5, 0.25, 0.05
    secs = [steel(a, 1.2e-3), steel(L, 0.9e-3, 0.4e-3, youngs=70e9)]
    rob = tw.Robot(length=L, sections=secs, tip_moment=(0, M, 0))
    sol = tw.solve_static(rob, NONE, nodes=100, tol=1e-13, rod=rod)
    EI1 = E * math.pi * 1.2e-3**4 / 4
    EI2 = 70e9 * math.pi * (0.9e-3**4 - 0.4e-3**4) / 4
    tip = jump_arcs(M, L, a, EI1, EI2)
    assert M * L / EI2 > 0.5  # a large bend
    assert np.abs(sol.tip_position[0] - tip).max() < 1e-9, sol.tip_position[0] - tip


TENDON_ROBOT = dict(length=0.5, sections=[steel(0.3, (1.2e-3, 0.9e-3), (0.5e-3, 0.3e-3)),
                                          steel(0.5, (0.7e-3, 0.5e-3), youngs=60e9)],
                    tendons=[tw.Tendon(offset=(0.008, 0.0)), tw.Tendon(offset=(0.0, 0.006), length=0.4)],
                    gravity=(0, -9.81, 0))


SCIPY_ROD = dict(length=0.5, gravity=(0, -9.81, 0),
                 sections=[dict(end=0.3, radius=[1.2e-3, 0.9e-3], inner_radius=[0.5e-3, 0.3e-3], youngs_modulus=E,
                                poisson_ratio=NU, density=RHO),
                           dict(end=0.5, radius=[0.7e-3, 0.5e-3], youngs_modulus=60e9, poisson_ratio=NU, density=RHO)],
                 tendons=[dict(offset=(0.008, 0.0), tension=1.5), dict(offset=(0.0, 0.006), length=0.4, tension=0.8)])


@pytest.mark.parametrize("model", ["coupled", "point"])
def test_tendon_driven_tapered_hollow_jump_against_scipy_reference(model):
    """TENDON_ROBOT (a tapered tube, then a thinner solid taper of another modulus, two tendons, gravity
    across) against the independent SciPy solver (tests/scipy_reference.py, DOP853 at rtol 1e-12): the tip
    within 1e-8 m at 100 nodes (measured 2e-10 m coupled, 6e-9 m point). In the coupled model the tendon
    going on through the jump kinks there (a point load on the backbone, in both solvers)."""
    ref = solve_reference(SCIPY_ROD, model=model)
    assert ref["success"]
    if model == "coupled":
        angles = [k["angle"] for k in ref["kinks"] if abs(k["s"] - 0.3) < 1e-12]
        assert len(angles) == 2 and min(angles) > 5e-5, angles  # both tendons kink at the jump (~1e-4 rad)
    sol = tw.solve_static(tw.Robot(**TENDON_ROBOT), [[1.5, 0.8]], model=model, nodes=100, tol=1e-13)
    assert sol.converged.all()
    assert np.linalg.norm(ref["tip_position"] - [0, 0, 0.5]) > 1e-2
    assert np.linalg.norm(sol.tip_position[0] - ref["tip_position"]) < 1e-8
    assert np.abs(sol.base_wrench[0] - np.concatenate([ref["n0"], ref["m0"]])).max() < 1e-6


def test_rk4_keeps_fourth_order_with_nodes_on_section_ends():
    """Taper, a hollow base, a jump at s = 0.3 (a node) and two tendons: the tip error of RK4 falls
    16-fold per halving of the step (orders within 0.3 of 4)."""
    rob = tw.Robot(**TENDON_ROBOT)
    tau = [[1.5, 0.8]]
    ref = tw.solve_static(rob, tau, nodes=1024, tol=1e-13).tip_position[0]
    errs = [np.linalg.norm(tw.solve_static(rob, tau, nodes=n, tol=1e-13).tip_position[0] - ref)
            for n in (10, 20, 40)]
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all(np.abs(orders - 4) < 0.3), (errs, orders)


def test_float32_agrees_with_float64_within_its_precision():
    """float32 finds the section ends among the nodes too (both rounded alike): the tip within 1e-5 m, the
    bound test_statics.py sets for a constant rod."""
    rob = tw.Robot(**TENDON_ROBOT)
    f64 = tw.solve_static(rob, [[1.5, 0.8]], nodes=100)
    f32 = tw.solve_static(rob, [[1.5, 0.8]], nodes=100, precision="float32")
    assert f32.converged.all()
    assert np.linalg.norm(f32.tip_position - f64.tip_position) < 1e-5


def stepped_critical_load(EI1, EI2, a, b):
    """The buckling load of a cantilever, EI1 on the base's a, EI2 on the tip's b, under a dead axial tip
    load: tan(k1 a) tan(k2 b) = k2 / k1, k_i = sqrt(P / EI_i), the least root."""
    def f(P):
        k1, k2 = math.sqrt(P / EI1), math.sqrt(P / EI2)
        return math.tan(k1 * a) * math.tan(k2 * b) - k2 / k1
    hi = min((math.pi / 2 / a)**2 * EI1, (math.pi / 2 / b)**2 * EI2) * (1 - 1e-9)  # before the first pole
    return brentq(f, 1e-9 * hi, hi, xtol=1e-14, rtol=1e-14)


@pytest.mark.parametrize("factor,index", [(0.999, 0), (1.001, 2)])
def test_verdict_finds_the_stepped_columns_buckling_load(factor, index):
    """A straight stepped column under an axial tip load 0.1% below its buckling load is stable, 0.1% above
    it unstable in both bending directions (the verdict's Jacobi fields run the varying stiffness; shear and
    stretch move the Cosserat rod's load by ~(r / L)^2, far less)."""
    L, a = 0.5, 0.2
    EI1, EI2 = E * math.pi * 1.5e-3**4 / 4, E * math.pi * 0.8e-3**4 / 4
    P = factor * stepped_critical_load(EI1, EI2, a, L - a)
    rob = tw.Robot(length=L, sections=[steel(a, 1.5e-3), steel(L, 0.8e-3)], tip_force=(0, 0, -P))
    sol = tw.solve_static(rob, NONE, nodes=100, tol=1e-13)
    assert sol.converged.all()
    assert sol.stability_index.tolist() == [index], sol.stability_reasons()


def test_soft_tapered_arm_sags_under_its_weight_to_a_stable_equilibrium():
    """A silicone arm (E = 1 MPa, radius 10 to 5 mm, 0.2 m, 1100 kg/m^3) held horizontal by its clamp,
    gravity across it: the default solve converges to a stable equilibrium, sagging far, and the base
    carries the whole weight: n(0) = m g, m = pi rho L (r0^2 + r0 r1 + r1^2) / 3 (to RK4's error at the
    default grid, 2e-8 of it: the stages' R are not quite rotations, and R R^T g enters n'; a uniform rod's
    is 6e-8)."""
    L, r0, r1, rho = 0.2, 10e-3, 5e-3, 1100.0
    g = np.array([-9.81, 0, 0])
    sec = tw.Section(end=L, radius=(r0, r1), youngs_modulus=1e6, poisson_ratio=0.45, density=rho)
    sol = tw.solve_static(tw.Robot(length=L, sections=[sec], gravity=g), NONE)
    assert sol.converged.all() and sol.stable.all(), sol.stability_reasons()
    assert sol.tip_position[0, 0] < -0.05  # a sag of a quarter of the length or more
    mass = math.pi * rho * L * (r0**2 + r0 * r1 + r1**2) / 3
    assert np.abs(sol.base_wrench[0, :3] - mass * g).max() < 1e-7 * mass * 9.81


def test_weight_of_a_later_section_counts():
    """A weightless first section (density 0) and a heavy second one under gravity across: the base carries
    the second section's weight (gravity compiles in where any section has a density)."""
    secs = [tw.Section(end=0.25, radius=1e-3, youngs_modulus=E, poisson_ratio=NU, density=0.0), steel(0.5, 1e-3)]
    sol = tw.solve_static(tw.Robot(length=0.5, sections=secs, gravity=(0, -9.81, 0)), NONE, tol=1e-13)
    weight = RHO * math.pi * 1e-3**2 * 0.25 * 9.81
    assert sol.converged.all()
    assert abs(sol.base_wrench[0, 1] + weight) < 1e-7 * weight


def test_sections_checked():
    """Bad sections are InputErrors naming the field and the value."""
    with pytest.raises(InputError, match=r"section radius must be greater than inner_radius, got \[0.001, 0.001\]"):
        tw.Section(end=0.5, radius=1e-3, inner_radius=1e-3, youngs_modulus=E, poisson_ratio=NU, density=RHO)
    with pytest.raises(InputError, match=r"section youngs_modulus must be positive, got \[-1.0, -1.0\]"):
        tw.Section(end=0.5, radius=1e-3, youngs_modulus=-1.0, poisson_ratio=NU, density=RHO)
    with pytest.raises(InputError, match=r"sections\[1\].end = 0.2 m must be greater than sections\[0\].end = 0.3"):
        tw.Robot(length=0.5, sections=[steel(0.3, 1e-3), steel(0.2, 1e-3), steel(0.5, 1e-3)])
    with pytest.raises(InputError, match=r"sections\[1\].end = 0.4 m must be the rod length"):
        tw.Robot(length=0.5, sections=[steel(0.3, 1e-3), steel(0.4, 1e-3)])
    with pytest.raises(InputError, match=r"radius = 0.002 with sections"):
        tw.Robot(length=0.5, radius=2e-3, sections=[steel(0.5, 1e-3)])
    with pytest.raises(InputError, match="exactly one of poisson_ratio and shear_modulus"):
        tw.Section(end=0.5, radius=1e-3, youngs_modulus=E, density=RHO)


REFUSED = {
    "friction": (dict(tendons=[tw.Tendon(offset=(0.005, 0), friction=0.1)]), {}, r"friction \(tendons\[0\]"),
    "displacement": (dict(tendons=[tw.Tendon(offset=(0.005, 0), control="displacement")]), {},
                     "displacement control"),
    "obstacles": (dict(obstacles=[tw.Obstacle(kind="plane", point=(0.01, 0, 0), normal=(-1, 0, 0))]), {},
                  "obstacles"),
    "held tip": (dict(tip_constraint=tw.TipConstraint(kind="point", point=(0, 0, 0.5))), {}, r"a held tip"),
    "disks": (dict(tendons=[tw.Tendon(offset=(0.005, 0))], disks=4), dict(model="disks"), 'model = "disks"'),
    "constant curvature": (dict(tendons=[tw.Tendon(offset=(0.005, 0))]), dict(model="constant_curvature"),
                           'model = "constant_curvature"'),
    "sensitivities": (dict(tendons=[tw.Tendon(offset=(0.005, 0))]), dict(sensitivities=True), "sensitivities"),
    "stable branch": (dict(tendons=[tw.Tendon(offset=(0.005, 0))]), dict(stability="stable"), "stable-branch"),
    "segments": ({}, dict(segments=2), "sections"),
}


@pytest.mark.parametrize("name", list(REFUSED))
def test_unsupported_combinations_refused(name):
    kw, opts, match = REFUSED[name]
    rob = tw.Robot(length=0.5, sections=[steel(0.25, 1e-3), steel(0.5, 0.8e-3)], **kw)
    tau = np.zeros((1, rob.n_tendons))
    with pytest.raises(InputError, match=match):
        tw.solve_static(rob, None if name == "displacement" else tau,
                        displacements=[[0.0]] if name == "displacement" else None, **opts)


def test_dynamics_refused():
    rob = tw.Robot(length=0.5, sections=[steel(0.5, 1e-3)])
    with pytest.raises(InputError, match=r"not with dynamics"):
        tw.Simulator(rob, dt=1e-3)


SCENE = """
[robot]
length = 0.2

[[sections]]
end = 0.1
radius = [0.01, 0.0075]
youngs_modulus = 1e6
poisson_ratio = 0.45
density = 1100

[[sections]]
end = 0.2
radius = [0.0075, 0.005]
inner_radius = 0.002
youngs_modulus = 1.5e6
shear_modulus = 0.5e6
density = 1100

[loads]
gravity = [-9.81, 0, 0]

[actuation]
tensions = [0.3]

[[tendons]]
offset = [0.004, 0.0]
"""


def test_scene_sections(tmp_path):
    """[[sections]] read into Robot.sections (a number is constant, a pair linear); [robot]'s four backbone keys
    are refused beside them and required without them; a bad section is named by its table."""
    from tdcr_warp.io.scene import load_scene

    path = tmp_path / "arm.toml"
    path.write_text(SCENE)
    rob = load_scene(path).robot
    assert [s.end for s in rob.sections] == [0.1, 0.2]
    assert rob.sections[0].radius.tolist() == [0.01, 0.0075] and rob.sections[1].inner_radius.tolist() == [0.002] * 2
    assert rob.radius.tolist() == [0.01] and rob.sections[1].shear.tolist() == [0.5e6] * 2
    path.write_text(SCENE.replace("length = 0.2", "length = 0.2\nradius = 0.01"))
    with pytest.raises(InputError, match=r"\[robot\].radius = 0.01 with \[\[sections\]\]"):
        load_scene(path)
    path.write_text(SCENE.replace("inner_radius = 0.002", "inner_radius = 0.008"))
    with pytest.raises(InputError, match=r"\[\[sections\]\] #2: section radius must be greater than inner_radius"):
        load_scene(path)
    path.write_text(SCENE.replace("end = 0.2", "end = 0.25"))
    with pytest.raises(InputError, match=r"sections\[1\].end = 0.25 m must be the rod length"):
        load_scene(path)
    path.write_text(SCENE.split("[[sections]]")[0] + "youngs_modulus = 1e6\n" + SCENE[SCENE.index("[loads]"):])
    with pytest.raises(InputError, match=r"missing key 'poisson_ratio' in \[robot\] \(or describe the backbone"):
        load_scene(path)
