"""The spacer-disk tendon model (solver model "disks", kernels/disks.py): a closed form, its
convergence to the continuous coupled model as disks are added, global balance, the tendon
lengths, displacement control, and its input errors. The independent SciPy reference is
compared in tests/test_scipy_disks.py."""

from dataclasses import replace

import numpy as np
import pytest

import tdcr_warp as tw
from tdcr_warp.model.robot import InputError

L, RADIUS, YOUNG = 0.2, 0.5e-3, 50e9
EI = YOUNG * np.pi * RADIUS**4 / 4


def robot(disks, tendons=None, **kw):
    tendons = tendons if tendons is not None else [tw.Tendon(offset=(0.0045, 0.0))]
    return tw.Robot(length=L, radius=RADIUS, youngs_modulus=YOUNG, density=0.0, tendons=tendons, disks=disks, **kw)


def solve(rb, tensions, **opts):
    sol = tw.solve_static(rb, tensions=tensions, options=tw.StaticOptions(model="disks", **opts))
    assert sol.converged.all()
    return sol


@pytest.mark.parametrize("kL", [1.0, 2.0])
def test_a_single_disk_at_the_tip_is_an_eccentric_column(kL):
    """One disk at the tip, a tendon at offset d: its chord runs from the base hole to the tip
    hole, so the rod is a column compressed by tau along that line. Small deflection,
    inextensible: EI x'' + tau x = tau (d + x_L s / L), x(0) = x'(0) = 0, whence
    x_L = d kL (1 - cos kL) / sin kL with k^2 = tau / EI (the continuous model: d (kL)^2 / 2)."""
    d = 1e-4
    tau = (kL / L) ** 2 * EI
    sol = solve(robot([L], [tw.Tendon(offset=(d, 0.0))]), [[tau]], nodes=64, rod="kirchhoff")
    closed = d * kL * (1 - np.cos(kL)) / np.sin(kL)
    assert sol.tip_position[0, 0] == pytest.approx(closed, rel=1e-5)  # (x_L / L)^2 ~ 1e-6 of geometry left out
    assert abs(closed - d * kL**2 / 2) > 0.08 * closed  # what the disk changes: 8.5% at kL = 1


def test_disks_converge_to_the_continuous_model_at_second_order():
    """Evenly spaced disks, spacing h: each chord cuts the corner of the route by O(h^2), and the
    tip approaches the coupled model's like h^2 (measured ratios 4.42, 4.10, 4.02, 4.01 from 5 to
    80 disks)."""
    tau = [[2.0]]
    cont = tw.solve_static(robot(10), tensions=tau, options=tw.StaticOptions(model="coupled", nodes=160))
    errors = [np.linalg.norm(solve(robot(D), tau, nodes=160).tip_position[0] - cont.tip_position[0])
              for D in (10, 20, 40)]
    orders = np.log2(np.array(errors[:-1]) / errors[1:])
    assert orders == pytest.approx([2.0, 2.0], abs=0.06), orders
    assert 1e-3 < errors[0] < 3e-3  # 10 disks on a 73 degree bend: 2 mm at a 20 cm tip


def test_the_grid_between_disks_converges_at_the_integrators_order():
    """Sub-intervals between the disks (nodes a multiple of the disk count): RK4's 4th order."""
    rb = robot(10)
    tips = [solve(rb, [[2.0]], nodes=n).tip_position[0] for n in (10, 20, 40, 80)]
    diffs = [np.linalg.norm(a - b) for a, b in zip(tips[:-1], tips[1:])]
    orders = np.log2(np.array(diffs[:-1]) / diffs[1:])
    assert (orders > 3.5).all(), orders


