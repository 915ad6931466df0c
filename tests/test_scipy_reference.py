"""Self-checks of the independent SciPy reference solver (tests/scipy_reference.py) only,
against closed forms and global equilibrium: the frictionless coupled/point models, kink loads,
tendon friction (capstan) and length control with slack."""

import functools

import numpy as np
import pytest
import scipy_reference as sr
from scipy_reference import reference_lengths, solve_reference, solve_reference_user_style

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
    en, em, _ = _balance(d, **kw)
    return en, em


def _balance(d, **kw):
    """n0, m0 minus the resultant (about the base) of all external loads: tip loads, point
    forces, gravity, and the tendons' net load on the backbone, -tau_i(0) t_i(0) applied at
    r_i(0) (with friction and kinks too: the tendon's loads integrate to (tau t)' plus jumps).
    Returns (force error, moment error, the solution)."""
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
    for i, t in enumerate(tend):
        lt = t.get("length", L)
        a, w, ph = t.get("helix_radius", 0.0), 2 * np.pi * t.get("turns", 0.0) / lt, t.get("phase", 0.0)
        r0 = np.array([t["offset"][0] + a * np.cos(ph), t["offset"][1] + a * np.sin(ph), 0])
        dr0 = np.array([-a * w * np.sin(ph), a * w * np.cos(ph), 0])
        pb = np.cross(u, r0) + dr0 + v
        F = -res["tendon_tension_base"][i] * pb / np.linalg.norm(pb)
        n_exp += F
        m_exp += np.cross(r0, F)
    for k, p in enumerate(pf):
        n_exp += p["force"]
        m_exp += np.cross(P[ng + k], p["force"])
    return n0 - n_exp, m0 - m_exp, res


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


# ---- kink loads, tendon friction (capstan), length control with slack ----------------------
# The closed forms below are exact for the coupled Cosserat model (shear and extension
# included) unless stated; their tolerances are set by the integrator (rtol 1e-10 .. 1e-11).

def _turning_from_shape(res, offset):
    """Total turning [rad] of a tendon's path P(s) = p(s) + R(s) r(s) (offset: r (2,) or r(s) (k, 3))
    from the sampled shape alone (uniform s, k - 1 divisible by 4): sum of the angles between
    successive chords plus half the first and last (the half chords at the ends), whose error
    h^2 c2 + h^3 c3 + ... is removed by Richardson extrapolation over h, 2h, 4h."""
    rr = np.asarray(offset, float)
    rr = np.broadcast_to([rr[0], rr[1], 0.0] if rr.ndim == 1 else rr, res["positions"].shape)
    P = res["positions"] + np.einsum("kij,kj->ki", res["rotations"], rr)

    def est(Q):
        ch = np.diff(Q, axis=0)
        ch /= np.linalg.norm(ch, axis=1)[:, None]
        ang = np.arctan2(np.linalg.norm(np.cross(ch[:-1], ch[1:]), axis=1), np.sum(ch[:-1] * ch[1:], axis=1))
        return ang.sum() + 0.5 * (ang[0] + ang[-1])

    def rich1(Q):
        return (4 * est(Q) - est(Q[::2])) / 3

    return (8 * rich1(P) - rich1(P[::2])) / 7


def test_mu_zero_is_exactly_the_frictionless_solver():
    d = rod(tendons=[dict(HELIX, length=0.3), STRAIGHT], point_forces=[dict(s=0.2, force=(0.01, -0.02, 0.005))],
            **LOADS)
    d0 = rod(tendons=[dict(HELIX, length=0.3, friction=0.0, slip=-1), dict(STRAIGHT, friction=0.0)],
             point_forces=d["point_forces"], **LOADS)
    # numbers of the solver before friction / length control were added (same machine, DOP853 rtol 1e-12)
    before = {("coupled", True): ([0.03230512590999229, 0.01167958118192335, 0.49849794775981093],
                                  [-0.01459120627437401, 0.04741296553873585, 0.00031175853316737]),
              ("coupled", False): ([0.0323051209565081, 0.01167998549325474, 0.49849793709620627],
                                   [-0.01459216133157132, 0.04741296677907091, 0.00031181711513844])}
    for (model, kl), (tip, m0) in before.items():
        a = solve_reference(d, model=model, kink_loads=kl)
        b = solve_reference(d0, model=model, kink_loads=kl)
        for k in ("tip_position", "tip_rotation", "n0", "m0", "tendon_tension_end", "tendon_turning"):
            assert np.array_equal(a[k], b[k]), k  # mu = 0 takes the frictionless code path: bitwise equal
        assert np.abs(a["tip_position"] - tip).max() < 1e-13 and np.abs(a["m0"] - m0).max() < 1e-14
        assert np.array_equal(a["tendon_tension_end"], [1.5, 3.0])
        # the tendon-state integration (tensions as ODE states, mu = 0) keeps that solution's balance
        mdl = sr._Model(d0, model, kink_loads=kl, augmented=True)
        res, yL = mdl.residual(a["n0"], a["m0"], method="DOP853", rtol=1e-12, atol=1e-14)
        assert np.abs(res).max() < 1e-12 and np.array_equal(yL[18:20], [1.5, 3.0])


