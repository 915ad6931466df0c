"""The latency machinery (tdcr_warp/core/launch.py and its users): recorded launches give the
bits of fresh ones over changed inputs, host mirrors read and write the device arrays, options
are validated once, and the cheaper host arithmetic (the straight-rod start, the continuation
rule, the tension allocation) is the old arithmetic. Equality is exact throughout; nothing is timed."""

import numpy as np
import pytest
import warp as wp

import tdcr_warp as tw
from tdcr_warp.core.build import StraightRod, _cross
from tdcr_warp.core.homotopy import continuation_steps
from tdcr_warp.core.launch import Mirror, Replay
from tdcr_warp.physics import statics
from tdcr_warp.physics.statics import StaticProblem

OFFSETS = [(0.01, 0.0), (0.0, 0.01), (-0.01, 0.0), (0.0, -0.01)]


def report_robot(**kw):
    return tw.Robot(**({"length": 0.5, "youngs_modulus": 190e9, "poisson_ratio": 0.3, "radius": 1e-3,
                        "density": 17189.0, "gravity": (0.0, 0.0, -9.81),
                        "tendons": [tw.Tendon(offset=o) for o in OFFSETS]} | kw))


@wp.struct
class _Scale:
    factor: wp.float64
    values: wp.array(dtype=wp.float64)


@wp.kernel
def _scaled(s: _Scale, add: wp.float64, out: wp.array(dtype=wp.float64)):
    i = wp.tid()
    out[i] = s.factor * s.values[i] + add


def test_replay_sees_struct_fields_and_repacks_changed_arguments():
    """A replay reads a struct's fields as they are at launch (a swapped array too) and packs
    again a scalar or array argument that changed; its outputs are those of wp.launch."""
    n = 5
    s = _Scale()
    s.factor = 2.0
    s.values = wp.array(np.arange(n, dtype=np.float64), dtype=wp.float64, device="cpu")
    outs = [wp.zeros(n, dtype=wp.float64, device="cpu") for _ in range(2)]
    fresh = wp.zeros(n, dtype=wp.float64, device="cpu")
    replay = Replay(_scaled, n, "cpu")

    def check(add, out):
        replay(s, add, out)
        wp.launch(_scaled, dim=n, device="cpu", inputs=[s, add, fresh])
        assert np.array_equal(out.numpy(), fresh.numpy())

    check(1.0, outs[0])
    s.factor = -3.5
    check(1.0, outs[0])
    s.values = wp.array(np.linspace(1.0, 2.0, n), dtype=wp.float64, device="cpu")
    check(0.25, outs[1])
    check(0.25, outs[0])
    assert np.array_equal(outs[0].numpy(), -3.5 * np.linspace(1.0, 2.0, n) + 0.25)


def test_loading_the_evaluation_kernels_announces_a_compile(monkeypatch, capsys):
    """The evaluation module (the unloaded Jacobian, sensitivities, the stability verdict, the
    controller's linearisation), loaded with the solver's kernels when a problem is made, says so on
    stderr when it compiles, as the solver's kernels do (core/solver.py set_compile_notice)."""
    from tdcr_warp.core import solver

    loaded = []
    real_load = solver._load_modules
    monkeypatch.setattr(solver, "_load_modules", lambda kernels, device: loaded.extend(
        k.module.name for k in kernels) or real_load(kernels, device))
    monkeypatch.setattr(solver, "_needs_compile", lambda *args: True)  # as on an empty kernel cache
    capsys.readouterr()
    StaticProblem(report_robot(), 1, tw.StaticOptions(nodes=8, stability="off"), wp.get_device("cpu"))
    assert any("_evaluate_" in name for name in loaded)
    assert "tdcr-warp: compiling kernels for cpu" in capsys.readouterr().err
    solver.set_compile_notice(False)
    try:
        StaticProblem(report_robot(), 1, tw.StaticOptions(nodes=8, stability="off"), wp.get_device("cpu"))
        assert capsys.readouterr().err == ""
    finally:
        solver.set_compile_notice(True)


def test_mirror_is_a_view_on_the_cpu():
    a = wp.zeros((3, 2), dtype=wp.float32, device="cpu")
    m = Mirror(a, np.float32)
    m.put(np.array([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]]))
    assert np.array_equal(a.numpy(), [[1, 2], [3, 4], [5, 6]])
    got = m.get(np.float64)
    assert got.dtype == np.float64 and not np.shares_memory(got, m.peek())
    with pytest.raises(ValueError, match="shape"):
        m.put(np.zeros((1, 2)))
    flags = wp.zeros(3, dtype=int, device="cpu")
    Mirror(flags, np.float64).put(np.array([True, False, True]))
    assert flags.numpy().tolist() == [1, 0, 1]


