"""Tip trajectory tracking: desired paths and their derivatives, the law on a known plant, the
closed loop on the rod (a batch equals each rod alone), metrics, scenes and bad input."""

import json

import numpy as np
import pytest
from test_control import seed_robot

import tdcr_warp as tw
from tdcr_warp.apps.control import ControlRun, TipController, control_metrics, run_closed_loop, sliding_command
from tdcr_warp.cli import main
from tdcr_warp.model.robot import InputError
from tdcr_warp.model.tippath import TipPath, path_from_table


def _finite_difference(path, t, h=1e-6):
    (p0, _, _), (p1, v, a), (p2, _, _) = path(t - h), path(t), path(t + h)
    return (p2 - p0) / (2 * h), (p2 - 2 * p1 + p0) / h**2, v, a


@pytest.mark.parametrize("path", [
    TipPath.circle([0.0, 0.0, 0.5], 0.01, 1.0),
    TipPath.circle([[0.0, 0.0, 0.5], [0.01, 0.0, 0.4]], [0.01, 0.02], [1.0, -0.5], axis="x", phase=[0.0, 1.0]),
    TipPath.waypoints([0.0, 0.3, 0.7, 1.0], [[0, 0, 0.5], [0.01, 0, 0.5], [0.01, 0.01, 0.49], [0, 0, 0.5]]),
])
def test_velocity_and_acceleration_are_the_derivatives_of_the_path(path):
    for t in (0.1, 0.37, 0.8):
        fd_v, fd_a, v, a = _finite_difference(path, t)
        assert np.allclose(v, fd_v, atol=1e-8) and np.allclose(a, fd_a, atol=1e-3)


def test_shapes_pass_where_they_should():
    c = TipPath.circle([0.0, 0.0, 0.5], 0.01, 2.0)
    p, v, a = c(0.0)
    assert np.allclose(p, [[0.01, 0.0, 0.5]]) and np.allclose(np.linalg.norm(v), 2 * np.pi * 2 * 0.01)
    assert np.allclose(c(0.5)[0], p)  # one period at 2 rev/s
    pts = np.array([[0, 0, 0.5], [0.01, 0, 0.5], [0.01, 0.01, 0.49]])
    w = TipPath.waypoints([0.0, 0.5, 1.0], pts)
    for t, q in zip((0.0, 0.5, 1.0), pts):
        assert np.allclose(w(t)[0], q)
    assert np.allclose(w(0.0)[1], 0) and np.allclose(w(1.0)[1], 0)  # clamped: at rest at both ends
    assert np.allclose(w(2.0)[0], pts[-1]) and np.allclose(w(2.0)[1], 0)  # held after the last
    line = TipPath.line([0, 0, 0.5], [0.03, 0.04, 0.5], 0.1)  # 50 mm at 0.1 m/s: 0.5 s
    assert np.allclose(line(0.25)[0], [[0.015, 0.02, 0.5]]) and np.allclose(np.linalg.norm(line(0.25)[1]), 0.1)
    assert np.allclose(line(1.0)[0], [[0.03, 0.04, 0.5]]) and np.allclose(line(1.0)[1], 0)


def test_tracking_on_a_known_plant_obeys_the_lyapunov_bound():
    """X2_t = a_c + b_c tau, known: with the desired velocity and acceleration in the law, V = |S|^2/2
    falls as V_t <= -2 k V and the tip converges onto a moving circle."""
    rng = np.random.default_rng(0)
    ac = np.array([[0.3, -0.2, 0.1]])
    bc = rng.normal(size=(1, 3, 3)) + 3 * np.eye(3)
    C, k = np.array([[5.0, 4.0, 3.0]]), np.array([[2.0, 2.0, 2.0]])
    eps, phi = np.array([0.05]), np.array([1e-3])
    path = TipPath.circle([0.0, 0.0, 0.0], 0.02, 0.5, axis="y")
    x, v, dt = np.zeros((1, 3)), np.zeros((1, 3)), 2e-4
    V, err = [], []
    for i in range(25000):
        p_d, v_d, a_d = path(i * dt)
        S, cmd = sliding_command(p_d - x, v_d - v, ac, C=C, k=k, eps=eps, phi=phi, method="boundary_layer",
                                 xdd_d=a_d)
        V.append(0.5 * float((S**2).sum()))
        err.append(float(np.linalg.norm(p_d - x)))
        acc = ac + np.einsum("bij,bj->bi", bc, np.linalg.solve(bc[0], cmd[0])[None])
        v, x = v + dt * acc, x + dt * (v + dt * acc)
    V, t = np.array(V), dt * np.arange(len(V))
    big = V > 1e-8
    assert np.all(np.diff(V)[big[:-1]] < 0)
    assert np.all(V[big] <= V[0] * np.exp(-2 * k.min() * t[big]) * (1 + 1e-2) + 1e-12)
    assert max(err[-5000:]) < 1e-4  # on the surface the error decays as e^(-C t): 5 s in, it tracks