def test_length_control_single_tendon_closed_form():
    # Straight tendon at (0, r) to the tip, no gravity: rod + tendon are a closed system, so
    # n = -tau t, m = -(R r) x tau t: constant strains v = (0, 0, 1 - tau/EA), u = (-tau r/EI, 0, 0)
    # (bends toward +y), tendon path rate |pb| = 1 - tau/EA - tau r^2/EI =: 1 - k tau, and
    # ell0(tau) = L (1 - k tau) / (1 + c tau). Command ell0(tau) = ell0(tau_ref) - q =: T0 - q:
    # L (1 - k tau) = T (1 + c tau)  ->  tau = (L - T) / (L k + T c).
    r, c, pre, q = 0.01, 2e-4, 1.0, 1.5e-3
    k = 1 / EA + r * r / EI
    ell0_ref = L * (1 - k * pre) / (1 + c * pre)
    target = ell0_ref - q
    tau = (L - target) / (L * k + target * c)
    d = rod(tendons=[dict(offset=(0, r), control="displacement", displacement=q, compliance=c, pretension=pre)])
    res = solve_reference(d, rtol=1e-11)
    assert res["success"] and not res["tendon_slack"][0]
    assert abs(res["tendon_tension_base"][0] / tau - 1) < 1e-9, res["tendon_tension_base"][0] - tau
    assert abs(res["tendon_tension_end"][0] / tau - 1) < 1e-9
    assert abs(res["tendon_reference_length"][0] - ell0_ref) < 1e-12
    assert abs(reference_lengths(d, rtol=1e-11)[0] - ell0_ref) < 1e-12
    assert abs(res["tendon_unstretched_length"][0] - target) < 1e-12
    assert abs(res["tendon_length"][0] - L * (1 - k * tau)) < 1e-12
    kap, vz = tau * r / EI, 1 - tau / EA
    assert abs(res["tendon_turning"][0] - kap * L) < 1e-11
    tip = vz / kap * np.array([0, 1 - np.cos(kap * L), np.sin(kap * L)])  # arc of radius vz / |u|
    assert np.abs(res["tip_position"] - tip).max() < 1e-12, res["tip_position"] - tip
    assert np.allclose(res["n0"], [0, 0, -tau], rtol=1e-9, atol=1e-12)
    assert np.allclose(res["m0"], [-tau * r, 0, 0], rtol=1e-9, atol=1e-14)