def _fields(sol):
    return (sol.positions, sol.rotations, sol.n, sol.m, sol.base_wrench, sol.status, sol.iterations,
            sol.integrations, sol.residual, sol.jacobian, sol.unknowns)


def _assert_same(a, b):
    for x, y in zip(_fields(a), _fields(b)):
        assert np.array_equal(x, y)


def test_replayed_solves_equal_fresh_problems():
    """A cached problem replays its recorded launch: over changed tensions and a warm start, every
    answer has the bits of a problem made afresh (its launches recorded anew). A fresh problem's
    first solve also makes the robot's unloaded Jacobian (7 integrations, counted on its first rod)."""
    robot = report_robot()
    opts = tw.StaticOptions(nodes=12, stability="off")
    cached = StaticProblem(robot, 3, opts, wp.get_device("cpu"))
    for tau in np.random.default_rng(7).uniform(0.0, 2.0, (3, 3, 4)):
        again, fresh = cached.solve(tau, None), StaticProblem(robot, 3, opts, wp.get_device("cpu")).solve(tau, None)
        assert (fresh.integrations - again.integrations).tolist() in ([0, 0, 0], [7, 0, 0])
        fresh.integrations = again.integrations
        _assert_same(again, fresh)
    first = cached.solve(tau, None)
    _assert_same(cached.solve(tau * 0.9, first),
                 StaticProblem(robot, 3, opts, wp.get_device("cpu")).solve(tau * 0.9, first))


def test_replayed_newton_equals_plain_launches():
    """The Newton launch replayed with other tensions, masks (another array argument) and Newton
    settings (scalars packed again) gives the bits of a plain wp.launch of the same arguments."""
    robot = report_robot()
    opts = tw.StaticOptions(nodes=12, stability="off")
    problems = [StaticProblem(robot, 3, opts, wp.get_device("cpu")) for _ in range(2)]
    replayed, plain = (p.solvers[0] for p in problems)
    rng = np.random.default_rng(1)
    cases = [(1e-10, 50, 10.0, True, None), (1e-10, 50, 10.0, True, [True, False, True]),
             (1e-6, 3, 1.0, False, None), (1e-10, 50, 10.0, True, [False, True, True])]
    for tol, max_iter, max_step, broyden, mask in cases:
        tau = rng.uniform(0.0, 2.0, (3, 4))
        x0 = problems[0].start(tau, None)
        for sh in (replayed, plain):
            sh.set_command(tau)
        replayed.solve(x0, tol=tol, max_iter=max_iter, max_step=max_step, broyden=broyden, mask=mask)
        plain.host(plain.x_in).put(x0)
        m = plain.all_rods if mask is None else wp.array(np.array(mask, dtype=np.int32), device="cpu")
        newton = [plain.dev.wdtype(tol), max_iter, plain.dev.wdtype(max_step), int(broyden)]
        wp.launch(plain.kern.solve, dim=plain.b, device="cpu", inputs=[
            plain.model, plain.control, plain.step, plain.newton, plain.nodes, plain.x_in, 1, *newton,
            plain.coarse_jacobian, m])
        got, want = replayed.results(), plain.results()
        assert all(np.array_equal(got[k], want[k]) for k in want)


def test_options_validated_once_per_distinct_overrides():
    a = statics._options(None, {"nodes": 20, "stability": "off"})
    assert statics._options(None, {"nodes": 20, "stability": "off"}) is a
    assert statics._options(None, {}) is statics._options(None, {})
    base = tw.StaticOptions(nodes=10)
    assert statics._options(base, {}) is base
    assert statics._options(base, {"tol": 1e-9}).nodes == 10
    for _ in range(2):  # 20.0 equals 20 but is not an integer: refused every time
        with pytest.raises(tw.InputError, match="nodes"):
            tw.solve_static(report_robot(), [1.0, 0, 0, 0], nodes=20.0)
        with pytest.raises(tw.InputError, match="max_iter"):
            tw.solve_static(report_robot(), [1.0, 0, 0, 0], max_iter=[5])