def _tracking(paths, steps=30):
    rob = seed_robot()
    B = len(paths) if isinstance(paths, list) else 1
    sim = tw.Simulator(rob, np.zeros((B, 4)), dt=0.005, alpha=-0.2, nodes=10)
    path = paths if not isinstance(paths, list) else TipPath(
        lambda t: tuple(np.concatenate(q) for q in zip(*(p(t) for p in paths))))
    ctl = TipController(sim, path, epsilon=0.5, phi=0.005, tension_max=8.0)
    return run_closed_loop(sim, ctl, steps), ctl


def test_a_batch_of_trajectories_equals_each_alone():
    paths = [TipPath.circle([0.0, 0.0, 0.4998], 0.01, 1.0), TipPath.circle([0.0, 0.0, 0.4998], 0.005, -1.0, phase=1.0)]
    both, _ = _tracking(paths)
    for b, p in enumerate(paths):
        alone, _ = _tracking(p)
        assert np.abs(both.tip_position[:, b] - alone.tip_position[:, 0]).max() < 1e-12
        assert np.array_equal(both.desired[:, b], alone.desired[:, 0])


def test_tracking_on_the_rod_follows_the_circle_and_respects_the_limits():
    run, ctl = _tracking(TipPath.circle([0.0, 0.0, 0.4998], 0.01, 1.0), steps=120)
    assert run.converged.all() and (run.tensions >= 0).all() and (run.tensions <= 8.0).all()
    m = control_metrics(run, ctl.tau_max)
    # the tip starts 10 mm off the path's start (at rest on the axis) and has caught up by the end
    assert np.linalg.norm(run.error[0]) == pytest.approx(0.01, rel=1e-3)
    assert m["max_error"][0] < 0.004 and m["rms_error"][0] < 0.006
    assert np.array_equal(run.desired[0], ctl.target)


def test_lag_of_a_delayed_history():
    t = np.arange(201) * 0.01
    desired = np.stack([np.sin(2 * np.pi * t), np.cos(2 * np.pi * t), 0 * t], axis=-1)[:, None] * 0.01
    delayed = np.concatenate([np.repeat(desired[:1], 7, axis=0), desired[:-7]])  # 7 steps behind
    run = ControlRun(time=t, tip_position=delayed, tip_velocity=0 * delayed, error=desired - delayed,
                     sliding=0 * delayed, tensions=np.ones((200, 1, 2)), converged=np.ones((200, 1), bool),
                     target=desired[0])
    m = control_metrics(run, np.full((1, 2), 8.0))
    assert m["lag"][0] == pytest.approx(0.07)
    assert m["max_error"][0] == pytest.approx(np.linalg.norm(desired - delayed, axis=2)[100:].max())


@pytest.mark.parametrize("make,message", [
    (lambda: TipPath.circle([0.0, np.nan, 0.5], 0.01, 1.0), "centre"),
    (lambda: TipPath.circle([0.0, 0.0, 0.5], -0.01, 1.0), "radius"),
    (lambda: TipPath.circle([0.0, 0.0, 0.5], 0.01, 1.0, axis="w"), "axis"),
    (lambda: TipPath.waypoints([0.0, 0.5, 0.5], np.zeros((3, 3))), "strictly increasing"),
    (lambda: TipPath.waypoints([0.0, 1.0], np.zeros((3, 3))), r"points: expected finite \(2, 3\)"),
    (lambda: TipPath.waypoints([0.0, np.inf], np.zeros((2, 3))), "times"),
    (lambda: TipPath.line([0, 0, 0.5], [0, 0, 0.5], 0.1), "same point"),
    (lambda: TipPath(lambda t: (np.zeros(2), np.zeros(3), np.zeros(3)))(0.0), "position"),
    (lambda: TipPath(lambda t: (np.zeros(3), np.full(3, np.nan), np.zeros(3)))(0.0), "velocity"),
    (lambda: path_from_table({"shape": "spiral"}), "path.shape"),
    (lambda: path_from_table({"shape": "circle", "centre": [0, 0, 0.5], "radius": 0.01}), "frequency"),
    (lambda: path_from_table({"shape": "line", "start": [0, 0, 0], "end": [1, 0, 0], "speed": 1, "x": 1}), "'x'"),
])
def test_bad_trajectories_are_clear_errors(make, message):
    with pytest.raises(InputError, match=message):
        make()


