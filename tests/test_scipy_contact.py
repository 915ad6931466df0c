"""Penalty contact with rigid obstacles: the independent SciPy reference (tests/scipy_contact.py)
checked on its own, then the Warp solver compared with it node by node.

Scenes (SI units, N = 200 intervals):
  planar  -- horizontal cantilever (gravity -x) bent by a 1 N tip force around a sphere; the
             contact is in the rod's interior (nodes ~115..121), tip angle ~39 degrees.
  tube    -- 3-D: the rod inside a bent_tube bending toward (1, 1, 0), gravity -y, tip force +x.
  resting -- a rod lying on a soft plane under its own weight, so that most nodes sit inside the
             smoothing band |delta| < eps/2 of the contact law (a direct test of phi and eps).
"""

import functools
import time

import numpy as np
import pytest
import scipy_contact as sc
from scipy_reference import solve_reference

N = 200
BASE = dict(length=0.3, radius=1e-3, youngs_modulus=60e9, poisson_ratio=0.3, density=6450.0)
SPHERE = dict(kind="sphere", center=(-0.08, 0.0, 0.15), radius=0.03, stiffness=1e5)
TUBE = dict(kind="bent_tube", start=(0.0, 0.0, -0.01), direction=(0.0, 0.0, 1.0),
            toward=(2**-0.5, 2**-0.5, 0.0), bend_radius=2.0, angle=0.3, radius=3e-3, stiffness=1e5)
PLANE = dict(kind="plane", point=(-1e-3 - 1e-6, 0.0, 0.0), normal=(1.0, 0.0, 0.0), stiffness=1e5)
SCENES = {
    "planar": dict(BASE, gravity=(-9.81, 0, 0), tip_force=(-1.0, 0, 0), obstacles=[SPHERE]),
    "tube": dict(BASE, gravity=(0, -9.81, 0), tip_force=(0.05, 0, 0), obstacles=[TUBE]),
    "resting": dict(BASE, gravity=(-9.81, 0, 0), tip_force=(0, 0, 0), obstacles=[PLANE]),
}
K_START = {"tube": 1e3}  # the straight rod starts deep in the tube's wall: continuation in k


@functools.cache
def reference(name):
    return sc.solve_contact(SCENES[name], N, k_start=K_START.get(name))


def ours(rod, **options):
    from tdcr_warp.model.robot import Obstacle, Robot
    from tdcr_warp.physics.statics import solve_static

    obs = [Obstacle(o["kind"], **{k: v for k, v in o.items() if k != "kind"}) for o in rod["obstacles"]]
    rob = Robot(**{k: v for k, v in rod.items() if k != "obstacles"}, obstacles=obs)
    return solve_static(rob, np.zeros((1, 0)), nodes=N, tol=1e-12, **options)


def compare(name, **options):
    """Max differences ours - reference; `law`: our F_i against the contact law at our own p_i."""
    ref, sol = reference(name), ours(SCENES[name], **options)
    assert sol.converged[0], f"our solver did not converge on {name}: {sol.failure_reasons()}"
    Fmax = np.abs(ref["contact_force"]).max()
    rod = sc._Rod(SCENES[name], N)
    law = np.array([rod.contact(i, sol.positions[0, i:i + 1])[0][0] for i in range(N + 1)])
    d = dict(positions=np.abs(sol.positions[0] - ref["positions"]).max(),
             force_rel=np.abs(sol.contact_force[0] - ref["contact_force"]).max() / Fmax,
             gap=np.abs(sol.contact_gap[0] - ref["gaps"]).max(),
             n_rel=np.abs(sol.n[0] - ref["n"]).max() / np.abs(ref["n"]).max(),
             wrench_rel=np.abs(sol.base_wrench[0] - np.r_[ref["n0"], ref["m0"]]).max()
             / np.abs(np.r_[ref["n0"], ref["m0"]]).max(),
             law_rel=np.abs(sol.contact_force[0] - law).max() / Fmax)
    print(name, {k: f"{v:.2e}" for k, v in d.items()})
    return d


