"""Sliding-mode tip control: the law on a known plant, and closed loops on the rod."""

import numpy as np
import pytest

import tdcr_warp as tw
from tdcr_warp.apps.control import (
    TipController,
    allocate,
    control_metrics,
    run_closed_loop,
    sliding_command,
    static_target,
)

OFFSETS = [(0.01, 0.0), (0.0, 0.01), (-0.01, 0.0), (0.0, -0.01)]


def seed_robot(**kw):
    base = dict(length=0.5, youngs_modulus=190e9, poisson_ratio=0.3, radius=1e-3, density=17189.0,
                tendons=[tw.Tendon(offset=o) for o in OFFSETS], gravity=(0.0, 0.0, -9.81),
                damping_bending=(0.008, 0.008, 0.008), drag=(0.01, 0.01, 0.01))
    base.update(kw)
    return tw.Robot(**base)


@pytest.mark.parametrize("method", ["smc", "boundary_layer"])
def test_lyapunov_decreases_on_known_second_order_plant(method):
    """X2_t = a_c + b_c tau with known a_c, b_c: V = |S|^2 / 2 obeys V_t <= -2 k V."""
    rng = np.random.default_rng(0)
    ac = np.array([[0.3, -0.2, 0.1]])
    bc = rng.normal(size=(1, 3, 3)) + 3 * np.eye(3)
    C, k = np.array([[5.0, 4.0, 3.0]]), np.array([[2.0, 2.0, 2.0]])
    eps, phi = np.array([0.05]), np.array([1e-3])
    x, v, target = np.zeros((1, 3)), np.zeros((1, 3)), np.array([[0.02, -0.01, 0.03]])
    dt = 2e-4
    V = []
    for _ in range(20000):
        S, cmd = sliding_command(target - x, -v, ac, C=C, k=k, eps=eps, phi=phi, method=method)
        V.append(0.5 * float((S**2).sum()))
        tau = np.linalg.solve(bc[0], cmd[0])[None]
        acc = ac + np.einsum("bij,bj->bi", bc, tau)
        v = v + dt * acc
        x = x + dt * v
    V = np.array(V)
    t = dt * np.arange(len(V))
    big = V > 1e-8  # away from the discrete-time switching layer
    assert np.all(np.diff(V)[big[:-1]] < 0), "V must decrease along the closed loop"
    kmin = k.min()
    assert np.all(V[big] <= V[0] * np.exp(-2 * kmin * t[big]) * (1 + 1e-2) + 1e-12)
    assert np.abs(target - x).max() < 1e-5  # 4 s: the slowest sliding mode e^(-3 t) has decayed


def test_allocation_respects_bounds_and_reaches_interior_command():
    rng = np.random.default_rng(1)
    Bc = rng.normal(size=(50, 3, 4))
    tau_true = rng.uniform(0.5, 2.0, (50, 4))
    v = np.einsum("bik,bk->bi", Bc, tau_true)
    tau = allocate(Bc, v, np.full((50, 4), 5.0), np.zeros((50, 4)), sweeps=400)
    assert np.abs(np.einsum("bik,bk->bi", Bc, tau) - v).max() < 1e-5
    wild = allocate(Bc, 100 * rng.normal(size=(50, 3)), np.full((50, 4), 5.0), np.zeros((50, 4)))
    assert (wild >= 0).all() and (wild <= 5.0).all()


def _closed_loop(target_tau, steps=200, B=1, **kw):
    rob = seed_robot()
    target = static_target(rob, target_tau, nodes=20)
    sim = tw.Simulator(rob, np.zeros((B, 4)), dt=0.005, alpha=-0.2, nodes=20)
    ctl = TipController(sim, target, **kw)
    run = run_closed_loop(sim, ctl, steps)
    assert run.converged.all()
    return run, ctl, control_metrics(run, ctl.tau_max)


def test_settles_on_own_static_tip_at_3N():
    run, ctl, m = _closed_loop([[3.0, 0.0, 0.0, 0.0]])
    assert m["final_error"][0] < 5e-4, f"final error {m['final_error'][0] * 1e3:.3f} mm"
    assert np.isfinite(m["settling_time"][0])
    tau1 = run.tensions[-1, 0, 0] - run.tensions[-1, 0, 2]  # net pull in the tendon-1 plane
    assert abs(tau1 - 3.0) < 0.06, f"settled tension {tau1:.3f} N"
    assert abs(run.tensions[-1, 0, 0] - 3.0) < 0.06