def test_a_path_for_the_wrong_batch_is_refused():
    rob = seed_robot()
    sim = tw.Simulator(rob, np.zeros((3, 4)), dt=0.005, nodes=10)
    two = TipPath.circle([[0.0, 0.0, 0.5], [0.0, 0.0, 0.5]], 0.01, 1.0)
    with pytest.raises(InputError, match="for 3 rods"):
        TipController(sim, two)


def test_cli_tracks_a_scene_path(tmp_path):
    text = """
[robot]
length = 0.5
youngs_modulus = 190e9
poisson_ratio = 0.3
radius = 0.001
density = 17189
[[tendons]]
offset = [0.01, 0.0]
[[tendons]]
offset = [0.0, 0.01]
[[tendons]]
offset = [-0.01, 0.0]
[[tendons]]
offset = [0.0, -0.01]
[actuation]
tensions = [[0.0, 0.0, 0.0, 0.0]]
[dynamics]
dt = 0.005
steps = 20
damping_bending = [0.008, 0.008, 0.008]
[control]
path = { shape = "circle", centre = [0.0, 0.0, 0.4998], radius = 0.01, frequency = 1.0 }
epsilon = 0.5
phi = 0.005
[solver]
nodes = 10
"""
    scene = tmp_path / "c.toml"
    scene.write_text(text)
    assert main(["control", str(scene), "--out", str(tmp_path / "o"), "--quiet"]) == 0
    m = json.loads((tmp_path / "o" / "metrics.json").read_text())
    assert m["units"]["lag"] == "s" and len(m["metrics"]["max_error"]) == 1
    run = np.load(tmp_path / "o" / "control.npz")
    assert np.allclose(run["desired"][0, 0], [0.01, 0.0, 0.4998])
    scene.write_text(text.replace('path = { shape = "circle"', 'target = [0.0, 0.0, 0.5]\npath = { shape = "circle"'))
    assert main(["control", str(scene), "--out", str(tmp_path / "o2"), "--quiet"]) == 2


def test_integral_sliding_mode_removes_the_steady_error_of_a_wrong_model():
    """The plant's drift a_c is up to 0.4 m/s^2 off the model's (a constant model error d): the
    boundary layer settles where k S + eps sw(S) balances d, off the target; the integral surface
    S = e_t + C e + Ci int e settles at the same S, which now means e -> 0 (e_tt + C e_t + Ci e = 0)."""
    ac_model = np.array([[0.3, -0.2, 0.1]])
    d = np.array([[0.4, -0.3, 0.2]])
    bc = np.eye(3)[None] * 2.0
    C, k = np.full((1, 3), 10.0), np.full((1, 3), 5.0)
    eps, phi = np.array([0.05]), np.array([0.01])
    target, dt = np.array([[0.02, -0.01, 0.03]]), 1e-3
    final = {}
    for method in ("boundary_layer", "integral"):
        x, v, ie = np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3))
        for _ in range(8000):
            e = target - x
            _, cmd = sliding_command(e, -v, ac_model, C=C, k=k, eps=eps, phi=phi, method=method, Ci=C**2 / 4, ie=ie)
            acc = ac_model + d + np.einsum("bij,bj->bi", bc, np.linalg.solve(bc[0], cmd[0])[None])
            v, x, ie = v + dt * acc, x + dt * (v + dt * acc), ie + dt * e
        final[method] = float(np.abs(target - x).max())
    # boundary layer: S_t = -d - eps sw(S) - k S settles at |S*| = (|d| - eps) / k = 0.07 (outside the
    # layer phi), so e = S* / C = 7 mm off
    assert final["boundary_layer"] == pytest.approx((0.4 - 0.05) / 5 / 10, rel=1e-3)
    assert final["integral"] < 1e-6


def test_integral_control_on_the_rod_settles_where_the_nominal_model_is_wrong():
    """A plant 10% stiffer than the controller's model: the boundary layer is left off the
    target, the integral surface brings the tip within 0.1 mm."""
    plant, model = seed_robot(youngs_modulus=209e9), seed_robot()
    from tdcr_warp.apps.control import static_target
    target = static_target(model, [[3.0, 0.0, 0.0, 0.0]], nodes=10)
    err = {}
    for method in ("boundary_layer", "integral"):
        sim = tw.Simulator(plant, np.zeros((1, 4)), dt=0.005, alpha=-0.2, nodes=10)
        ctl = TipController(sim, target, method=method, epsilon=0.05, phi=0.005, model_robot=model)
        run = run_closed_loop(sim, ctl, 300)
        assert (run.tensions >= 0).all() and (run.tensions <= 8.0).all()
        err[method] = float(np.linalg.norm(run.error[-1]))
    assert err["integral"] < 1e-4 < err["boundary_layer"], err
