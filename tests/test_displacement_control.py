"""Displacement-commanded control: the batched QP solver, the tension and slack Jacobians it
relies on, and the closed loop on the report's robot driven by its motors."""

import itertools
import tomllib
from pathlib import Path

import numpy as np
import pytest

from tdcr_warp.apps.allocation import solve_qp
from tdcr_warp.apps.control import TipController, control_metrics, run_closed_loop
from tdcr_warp.apps.jobs import scene_controller, scene_simulator
from tdcr_warp.io.scene import scene_from_dict
from tdcr_warp.model.robot import InputError
from tdcr_warp.physics.dynamics import Simulator
from tdcr_warp.physics.statics import reference_lengths, solve_static

EXAMPLE = Path(__file__).parents[1] / "examples" / "displacement_control.toml"


def example(**control):
    data = tomllib.loads(EXAMPLE.read_text())
    data["control"] |= control
    return scene_from_dict(data)


def exact_qp(H, c, A, lo, hi):
    """The optimum by enumeration of active sets (each row at lo, at hi or free): the KKT
    system of every set, the feasible solution with the least objective."""
    n, m = c.shape[0], A.shape[0]
    best, best_f = None, np.inf
    for pattern in itertools.product((0, 1, 2), repeat=m):
        rows = [i for i in range(m) if pattern[i]]
        b = np.array([lo[i] if pattern[i] == 1 else hi[i] for i in rows])
        if not np.isfinite(b).all():  # a one-sided row cannot bind on its open side
            continue
        Aa = A[rows]
        kkt = np.block([[H, Aa.T], [Aa, np.zeros((len(rows), len(rows)))]])
        try:
            sol = np.linalg.solve(kkt, np.concatenate([-c, b]))
        except np.linalg.LinAlgError:
            continue
        x = sol[:n]
        if (A @ x < lo - 1e-9).any() or (A @ x > hi + 1e-9).any():
            continue
        f = 0.5 * x @ H @ x + c @ x
        if f < best_f:
            best, best_f = x, f
    return best, best_f


def test_admm_finds_the_exact_optimum_of_bounded_quadratic_programmes():
    rng = np.random.default_rng(3)
    B, n = 12, 3
    M = rng.normal(size=(B, 3, n))
    H = np.einsum("bik,bil->bkl", M, M) + 1e-3 * np.eye(n)
    c = rng.normal(size=(B, n)) * 3
    A = np.concatenate([np.broadcast_to(np.eye(n), (B, n, n)), rng.normal(size=(B, n, n))], axis=1)
    lo = np.concatenate([np.full((B, n), -1.0), np.full((B, n), -0.5)], axis=1)
    hi = np.concatenate([np.full((B, n), 1.0), rng.uniform(0.1, 1.0, size=(B, n))], axis=1)
    lo[:, 4], hi[:, 5] = -np.inf, np.inf  # one-sided rows
    x, _, iters = solve_qp(H, c, A, lo, hi)
    active = 0
    for b in range(B):
        ref, f_ref = exact_qp(H[b], c[b], A[b], lo[b], hi[b])
        f = 0.5 * x[b] @ H[b] @ x[b] + c[b] @ x[b]
        assert abs(f - f_ref) <= 1e-6 * max(1.0, abs(f_ref))
        assert np.abs(x[b] - ref).max() < 1e-4
        Ax = A[b] @ x[b]
        assert (Ax >= lo[b] - 1e-6).all() and (Ax <= hi[b] + 1e-6).all()
        active += int(((np.abs(A[b] @ ref - lo[b]) < 1e-9) | (np.abs(A[b] @ ref - hi[b]) < 1e-9)).any())
    assert active >= B // 2  # the test exercises bounds that bind
    assert iters < 4000


def slack_lengths(robot, q, opts):
    s = solve_static(robot, np.zeros_like(q), displacements=q, options=opts)
    return reference_lengths(robot, options=opts) - q - s.tendon_free_length, s.tendon_tension_base