@pytest.mark.parametrize("slip", [1, -1])
def test_planar_capstan_closed_form(slip):
    # Straight tendon at (r, 0) to the tip, friction mu, base tension tau0, no gravity. The cut
    # argument holds with friction (the tendon's loads are (tau t)'): n = -tau(s) t, m = -(R r) x
    # tau(s) t, so in the body frame the tendon tangent stays e3 and u_y = r tau(s) / EI EXACTLY
    # (shear and extension change only |v| = 1 - tau/EA, not theta' or t). Then kappa = theta' and
    # tau' = -mu sigma kappa tau = -sigma mu r tau^2 / EI:
    #   tau(s) = tau0 / (1 + sigma mu r tau0 s / EI),  theta(s) = ln(1 + sigma mu r tau0 s / EI) / (sigma mu).
    # The Kirchhoff-like (inextensible) shape with this theta differs only by the neglected
    # tau/EA ~ 2e-5 (checked below); theta and tau themselves are exact.
    r, mu, tau0 = 0.01, 0.8, 15.0
    d = rod(tendons=[dict(offset=(r, 0), tension=tau0, friction=mu, slip=slip)])
    c = slip * mu * r * tau0 / EI
    ss = np.linspace(0, L, 201) if slip == 1 else None
    res = solve_reference(d, rtol=1e-11 if slip == 1 else 1e-10, s_eval=ss)
    assert res["success"]
    theta_L = np.log1p(c * L) / (slip * mu)
    tau_L = tau0 / (1 + c * L)
    assert res["tendon_tension_base"][0] == tau0
    assert abs(res["tendon_tension_end"][0] / tau_L - 1) < 1e-9
    assert abs(res["tendon_turning"][0] / theta_L - 1) < 1e-9
    Rl = res["tip_rotation"]
    assert abs(np.arctan2(Rl[0, 2], Rl[2, 2]) - theta_L) < 1e-9
    # capstan identity with the solver's own turning
    assert abs(res["tendon_tension_end"][0] / tau0 - np.exp(-slip * mu * res["tendon_turning"][0])) < 1e-12
    # tip by quadrature of p' = (1 - tau/EA) (sin theta, 0, cos theta), and its inextensible version
    x, w = np.polynomial.legendre.leggauss(40)
    s = 0.5 * L * (x + 1)
    th = np.log1p(c * s) / (slip * mu)
    stretch = 1 - tau0 / (1 + c * s) / EA
    tip = 0.5 * L * np.array([np.sum(w * stretch * np.sin(th)), 0.0, np.sum(w * stretch * np.cos(th))])
    assert np.abs(res["tip_position"] - tip).max() < 1e-11, res["tip_position"] - tip
    tip_k = 0.5 * L * np.array([np.sum(w * np.sin(th)), 0.0, np.sum(w * np.cos(th))])
    assert np.linalg.norm(res["tip_position"] - tip_k) < 2 * tau0 / EA * L
    if slip == 1:
        tau_s = tau0 / (1 + c * ss)
        assert np.abs(res["tendon_tensions"][:, 0] / tau_s - 1).max() < 1e-9
        # capstan identity tau(L)/tau(0) = exp(-mu Theta) with Theta from the sampled shape only
        theta_shape = _turning_from_shape(res, (r, 0))
        assert abs(theta_shape - res["tendon_turning"][0]) < 1e-8, theta_shape - res["tendon_turning"][0]
        assert abs(res["tendon_tension_end"][0] / tau0 - np.exp(-mu * theta_shape)) < 1e-8


FRICTION_SCENE = rod(
    tendons=[dict(HELIX, length=0.3, friction=0.2, compliance=1e-4, pretension=0.5),
             dict(STRAIGHT, friction=0.1, slip=-1, pretension=0.3)],
    point_forces=[dict(s=0.2, force=(0.01, -0.02, 0.005))], **LOADS)


@functools.lru_cache(maxsize=None)
def _friction_scene_solution():
    return _balance(FRICTION_SCENE, kink_loads=True, rtol=1e-10)


def test_friction_global_balance_and_capstan_identity_with_kinks():
    en, em, res = _friction_scene_solution()
    # rod + tendons stay exactly balanced with friction and kink tension jumps
    assert np.abs(en).max() < 1e-11 and np.abs(em).max() < 1e-12, (en, em)
    mu, sig = np.array([0.2, 0.1]), np.array([1.0, -1.0])
    # kinks at s = 0.2 (point force, both tendons) and 0.3 (end of the helix, straight tendon)
    assert sorted((k["s"], k["tendon"]) for k in res["kinks"]) == [(0.2, 0), (0.2, 1), (0.3, 1)]
    assert np.all(res["tendon_kink_angle"] > 0)
    ratio = res["tendon_tension_end"] / res["tendon_tension_base"]
    assert np.abs(ratio - np.exp(-mu * sig * res["tendon_turning"])).max() < 1e-12
    assert ratio[0] < 1 < ratio[1]  # slip +1 loses tension toward the tip, slip -1 gains
    for kk in res["kinks"]:
        i = kk["tendon"]
        assert abs(kk["tension_plus"] - kk["tension_minus"] * np.exp(-mu[i] * sig[i] * kk["angle"])) < 1e-15


