"""Multiple shooting in statics: long line contacts, beyond single shooting, against the closed
form of a rod lying on a wall; the same answers as single shooting where both work; global
balance; the independence of the rods of a batch; what a split rod reports and what is refused."""

import numpy as np
import pytest

import tdcr_warp as tw
from tdcr_warp.kernels import layout
from tdcr_warp.model.robot import InputError, Obstacle, Robot, Tendon
from tdcr_warp.physics.statics import solve_static

# a nitinol wire sagging under its own weight (gravity -x): w = rho A g
ROD = dict(radius=0.5e-3, youngs_modulus=60e9, density=6450.0, gravity=(-9.81, 0.0, 0.0))
W = 6450.0 * np.pi * 0.5e-3**2 * 9.81  # [N/m]
EI = 60e9 * np.pi * 0.5e-3**4 / 4  # [N m^2]
NONE = np.zeros((1, 0))


def in_tube(L: float, clearance) -> Robot:
    """The wire, clamped on the axis of a horizontal straight tube of the given clearance [m]."""
    return Robot(length=L, obstacles=[Obstacle("tube", start=(0, 0, -0.01), end=(0, 0, L + 0.01),
                                               radius=0.5e-3 + np.asarray(clearance, dtype=float))], **ROD)


def test_long_line_contact_matches_the_closed_form():
    """A 1 m wire in a tube of 0.2 mm clearance lies on the wall from a = (72 EI c / w)^(1/4)
    = 0.171 m to the tip (tests/test_contact.py derives the reactions). At the stiffness that
    holds 0.01 r, beta l ~ 26 along the contact: single shooting is flagged PENETRATION (it
    cannot climb there); by default the rod is split and meets the closed form: total reaction
    w (L - 2a/3) to 2e-4 (measured 1.1e-4), its moment about the base to 1e-4 (2.4e-5), the
    contact beginning within three intervals of a (2.1). Force balance with the contact forces and
    the weight: 1e-10 of the contact forces (measured 2.0e-11: the O(h^4) integration error of the
    distributed weight, which an unsplit cantilever under its weight shows too)."""
    L, c = 1.0, 0.2e-3
    a = (72 * EI * c / W) ** 0.25
    single = solve_static(in_tube(L, c), NONE, nodes=100, segments=1)
    assert single.converged[0] and single.status[0] & layout.PENETRATION and not single.success[0]
    sol = solve_static(in_tube(L, c), NONE, nodes=100)
    assert sol.success[0] and sol.segments[0] > 1
    assert sol.penetration[0, 0] <= 0.01 * 0.5e-3
    F = sol.contact_force[0, :, 0]
    assert abs(F.sum() / (W * (L - 2 * a / 3)) - 1) < 2e-4
    assert abs((F * sol.positions[0, :, 2]).sum() / (W * a * a / 3 + W * (L * L - a * a) / 2) - 1) < 1e-4
    assert abs(sol.s[0, np.flatnonzero(F > 0)[0]] - a) < 3 * L / 100  # the nodal law spreads the point reaction
    external = np.array([-W * L, 0.0, 0.0]) + sol.contact_force[0].sum(axis=0)
    assert np.abs(sol.base_wrench[0, :3] - external).max() < 1e-10 * np.abs(sol.contact_force[0]).sum()
    # a split rod's stability verdict: its fields carried over the segments (physics/stability.py)
    assert sol.stability_reasons()[0] == "stable"
    assert sol.orthogonality_error[0] < 1e-12


def test_a_wire_pushed_into_a_bent_tube_balances_its_contact_forces():
    """A wire clamped 1 mm before a tube bent at R 0.4 m (0.3 mm clearance), 0.3 m long, no
    distributed load: single shooting is flagged PENETRATION; by default the rod is split and the
    base wrench equals the force just before the tip node plus every contact force before it
    (and their moments about the base) to 1e-10 of the contact forces (measured 1.2e-11 and
    2.0e-11: the gaps between segments close to the residual's floor at rigid stiffness, not to
    round-off; single shooting's identity holds to round-off, tests/test_contact.py)."""
    tube = Obstacle("bent_tube", start=(0, 0, -1e-3), direction=(0, 0, 1), toward=(1, 0, 0), bend_radius=0.4,
                    angle=0.3 / 0.4 + 0.1, radius=0.5e-3 + 0.3e-3)
    rob = Robot(length=0.3, radius=0.5e-3, youngs_modulus=60e9, obstacles=[tube])
    single = solve_static(rob, NONE, nodes=60, segments=1)
    assert single.status[0] & layout.PENETRATION and not single.success[0]
    sol = solve_static(rob, NONE, nodes=60)
    assert sol.success[0] and sol.segments[0] > 1 and sol.penetration[0, 0] <= 0.01 * 0.5e-3
    F, p = sol.contact_force[0], sol.positions[0]
    nL, mL = sol.n[0, -1], sol.m[0, -1]  # just proximal of the tip node
    n0 = nL + F[:-1].sum(axis=0)
    m0 = mL + np.cross(p[-1], nL) + np.cross(p[:-1], F[:-1]).sum(axis=0)
    assert np.abs(sol.base_wrench[0, :3] - n0).max() < 1e-10 * np.abs(F).sum()
    assert np.abs(sol.base_wrench[0, 3:] - m0).max() < 1e-10 * np.abs(np.cross(p, F)).sum()