def test_boundary_layer_cuts_chatter_tenfold():
    _, _, sgn = _closed_loop([[3.0, 0.0, 0.0, 0.0]], method="smc")
    _, _, sat = _closed_loop([[3.0, 0.0, 0.0, 0.0]], method="boundary_layer")
    assert sgn["chatter"][0] > 10 * sat["chatter"][0], (sgn["chatter"], sat["chatter"])
    assert sgn["reversal_fraction"][0] > 10 * sat["reversal_fraction"][0]


def test_tension_bounds_never_violated_even_with_report_gains():
    run, ctl, m = _closed_loop([[3.0, 0.0, 0.0, 0.0]], steps=60, method="smc", gain_c=(15000.0, 1.0, 500.0),
                               gain_k=(30.0, 1.0, 5.0), tension_max=8.0)
    assert (run.tensions >= 0).all() and (run.tensions <= 8.0).all()
    assert m["saturation_fraction"][0] > 0.1  # the report's gains do saturate


def test_off_plane_3d_target_reached_with_two_tendons():
    run, ctl, m = _closed_loop([[2.0, 1.5, 0.0, 0.0]], steps=240)
    assert m["final_error"][0] < 5e-4, f"final error {m['final_error'][0] * 1e3:.3f} mm"
    final = run.tensions[-1, 0]
    assert (final[:2] > 1.0).all(), f"final tensions {final}"


def test_batch_of_gains_matches_each_run_alone():
    gains_c = np.array([[20.0] * 3, [10.0] * 3, [40.0, 30.0, 20.0]])
    target_tau = np.array([[3.0, 0, 0, 0], [1.0, 1.0, 0, 0], [0.0, 0.0, 2.0, 0.5]])
    rob = seed_robot()
    target = static_target(rob, target_tau, nodes=20)
    sim = tw.Simulator(rob, np.zeros((3, 4)), dt=0.005, alpha=-0.2, nodes=20)
    batch = run_closed_loop(sim, TipController(sim, target, gain_c=gains_c, method="smc"), 40)
    for b in range(3):
        one = tw.Simulator(rob, np.zeros((1, 4)), dt=0.005, alpha=-0.2, nodes=20)
        alone = run_closed_loop(one, TipController(one, target[b], gain_c=gains_c[b], method="smc"), 40)
        assert np.abs(alone.tip_position[:, 0] - batch.tip_position[:, b]).max() < 1e-9
        assert np.abs(alone.tensions[:, 0] - batch.tensions[:, b]).max() < 1e-6


def test_quasi_static_jacobian_tracks_better_than_report_alpha_model():
    _, _, jac = _closed_loop([[3.0, 0.0, 0.0, 0.0]], steps=100, input_model="jacobian")
    _, _, alpha = _closed_loop([[3.0, 0.0, 0.0, 0.0]], steps=100, input_model="alpha")
    assert jac["rms_error"][0] < 0.5 * alpha["rms_error"][0], (jac["rms_error"], alpha["rms_error"])


def test_metrics_on_a_known_history():
    from tdcr_warp.apps.control import ControlRun
    t = np.arange(6) * 0.1
    err = np.array([1e-2, 5e-3, -1e-3, 2e-4, 1e-4, 0.0])
    tau = np.array([0.0, 1.0, 2.0, 1.5, 2.5])[:, None, None]
    run = ControlRun(time=t, tip_position=np.zeros((6, 1, 3)), tip_velocity=np.zeros((6, 1, 3)),
                     error=np.stack([err, 0 * err, 0 * err], -1)[:, None], sliding=np.zeros((6, 1, 3)),
                     tensions=tau, converged=np.ones((5, 1), bool), target=np.zeros((1, 3)))
    m = control_metrics(run, np.array([[2.5]]), band=5e-4)
    assert m["settling_time"][0] == pytest.approx(0.3)
    assert m["overshoot"][0] == pytest.approx(1e-3)
    assert m["peak_tension"][0] == 2.5 and m["saturation_fraction"][0] == pytest.approx(2 / 5)
    assert m["tension_rate"][0] == pytest.approx((1 + 1 + 0.5 + 1) / 4)


def test_bad_control_input():
    rob = seed_robot()
    sim = tw.Simulator(rob, np.zeros((1, 4)), dt=0.005, nodes=10)
    with pytest.raises(tw.InputError, match="control method"):
        TipController(sim, [0, 0, 0.5], method="pid")
    with pytest.raises(tw.InputError, match="gain_c must be positive"):
        TipController(sim, [0, 0, 0.5], gain_c=-1.0)
    with pytest.raises(tw.InputError, match="target"):
        TipController(sim, [0, 0.5])
