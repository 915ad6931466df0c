"""Tendons as hardware drives them: displacement control with slack, capstan friction with
stick-slip memory, converging routes and the kink-load switch, each checked against a closed
form derived in its docstring or an identity of the model (tests/test_tendons_reference.py
holds the comparisons with the independent SciPy solver)."""

import numpy as np
import pytest

import tdcr_warp as tw
from tdcr_warp.physics.statics import reference_lengths

E, NU, RB, L = 190e9, 0.3, 1e-3, 0.5
A = np.pi * RB**2
EI = E * np.pi * RB**4 / 4
EA = E * A
OFF = 0.01
# A tendon's length fixes its tension through its stiffness in the rod, dtau/dell = 1 / (L (r^2 / EI +
# 1 / EA + c)) ~ 3e3 N/m here: tensions to 1e-9 N need the length residual below ~3e-13 m.
TIGHT = 1e-13


def robot(tendons, **kw):
    base = dict(length=L, youngs_modulus=E, poisson_ratio=NU, radius=RB, density=7800.0)
    return tw.Robot(tendons=tendons, **(base | kw))


def arc_tip(kappa: float, stretch: float) -> np.ndarray:
    """Tip of an arc of length L stretch bending toward +y with curvature kappa (per unit s)."""
    return stretch * np.array([0.0, (1 - np.cos(kappa * L)) / kappa, np.sin(kappa * L) / kappa])


def test_displacement_control_of_one_tendon_is_the_closed_form():
    """One straight tendon at (0, r) to the tip, gravity-free, coupled Cosserat rod. The rod
    force is n = -tau t and the moment r tau about x, so the arc has constant curvature
    kappa = tau r / EI, axial strain 1 - tau / EA and tendon path rate |pb| = 1 - tau / EA -
    tau r^2 / EI. The wire (compliance c) holds ell0 = L |pb| / (1 + c tau) of unstretched
    tendon; the motor takes in q of it: ell0(tau) = ell0(tau_ref) - q, linear in tau."""
    c, pre, q = 2e-4, 1.5, 0.003
    rb = robot([tw.Tendon(offset=(0, OFF), control="displacement", compliance=c, pretension=pre)])
    sol = tw.solve_static(rb, displacements=[q], nodes=50, tol=TIGHT)
    ell0 = lambda t: L * (1 - t / EA - t * OFF**2 / EI) / (1 + c * t)  # noqa: E731
    avail = ell0(pre) - q
    tau = (L - avail) / (L * (1 / EA + OFF**2 / EI) + c * avail)
    assert sol.converged.all()
    assert abs(sol.tendon_tension_base[0, 0] - tau) < 1e-9 * tau
    assert abs(sol.tendon_tension_end[0, 0] - tau) < 1e-9 * tau
    assert not sol.slack[0, 0]
    assert np.abs(sol.tip_position[0] - arc_tip(tau * OFF / EI, 1 - tau / EA)).max() < 1e-9
    # the definition: the path holds exactly the unstretched tendon the motor left it, stretched by c tau
    assert abs(sol.tendon_free_length[0, 0] - avail) < 1e-12
    assert abs(sol.tendon_path_length[0, 0] - avail * (1 + c * tau)) < 1e-12
    ref = tw.solve_static(rb, displacements=[0.0], nodes=50, tol=TIGHT)
    assert abs(ref.tendon_tension_base[0, 0] - pre) < 1e-9  # q = 0 is the reference state
    assert abs(ref.tendon_free_length[0, 0] - ell0(pre)) < 1e-12


def _three_tendons(control):
    return [tw.Tendon(offset=(OFF, 0.0)),
            tw.Tendon(offset=(0.0, OFF), routing="linear", offset_end=(0.0, 0.004), control=control,
                      compliance=1e-4, pretension=0.5),
            tw.Tendon(offset=(-0.006, 0.0), routing="helix", helix_radius=0.004, turns=0.5, control=control,
                      pretension=0.5, length=0.3)]