def test_path_lengths_are_the_chords_and_the_base_balances_the_first_chords():
    """Two tendons, one ending mid-rod, a tip force: each tendon's path length is the sum of its
    chords between the holes of the solved shape, and the free body of rod and tendons above
    the base gives n(0) + sum tau u_1 = F_tip, m(0) + sum r x tau u_1 = M_tip + p(L) x F_tip
    (u_1: each tendon's first chord, from its base hole)."""
    tendons = [tw.Tendon(offset=(0.0045, 0.0), length=0.1), tw.Tendon(offset=(0.0, -0.004))]
    tip_force = np.array([0.02, -0.01, 0.03])
    rb = robot(5, tendons, tip_force=tip_force)
    tau = np.array([3.0, 1.5])
    sol = solve(rb, [tau], nodes=20)
    s, p, R = sol.s[0], sol.positions[0], sol.rotations[0]
    at = np.flatnonzero(np.isclose(s[:, None], rb.disks[None]).any(axis=1))
    firsts = []
    for k, t in enumerate(tendons):
        r = np.array([*t.offset[0], 0.0])
        ends = at[s[at] <= (t.length[0] if t.length is not None else L) + 1e-12]
        holes = np.vstack([r, p[ends] + R[ends] @ r])
        chords = np.diff(holes, axis=0)
        assert sol.tendon_path_length[0, k] == pytest.approx(np.linalg.norm(chords, axis=1).sum(), rel=1e-12)
        firsts.append((r, chords[0] / np.linalg.norm(chords[0])))
    pull = sum(tk * u for tk, (_, u) in zip(tau, firsts))
    turn = sum(np.cross(r, tk * u) for tk, (r, u) in zip(tau, firsts))
    n0, m0 = sol.base_wrench[0, :3], sol.base_wrench[0, 3:]
    np.testing.assert_allclose(n0 + pull, tip_force, atol=1e-9 * tau.sum())
    np.testing.assert_allclose(m0 + turn, np.cross(p[-1], tip_force), atol=1e-9 * tau.sum() * L)


def test_disk_weights_load_the_base():
    """No tendon, gravity, disks of 2 g and a rod of its own weight: n(0) carries the total
    weight (n(0) = F_tip + the integral of f + the point forces; RK4 integrates f through
    R R^T at its stages, where R is a rotation to O(h^2) only: 6e-8 at this 7 cm sag)."""
    g = np.array([0.0, -9.81, 0.0])
    rb = tw.Robot(length=L, radius=RADIUS, youngs_modulus=YOUNG, density=7800.0, gravity=g, disks=8,
                  disk_mass=0.002)
    sol = solve(rb, np.zeros((1, 0)), nodes=16)
    weight = (7800.0 * np.pi * RADIUS**2 * L + 8 * 0.002) * g
    np.testing.assert_allclose(sol.base_wrench[0, :3], weight, rtol=1e-6, atol=1e-15)
    bare = solve(tw.Robot(length=L, radius=RADIUS, youngs_modulus=YOUNG, density=7800.0, gravity=g, disks=8),
                 np.zeros((1, 0)), nodes=16)
    assert sol.tip_position[0, 1] < bare.tip_position[0, 1] - 1e-4  # the disks sag it further


def test_displacement_control_finds_the_tension_that_tension_control_bends_the_same():
    """A displacement-controlled tendon under the disk model, then tension control at the
    tension it found: the same shape (the lengths it controls are the chords')."""
    tendons = [tw.Tendon(offset=(0.0045, 0.0), control="displacement", compliance=1e-3, pretension=0.5)]
    sol = tw.solve_static(robot(6, tendons), displacements=[[0.002]],
                          options=tw.StaticOptions(model="disks", nodes=24))
    assert sol.converged.all()
    tau = sol.tendon_tension_base
    assert tau[0, 0] > 0.5
    again = solve(robot(6, [tw.Tendon(offset=(0.0045, 0.0))]), tau, nodes=24)
    np.testing.assert_allclose(again.tip_position, sol.tip_position, atol=1e-10)


@pytest.mark.parametrize("change, message", [
    (dict(disks=()), "needs the robot's disks"),
    (dict(disks=[0.1, 0.2], tendons=[tw.Tendon(offset=(0.004, 0.0), length=0.05)]), "not at a disk"),
    (dict(tendons=[tw.Tendon(offset=(0.004, 0.0), friction=0.1)]), "frictionless"),
])
def test_the_disk_model_refuses_what_it_does_not_model(change, message):
    kw = dict(disks=4) | change
    with pytest.raises(InputError, match=message):
        tw.solve_static(robot(**kw), tensions=[[1.0]], options=tw.StaticOptions(model="disks", nodes=8))


def test_too_few_nodes_for_the_disks_and_dynamics_are_refused():
    with pytest.raises(InputError, match="spacer disks"):
        tw.solve_static(robot(10), tensions=[[1.0]], options=tw.StaticOptions(model="disks", nodes=8))
    with pytest.raises(InputError, match="does not support dynamics"):
        tw.Simulator(robot(4), tensions=[[1.0]], dt=1e-3, options=tw.StaticOptions(model="disks", nodes=8))