def _guess_one_by_one(sr: StraightRod, tensions):
    """The straight-rod start as it was written: tendon after tendon."""
    B = tensions.shape[0]
    ext = np.broadcast_to(sr.external, (B, 6))
    n0, m0 = ext[:, :3], ext[:, 3:]
    for k in range(tensions.shape[1]):
        F = -tensions[:, k, None] * sr.tangent[:, k] / sr.tangent_norm[:, k]
        n0 = n0 + F
        m0 = m0 + _cross(sr.arm[:, k], F)
    if sr.points is not None:
        n0 = n0 + sr.points[:, :3]
        m0 = m0 + sr.points[:, 3:]
    return np.concatenate(np.broadcast_arrays(n0, m0), axis=1)


@pytest.mark.parametrize("robot", [
    report_robot(tip_force=(0.1, -0.2, 0.3)),
    tw.Robot(tendons=[tw.Tendon(offset=(0.01, 0.0), routing="helix", helix_radius=0.002, turns=1.0),
                      tw.Tendon(offset=(0.0, 0.01), length=0.3),
                      tw.Tendon(offset=(0.0, -0.01), offset_end=(0.0, -0.005), routing="linear")],
             point_forces=[tw.PointForce(s=0.2, force=(0.1, 0.0, 0.0))], gravity=(0.0, -9.81, 0.0)),
    report_robot(length=np.array([0.4, 0.5, 0.6])),
    tw.Robot(tendons=[]),
], ids=["report", "routes-points", "per-rod", "no-tendons"])
def test_straight_start_is_the_one_by_one_sum(robot):
    sr = StraightRod.of(robot)
    rng = np.random.default_rng(3)
    B = max(3, robot.batch_size)
    for tau in (rng.uniform(0.0, 3.0, (B, robot.n_tendons)), np.zeros((B, robot.n_tendons))):
        got, want = sr.guess(tau), _guess_one_by_one(sr, tau)
        assert np.array_equal(got, want) and np.array_equal(np.signbit(got), np.signbit(want))


def test_continuation_rule_is_the_norms():
    rng = np.random.default_rng(0)
    x0 = np.concatenate([rng.normal(0.0, 2.0, (40, 7)), [[np.nan] + [0.0] * 6, [1e300] * 7, [0.0] * 7]])
    finite, large, steps = continuation_steps(x0, 8)
    with np.errstate(all="ignore"):
        load = np.linalg.norm(x0[:, 3:6], axis=1) + np.linalg.norm(x0[:, :2], axis=1)
        compression = np.sqrt(np.abs(x0[:, 2]))
        ok = np.isfinite(load) & np.isfinite(compression)
    assert np.array_equal(finite, ok) and np.array_equal(large, load > 1.5)
    assert np.array_equal(steps, np.clip(np.ceil(np.where(ok, np.maximum(load, compression), 0.0)), 8, 64))


def _allocate_as_written(Bc, v, tau_max, tau0, sweeps=60):
    """tdcr_warp.apps.control.allocate as it was written (np.clip on freshly indexed columns)."""
    Q = np.einsum("bik,bil->bkl", Bc, Bc)
    lam = 1e-9 * np.trace(Q, axis1=1, axis2=2)[:, None] + 1e-300
    K = Q.shape[1]
    Q = Q + lam[:, :, None] * np.eye(K)
    g = np.einsum("bik,bi->bk", Bc, v)
    tau = np.clip(tau0, 0.0, tau_max).copy()
    diag = np.einsum("bkk->bk", Q)
    for _ in range(sweeps):
        for k in range(K):
            r = g[:, k] - np.einsum("bl,bl->b", Q[:, k], tau) + diag[:, k] * tau[:, k]
            tau[:, k] = np.clip(r / diag[:, k], 0.0, tau_max[:, k])
    return tau


@pytest.mark.parametrize("B", [1, 5])
def test_allocation_is_the_arithmetic_as_written(B):
    """The batch and the one-rod sweeps give the bits of the code as written: at either bound,
    inside, for a tendon without effect, with an infinite bound and with a NaN command."""
    from tdcr_warp.apps.control import allocate

    for seed in range(12):
        rng = np.random.default_rng(seed)
        Bc = rng.normal(0.0, 1.0, (B, 3, 4))
        Bc[0, :, 2] = 0.0  # a tendon without effect: its coordinate stays where the bound puts it
        v = rng.normal(0.0, 2.0, (B, 3))
        tau_max = rng.uniform(0.5, 3.0, (B, 4))
        tau_max[-1, 1] = np.inf
        if seed == 0:
            v[-1, 0] = np.nan
        tau0 = rng.uniform(-1.0, 4.0, (B, 4))
        got, want = allocate(Bc, v, tau_max, tau0), _allocate_as_written(Bc, v, tau_max, tau0)
        assert np.array_equal(got, want, equal_nan=True) and np.array_equal(np.signbit(got), np.signbit(want))