def test_friction_turning_matches_the_sampled_3d_tendon_paths():
    # Theta_i = int |t_i'| ds + kink angles, against the chord polygon of P(s) = p + R r_i(s)
    # sampled on each smooth piece (nodes at the kinks s = 0.2, 0.3); checks kappa in 3D, where
    # it comes out of the friction-coupled strain system. The kink angles are 1e-7 .. 1e-6 rad.
    _, _, sol = _friction_scene_solution()
    cuts = [0.0, 0.2, 0.3, L]
    pieces = [np.linspace(a, b, 101) for a, b in zip(cuts[:-1], cuts[1:])]
    res = solve_reference(FRICTION_SCENE, rtol=1e-10, s_eval=np.concatenate(pieces),
                          guess=dict(n0=sol["n0"], m0=sol["m0"]))
    for i, t in enumerate(FRICTION_SCENE["tendons"]):
        lt = t.get("length", L)
        total, k0 = res["tendon_kink_angle"][i], 0
        for pc in pieces:
            k1 = k0 + len(pc)
            if pc[-1] <= lt + 1e-12:
                ang = 2 * np.pi * t.get("turns", 0.0) / lt * pc + t.get("phase", 0.0)
                a = t.get("helix_radius", 0.0)
                r = np.stack([t["offset"][0] + a * np.cos(ang), t["offset"][1] + a * np.sin(ang), 0 * pc], axis=1)
                total += _turning_from_shape(dict(positions=res["positions"][k0:k1],
                                                  rotations=res["rotations"][k0:k1]), r)
            k0 = k1
        assert abs(total - res["tendon_turning"][i]) < 1e-8, (i, total - res["tendon_turning"][i])


def test_length_control_round_trip_recovers_tensions():
    _, _, res = _friction_scene_solution()
    ell0_ref = reference_lengths(FRICTION_SCENE, rtol=1e-10)
    q = ell0_ref - res["tendon_unstretched_length"]
    tendons = [{k: v for k, v in t.items() if k != "tension"} for t in FRICTION_SCENE["tendons"]]
    for t, qi in zip(tendons, q):
        t.update(control="displacement", displacement=qi)
    d = dict(FRICTION_SCENE, tendons=tendons)
    back = solve_reference(d, rtol=1e-10)
    assert back["success"] and not back["tendon_slack"].any()
    assert np.array_equal(back["tendon_reference_length"], ell0_ref)
    err = np.abs(back["tendon_tension_base"] - res["tendon_tension_base"]).max()
    assert err < 1e-9, f"round trip tension error {err:.2e} N"
    assert np.abs(back["tip_position"] - res["tip_position"]).max() < 1e-11
    assert np.abs(back["tendon_unstretched_length"] - res["tendon_unstretched_length"]).max() < 1e-13


@pytest.mark.parametrize("frac", [0.9, 1.1])
def test_antagonistic_pair_release_goes_slack_at_predicted_q(frac):
    # Tendons at (+r, 0) and (-r, 0) to the tip, inextensible, pretension tau_ref, no loads.
    # Both taut: constant curvature u_y = r (tau1 - tau2)/EI, v_z = 1 - (tau1 + tau2)/EA, lengths
    # ell_1,2 = L (1 - a S -+ b D), S = tau1 + tau2, D = tau1 - tau2, a = 1/EA, b = r^2/EI; reference
    # (both at tau_ref) ell_ref = L (1 - 2 a tau_ref). Pull 1 by q, release 2 by q:
    #   ell_1 = ell_ref - q, ell_2 = ell_ref + q  ->  S = 2 tau_ref, D = q / (L b),
    #   tau_2 = tau_ref - q EI / (2 L r^2): slack for q > q* = 2 L r^2 tau_ref / EI.
    # Beyond q*: tau_2 = 0, tau_1 = (q + 2 L a tau_ref) / (L (a + b)), and tendon 2's spare length
    # (ell_ref + q) - ell_2 = 2 L a (tau_1 - 2 tau_ref) > 0.
    r, pre = 0.01, 1.0
    a, b = 1 / EA, r * r / EI
    q_star = 2 * L * r * r * pre / EI
    q = frac * q_star
    d = rod(tendons=[dict(offset=(r, 0), control="displacement", displacement=q, pretension=pre),
                     dict(offset=(-r, 0), control="displacement", displacement=-q, pretension=pre)])
    res = solve_reference(d, rtol=1e-10)
    assert res["success"]
    tau = res["tendon_tension_base"]
    ell_ref = L * (1 - 2 * a * pre)
    assert np.allclose(res["tendon_reference_length"], ell_ref, rtol=0, atol=1e-13)
    if frac < 1:
        exact = [pre + q / (2 * L * b), pre - q / (2 * L * b)]
        assert not res["tendon_slack"].any()
        assert np.abs(res["tendon_unstretched_length"] - [ell_ref - q, ell_ref + q]).max() < 1e-13
    else:
        t1 = (q + 2 * L * a * pre) / (L * (a + b))
        exact = [t1, 0.0]
        assert list(res["tendon_slack"]) == [False, True]
        assert tau[1] == 0.0 and res["tendon_tension_end"][1] == 0.0
        spare = (ell_ref + q) - res["tendon_unstretched_length"][1]
        assert spare > 0 and abs(spare - 2 * L * a * (t1 - 2 * pre)) < 1e-13
    assert np.abs(tau - exact).max() < 1e-9, tau - exact
    kap = r * (exact[0] - exact[1]) / EI
    assert abs(res["tendon_turning"][0] - kap * L) < 1e-10


