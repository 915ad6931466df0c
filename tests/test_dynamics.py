"""Checks of the batched BDF-alpha dynamics against things nobody tuned."""

import warnings
from pathlib import Path

import numpy as np
import pytest

import tdcr_warp as tw
from tdcr_warp.kernels import layout
from tdcr_warp.model.options import describe_status
from tdcr_warp.physics.dynamics import bdf_alpha_coefficients

E, NU, R, L, RHO = 190e9, 0.3, 1e-3, 0.5, 7800.0
EI = E * np.pi * R**4 / 4
RHO_A = RHO * np.pi * R**2


def four_tendons():
    return [tw.Tendon(offset=o) for o in [(0.01, 0.0), (0.0, 0.01), (-0.01, 0.0), (0.0, -0.01)]]


def robot(**kw):
    base = dict(length=L, youngs_modulus=E, poisson_ratio=NU, radius=R, density=RHO,
                tendons=four_tendons(), gravity=(0.0, 0.0, -9.81))
    base.update(kw)
    return tw.Robot(**base)


def test_coefficients_consistent():
    """A constant history has zero rate: c0 + c1 + c2 = 0 for any alpha."""
    for a in (0.0, -0.2, -0.45):
        c0, c1, c2, d1 = bdf_alpha_coefficients(0.01, a)
        assert abs(c0 + c1 + c2) < 1e-12


def test_damped_run_settles_to_static_solution():
    # Bbt = 0.008 N m^2 s damps the first bending mode near critically (zeta ~ 0.9)
    rob = robot(damping_bending=(0.008, 0.008, 0.008), damping_shear=(1e-3, 1e-3, 1e-3), drag=(0.01, 0.01, 0.01))
    tau = [[3.0, 0.0, 1.0, 0.5]]
    sim = tw.Simulator(rob, [[0.0] * 4], dt=0.005, alpha=-0.2, nodes=30)
    tr = sim.simulate(np.tile(tau, (400, 1)), 400)
    assert tr.converged.all()
    static = tw.solve_static(rob, tau, nodes=30)
    err = np.abs(tr.tip_position[-1] - static.tip_position).max()
    assert err < 1e-6, f"settled tip {err:.2e} m from the static solution"
    moved = np.abs(tr.tip_position[0] - static.tip_position).max()
    assert moved > 1e-3, "the test must start away from the final state"


def test_large_dt_reproduces_statics():
    """dt -> infinity: c0 -> 0, every inertial and damping term vanishes."""
    rob = robot(damping_bending=(0.01, 0.01, 0.01), drag=(0.1, 0.1, 0.1))
    tau = [[2.0, 1.0, 0.0, 0.0]]
    sim = tw.Simulator(rob, [[0.0] * 4], dt=1e7, alpha=-0.2)
    r = sim.step(tau)
    static = tw.solve_static(rob, tau)
    assert r.converged.all()
    assert np.abs(r.tip_position - static.tip_position).max() < 1e-9


def _release(nodes, dt, steps, alpha=0.0):
    """Cantilever without tendons or gravity, released at rest from a small static bend."""
    bent = tw.Robot(length=L, youngs_modulus=E, poisson_ratio=NU, radius=R, density=RHO,
                    tip_force=(1e-3, 0.0, 0.0))
    free = tw.Robot(length=L, youngs_modulus=E, poisson_ratio=NU, radius=R, density=RHO)
    start = tw.solve_static(bent, np.zeros((1, 0)), nodes=nodes)
    sim = tw.Simulator(free, np.zeros((1, 0)), dt=dt, alpha=alpha, nodes=nodes, initial=start)
    return sim.simulate(np.zeros((steps, 0)), steps)


def test_undamped_cantilever_first_natural_frequency():
    f_eb = 1.8751**2 * np.sqrt(EI / (RHO_A * L**4)) / (2 * np.pi)
    dt = 1e-3  # 180 steps per period
    tr = _release(nodes=40, dt=dt, steps=int(2.2 / (f_eb * dt)))
    assert tr.converged.all()
    x = tr.tip_position[:, 0, 0]
    crossings = []
    for i in range(len(x) - 1):
        if x[i] > 0 >= x[i + 1] or x[i] < 0 <= x[i + 1]:
            crossings.append(tr.time[i] + dt * x[i] / (x[i] - x[i + 1]))
    assert len(crossings) >= 4
    period = 2 * np.mean(np.diff(crossings))
    rel = abs(1 / period - f_eb) / f_eb
    assert rel < 0.01, f"f = {1 / period:.4f} Hz vs Euler-Bernoulli {f_eb:.4f} Hz ({rel:.2%})"