def test_round_trip_tension_to_displacement_recovers_the_tensions():
    """Solve in tension control (gravity, a tip force, helical, converging and straight routes,
    a tendon ending at mid-length), read each tendon's unstretched length, command the length
    change from the reference as displacements of two of them (the third stays in tension
    control), and get the tensions back."""
    kw = dict(gravity=(0, 0, -9.81), tip_force=(0.02, 0.0, 0.0))
    tau = np.array([[1.0, 3.0, 2.0], [0.5, 0.0, 4.0], [2.0, 6.0, 0.2]])
    forward = tw.solve_static(robot(_three_tendons("tension"), **kw), tau, nodes=40, tendon_states=True, tol=TIGHT)
    disp = robot(_three_tendons("displacement"), **kw)
    ref = reference_lengths(disp, nodes=40, tol=TIGHT)
    q = np.zeros((3, 3))
    q[:, 1:] = ref[:, 1:] - forward.tendon_free_length[:, 1:]
    back = tw.solve_static(disp, tau * [1, 0, 0], displacements=q, nodes=40, tol=TIGHT)
    assert forward.converged.all() and back.converged.all()
    assert np.abs(back.tendon_tension_base - tau).max() < 1e-9
    assert np.abs(back.tip_position - forward.tip_position).max() < 1e-10


def test_antagonistic_pair_releases_at_the_predicted_displacement():
    """Tendons at +r and -r, inextensible, both at pretension p in the reference (straight,
    compressed: ell_ref = L (1 - 2 p / EA)). Pull one by q and release the other by q: the
    lengths give tau1 + tau2 = 2 p and tau1 - tau2 = q EI / (L r^2), so the released tendon
    goes slack at q* = 2 p L r^2 / EI; beyond it tau2 = 0 and tau1 solves the one-tendon
    constraint L (1 - tau1 / EA - tau1 r^2 / EI) = ell_ref - q."""
    p = 1.0
    pair = robot([tw.Tendon(offset=(0, OFF), control="displacement", pretension=p),
                  tw.Tendon(offset=(0, -OFF), control="displacement", pretension=p)])
    q_star = 2 * p * L * OFF**2 / EI
    q = np.array([0.8, 1.2]) * q_star
    sol = tw.solve_static(pair, displacements=np.c_[q, -q], nodes=50, tol=TIGHT)
    assert sol.converged.all()
    d = q[0] * EI / (L * OFF**2)
    assert np.abs(sol.tendon_tension_base[0] - [p + d / 2, p - d / 2]).max() < 1e-9
    assert not sol.slack[0].any()
    ell_ref = L * (1 - 2 * p / EA)
    tau1 = (L - ell_ref + q[1]) / (L * (1 / EA + OFF**2 / EI))
    assert abs(sol.tendon_tension_base[1, 0] - tau1) < 1e-9 * tau1
    assert sol.tendon_tension_base[1, 1] == 0.0 and sol.slack[1, 1] and not sol.slack[1, 0]


def test_slack_converges_from_the_straight_start_over_a_sweep():
    """Antagonistic displacements (q, -q) from -10 mm to +10 mm (up to 1.15 rad of bending) on a
    pair with elastic wires, every rod from the straight-rod start in one batch: all converge,
    tensions are >= 0, and beyond the release (q* = 2 p L r^2 / EI + the wires' share, under
    1 mm here) the released tendon is slack and carries nothing."""
    pair = robot([tw.Tendon(offset=(0, OFF), control="displacement", pretension=0.5, compliance=5e-5),
                  tw.Tendon(offset=(0, -OFF), control="displacement", pretension=0.5, compliance=5e-5)])
    q = np.linspace(-0.01, 0.01, 41)
    sol = tw.solve_static(pair, displacements=np.c_[q, -q], nodes=30)
    assert sol.converged.all(), sol.failure_reasons()
    t = sol.tendon_tension_base
    assert (t >= 0).all()
    assert (sol.slack == (t == 0)).all()
    assert sol.slack[q < -0.001, 0].all() and sol.slack[q > 0.001, 1].all()
    assert not sol.slack[q > -0.0002, 0].any() and not sol.slack[q < 0.0002, 1].any()