def test_tension_and_slack_jacobians_match_finite_differences():
    """d tension / d q of the taut tendons and d slack / d q of the slack one, against central
    differences of solved states (tendon 3 released into slack)."""
    scene = example()
    robot, opts = scene.robot, scene.options
    q = np.array([[0.002, 0.0005, -0.002, 0.0]])
    sol = solve_static(robot, np.zeros((1, 4)), displacements=q, options=opts, sensitivities=True)
    assert sol.slack[0].tolist() == [False, False, True, False]
    h = 1e-6
    dT, dG = np.zeros((4, 4)), np.zeros((4, 4))
    for j in range(4):
        up, down = q.copy(), q.copy()
        up[0, j] += h
        down[0, j] -= h
        (gu, tu), (gd, td) = slack_lengths(robot, up, opts), slack_lengths(robot, down, opts)
        dT[:, j], dG[:, j] = (tu - td)[0] / (2 * h), (gu - gd)[0] / (2 * h)
    T, G = sol.tension_jacobian[0], sol.slack_jacobian[0]
    taut = [0, 1, 3]
    assert np.abs(T[taut] - dT[taut]).max() < 1e-4 * np.abs(dT).max()
    assert np.abs(G[2] - dG[2]).max() < 1e-4
    assert G[2, 2] == pytest.approx(-1.0, abs=1e-6)  # releasing it by 1 mm leaves it 1 mm more slack
    assert G[2, 0] < -0.5  # pulling its antagonist takes its slack in
    assert not T[2].any() and not G[taut].any()


@pytest.fixture(scope="module")
def closed_loop():
    scene = example()
    sim = scene_simulator(scene)
    ctl = scene_controller(scene, sim)
    run = run_closed_loop(sim, ctl, scene.dynamics.steps)
    return scene, sim, ctl, run


def test_displacement_commands_reach_the_target_within_range_and_limits(closed_loop):
    scene, sim, ctl, run = closed_loop
    m = control_metrics(run, ctl.tau_max)
    assert (sim.failed_step < 0).all()
    assert m["final_error"][0] < 1e-4
    assert m["settling_time"][0] < 0.8
    assert run.displacements.shape == run.tensions.shape
    assert (run.displacements >= -0.005).all() and (run.displacements <= 0.005).all()
    assert run.tensions.max() <= ctl.tau_max.max()  # 8 N: the bound of the allocation
    assert (run.tensions >= 0).all()
    # the commanded displacements end where the statics put this tip (tendon 3, released, may
    # hold a little more or less slack: it does not pull)
    target_q = np.array(scene.control["target_displacements"])[0]
    assert np.abs(run.displacements[-1, 0, [0, 1, 3]] - target_q[[0, 1, 3]]).max() < 1e-4


def test_a_slack_antagonist_is_paid_out_and_held_ready(closed_loop):
    """Tendon 3 goes slack as tendon 1 pulls; the allocation never lets it unwind: at every
    refresh of the model a slack tendon has under 0.1 mm to spare."""
    scene, sim, ctl, run = closed_loop
    assert (run.tensions[:, 0, 2] == 0).mean() > 0.1  # slack for part of the run
    gaps = []
    sim2 = scene_simulator(scene)
    ctl2 = scene_controller(scene, sim2)
    for i in range(120):
        q = ctl2()
        if ctl2._lin["slack"].any():
            gaps.append(ctl2._lin["gap"][ctl2._lin["slack"]].max())
        sim2.step(displacements=q)
    assert gaps and max(gaps) < 1e-4