def test_numerical_damping_is_largest_at_alpha_zero():
    """BDF-alpha's own damping of an undamped oscillation: per period of the first bending mode
    at omega dt = 0.5 (12.6 steps a period), alpha = 0 (BDF2) damps most and alpha -> -0.5
    (the trapezoidal rule) least. Each ratio equals that of the scheme on y' = i omega y, the
    principal root z of (c0 dt - i h) z^2 + (c1 dt + d1 i h) z + c2 dt = 0 raised to the steps of
    one numerical period, 2 pi / arg z."""
    w1 = 1.8751**2 * np.sqrt(EI / (RHO_A * L**4))  # Euler-Bernoulli's first mode [rad/s]
    h = 0.5
    dt = h / w1
    measured = {}
    for alpha in (0.0, -0.2, -0.45):
        tr = _release(nodes=10, dt=dt, steps=int(5 * 2 * np.pi / h), alpha=alpha)
        assert tr.converged.all()
        x = tr.tip_position[:, 0, 0]
        i = np.flatnonzero((x[1:-1] >= x[:-2]) & (x[1:-1] > x[2:])) + 1  # the maxima, sharpened by a parabola
        peaks = x[i] - (x[i - 1] - x[i + 1]) ** 2 / (8 * (x[i - 1] - 2 * x[i] + x[i + 1]))
        assert len(peaks) >= 4
        measured[alpha] = (peaks[-1] / peaks[0]) ** (1 / (len(peaks) - 1))  # from the first peak: past the start-up
        c0, c1, c2, d1 = bdf_alpha_coefficients(1.0, alpha)
        z = np.roots([c0 - 1j * h, c1 + d1 * 1j * h, c2])
        z = z[np.argmin(np.abs(z - np.exp(1j * h)))]
        theory = abs(z) ** (2 * np.pi / np.angle(z))  # 0.878, 0.932, 0.991
        assert abs(measured[alpha] - theory) < 5e-3, (alpha, measured[alpha], theory)
    assert measured[0.0] < measured[-0.2] < measured[-0.45] < 1.0, measured


def _tip_history(dt, T, alpha, nodes=20, bbt=0.008):
    """Tip over [0, T] under a smooth tension ramp 3 sin^2(pi t / T) N (flat at t = 0: a step
    input has a jump in acceleration that limits any start-up to first order)."""
    rob = robot(damping_bending=(bbt, bbt, bbt), drag=(0.01, 0.01, 0.01))
    steps = int(round(T / dt))
    sim = tw.Simulator(rob, [[0.0] * 4], dt=dt, alpha=alpha, nodes=nodes, tol=1e-12)
    tr = sim.simulate(lambda i: [[3.0 * np.sin(np.pi * min((i + 1) * dt, T / 2) / T) ** 2, 0, 0, 0]], steps)
    assert tr.converged.all()
    return tr.tip_position[:, 0]