def test_segments_give_single_shootings_answers():
    """Where single shooting resolves the contact (a tip force pressing a rod on a sphere and a
    plane), every rod in 4 segments gives its answer: shapes to 1e-12 m (measured 2.4e-14)."""
    obstacles = [Obstacle("sphere", center=(0.0235, 0.0, 0.16), radius=0.02),
                 Obstacle("plane", point=(0.0, -0.0025, 0.0), normal=(0.0, 1.0, 0.0))]
    rob = Robot(length=0.25, radius=0.5e-3, youngs_modulus=60e9, tip_force=(0.01, -0.002, 0.0), obstacles=obstacles)
    one = solve_static(rob, NONE, nodes=60, segments=1)
    four = solve_static(rob, NONE, nodes=60, segments=4, sensitivities=True)
    assert one.success[0] and four.success[0] and four.segments[0] == 4 and one.segments[0] == 1
    assert np.abs(one.positions - four.positions).max() < 1e-12
    assert np.isnan(four.tip_jacobian).all() and four.stability_index[0] == 0  # split: NaN sensitivities, a verdict


def test_rods_of_a_batch_are_independent_when_split():
    """Three wires: one split (0.2 mm clearance), one whose tip touches (5 cm: single shooting
    resolves it), one clear of the wall (50 cm): each equals the rod alone, bit for bit."""
    clearance = np.array([0.2e-3, 0.05, 0.5])
    batch = solve_static(in_tube(0.5, clearance), np.zeros((3, 0)), nodes=60)
    assert batch.success.all() and batch.segments[0] > 1 and (batch.segments[1:] == 1).all()
    for b in range(3):
        alone = solve_static(in_tube(0.5, clearance[b]), NONE, nodes=60)
        for name in ("positions", "n", "m", "contact_force", "contact_stiffness", "iterations", "segments"):
            assert np.array_equal(getattr(batch, name)[b], getattr(alone, name)[0]), (b, name)


def test_segments_refused_where_not_built():
    """A count beyond the grid, or multiple shooting with tendon states: one-line errors."""
    with pytest.raises(InputError, match="segments must be at most nodes = 20"):
        solve_static(in_tube(0.5, 1e-3), NONE, nodes=20, segments=21)
    with pytest.raises(InputError, match="segments must be a positive integer"):
        solve_static(in_tube(0.5, 1e-3), NONE, nodes=20, segments=0)
    displaced = Robot(length=0.2, tendons=[Tendon(offset=(0.01, 0.0), control="displacement")])
    with pytest.raises(InputError, match="multiple shooting"):
        solve_static(displaced, [[0.0]], nodes=20, segments=4)


def tendon_wire(L, **kw) -> Robot:
    """The wire in a tube of 0.2 mm clearance (as ``in_tube``, the tube 0.51 m long), with a
    tendon 0.4 mm off its axis and damping."""
    tube = Obstacle("tube", start=(0, 0, -0.01), end=(0, 0, 0.51), radius=0.7e-3)
    return Robot(length=L, obstacles=[tube], tendons=[Tendon(offset=(0.0, 0.4e-3))], damping_bending=(0.01,) * 3,
                 drag=(0.1,) * 3, **ROD, **kw)


def test_dynamics_steps_a_split_static_start():
    """A 0.5 m wire lying in its tube (the static start split into 21 segments) stays split in
    dynamics: at rest under the start's tension it stays put (1e-15 m over 3 steps); pulled by
    2 N at dt = 10 s (BDF2: each step close to equilibrium) it settles on the statics at 2 N
    (55 segments) within the contact tolerance, 5 um (measured 2.1 um: the two stiffness
    climbs stop at different stiffnesses, the dynamics' rod 4.7 um deep, the static 2.5 um);
    the total contact force agrees to 1e-4 (measured 1e-5); every step converged within the
    penetration tolerance."""
    rob = tendon_wire(0.5)
    sim = tw.Simulator(rob, np.zeros((1, 1)), dt=10.0, alpha=0.0, nodes=100)
    assert sim.parts[0].count[0] == 21
    start = sim.shapes()[0].copy()
    for _ in range(3):
        assert sim.step(np.zeros((1, 1))).converged[0]
    assert np.abs(sim.shapes()[0] - start).max() < 1e-15
    for _ in range(10):
        r = sim.step(np.full((1, 1), 2.0))
        assert r.converged[0] and not r.status[0] & layout.PENETRATION
    target = solve_static(rob, np.full((1, 1), 2.0), nodes=100)
    assert target.success[0] and target.segments[0] > 1
    assert np.abs(sim.shapes()[0] - start).max() > 1e-4  # it moved
    assert np.abs(sim.shapes()[0] - target.positions[0]).max() < 0.01 * 0.5e-3
    F = sim.contact()["contact_force"][0].sum(axis=0)
    assert np.abs(F - target.contact_force[0].sum(axis=0)).max() < 1e-4 * np.abs(F).max()