def capstan(tau0, mu, s):
    """Kirchhoff rod, one straight tendon at offset r, slip +1: the moment is r tau(s) (the
    distal free body is loaded only by the cut tendon), so theta' = r tau / EI, and the tendon
    turns with the disks: tau' = -mu theta' tau. Hence tau = tau0 exp(-mu theta) and
    theta(s) = ln(1 + mu r tau0 s / EI) / mu, tau(s) = tau0 / (1 + mu r tau0 s / EI)."""
    return tau0 / (1 + mu * OFF * tau0 * s / EI), np.log(1 + mu * OFF * tau0 * s / EI) / mu


@pytest.mark.parametrize("rod", ["kirchhoff", "cosserat"])
def test_planar_capstan_is_the_closed_form(rod):
    mu, tau0 = 0.3, 4.0
    rb = robot([tw.Tendon(offset=(0, OFF), friction=mu)])
    sol = tw.solve_static(rb, [tau0], nodes=40, rod=rod)
    t_end, theta = capstan(tau0, mu, L)
    Rt = sol.tip_rotation[0]
    tip_angle = np.arctan2(Rt[1, 2], Rt[2, 2])
    # Cosserat adds extension and shear, O(tau / EA) ~ 1e-5 relative: they do not change the moment
    assert abs(sol.tendon_tension_end[0, 0] / t_end - 1) < 1e-9
    assert abs(tip_angle / theta - 1) < 1e-9
    assert abs(sol.tendon_turning[0, 0] / theta - 1) < 1e-9
    prof, _ = capstan(tau0, mu, sol.s[0])
    assert np.abs(sol.tendon_tension[0, :, 0] / prof - 1).max() < 1e-9
    assert (sol.slip_state == 1).all() and (sol.slip == 1).all()


def _polyline_turning(pts: np.ndarray, t0: np.ndarray, t1: np.ndarray) -> float:
    """Total turning of a sampled curve: angles between successive chords, and between the
    end tangents and the first and last chords (error O(h^2))."""
    d = np.diff(pts, axis=0)
    d = np.concatenate([t0[None], d / np.linalg.norm(d, axis=1, keepdims=True), t1[None]])
    return float(np.arctan2(np.linalg.norm(np.cross(d[:-1], d[1:]), axis=1), np.sum(d[:-1] * d[1:], axis=1)).sum())


@pytest.mark.parametrize("slip", [1.0, -1.0])
def test_capstan_identity_holds_on_a_general_3d_solution(slip):
    """tau(end) / tau(0) = exp(-sigma mu Theta) with Theta the total turning of the solved tendon
    path, measured here from the solved shape (the path p + R r at the nodes, the end tangents
    from the strains there), independently of the solver's own integral of |t'|: a helical
    tendon and a straight one under gravity and a tip force. (A kink where a tendon ends adds its
    angle to Theta; chords across it do not resolve it: the SciPy comparison covers kinks.)"""
    mu = 0.25
    tendons = [tw.Tendon(offset=(0.004, 0.0), routing="helix", helix_radius=0.006, turns=0.75, friction=mu),
               tw.Tendon(offset=(0.0, -OFF), friction=mu)]
    rb = robot(tendons, gravity=(0, -9.81, 0), tip_force=(0.05, 0.0, 0.02))
    sol = tw.solve_static(rb, [3.0, 2.0], slip=[slip, slip], nodes=400)
    assert sol.converged.all()
    ratio = sol.tendon_tension_end[0] / sol.tendon_tension_base[0]
    assert np.allclose(ratio, np.exp(-slip * mu * sol.tendon_turning[0]), rtol=1e-12, atol=0)
    r, dr, _ = rb.tendon_routing(sol.s[0])
    Rn = sol.rotations[0]
    pts = sol.positions[0][:, None] + np.einsum("nij,nkj->nki", Rn, r)
    sec = rb.section()

    def tangent(i, k):  # the path's unit tangent at node i (n, m just proximal of it)
        v = Rn[i].T @ sol.n[0, i] / sec["kse"][0] + [0, 0, 1]
        u = Rn[i].T @ sol.m[0, i] / sec["kbt"][0]
        pb = np.cross(u, r[i, k]) + dr[i, k] + v
        return Rn[i] @ pb / np.linalg.norm(pb)

    for k in range(2):  # O(h^2): measured 7e-6 at N = 400 (2.8e-5 at N = 200)
        theta = _polyline_turning(pts[:, k], tangent(0, k), tangent(400, k))
        assert abs(theta / sol.tendon_turning[0, k] - 1) < 3e-5, (k, theta, sol.tendon_turning[0, k])