def test_kink_loads_on_off_two_sections_under_tip_load():
    # tendon 1 ends at L/2, tendon 2 (straight, orthogonal plane) goes on to the tip
    d = rod(tendons=[dict(offset=(0.01, 0), tension=5.0, length=L / 2), dict(offset=(0, 0.01), tension=3.0)],
            tip_force=(0.5, 0, 0))
    en_on, em_on, on = _balance(d, kink_loads=True, rtol=1e-10)
    en_off, em_off, off = _balance(d, kink_loads=False, rtol=1e-10)
    # with kink loads: rod + tendons exactly balanced
    assert np.abs(en_on).max() < 1e-12 and np.abs(em_on).max() < 1e-13, (en_on, em_on)
    # without: the rod is balanced against the loads it does get, i.e. short by the kink force
    # P = tau (t+ - t-) at P(L/2) that the published rule leaves out
    (k_off,) = off["kinks"]
    assert np.array_equal(k_off["force"], np.zeros(3))
    P = k_off["tension_minus"] * (k_off["t_plus"] - k_off["t_minus"])
    assert np.abs(en_off + P).max() < 1e-12 and np.abs(em_off + np.cross(k_off["point"], P)).max() < 1e-13
    assert np.linalg.norm(P) > 1e-6  # the kink is there (a shear jump of the tip-loaded rod)
    (k_on,) = on["kinks"]
    assert np.linalg.norm(k_on["force"] - k_on["tension_minus"] * (k_on["t_plus"] - k_on["t_minus"])) < 1e-18
    # the tip moves a little: about 2.5e-7 m here (straight tendons kink only through the shear
    # jump; a helical continuing tendon kinks ~400x more, ~0.1 mm tip difference)
    diff = np.linalg.norm(on["tip_position"] - off["tip_position"])
    assert 1e-8 < diff < 1e-5, diff


def test_point_model_friction_uses_the_end_tension():
    r, mu, tau0 = 0.01, 0.5, 1.0
    d = rod(tendons=[dict(offset=(r, 0), tension=tau0, friction=mu)], gravity=(0, -9.81, 0))
    res = solve_reference(d, model="point", rtol=1e-10)
    assert res["success"]
    tau_L = res["tendon_tension_end"][0]
    assert abs(tau_L / tau0 - np.exp(-mu * res["tendon_turning"][0])) < 1e-12
    assert tau_L < tau0 * (1 - 1e-3)
    # termination load only: n0 = F_tip_tendon + rho A g L with |F| = tau(L-), along the tip tangent
    fe = RHO * A * np.array([0, -9.81, 0])
    F = res["n0"] - fe * L
    Rl = res["tip_rotation"]
    # strains just before the tip, where n(L-) = F and m(L-) = (R r) x F (m(L+) = 0)
    v = np.linalg.solve(np.diag([GA, GA, EA]), Rl.T @ F) + [0, 0, 1]
    u = np.linalg.solve(np.diag([EI, EI, 2 * E / (2 * (1 + NU)) * I]), np.cross([r, 0, 0], Rl.T @ F))
    pb = np.cross(u, [r, 0, 0]) + v
    assert abs(np.linalg.norm(F) - tau_L) < 1e-12
    assert np.allclose(F, -tau_L * Rl @ pb / np.linalg.norm(pb), atol=1e-12)


def test_length_control_homotopy_fallback_gives_same_answer(monkeypatch):
    d = rod(tendons=[dict(offset=(0, 0.01), control="displacement", displacement=1e-3, compliance=1e-4,
                          pretension=0.5)], gravity=(0, 0, -9.81))
    ref = solve_reference(d, rtol=1e-10)
    real = sr._scaled_shoot
    calls = []

    def first_free_fails(mdl, *a, **k):  # the direct length-controlled solve "fails"
        calls.append(len(mdl.free))
        if mdl.free and calls.count(1) == 1:
            return None, np.inf, False
        return real(mdl, *a, **k)

    monkeypatch.setattr(sr, "_scaled_shoot", first_free_fails)
    cont = solve_reference(d, rtol=1e-10)
    assert calls.count(1) > 3 and cont["success"]
    assert abs(cont["tendon_tension_base"][0] - ref["tendon_tension_base"][0]) < 1e-9
    assert np.allclose(cont["tip_position"], ref["tip_position"], atol=1e-12)
