"""Self-checks of the independent SciPy reference solver (tests/scipy_reference.py) only,
against closed forms and global equilibrium."""

import numpy as np
from scipy_reference import solve_reference, solve_reference_user_style

L, E, NU, R_, RHO = 0.5, 190e9, 0.3, 1e-3, 17189.0
A = np.pi * R_**2
I = np.pi * R_**4 / 4
EI = E * I
EA = E * A
GA = E / (2 * (1 + NU)) * A


def rod(**kw):
    d = dict(length=L, youngs_modulus=E, poisson_ratio=NU, radius=R_, density=RHO,
             precurvature=(0, 0, 0), gravity=(0, 0, 0), tip_force=(0, 0, 0), tip_moment=(0, 0, 0),
             tendons=[], point_forces=[])
    d.update(kw)
    return d


def test_pure_tip_moment_is_a_circle():
    M = 0.02
    res = solve_reference(rod(tip_moment=(0, M, 0)), s_eval=np.linspace(0, L, 6))
    rho = EI / M
    th = L / rho
    assert res["success"]
    assert np.allclose(res["tip_position"], [rho * (1 - np.cos(th)), 0, rho * np.sin(th)], atol=1e-9, rtol=0)
    ss = np.linspace(0, L, 6)
    exact = np.stack([rho * (1 - np.cos(ss / rho)), 0 * ss, rho * np.sin(ss / rho)], axis=1)
    assert np.allclose(res["positions"], exact, atol=1e-9, rtol=0)
    c, s = np.cos(th), np.sin(th)
    assert np.allclose(res["tip_rotation"], [[c, 0, s], [0, 1, 0], [-s, 0, c]], atol=1e-9)
    assert np.allclose(res["n0"], 0, atol=1e-10) and np.allclose(res["m0"], [0, M, 0], rtol=1e-10, atol=1e-14)


def test_small_tip_force_matches_beam_theory():
    F = 1e-4
    res = solve_reference(rod(tip_force=(F, 0, 0)))
    assert res["success"]
    d = F * L**3 / (3 * EI)
    assert abs(res["tip_position"][0] / d - 1) < 5e-3
    assert np.allclose(res["n0"], [F, 0, 0], rtol=1e-10, atol=1e-16)
    assert np.allclose(res["m0"], [0, F * L, 0], rtol=1e-6, atol=1e-16)


def test_precurved_rod_without_load_is_its_own_circle():
    k = 0.8
    res = solve_reference(rod(precurvature=(k, 0, 0)))
    # u = (k, 0, 0): rotation about x takes +z towards -y
    assert np.allclose(res["tip_position"], [0, -(1 - np.cos(k * L)) / k, np.sin(k * L) / k], atol=1e-12)
    assert np.allclose(res["n0"], 0, atol=1e-12) and np.allclose(res["m0"], 0, atol=1e-14)


def test_straight_tendon_coupled_gives_circular_arc():
    tau, dx = 3.0, 0.01
    res = solve_reference(rod(tendons=[dict(offset=(dx, 0), tension=tau)]), model="coupled")
    assert res["success"]
    # rod + tendon form a closed system: rod force = -tau * tendon tangent, rod moment balances the
    # tendon's lever arm -> constant curvature tau dx / EI, axial strain -tau / EA, no shear.
    k = tau * dx / EI
    vz = 1 - tau / EA
    exact = vz / k * np.array([1 - np.cos(k * L), 0, np.sin(k * L)])
    assert np.allclose(res["tip_position"], exact, atol=1e-11, rtol=0)
    ext = 1 / k * np.array([1 - np.cos(k * L), 0, np.sin(k * L)])  # inextensible arc
    assert np.linalg.norm(res["tip_position"] - ext) < 1e-3 * np.linalg.norm(ext)
    assert np.allclose(res["n0"], [0, 0, -tau], rtol=1e-10, atol=1e-12)
    assert np.allclose(res["m0"], [0, tau * dx, 0], rtol=1e-10, atol=1e-14)