def test_mu_zero_is_the_frictionless_answer_bit_for_bit():
    base = [tw.Tendon(offset=(0, OFF)), tw.Tendon(offset=(OFF, 0), length=0.3)]
    zero = [tw.Tendon(offset=(0, OFF), friction=0.0), tw.Tendon(offset=(OFF, 0), length=0.3, friction=0.0)]
    kw = dict(gravity=(0, 0, -9.81), tip_force=(0.01, 0, 0))
    a = tw.solve_static(robot(base, **kw), [2.0, 1.0], nodes=30)
    b = tw.solve_static(robot(zero, **kw), [2.0, 1.0], nodes=30)
    assert np.array_equal(a.positions, b.positions) and np.array_equal(a.n, b.n) and np.array_equal(a.m, b.m)
    # a batch where another rod has friction runs the friction kernel: mu = 0 there is exact too
    mixed = [tw.Tendon(offset=(0, OFF), friction=[0.0, 0.3]), tw.Tendon(offset=(OFF, 0), length=0.3)]
    c = tw.solve_static(robot(mixed, **kw), [[2.0, 1.0], [2.0, 1.0]], nodes=30)
    assert np.abs(c.positions[0] - a.positions[0]).max() < 1e-14
    assert np.abs(c.positions[1] - a.positions[0]).max() > 1e-4


def test_pull_release_freezes_the_tip_tension_and_moves_a_slip_front():
    """Pull to tau0 (slip +1: tau_p(s) = tau0 / (1 + mu r tau0 s / EI)), then release the motor
    to tau_m < tau0 from that state. Near the motor the tendon slides out (tau' = +mu kappa tau:
    1 / tau = 1 / tau_m - mu r s / EI); beyond the slip front it sticks with its old tension,
    so the tip tension is frozen. The front sits where both meet,
    s* = (1 / tau_m - 1 / tau0) EI / (2 mu r), and reaches the tip when the motor has dropped by
    the factor 1 / (1 + 2 mu r tau0 L / EI) = exp(-mu (Theta_pull + Theta_release)) (Kirchhoff):
    below it the whole tendon slides out and the tip tension falls."""
    mu, tau0, N = 0.3, 4.0, 40
    rb = robot([tw.Tendon(offset=(0, OFF), friction=mu)])
    opts = dict(nodes=N, rod="kirchhoff")
    pull = tw.solve_static(rb, [tau0], **opts)
    factor = 1 / (1 + 2 * mu * OFF * tau0 * L / EI)
    for tm in (3.95, 3.85, tau0 * factor * 1.002):
        rel = tw.solve_static(rb, [tm], history=pull, **opts)
        assert rel.converged.all()
        assert rel.tendon_tension_end[0, 0] == pull.tendon_tension_end[0, 0]  # frozen, exactly
        s_front = (1 / tm - 1 / tau0) * EI / (2 * mu * OFF)
        s = rel.s[0]
        state = rel.slip_state[0, :-1, 0]
        assert (state[s[:-1] < s_front - L / N] == -1).all() and (state[s[:-1] > s_front + L / N] == 0).all()
        pred = np.where(s < s_front, 1 / (1 / tm - mu * OFF * s / EI), capstan(tau0, mu, s)[0])
        # the friction load switches from stick to slip over about one interval beyond the front
        # (kernels/rod.py, ``tensions``): a local error of O(h), 1.1e-5 measured at N = 40
        assert np.abs(rel.tendon_tension[0, :, 0] / pred - 1).max() < 3e-5
        assert (rel.slip == 0).all()
    theta_sum = pull.tendon_turning[0, 0] + rel.tendon_turning[0, 0]
    assert abs(np.exp(-mu * theta_sum) / (factor * 1.002) - 1) < 5e-3
    below = tw.solve_static(rb, [tau0 * factor * 0.99], history=pull, **opts)
    assert below.tendon_tension_end[0, 0] < pull.tendon_tension_end[0, 0] * 0.995
    assert (below.slip_state[0, :, 0] == -1).all()