def assert_agrees(d):
    """Integration error of RK4 on 200 intervals is ~1e-9 m: 1e-8 leaves a margin, nothing more."""
    msg = f"disagreement with the reference: {d}"
    assert d["law_rel"] < 1e-9, "our contact forces do not follow the contact law at our own positions; " + msg
    assert d["positions"] < 1e-8 and d["gap"] < 1e-8, msg
    assert d["force_rel"] < 1e-8 and d["n_rel"] < 1e-8 and d["wrench_rel"] < 1e-8, msg


# ---- 1. the reference on its own -------------------------------------------------------------

def test_contact_law_and_geometry():
    """phi is 0 / quadratic / identity and C1 at +-eps/2; each obstacle's gap and normal at
    points with known answers (inside a tube, the normal points back to the axis)."""
    eps = 1e-3
    x = np.array([-1.0, -0.5, 0.0, 0.5, 1.0]) * eps
    assert np.allclose(sc.phi(x, eps), [0.0, 0.0, eps / 8, 0.5 * eps, eps], rtol=0, atol=1e-18)
    for b in (-0.5 * eps, 0.5 * eps):  # value and slope continuous at the band's edges
        h = 1e-9 * eps
        lo, mid, hi = sc.phi(np.array([b - h, b, b + h]), eps)
        assert abs(hi - lo) < 3e-9 * eps and abs((hi - mid) / h - (mid - lo) / h) < 1e-5
    r = 1e-3
    p = np.array([[0.0, 0.0, 0.5], [0.3, 0.4, 0.0]])
    g, n = sc.gaps_normals(dict(kind="sphere", center=(0, 0, 0), radius=0.1), p, r)
    assert np.allclose(g, [0.4 - r, 0.4 - r]) and np.allclose(n, [[0, 0, 1], [0.6, 0.8, 0]])
    g, n = sc.gaps_normals(dict(kind="capsule", start=(0, 0, 0), end=(0, 0, 1), radius=0.1), p, r)
    assert np.allclose(g, [-0.1 - r, 0.4 - r]) and np.allclose(n[1], [0.6, 0.8, 0])
    g, n = sc.gaps_normals(dict(kind="plane", point=(0, 0, 0.2), normal=(0, 0, 2)), p, r)
    assert np.allclose(g, [0.3 - r, -0.2 - r]) and np.allclose(n, [[0, 0, 1]] * 2)
    tube = dict(kind="tube", start=(0, 0, 0), end=(0, 0, 1), radius=0.01)
    g, n = sc.gaps_normals(tube, np.array([[0.004, 0, 0.5], [0.004, 0, 1.5]]), r)
    assert np.allclose(g[0], 0.006 - r) and np.isinf(g[1]) and np.allclose(n, [[-1, 0, 0], [0, 0, 0]])
    bent = dict(kind="bent_tube", start=(0, 0, 0), direction=(0, 0, 1), toward=(1, 0, 0), bend_radius=1.0,
                angle=np.pi / 2, radius=0.01)
    th = np.array([0.3, 1.2, 2.0])  # points 4 mm outward of the arc's centre line at angle th
    q = np.stack([1 - np.cos(th), 0 * th, np.sin(th)], axis=1)
    out = np.stack([-np.cos(th), 0 * th, np.sin(th)], axis=1)  # unit vector from the bend's centre
    g, n = sc.gaps_normals(bent, q + 0.004 * out, r)
    assert np.allclose(g[:2], 0.006 - r) and np.isinf(g[2]) and np.allclose(n[:2], -out[:2])


@pytest.mark.parametrize("name", ["planar", "tube"])
def test_reference_is_in_global_equilibrium(name):
    """n(0) - n(L+) = rho A g L + sum F_i and m(0) = p(L) x n(L+) + (int p ds) x rho A g + sum
    p_i x F_i (contact adds no moment about the centre line), with n(L+) = tip force, m(L+) = 0."""
    ref = reference(name)
    F, p, fg = ref["contact_force"], ref["positions"], ref["weight"] / BASE["length"]
    assert ref["residual"] < 1e-12 and np.abs(F).max() > 0
    scale = np.abs(ref["n0"]).max()
    assert np.allclose(ref["n_tip"], SCENES[name]["tip_force"], rtol=0, atol=1e-12 * scale)
    force = ref["n0"] - ref["n_tip"] - (ref["weight"] + F.sum(axis=0))
    moment = ref["m0"] - (np.cross(p[-1], ref["n_tip"]) + np.cross(ref["int_p"], fg) + np.cross(p, F).sum(axis=0))
    print(name, "force", np.abs(force).max() / scale, "moment", np.abs(moment).max() / np.abs(ref["m0"]).max())
    assert np.abs(force).max() < 1e-12 * scale
    assert np.abs(moment).max() < 1e-12 * np.abs(ref["m0"]).max()