def test_displacement_command_input_errors():
    scene = example()
    sim = scene_simulator(scene)
    with pytest.raises(InputError, match="input_model"):
        TipController(sim, [0.02, 0.0, 0.49], command="displacement", input_model="alpha")
    with pytest.raises(InputError, match="displacement_range"):
        TipController(sim, [0.02, 0.0, 0.49], command="displacement", displacement_range=(0.003, -0.003))
    with pytest.raises(InputError, match="displacement_range"):
        TipController(sim, [0.02, 0.0, 0.49], command="displacement", displacement_range=0.003)
    with pytest.raises(InputError, match="command"):
        TipController(sim, [0.02, 0.0, 0.49], command="torque")
    far = Simulator(scene.robot, np.zeros((1, 4)), dt=0.005, options=scene.options,
                    displacements=[[0.004, 0.0, 0.0, 0.0]])
    with pytest.raises(InputError, match="outside displacement_range"):
        TipController(far, [0.02, 0.0, 0.49], command="displacement", displacement_range=(-0.003, 0.003))
    data = tomllib.loads(EXAMPLE.read_text())
    for t in data["tendons"]:
        t.pop("control"), t.pop("pretension"), t.pop("compliance")
    data["actuation"].pop("displacements")
    with pytest.raises(InputError, match=r"tendon\(s\) \[0, 1, 2, 3\].*tension control"):
        tension = scene_from_dict({k: v for k, v in data.items() if k != "control"})
        TipController(scene_simulator(tension), [0.02, 0.0, 0.49], command="displacement")


@pytest.mark.parametrize("control, message", [
    ({"command": "torque"}, "command"),
    ({"target": [0.02, 0.0, 0.49]}, "exactly one"),
    ({"target_displacements": [[0.1, 0.0]]}, "target_displacements"),
    ({"displacement_range": ["a", 0.1]}, "displacement_range"),
])
def test_bad_control_tables_name_the_key(control, message):
    with pytest.raises(InputError, match=message):
        example(**control)


def test_a_batch_of_different_targets_equals_each_alone():
    """Three rods with their own targets in one batch: each rod's closed loop is the one it runs
    alone (the QP's iterations and step sizes are per rod)."""
    targets = [[0.0015, 0.0, -0.0015, 0.0], [0.0, 0.001, 0.0, -0.001], [-0.0008, 0.0005, 0.0008, -0.0005]]

    def run(rows):
        data = tomllib.loads(EXAMPLE.read_text())
        data["actuation"] = {"tensions": [[0.0] * 4] * len(rows), "displacements": [[0.0] * 4] * len(rows)}
        data["control"]["target_displacements"] = rows
        data["dynamics"]["steps"] = 30
        scene = scene_from_dict(data)
        sim = scene_simulator(scene)
        return run_closed_loop(sim, scene_controller(scene, sim), 30)

    batch = run(targets)
    for b, t in enumerate(targets):
        alone = run([t])
        assert np.abs(batch.tip_position[:, b] - alone.tip_position[:, 0]).max() <= 1e-12
        assert np.abs(batch.displacements[:, b] - alone.displacements[:, 0]).max() <= 1e-12


def test_allocation_stays_finite_without_slack_tendons_at_any_scale():
    """No slack tendon (G = 0) and a large input matrix: the regularisation weights stay finite
    (a weight over an empty matrix once overflowed to inf and made the command NaN)."""
    from tdcr_warp.apps.allocation import allocate_displacements

    rng = np.random.default_rng(1)
    B, K = 4, 4
    lin = {"q": np.zeros((B, K)), "tension": np.ones((B, K)), "tension_jacobian": 3e4 * np.eye(K)[None].repeat(B, 0),
           "slack_jacobian": np.zeros((B, K, K)), "gap": np.zeros((B, K))}
    for scale in (1.0, 1e6, 1e9):
        bc = scale * rng.normal(size=(B, 3, K))
        v = scale * 1e-3 * rng.normal(size=(B, 3))
        q, _ = allocate_displacements(bc, v, np.zeros((B, K)), lin, np.full((B, K), -5e-3), np.full((B, K), 5e-3),
                                      np.full((B, K), 8.0))
        assert np.isfinite(q).all()
        assert (np.abs(q) <= 5e-3).all()