def test_pull_release_cycle_under_displacement_control_dissipates():
    """Quasi-static cycle q: 0 -> q_max -> 0, each step from the last (history). The motor's
    work over the cycle, the loop integral of tau(0) dq, is what friction dissipated: positive
    with friction, zero (the same points up and down) without. At the same q the motor pulls
    harder on the way up than it holds on the way down, and the shape differs (the tendon's
    length is set, its tension along s is not)."""
    def cycle(mu):
        rb = robot([tw.Tendon(offset=(0, OFF), control="displacement", friction=mu, pretension=0.2)])
        q = np.r_[np.linspace(0, 0.004, 9), np.linspace(0.004, 0, 9)[1:]]
        sol, taus, tips = None, [], []
        for qi in q:
            sol = tw.solve_static(rb, displacements=[qi], history=sol, nodes=30)
            assert sol.converged.all()
            taus.append(sol.tendon_tension_base[0, 0])
            tips.append(sol.tip_position[0])
        taus = np.array(taus)
        return np.sum(0.5 * (taus[1:] + taus[:-1]) * np.diff(q)), np.array(tips), taus

    w0, tips0, _ = cycle(0.0)
    w, tips, taus = cycle(0.3)
    # frictionless: up and down differ only by the solver tolerance (tensions to ~1e-9 N over 4 mm)
    assert abs(w0) < 1e-10 and np.abs(tips0[4] - tips0[-5]).max() < 1e-9
    assert w > 1e-4  # J
    assert (taus[1:8] > taus[-2:-9:-1] * 1.01).all()  # up vs down at the same q
    assert np.linalg.norm(tips[4] - tips[-5]) > 5e-4  # 1.1 mm apart at q = 2 mm


def test_linear_routing_base_wrench_is_the_tendon_pull():
    """Rod + tendon with no external load: cutting at s = 0 leaves only the backbone wrench
    and the tendon's pull, so n(0) = -tau t(0), m(0) = r(0) x n(0), with t(0) the tendon's unit
    tangent at the base (pb = u x r + r' + v). A converging route has r' != 0."""
    tau = 3.0
    t = tw.Tendon(offset=(0.0, OFF), routing="linear", offset_end=(0.003, 0.002))
    rb = robot([t])
    sol = tw.solve_static(rb, [tau], nodes=60, tol=1e-12)  # a base wrench to ~1e-12 N needs the tip to ~1e-12 m
    n0, m0 = sol.base_wrench[0, :3], sol.base_wrench[0, 3:]
    sec = rb.section()
    v = n0 / sec["kse"][0] + [0, 0, 1]
    u = m0 / sec["kbt"][0]
    r, dr, _ = rb.tendon_routing(0.0)
    pb = np.cross(u, r[0, 0]) + dr[0, 0] + v
    assert np.allclose(n0, -tau * pb / np.linalg.norm(pb), rtol=0, atol=1e-11)  # 3 N to 5e-12 relative
    assert np.allclose(m0, np.cross(r[0, 0], n0), rtol=0, atol=1e-12)
    assert abs(rb.tendon_routing(L)[0][0, 0, 0] - 0.003) < 1e-15  # reaches offset_end at the termination


def test_kink_loads_switch_changes_a_two_segment_robot_slightly():
    """A helical tendon ending at mid-length turns the torsion there (its pull has a tangential
    part), and the straight tendon that goes on kinks; with straight tendons alone only the
    tiny shear jump kinks them."""
    tendons = [tw.Tendon(routing="helix", helix_radius=OFF, turns=0.5, length=0.25), tw.Tendon(offset=(0, -OFF))]
    rb = robot(tendons, tip_force=(0.2, 0.3, 0.0))
    on = tw.solve_static(rb, [4.0, 2.0], nodes=40)
    off = tw.solve_static(rb, [4.0, 2.0], nodes=40, kink_loads=False)
    d = np.linalg.norm(on.tip_position - off.tip_position)
    assert 2e-5 < d < 5e-4, d  # 7.3e-5 m measured
    single = robot([tw.Tendon(offset=(0, OFF))], tip_force=(0.0, 0.3, 0.0))  # no jump: nothing to switch
    assert np.array_equal(tw.solve_static(single, [4.0], nodes=20).positions,
                          tw.solve_static(single, [4.0], nodes=20, kink_loads=False).positions)