def test_dynamics_splits_a_rod_as_its_contact_grows():
    """A damped 0.5 m wire on the axis of its tube (no load at the start), its tendon pulled from
    0.25 to 4 N in 16 quasi-static steps (dt = 10 s, BDF2): the wire is drawn onto the wall along
    a growing length. Single shooting (segments = 1) is flagged PENETRATION from the third step
    and fails at the ninth. By default a step that single shooting leaves too deep in a long
    contact is solved again from a softened contact and climbs back, split on the way (and split
    again as the contact grows: 63 segments at the end): every step converges within the
    tolerance, and the last shape is the statics' at 4 N within the contact tolerance (2.4 um)."""
    tube = Obstacle("tube", start=(0, 0, -0.01), end=(0, 0, 0.51), radius=0.7e-3)
    rob = Robot(length=0.5, radius=0.5e-3, youngs_modulus=60e9, tendons=[Tendon(offset=(0.4e-3, 0.0))],
                obstacles=[tube], damping_bending=(0.01,) * 3, drag=(0.1,) * 3)
    tau = np.linspace(0.25, 4.0, 16)[None, :, None]
    single = tw.Simulator(rob, np.zeros((1, 1)), dt=10.0, alpha=0.0, nodes=100, segments=1).simulate(tau, 16)
    assert (single.status[:, 0] & layout.PENETRATION).any() and single.failed_step[0] >= 0
    sim = tw.Simulator(rob, np.zeros((1, 1)), dt=10.0, alpha=0.0, nodes=100)
    assert sim.parts[0].count[0] == 0
    run = sim.simulate(tau, 16)
    assert run.converged.all() and not (run.status & layout.PENETRATION).any()
    assert sim.parts[0].count[0] > 1
    target = solve_static(rob, np.full((1, 1), 4.0), nodes=100)
    assert target.success[0] and np.abs(sim.shapes()[0] - target.positions[0]).max() < 0.01 * 0.5e-3


def test_split_rods_of_a_batch_are_independent_in_dynamics():
    """Wires of 0.5 m (split at the start) and 0.2 m (single shooting) in one batch, pulled for
    5 steps of 2 ms: each rod's trajectory equals its own alone, bit for bit."""
    L, tau = np.array([0.5, 0.2]), np.array([[1.0], [0.5]])
    steps = np.repeat(tau[:, None], 5, axis=1)
    both = tw.Simulator(tendon_wire(L), np.zeros((2, 1)), dt=2e-3, alpha=-0.2, nodes=100)
    assert both.parts[0].count.tolist() == [21, 0]
    run = both.simulate(steps, 5)
    assert run.converged.all()
    for i in range(2):
        alone = tw.Simulator(tendon_wire(L[i]), np.zeros((1, 1)), dt=2e-3, alpha=-0.2, nodes=100)
        assert np.array_equal(alone.simulate(steps[i:i + 1], 5).positions[:, 0], run.positions[:, i])


@pytest.mark.parametrize("nodes", [100, 200])
def test_an_inextensible_wire_in_a_bent_tube_solves_as_the_cosserat_one(nodes):
    """Issue 39's scene: a 0.25 m wire pushed into a lumen of 0.2 mm clearance bent at R 0.3 m was
    flagged with the inextensible rod (21 segments, 17 mm deep) where the Cosserat rod solved.
    Both succeed now, within the contact tolerance, and the shapes agree to the shear and
    extension the Kirchhoff rod leaves out (measured 1.8e-7 and 1.9e-7 m)."""
    tube = Obstacle("bent_tube", start=(0, 0, -1e-3), direction=(0, 0, 1), toward=(1, 0, 0), bend_radius=0.3,
                    angle=0.25 / 0.3 + 0.1, radius=0.5e-3 + 0.2e-3)
    rob = Robot(length=0.25, radius=0.5e-3, youngs_modulus=60e9, obstacles=[tube])
    kirchhoff = solve_static(rob, NONE, nodes=nodes, rod="kirchhoff")
    cosserat = solve_static(rob, NONE, nodes=nodes)
    for sol in (kirchhoff, cosserat):
        assert sol.success[0] and sol.penetration[0].max() <= 0.01 * 0.5e-3
    assert np.abs(kirchhoff.positions - cosserat.positions).max() < 1e-6