def test_the_disk_model_agrees_with_the_independent_scipy_solver():
    """Three tendons (one ending at the third of six disks), a tip force, the rod's and the disks'
    weight, against tests/scipy_disks.py (the holes as unknowns of one root problem, DOP853 at
    rtol 1e-12): tip, base wrench and path lengths. Ours converges to it at RK4's fourth order
    (16, 32, 64 steps a disk: 1.2e-8, 7.3e-10, 6.2e-11 m)."""
    from scipy_disks import solve_disks

    disks = list(np.linspace(L / 6, L, 6))
    g, tip_force = (0.0, -9.81, 0.0), (0.01, 0.0, -0.02)
    spec = [((0.0045, 0.0), disks[2], 1.2), ((-0.002, 0.004), L, 0.8), ((0.0, -0.0045), L, 0.5)]
    ref = solve_disks(dict(length=L, youngs_modulus=YOUNG, poisson_ratio=0.3, radius=RADIUS, density=6450.0,
                           gravity=g, tip_force=tip_force, disks=disks, disk_mass=0.001,
                           tendons=[dict(offset=o, length=s, tension=t) for o, s, t in spec]))
    rb = tw.Robot(length=L, radius=RADIUS, youngs_modulus=YOUNG, density=6450.0, gravity=g, tip_force=tip_force,
                  disks=disks, disk_mass=0.001, tendons=[tw.Tendon(offset=o, length=s) for o, s, _ in spec])
    sol = solve(rb, [[t for *_, t in spec]], nodes=192)
    assert np.linalg.norm(sol.tip_position[0] - ref["tip"]) < 1e-8
    np.testing.assert_allclose(sol.base_wrench[0, :3], ref["n0"], atol=1e-9)
    np.testing.assert_allclose(sol.base_wrench[0, 3:], ref["m0"], atol=1e-11)
    np.testing.assert_allclose(sol.tendon_path_length[0], ref["path_lengths"], atol=1e-9)
    assert np.linalg.norm(sol.tip_position[0] - [0.0, 0.0, L]) > 0.01  # a real bend, not a straight rod


def test_float32_costs_a_fraction_of_a_micrometre():
    """The disk model in float32 (its chord iteration stops at 1e-6 of the tension) against
    float64: 1.3e-7 m on a 73 degree bend of a 20 cm rod."""
    rb = robot(10)
    a = solve(rb, [[2.0]], nodes=40)
    b = solve(rb, [[2.0]], nodes=40, precision="float32")
    assert np.linalg.norm(b.tip_position[0] - a.tip_position[0]) < 1e-6


def test_the_default_solve_reaches_what_a_load_ramp_reaches():
    """Two sections (two tendons end at mid-length), 10 disks, one or two tendons pulled with up to
    5 N: from its default start (the coupled model's answer) the disk model's Newton used to stop
    at the iteration cap on some rods (continuation = 0 shows which), each of which a ramp of warm
    starts gets through. Now such a rod takes the load path from the straight rod itself: every
    rod converges, and those rods end where a 10-step ramp of warm starts ends (measured 1.7e-11 m)."""
    off = 0.0045
    tendons = [tw.Tendon(offset=(off, 0.0), length=L / 2), tw.Tendon(offset=(0.0, off), length=L / 2),
               tw.Tendon(offset=(-off, 0.0)), tw.Tendon(offset=(0.0, -off))]
    rb = tw.Robot(length=L, radius=RADIUS, youngs_modulus=YOUNG, density=0.0, tendons=tendons,
                  disks=list(np.linspace(L / 10, L, 10)))
    rng = np.random.default_rng(2)
    tau = np.zeros((60, 4))
    for i in range(60):
        k = rng.choice(4, rng.integers(1, 3), replace=False)
        tau[i, k] = rng.uniform(0.5, 5.0, len(k))
    opts = tw.StaticOptions(model="disks", nodes=40, stability="off")
    coupled = tw.solve_static(rb, tensions=tau, options=replace(opts, model="coupled"))
    stuck = ~tw.solve_static(rb, tensions=tau, options=replace(opts, continuation=0), initial=coupled).converged
    assert stuck.sum() >= 3
    sol = tw.solve_static(rb, tensions=tau, options=opts)
    assert sol.converged.all()
    ramp = None
    for lam in np.linspace(0.1, 1.0, 10):
        ramp = tw.solve_static(rb, tensions=tau[stuck] * lam, options=opts, initial=ramp)
    assert ramp.converged.all()
    assert np.abs(sol.tip_position[stuck] - ramp.tip_position).max() < 1e-9