@pytest.mark.parametrize("alpha", [0.0, -0.2, -0.45])
def test_time_convergence_is_second_order(alpha):
    """BDF-alpha measured second order for every alpha (max tip error over the run)."""
    T = 0.16
    ref = _tip_history(T / 160, T, alpha)
    errs = [np.abs(_tip_history(T / n, T, alpha) - ref[::160 // n]).max() for n in (20, 40)]
    order = np.log2(errs[0] / errs[1])
    assert 1.7 < order < 2.3, f"alpha {alpha}: errors {errs}, order {order:.2f}"


def test_space_convergence_at_fixed_dt():
    dt, T = 4e-3, 0.08
    ref = _tip_history(dt, T, -0.2, nodes=160)
    errs = [np.abs(_tip_history(dt, T, -0.2, nodes=n) - ref).max() for n in (5, 10, 20)]
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all(orders > 3.5), f"errors {errs}, orders {orders}"


def test_mixed_batch_matches_each_rod_alone():
    B = 3
    per_rod = dict(youngs_modulus=np.array([190e9, 120e9, 60e9]), density=np.array([7800.0, 17189.0, 5000.0]),
                   damping_bending=np.array([[0.008] * 3, [0.02] * 3, [0.0] * 3]),
                   drag=np.array([[0.01] * 3, [0.0] * 3, [0.1] * 3]))
    tau0 = np.zeros((B, 4))
    sched = np.zeros((B, 30, 4))
    sched[0, 5:, 0] = 3.0
    sched[1, :, 1] = 2.0
    sched[2, 10:, 2] = 1.0
    sched[2, 10:, 3] = 1.5
    batch = tw.Simulator(robot(**per_rod), tau0, dt=0.005, alpha=-0.2, nodes=20).simulate(sched, 30)
    assert batch.converged.all()
    for b in range(B):
        one = robot(**{k: v[b] for k, v in per_rod.items()})
        alone = tw.Simulator(one, tau0[b:b + 1], dt=0.005, alpha=-0.2, nodes=20).simulate(sched[b], 30)
        err = np.abs(alone.tip_position[:, 0] - batch.tip_position[:, b]).max()
        assert err < 1e-12, f"rod {b}: {err:.2e} m"


@pytest.mark.parametrize("case", [
    dict(dt=1e-5), dict(dt=0.1), dict(alpha=-0.45), dict(alpha=0.0),
    dict(tension=30.0), dict(youngs_modulus=1e6, dt=0.01), dict(youngs_modulus=1e12),
])
def test_extremes_converge_or_flag(case):
    case = dict(case)
    dt = case.pop("dt", 0.005)
    alpha = case.pop("alpha", -0.2)
    tension = case.pop("tension", 3.0)
    rob = robot(damping_bending=(0.008, 0.008, 0.008), drag=(0.01, 0.01, 0.01), **case)
    sim = tw.Simulator(rob, [[0.0] * 4], dt=dt, alpha=alpha, nodes=20)
    tr = sim.simulate(np.tile([[tension, 0.0, 0.0, 0.0]], (10, 1)), 10)
    good = tr.converged
    assert np.isfinite(tr.tip_position[1:][good]).all()
    # converged below tol, or at the round-off floor within 100 tol and flagged so (PRECISION_LIMITED)
    limit = np.where((tr.status & layout.PRECISION_LIMITED) != 0, 1e-8, 1e-10)
    assert np.isfinite(tr.residual[good]).all() and (tr.residual[good] < limit[good]).all()
    failed = tr.failed_step >= 0
    # a flagged rod stays flagged: no step after its failure is marked good
    for b in np.flatnonzero(failed):
        assert not good[tr.failed_step[b]:, b].any()
    assert good.all() or failed.any()


def test_dt_below_the_single_shooting_limit_warns_and_flags():
    """Single shooting (segments = 1): the warning's dt bound is where steps start to fail: below
    it flagged, above it converged. By default the rod is split there (tests/test_segments.py):
    the same steps converge."""
    rob = robot()  # undamped: damping would add c0 Bbt to the bending stiffness and ease the limit
    with pytest.warns(UserWarning, match="single-shooting limit") as record:
        below = tw.Simulator(rob, [[0.0] * 4], dt=2e-4, alpha=-0.2, nodes=20, segments=1)
    shooting = next(str(w.message) for w in record if "single-shooting" in str(w.message))  # (beside the grid's)
    dt_min = float(shooting.split("dt >= ")[1].split(" s")[0])
    assert 2e-4 < dt_min < 2e-3
    assert not below.simulate(np.tile([[1.0, 0, 0, 0]], (5, 1)), 5).converged.all()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        above = tw.Simulator(rob, [[0.0] * 4], dt=1.2 * dt_min, alpha=-0.2, nodes=20, segments=1)
    with pytest.warns(UserWarning) as record:  # only the grid's: 20 intervals are 1.43 l_b at dt = 2e-4 s
        split = tw.Simulator(rob, [[0.0] * 4], dt=2e-4, alpha=-0.2, nodes=20)
    assert [str(w.message).split(",")[0] for w in record] == [
        "alpha = -0.2 at dt = 0.0002 s: the grid's intervals are 1.43 of the bending layer l_b"]
    assert above.simulate(np.tile([[1.0, 0, 0, 0]], (5, 1)), 5).converged.all()
    assert split.segments > 1 and split.simulate(np.tile([[1.0, 0, 0, 0]], (5, 1)), 5).converged.all()
    with pytest.warns(UserWarning, match=f"dt >= {dt_min:.1e} s"):  # overflow-proof (the hostile campaign's 1e-300)
        tw.Simulator(rob, [[0.0] * 4], dt=1e-300, alpha=-0.2, nodes=20, segments=1)


def test_failed_rod_is_frozen_and_others_go_on():
    tau = np.array([[3.0, 0, 0, 0], [3.0, 0, 0, 0]])
    rob = robot(damping_bending=(0.008, 0.008, 0.008))
    sim = tw.Simulator(rob, np.zeros((2, 4)), dt=0.005, alpha=-0.2, nodes=20)
    sim.step(tau)
    sim.alive[1] = False  # as if rod 1 had failed: it must not move any more
    frozen = sim.tip_position[1].copy()
    for _ in range(5):
        r = sim.step(tau)
    assert np.array_equal(r.tip_position[1], frozen) and not r.converged[1]
    ref = tw.Simulator(rob, np.zeros((1, 4)), dt=0.005, alpha=-0.2, nodes=20)
    for _ in range(6):
        r1 = ref.step(tau[:1])
    assert np.abs(r1.tip_position[0] - r.tip_position[0]).max() < 1e-12


def test_bad_dynamic_input():
    rob = robot()
    with pytest.raises(tw.InputError, match="dt must be a positive"):
        tw.Simulator(rob, [[0.0] * 4], dt=0.0)
    with pytest.raises(tw.InputError, match="alpha"):
        tw.Simulator(rob, [[0.0] * 4], dt=0.01, alpha=0.3)
    with pytest.raises(tw.InputError, match=r"solver energy_tolerance must be a number >= 0 .*, got -0.1"):
        tw.Simulator(rob, [[0.0] * 4], dt=0.01, energy_tolerance=-0.1)
    with pytest.raises(tw.InputError, match="damping_bending must be >= 0"):
        robot(damping_bending=(-1.0, 0, 0))
    sim = tw.Simulator(rob, [[0.0] * 4], dt=0.01)
    with pytest.raises(tw.InputError, match=r"schedule: expected shape"):
        sim.simulate(np.zeros((3, 2)), 3)


def test_matches_independent_python_implementation():
    """Same scheme (Euler along s, N = 20), other code: tests/python_dynamics.py."""
    from python_dynamics import PythonRod

    offsets = [(0.01, 0.0), (0.0, 0.01), (-0.01, 0.0), (0.0, -0.01)]
    d = dict(length=L, youngs_modulus=E, poisson_ratio=NU, radius=R, density=17189.0,
             gravity=(0.0, 0.0, -9.81), offsets=offsets, damping_shear=(1e-4, 1e-4, 1e-4),
             damping_bending=(0.008, 0.008, 0.008), drag=(0.01, 0.01, 0.01))
    ref = PythonRod(d, [0.0] * 4, dt=0.005, alpha=-0.2, nodes=20)
    rob = tw.Robot(length=L, youngs_modulus=E, poisson_ratio=NU, radius=R, density=17189.0,
                   gravity=(0.0, 0.0, -9.81), tendons=[tw.Tendon(offset=o) for o in offsets],
                   damping_shear=(1e-4, 1e-4, 1e-4), damping_bending=(0.008, 0.008, 0.008),
                   drag=(0.01, 0.01, 0.01))
    sim = tw.Simulator(rob, [[0.0] * 4], dt=0.005, alpha=-0.2, nodes=20, integrator="euler", tol=1e-12)
    for i in range(25):
        tau = [3.0, 0.5, 0.0, 0.0] if i >= 4 else [0.0] * 4
        tip, vel = ref.step(tau)
        r = sim.step([tau])
        assert r.converged.all()
        assert np.abs(r.tip_position[0] - tip).max() < 1e-9, f"step {i}: {r.tip_position[0]} vs {tip}"
        assert np.abs(r.tip_velocity[0] - vel).max() < 1e-7, f"step {i}: {r.tip_velocity[0]} vs {vel}"


@pytest.mark.parametrize("alpha", [0.0, -0.2, -0.45, -0.49, -0.5])
def test_coefficients_second_order_for_every_alpha(alpha):
    """(1 + alpha) y_t(i+1) - alpha y_t(i) = [(1.5 + alpha) y(i+1) - 2 (1 + alpha) y(i) + (0.5 + alpha) y(i-1)] / dt
    (the history formula multiplied out) is exact for y = 1, t and t^2 (second order, the
    coefficients of [T19]); alpha = 0 is BDF2 and alpha = -0.5 the trapezoidal rule."""
    dt = 0.01
    c0, c1, c2, d1 = bdf_alpha_coefficients(dt, alpha)
    t = np.array([-dt, 0.0, dt])
    for y, yt in ((lambda s: s**0, lambda s: 0 * s), (lambda s: s, lambda s: s**0), (lambda s: s**2, lambda s: 2 * s)):
        predicted = c0 * y(t[2]) + c1 * y(t[1]) + c2 * y(t[0]) + d1 * yt(t[1])
        assert abs(predicted - yt(t[2])) < 1e-9
    if alpha == 0.0:
        assert np.allclose([c0 * dt, c1 * dt, c2 * dt, d1], [1.5, -2.0, 0.5, 0.0])
    if alpha == -0.5:  # y_t(i+1) + y_t(i) = 2 (y(i+1) - y(i)) / dt
        assert np.allclose([c0 * dt, c1 * dt, c2 * dt, d1], [2.0, -2.0, 0.0, -1.0])


def test_scheme_is_a_stable_for_every_alpha():
    """On y' = i omega y every root of the step's characteristic polynomial lies within the unit
    circle for alpha in (-0.5, 0] (no linear energy gain); at omega dt -> infinity the second root
    tends to alpha / (1 + alpha), which reaches -1 as alpha -> -0.5: no damping left there."""
    for alpha in (0.0, -0.2, -0.45, -0.49, -0.499):
        c0, c1, c2, d1 = bdf_alpha_coefficients(1.0, alpha)
        for h in np.geomspace(1e-3, 1e4, 60):
            assert np.abs(np.roots([c0 - 1j * h, c1 + d1 * 1j * h, c2])).max() <= 1.0 + 1e-12
        stiff = np.abs(np.roots([c0 - 1j * 1e9, c1 + d1 * 1j * 1e9, c2])).max()
        assert abs(stiff - abs(alpha) / (1 + alpha)) < 1e-4


def _host_energy(sim, tau):
    """The energy H of kernels/energy.py from the nodes' n, m, q, w, p of an undamped rod (its strains
    from n and m alone) and the tendons' (straight, parallel) paths p + R r as chords between nodes."""
    rod, dyn = sim.tables.rod[0], sim.tables.dyn[0]
    kse, kbt = rod[layout.KSE:layout.KSE + 3], rod[layout.KBT:layout.KBT + 3]
    nodes = sim.parts[0].sh.nodes
    p, R, n, m, q, w = (getattr(nodes, a).numpy().astype(float)[0] for a in ("p", "R", "n", "m", "q", "w"))
    nb, mb = np.einsum("kji,kj->ki", R, n), np.einsum("kji,kj->ki", R, m)
    dens = 0.5 * (dyn[layout.RHOA] * (q * q).sum(1) + (dyn[layout.RHOJ:layout.RHOJ + 3] * w * w).sum(1)
                  + (nb * nb / kse).sum(1) + (mb * mb / kbt).sum(1)) - p @ rod[layout.FE:layout.FE + 3]
    paths = p[:, None] + np.einsum("kij,tj->kti", R, [[*np.ravel(t.offset), 0.0] for t in sim.robot.tendons])
    return np.trapezoid(dens, sim.grid[0]) + np.dot(tau, np.linalg.norm(np.diff(paths, axis=0), axis=2).sum(0))


def test_energy_reading_matches_an_independent_sum():
    """Simulator.energy() (a kernel over the node slots) against the same energy summed on the host
    from other quantities: n, m instead of the strains, the tendons' paths as chords instead of the
    kernel's |v + u x r| (1e-5 of sum tau L: the chords' O(h^2) shortfall), while a held tendon
    swings the rod under gravity."""
    rob = robot(gravity=(-9.81, 0.0, 0.0))
    tau = np.array([2.0, 0.0, 0.0, 1.0])
    sim = tw.Simulator(rob, [[0.0] * 4], dt=0.005, alpha=-0.2, nodes=40)
    for i in range(12):
        sim.step([tau])
        e = sim.energy()
        assert abs(e["energy"][0] - _host_energy(sim, tau)) < 1e-5 * np.dot(tau, [L] * 4), i
    assert e["motion"][0] > 1e-3  # the rod moves and is bent


def _tendon_release(alpha, nodes, dt=1e-3, **kw):
    """The undamped wire released at t = 0 from 3 N on tendon 1 (its steps: no tension)."""
    return tw.Simulator(robot(gravity=(-9.81, 0.0, 0.0)), [[3.0, 0, 0, 0]], dt=dt, alpha=alpha, nodes=nodes, **kw)


def test_energy_monitor_flags_a_planted_gain():
    """N = 5 intervals of 0.1 m against l_b = 36 mm: the undamped wire gains energy from the first
    steps on (experiments/bdf_alpha_energy.py) while every step converges; the monitor flags
    the step (ENERGY with CONVERGED, not converged) and freezes the rod."""
    sim = _tendon_release(-0.45, 5, energy_tolerance=0.0)
    found = []
    for _ in range(8):
        assert sim.step([[0.0] * 4]).converged.all()  # no monitor: plain successes...
        found.append(sim.energy())
    assert found[-1]["energy"][0] - found[0]["energy"][0] > 10 * found[0]["motion"][0]  # ... of a tenfold gain
    tr = _tendon_release(-0.45, 5).simulate(np.zeros((8, 4)), 8)
    step = tr.failed_step[0]
    assert 0 < step < 8 and tr.status[step, 0] == layout.CONVERGED | layout.ENERGY
    assert tr.converged[:step].all() and not tr.converged[step:].any()
    assert "energy gained" in describe_status(tr.status[step, 0])


@pytest.mark.parametrize("alpha", [0.0, -0.2, -0.45, -0.49])
def test_free_swing_keeps_its_energy_where_the_grid_resolves_the_step(alpha):
    """Within the resolution bound (h / l_b = 0.35 here, below the measured limit of
    docs/solver.md) the undamped wire released from the pull keeps its energy over the whole
    alpha range: BDF-alpha only takes some away (to round-off), and no step is flagged."""
    sim = tw.Simulator(robot(gravity=(-9.81, 0.0, 0.0)), [[3.0, 0, 0, 0]], dt=1e-3, alpha=alpha, nodes=40)
    energy = []
    for _ in range(200):
        r = sim.step([[0.0] * 4])
        assert r.converged.all() and not (r.status & layout.ENERGY).any()
        energy.append(sim.energy()["energy"][0])
    gain = (np.array(energy) - energy[0]) / sim.energy()["motion"][0]
    assert gain.max() < 1e-9 and gain[-1] < -1e-3, gain.max()


def test_energy_monitor_passes_the_damped_actuated_seed_run():
    """The report's run (examples/seed_dynamics.toml: damped, drag, gravity, 3 N on tendon 1 from
    step 5 held to the end): every rod watched, steps 6-100 checked against the held tension's
    potential, none flagged; the energy falls from the step on (damping and drag)."""
    from tdcr_warp.io.scene import load_scene

    scene = load_scene(Path(__file__).resolve().parents[1] / "examples" / "seed_dynamics.toml")
    spec = scene.dynamics
    sim = tw.Simulator(scene.robot, scene.tensions, dt=spec.dt, alpha=spec.alpha, options=scene.options)
    assert all(c.monitor.watched.all() for c in sim.parts) and scene.options.energy_tolerance > 0
    energy = []
    for i in range(spec.steps):
        r = sim.step(spec.schedule[:, i])
        assert r.converged.all() and not (r.status & layout.ENERGY).any(), i
        energy.append(sim.energy()["energy"][0])
    assert np.all(np.diff(energy[5:]) < 1e-9), np.diff(energy[5:]).max()


@pytest.mark.parametrize("nodes, dt, alpha, need", [(20, 1e-3, -0.49, 40), (10, 1e-3, -0.45, 21), (5, 1e-3, 0.0, 10),
                                                    (40, 1e-3, -0.49, None), (20, 1e-3, -0.4, None),
                                                    (20, 4e-3, -0.49, None), (10, 1e-3, 0.0, None)])
def test_grid_bound_on_alpha_warns_where_energy_was_gained(nodes, dt, alpha, need):
    """The warning of LAYER_LIMITS on the wire of experiments/bdf_alpha_energy.py: where its map
    measured a gain (h / l_b 0.71 at -0.49, 1.39 at -0.45, 2.47 at 0) it warns and names the nodes
    that stay inside; where every run kept the energy it is silent."""
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        tw.Simulator(robot(), [[0.0] * 4], dt=dt, alpha=alpha, nodes=nodes)
    found = [str(w.message) for w in record if "bending layer" in str(w.message)]
    assert len(found) == (need is not None) and (need is None or found[0].endswith(f"nodes >= {need} stays inside"))