@pytest.mark.parametrize("make, match", [
    (lambda: tw.Tendon(friction=-0.1), "tendon friction must be >= 0"),
    (lambda: tw.Tendon(compliance=-1e-5), "tendon compliance must be >= 0"),
    (lambda: tw.Tendon(pretension=-1.0), "tendon pretension must be >= 0"),
    (lambda: tw.Tendon(control="length"), "tendon control must be one of"),
    (lambda: tw.Tendon(routing="linear"), "offset_end is required"),
    (lambda: tw.Tendon(offset_end=(0.0, 0.0)), "offset_end is only used"),
])
def test_bad_tendon_fields_name_the_field(make, match):
    with pytest.raises(tw.InputError, match=match):
        make()


def test_bad_commands_name_the_field_and_value():
    rb = robot([tw.Tendon(offset=(0, OFF), control="displacement"), tw.Tendon(offset=(0, -OFF), friction=0.2)])
    with pytest.raises(tw.InputError, match=r"displacements\[0\]\[0\] = 0.6 m needs a negative tendon length"):
        tw.solve_static(rb, [0.0, 1.0], displacements=[0.6, 0.0], nodes=10)
    with pytest.raises(tw.InputError, match=r"displacements\[0\]\[1\] = 0.001: tendon 1 is under tension control"):
        tw.solve_static(rb, [0.0, 1.0], displacements=[0.0, 0.001], nodes=10)
    with pytest.raises(tw.InputError, match=r"tensions\[0\]\[0\] = 2.0: tendon 0 is under displacement control"):
        tw.solve_static(rb, [2.0, 1.0], nodes=10)
    with pytest.raises(tw.InputError, match=r"slip\[0\]\[1\] must be \+1 \(pulled\) or -1 \(released\), got 0.5"):
        tw.solve_static(rb, [0.0, 1.0], slip=[1, 0.5], nodes=10)
    with pytest.raises(tw.InputError, match="no tendon of this robot is under displacement control"):
        tw.solve_static(robot([tw.Tendon()]), [1.0], displacements=[0.001], nodes=10)


def _dynamic_robot(**tendon):
    return robot([tw.Tendon(offset=(0, OFF), control="displacement", pretension=0.5, compliance=2.7e-5, **tendon),
                  tw.Tendon(offset=(0, -OFF), control="displacement", pretension=0.5, compliance=2.7e-5, **tendon)],
                 damping_bending=(0.02, 0.02, 0.02), drag=(0.01, 0.01, 0.01))


def test_displacement_control_in_dynamics_settles_to_the_static_answer():
    """Pull one tendon 2 mm and release its antagonist 2 mm (it goes slack) in one step, hold:
    the damped rod settles on the static solution of the same displacements."""
    rb = _dynamic_robot()
    sim = tw.Simulator(rb, displacements=[0.0, 0.0], dt=0.005, alpha=-0.2, nodes=20)
    for _ in range(300):
        r = sim.step(displacements=[0.002, -0.002])
        assert r.converged.all()
    st = tw.solve_static(rb, displacements=[0.002, -0.002], nodes=20)
    assert np.abs(r.tip_position - st.tip_position).max() < 1e-7  # 6e-9 m measured after 1.5 s
    held = sim.step()  # no displacements: the motors stay where they are
    assert np.abs(held.tip_position - r.tip_position).max() < 1e-9
    t = sim.tendons()
    assert t["tension_base"][0, 1] == 0.0 and st.slack[0, 1]
    assert abs(t["tension_base"][0, 0] / st.tendon_tension_base[0, 0] - 1) < 1e-6


