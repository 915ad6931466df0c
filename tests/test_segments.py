"""Multiple shooting in dynamics: the same answers as single shooting where both work, time steps
far below single shooting's limit (dt = 1e-5 s on the report's robot), the time-step refinement
there, and the choice of segments."""

import warnings

import numpy as np
import pytest

import tdcr_warp as tw
from tdcr_warp.kernels import layout

OFFSETS = [(0.01, 0.0), (0.0, 0.01), (-0.01, 0.0), (0.0, -0.01)]


def report_robot(**kw):
    """The report's robot (seed section 4), damped as in its control scene."""
    base = dict(length=0.5, youngs_modulus=190e9, poisson_ratio=0.3, radius=1e-3, density=17189.0,
                tendons=[tw.Tendon(offset=o) for o in OFFSETS], gravity=(0.0, 0.0, -9.81),
                damping_bending=(0.008,) * 3, drag=(0.01,) * 3)
    return tw.Robot(**(base | kw))


def test_segments_give_single_shootings_answers():
    """Two rods, 20 steps of 2 ms under a tension step (single shooting's ground): 4 segments
    give the same tips and shapes to 1e-12 m (measured 2.6e-13)."""
    tau = np.array([[3.0, 0.0, 0.0, 0.0], [0.0, 2.0, 1.0, 0.0]])
    runs = []
    for segments in (1, 4):
        sim = tw.Simulator(report_robot(), np.zeros((2, 4)), dt=2e-3, nodes=20, segments=segments)
        runs.append((sim.simulate(np.repeat(tau[:, None], 20, axis=1), 20), sim.shapes()[0]))
    (one, p1), (four, p4) = runs
    assert one.converged.all() and four.converged.all()
    assert np.abs(one.tip_position - four.tip_position).max() < 1e-12
    assert np.abs(p1 - p4).max() < 1e-12
    assert np.abs(one.tip_position[-1] - one.tip_position[0]).max() > 1e-3  # it moved


def test_dt_of_ten_microseconds_converges_on_the_report_robot():
    """dt = 1e-5 s: single shooting warns and fails at the first step (a start error grows ~e^36
    along the rod, its shear waves leading); the default picks 11 segments and every one of 100
    steps converges, silently."""
    tau = np.tile([[3.0, 0.0, 0.0, 0.0]], (100, 1))
    with pytest.warns(UserWarning, match="single-shooting limit"):
        single = tw.Simulator(report_robot(), [[0.0] * 4], dt=1e-5, nodes=40, segments=1)
    assert not single.simulate(tau[:3], 3).converged[0].any()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sim = tw.Simulator(report_robot(), [[0.0] * 4], dt=1e-5, nodes=40)
    assert sim.segments == 11
    tr = sim.simulate(tau, 100)
    assert tr.converged.all() and (tr.residual < 1e-9).all()
    assert np.abs(tr.tip_position[-1, 0, 0]) > 1e-5  # it moved


def test_time_step_refinement_at_small_dt():
    """A smooth pull, tau = 3 sin^2(pi t / 2 ms) N over 1 ms, at dt = 40, 20, 10 us (3, 6, 11
    segments): halving dt shrinks the change of the tip by 3.2x (BDF-alpha is second order: 4x)."""
    T, tips = 1e-3, []
    for dt in (4e-5, 2e-5, 1e-5):
        n = int(round(T / dt))
        tau = np.zeros((n, 4))
        tau[:, 0] = 3.0 * np.sin(0.5 * np.pi * dt * np.arange(1, n + 1) / T) ** 2
        tr = tw.Simulator(report_robot(), [[0.0] * 4], dt=dt, nodes=40).simulate(tau, n)
        assert tr.converged.all()
        tips.append(tr.tip_position[-1, 0])
    d1, d2 = np.abs(tips[0] - tips[1]).max(), np.abs(tips[1] - tips[2]).max()
    assert d1 / d2 > 2.5, (d1, d2)


def test_segment_choice_and_what_is_refused():
    """Single shooting where it resolves dt; a segment count outside 1..intervals, or segments with
    tendon states (friction), is a one-line error; with obstacles every rod is split as asked."""
    assert tw.Simulator(report_robot(), [[0.0] * 4], dt=5e-3, nodes=20).segments == 1
    for bad in (0, 21, 2.5):
        with pytest.raises(tw.InputError, match="segments must be"):
            tw.Simulator(report_robot(), [[0.0] * 4], dt=5e-3, nodes=20, segments=bad)
    rubbing = report_robot(tendons=[tw.Tendon(offset=o, friction=0.1) for o in OFFSETS])
    with pytest.raises(tw.InputError, match="multiple shooting"):
        tw.Simulator(rubbing, [[0.0] * 4], dt=5e-3, nodes=20, segments=4)
    walled = report_robot(obstacles=[tw.Obstacle("plane", point=(0.1, 0, 0), normal=(-1, 0, 0))])
    sim = tw.Simulator(walled, [[0.0] * 4], dt=5e-3, nodes=20, segments=4)
    assert sim.parts[0].count.tolist() == [4] and sim.step([[2.0, 0.0, 0.0, 0.0]]).converged[0]


def test_status_of_a_segmented_step():
    """A segmented step reports its status bits like a single-shooting one (converged, at most
    PRECISION_LIMITED beside it)."""
    sim = tw.Simulator(report_robot(), [[0.0] * 4], dt=1e-5, nodes=40)
    r = sim.step([[3.0, 0.0, 0.0, 0.0]])
    assert r.converged[0] and (r.status[0] & ~layout.PRECISION_LIMITED) == layout.CONVERGED


def test_the_banded_jacobian_is_the_whole_jacobian():
    """The Newton's Jacobian, formed block by block into band storage (kernels/banded.py), equals
    central differences of the whole residual taken one unknown at a time (to 1e-7 of its largest
    entry; measured 6e-10); the whole residual's differences are exactly 0 outside the band."""
    sim = tw.Simulator(report_robot(), np.zeros((2, 4)), dt=2e-3, nodes=20, segments=4)
    seg = sim.parts[0].segs[4]
    z = seg.z + 1e-3 * np.random.default_rng(0).normal(size=seg.z.shape)
    seg.jacobian(z)
    nz, kl = seg.nz, seg.band.kl
    i, c = np.meshgrid(np.arange(nz), np.arange(seg.band.a.shape[2]), indexing="ij")
    inside = (i + c - kl >= 0) & (i + c - kl < nz)
    banded = np.zeros((seg.b, nz, nz))
    banded[:, i[inside], (i + c - kl)[inside]] = seg.band.a[:, inside]
    h = 1e-6
    dense = np.stack([(seg.evaluate(z + h * e) - seg.evaluate(z - h * e)) / (2 * h) for e in np.eye(nz)], axis=2)
    assert np.abs(banded - dense).max() < 1e-7 * np.abs(dense).max()
    j = np.arange(nz)
    outside = (j[None, :] - j[:, None] < -kl) | (j[None, :] - j[:, None] > seg.band.a.shape[2] - 1 - 2 * kl)
    assert outside.any() and not dense[:, outside].any()