def _balance_error(d, **kw):
    """n0, m0 minus the resultant (about the base) of all external loads: tip loads, point
    forces, gravity, and the tendons' net load on the backbone, -tau t_i(0) applied at r_i(0)."""
    tend, pf = d["tendons"], d["point_forces"]
    cuts = sorted({0.0, L} | {t.get("length", L) for t in tend} | {p["s"] for p in pf})
    x, w = np.polynomial.legendre.leggauss(24)  # Gauss nodes on each smooth piece of p(s)
    nodes = [0.5 * (b - a) * x + 0.5 * (a + b) for a, b in zip(cuts[:-1], cuts[1:])]
    weights = [0.5 * (b - a) * w for a, b in zip(cuts[:-1], cuts[1:])]
    s_all = np.concatenate(nodes + [[p["s"] for p in pf], [L]])
    res = solve_reference(d, model="coupled", s_eval=s_all, **kw)
    assert res["success"] and res["residual_norm"] < 1e-12
    P = res["positions"]
    ng = sum(len(n) for n in nodes)
    int_p = (np.concatenate(weights)[:, None] * P[:ng]).sum(axis=0)
    p_tip = P[-1]
    assert np.allclose(p_tip, res["tip_position"], atol=1e-12)
    fe = RHO * A * np.asarray(d["gravity"], float)
    n0, m0 = res["n0"], res["m0"]
    # tendon tangent at the base from the strains there (R(0) = I)
    v = np.linalg.solve(np.diag([GA, GA, EA]), n0) + [0, 0, 1]
    u = np.linalg.solve(np.diag([EI, EI, 2 * E / (2 * (1 + NU)) * I]), m0)
    n_exp = np.asarray(d["tip_force"], float) + fe * L
    m_exp = np.asarray(d["tip_moment"], float) + np.cross(p_tip, d["tip_force"]) + np.cross(int_p, fe)
    for t in tend:
        lt = t.get("length", L)
        a, w, ph = t.get("helix_radius", 0.0), 2 * np.pi * t.get("turns", 0.0) / lt, t.get("phase", 0.0)
        r0 = np.array([t["offset"][0] + a * np.cos(ph), t["offset"][1] + a * np.sin(ph), 0])
        dr0 = np.array([-a * w * np.sin(ph), a * w * np.cos(ph), 0])
        pb = np.cross(u, r0) + dr0 + v
        F = -t["tension"] * pb / np.linalg.norm(pb)
        n_exp += F
        m_exp += np.cross(r0, F)
    for k, p in enumerate(pf):
        n_exp += p["force"]
        m_exp += np.cross(P[ng + k], p["force"])
    return n0 - n_exp, m0 - m_exp


HELIX = dict(offset=(0, 0.008), helix_radius=0.002, turns=0.5, phase=0.3, tension=1.5)
STRAIGHT = dict(offset=(0.01, 0), tension=3.0)
LOADS = dict(gravity=(0, 0, -9.81), tip_force=(0.02, 0.01, -0.05), tip_moment=(0.001, -0.002, 0.0005))


def test_global_balance_coupled_full_length_tendons():
    en, em = _balance_error(rod(tendons=[HELIX, STRAIGHT], **LOADS))
    assert np.abs(en).max() < 1e-11 and np.abs(em).max() < 1e-12


def test_global_balance_coupled_interior_jumps_with_kink_loads():
    d = rod(tendons=[dict(HELIX, length=0.3), STRAIGHT], point_forces=[dict(s=0.2, force=(0.01, -0.02, 0.005))],
            **LOADS)
    en, em = _balance_error(d, kink_loads=True)
    assert np.abs(en).max() < 1e-11 and np.abs(em).max() < 1e-12
    # the bare jump rule (termination/point loads only) leaves out the continuing tendons'
    # kink loads: a small, known imbalance, of the order of tau * (strain jump)
    en, em = _balance_error(d, kink_loads=False)
    assert 1e-8 < np.abs(en).max() < 1e-4


def test_point_model_force_balance_and_user_style_agrees():
    d = rod(tendons=[dict(offset=(0.01, 0), tension=3.0)], gravity=(0, 0, -9.81))
    res = solve_reference(d, model="point")
    assert res["success"]
    # n is constant apart from gravity: n0 = F_tendon(tip) + rho A g L, F along the tip tangent
    fe = RHO * A * np.array([0, 0, -9.81])
    F = res["n0"] - fe * L
    Rl = res["tip_rotation"]
    t_tip = Rl @ (np.linalg.solve(np.diag([GA, GA, EA]), Rl.T @ F) + [0, 0, 1])
    assert abs(np.linalg.norm(F) - 3.0) < 1e-10
    assert np.allclose(F / 3.0, -t_tip / np.linalg.norm(t_tip), atol=1e-10)
    for model in ("coupled", "point"):
        ref = solve_reference(d, model=model)
        usr = solve_reference_user_style(d, model=model)
        assert np.linalg.norm(usr["tip_position"] - ref["tip_position"]) < 1e-6
        assert usr["nfev"] > 0


def test_continuation_path_gives_same_answer(monkeypatch):
    import scipy_reference as sr

    d = rod(tendons=[dict(offset=(0.01, 0), tension=3.0)], gravity=(0, 0, -9.81))
    ref = solve_reference(d)
    real = sr._scaled_shoot
    calls = []

    def first_fails(mdl, *a, **k):  # the direct solve "fails": continuation must take over
        calls.append(1)
        if len(calls) == 1:
            return None, np.inf, False
        return real(mdl, *a, **k)

    monkeypatch.setattr(sr, "_scaled_shoot", first_fails)
    cont = solve_reference(d)
    assert len(calls) > 3 and cont["success"]
    assert np.allclose(cont["tip_position"], ref["tip_position"], atol=1e-12)
    assert np.allclose(cont["m0"], ref["m0"], atol=1e-13)