def test_friction_in_dynamics_follows_the_sliding_direction():
    """A tendon pulled at 5 mm/s slides toward the motor (sigma = tanh(5) ~ +1): its tension
    falls toward the tip by exp(-sigma mu Theta); released, it rises; held still, the slip
    direction and with it friction fade (no stick in dynamics)."""
    mu, dt = 0.3, 0.005
    rb = robot([tw.Tendon(offset=(0, OFF), control="displacement", pretension=0.5, compliance=2.7e-5, friction=mu)],
               damping_bending=(0.02, 0.02, 0.02), drag=(0.01, 0.01, 0.01))
    sim = tw.Simulator(rb, displacements=[0.0], dt=dt, alpha=-0.2, nodes=20)

    def run(q_of_step, n):
        for i in range(n):
            assert sim.step(displacements=[q_of_step(i)]).converged.all()
        return sim.tendons()

    pull = run(lambda i: (i + 1) * dt * 0.005, 60)
    assert pull["slip"][0, 0] > 0.99
    ratio = pull["tension_end"] / pull["tension_base"]
    assert np.allclose(ratio, np.exp(-pull["slip"] * mu * pull["turning"]), rtol=1e-12) and ratio[0, 0] < 0.97
    release = run(lambda i: 0.0015 - (i + 1) * dt * 0.005, 30)
    assert release["slip"][0, 0] < -0.99 and release["tension_end"][0, 0] > release["tension_base"][0, 0] * 1.01
    held = run(lambda i: 0.00075, 200)
    assert abs(held["slip"][0, 0]) < 1e-3


def test_points_routing_reproduces_linear_and_helical_routes():
    """A route through points is a not-a-knot cubic spline: through collinear points it is the
    straight line of a linear route (the same answer to round-off); through samples of a helix
    it converges to the helical route as the points get denser (interpolation error O(h^4);
    the knots are grid nodes, so RK4 keeps its order)."""
    lin = tw.Tendon(offset=(0.0, OFF), routing="linear", offset_end=(0.003, 0.002))
    pts = tw.Tendon(routing="points", points=[(0.0, 0.0, OFF), (0.2, 0.0012, 0.0068), (0.5, 0.003, 0.002)])
    a = tw.solve_static(robot([lin]), [3.0], nodes=40)
    b = tw.solve_static(robot([pts]), [3.0], nodes=40)
    assert np.abs(a.tip_position - b.tip_position).max() < 1e-14
    helix = tw.solve_static(robot([tw.Tendon(routing="helix", helix_radius=OFF, turns=0.5)]), [3.0], nodes=40)
    errs = []
    for m in (11, 21, 41):
        s = np.linspace(0.0, L, m)
        P = np.c_[s, OFF * np.cos(np.pi * s / L), OFF * np.sin(np.pi * s / L)]
        sol = tw.solve_static(robot([tw.Tendon(routing="points", points=P)]), [3.0], nodes=40)
        errs.append(np.abs(sol.tip_position - helix.tip_position).max())
    assert errs[2] < 1e-8 and errs[0] / errs[1] > 8 and errs[1] / errs[2] > 8, errs


@pytest.mark.parametrize("make, match", [
    (lambda: tw.Tendon(routing="points", points=[(0.0, 0.0, 0.01), (0.3, 0.0, 0.01), (0.2, 0.0, 0.01)]),
     r"tendon points must be increasing in s: s = 0.2 follows 0.3"),
    (lambda: tw.Tendon(routing="points", points=[(0.1, 0.0, 0.01), (0.5, 0.0, 0.01)]), "the first s must be 0"),
    (lambda: tw.Tendon(routing="points", points=[(0.0, 0.01)]), "expected two or more"),
    (lambda: robot([tw.Tendon(routing="points", points=[(0.0, 0.0, 0.01), (0.4, 0.0, 0.01)])]),
     "points end at s = 0.4, the tendon runs to the tip"),
    (lambda: robot([tw.Tendon(routing="points", points=[(0.0, 0.0, 0.01), (0.25, 0.013, 0.0), (0.5, 0.0, 0.01)])],
                   disk_radius=0.012), r"tendons\[0\] routing leaves the disk: \|r\| = 0.013\d* m at s = 0.2\d* m "
                                       r"\(rod 0\), beyond disk_radius = 0.012 m"),
    (lambda: robot([tw.Tendon(offset=(0.0, 0.01), routing="linear", offset_end=(0.0, 0.02))], disk_radius=0.015),
     r"tendons\[0\] routing leaves the disk"),
])
def test_bad_routes_name_the_field(make, match):
    with pytest.raises(tw.InputError, match=match):
        make()