def test_far_obstacles_give_the_contact_free_rod():
    """Obstacles far away exert nothing: the same rod as without them, and the same as the
    tendon reference (tests/scipy_reference.py, written independently) without tendons."""
    far = [dict(SPHERE, center=(1.0, 0, 0)), dict(PLANE, point=(-1.0, 0, 0)),
           dict(TUBE, radius=0.5, bend_radius=5.0)]
    rod = dict(SCENES["planar"], obstacles=far)
    a, b = sc.solve_contact(rod, N), sc.solve_contact(dict(rod, obstacles=[]), N)
    assert np.all(a["contact_force"] == 0) and np.all(a["gaps"] > 0.05)
    assert np.array_equal(a["positions"], b["positions"]) and np.array_equal(a["m0"], b["m0"])
    tr = solve_reference(dict(rod, obstacles=None, tendons=[], tip_moment=(0, 0, 0), precurvature=(0, 0, 0)))
    assert np.allclose(a["tip_position"], tr["tip_position"], rtol=0, atol=1e-10)
    assert np.allclose(np.r_[a["n0"], a["m0"]], np.r_[tr["n0"], tr["m0"]], rtol=1e-9, atol=1e-12)


def test_reference_converges_as_the_stiffness_grows():
    """k = 1e3 .. 1e7 N/m^2 on the planar scene (100 intervals): the tip moves less and less
    per decade of k, and the deepest penetration shrinks; the rigid limit is approached."""
    rod, prev, tips, pen = dict(SCENES["planar"]), None, [], []
    for k in 10.0 ** np.arange(3, 8):
        rod["obstacles"] = [dict(SPHERE, stiffness=k)]
        guess = None if prev is None else np.r_[prev["n0"], prev["m0"]]
        prev = sc.solve_contact(rod, 100, guess=guess, k_start=None if prev is None else k / 10)
        tips.append(prev["tip_position"])
        pen.append(-prev["gaps"].min())
    steps = np.linalg.norm(np.diff(tips, axis=0), axis=1)
    print("tip change per decade", steps, "ratios", steps[1:] / steps[:-1], "penetration", pen)
    assert np.all(np.diff(steps) < 0) and np.all(steps[1:] / steps[:-1] < 0.5)
    assert np.all(np.diff(pen) < 0) and pen[-1] < 2e-5


# ---- 2, 3. the Warp solver against the reference -----------------------------------------------

def test_planar_large_deflection_around_a_sphere():
    ref = reference("planar")
    angle = np.degrees(np.arccos(ref["rotations"][-1][2, 2]))
    touching = np.nonzero(np.abs(ref["contact_force"]).max(axis=1))[0]
    assert angle > 35 and 0.3 * N < touching.min() and touching.max() < 0.7 * N  # interior contact
    assert_agrees(compare("planar"))


def test_rod_inside_a_bent_tube():
    """From the straight rod our solver needs exact Newton steps and more iterations than its
    default 50 here (with the defaults it stops: 'iteration cap reached')."""
    ref = reference("tube")
    assert ref["tip_position"][0] > 0.01 and ref["tip_position"][1] > 0.01  # out of every plane
    assert_agrees(compare("tube", jacobian="newton", max_iter=500))


def test_rod_resting_on_a_plane_inside_the_smoothing_band():
    """The forces here depend on phi's quadratic piece and on eps = EI / (k L^3) directly.
    Our solver's Broyden iteration needs ~180 iterations on this mild scene (default cap 50)."""
    ref = reference("resting")
    delta_over_eps = -ref["gaps"][:, 0] * PLANE["stiffness"] * BASE["length"] ** 3 / ref["EI"]
    assert np.sum(np.abs(delta_over_eps) < 0.5) > 0.5 * N  # most nodes in the quadratic band
    assert_agrees(compare("resting", max_iter=500))


if __name__ == "__main__":
    t = time.time()
    pytest.main([__file__, "-q", "-s"])
    print(f"{time.time() - t:.1f} s")
