"""Dynamics with obstacles and with a held tip: the settled motion against statics, an impact on a
rigid wall (never through it), the Hunt-Crossley damping's dissipation measured as the work of
the contact forces, the rods of a batch independent, a start inside an obstacle refused, and the
tip controller against a wall."""

import numpy as np
import pytest

import tdcr_warp as tw
from tdcr_warp.apps.control import TipController, run_closed_loop, static_target
from tdcr_warp.kernels import layout

E, NU, R, L, RHO = 190e9, 0.3, 1e-3, 0.5, 7800.0
ROD = dict(length=L, youngs_modulus=E, poisson_ratio=NU, radius=R, density=RHO)
DAMPED = dict(damping_bending=(0.008,) * 3, damping_shear=(1e-3,) * 3, drag=(0.01,) * 3, gravity=(0.0, 0.0, -9.81))
NONE = np.zeros((1, 0))


def tendons():
    return [tw.Tendon(offset=o) for o in [(0.01, 0.0), (0.0, 0.01), (-0.01, 0.0), (0.0, -0.01)]]


def wall(x, **kw) -> tw.Obstacle:
    """A plane at x, the rod on its -x side."""
    return tw.Obstacle("plane", point=(x, 0.0, 0.0), normal=(-1.0, 0.0, 0.0), **kw)


def back_wall(x, **kw) -> tw.Obstacle:
    """A plane at x (a number or (B,)), the rod on its +x side."""
    x = np.asarray(x, dtype=float)
    return tw.Obstacle("plane", point=np.stack([x, 0 * x, 0 * x], axis=-1), normal=(1.0, 0.0, 0.0), **kw)


@pytest.mark.parametrize("stiffness", [2e5, None])
def test_settled_motion_against_a_wall_is_the_static_solution(stiffness):
    """One tendon pulls the rod from straight onto a wall at 60% of its free reach; the damped
    motion settles where statics puts it. A compliant wall (a fixed penalty) agrees to the
    settling error; a rigid one within the contact tolerance (each stiffens on its own
    schedule, so their penetrations differ by up to 0.01 r)."""
    tau = [[3.0, 0.0, 0.0, 0.0]]
    reach = tw.solve_static(tw.Robot(tendons=tendons(), **ROD, **DAMPED), tau, nodes=30).tip_position[0, 0]
    rob = tw.Robot(tendons=tendons(), obstacles=[wall(0.6 * reach, stiffness=stiffness)], **ROD, **DAMPED)
    static = tw.solve_static(rob, tau, nodes=30)
    assert static.success[0] and np.abs(static.contact_force).sum() > 0
    tr = tw.Simulator(rob, [[0.0] * 4], dt=0.005, alpha=-0.2, nodes=30).simulate(np.tile(tau, (400, 1)), 400)
    assert tr.converged.all() and not (tr.status & layout.PENETRATION).any()
    err = np.abs(tr.tip_position[-1] - static.tip_position).max()
    assert err < (1e-6 if stiffness else 2 * 0.01 * R), f"settled {err:.2e} m from the static solution"
    if stiffness is None:
        assert tr.penetration.max() <= 0.01 * R


def _release(obstacle, dt=0.002, steps=60, B=1):
    """A free cantilever released from a small static bend toward +x swings back onto a wall
    behind its base line; returns the simulator."""
    start = tw.solve_static(tw.Robot(tip_force=(0.02, 0.0, 0.0), **ROD), np.zeros((B, 0)), nodes=20)
    return tw.Simulator(tw.Robot(obstacles=[obstacle], **ROD), np.zeros((B, 0)), dt=dt, alpha=-0.45, nodes=20,
                        initial=start), start.tip_position[:, 0]


def test_impact_on_a_rigid_wall_never_passes_through():
    """The tip strikes a rigid wall at ~0.15 m/s within one step (the wall stiffens where the
    strike presses in beyond the tolerance, and a step that fails at the stiff contact is
    reached from a soft one): every step converges, no node sinks deeper than 0.01 r, and the
    rod comes off the wall again."""
    sim, x0 = _release(back_wall(-0.0028))
    tr = sim.simulate(np.zeros((100, 0)), 100)
    assert tr.converged.all() and not (tr.status & layout.PENETRATION).any()
    hit = np.flatnonzero(tr.penetration[:, 0] > 0)
    assert len(hit) and tr.penetration.max() <= 0.01 * R
    x = tr.tip_position[:, 0, 0]
    assert x.min() >= -0.0028 + R - 0.01 * R
    assert x[hit[0]:].max() > 0.5 * x0[0]  # it bounced back past half its start


def test_strong_damping_on_a_rigid_wall_is_flagged_never_fails():
    """Damping of 300 s/m on a rigid wall: a node leaving at 1 / (2 c) or faster carries at most
    half its elastic force, so no stiffness holds its depth (the schedule leaves it; before, it
    climbed to 1e11 N/m^2 and the next step failed). Every step converges, and every step a node
    sinks beyond the tolerance says so (PENETRATION): deep, but never silent."""
    sim, _ = _release(back_wall(-0.0028, damping=300.0))
    tr = sim.simulate(np.zeros((100, 0)), 100)
    assert tr.converged.all()
    deep = tr.penetration[:, 0] > 0.01 * R
    flagged = (tr.status[:, 0] & layout.PENETRATION) != 0
    assert deep.any() and not (deep & ~flagged).any()  # (a step at a softened stiffness is flagged for its band too)


def _contact_work(damping: float) -> tuple[float, float]:
    """The work of the contact forces on the rod over a strike on a compliant wall, W = int sum
    F . p_t dt (trapezoid over the steps), and int |sum F . p_t| dt [J]."""
    sim, _ = _release(back_wall(-0.0028, stiffness=5e4, damping=damping))
    power = [0.0]
    for _ in range(60):
        assert sim.step(NONE).converged[0]
        power.append(float(np.sum(sim.contact()["contact_force"] * sim.velocities())))
    power = np.array(power)
    return np.trapezoid(power, dx=sim.dt), np.trapezoid(np.abs(power), dx=sim.dt)


def test_contact_damping_dissipates():
    """The undamped penalty is a potential force: its work over a strike (in and out) is ~0,
    here within the time-stepping's error, 7.6% of int |P| dt at dt = 2 ms. The Hunt-Crossley
    damping takes energy out, more as it grows (measured: -6%, -24%, -48% at 3, 10, 30 s/m)."""
    (w0, a0), (w10, a10), (w30, a30) = (_contact_work(c) for c in (0.0, 10.0, 30.0))
    assert abs(w0) < 0.12 * a0
    assert w10 < -0.15 * a10 and w30 < -0.35 * a30 and w30 < w10 < w0


def test_rods_of_a_batch_strike_their_own_walls_independently():
    """Three rods, three wall positions (one out of reach): each rod's run equals its run alone,
    bit for bit."""
    xs = np.array([-0.0028, -0.0022, -0.05])
    sim, _ = _release(back_wall(xs), B=3)
    batch = sim.simulate(np.zeros((50, 0)), 50)
    assert batch.converged.all() and (batch.penetration[:, :2] > 0).any(axis=0).all()
    for b, x in enumerate(xs):
        one, _ = _release(back_wall(x))
        alone = one.simulate(np.zeros((50, 0)), 50)
        assert np.array_equal(alone.tip_position[:, 0], batch.tip_position[:, b])
        assert np.array_equal(alone.penetration[:, 0], batch.penetration[:, b])


def test_start_inside_an_obstacle_is_refused():
    """A start whose shape passes through a wall (given as ``initial``) is a one-line error."""
    start = tw.solve_static(tw.Robot(tip_force=(0.02, 0.0, 0.0), **ROD), NONE, nodes=20)
    rob = tw.Robot(obstacles=[wall(0.002)], **ROD)
    with pytest.raises(tw.InputError, match="inside an obstacle"):
        tw.Simulator(rob, NONE, dt=0.002, nodes=20, initial=start)


def test_held_tip_motion_settles_to_the_static_solution():
    """A tip held on a vertical line: as two tendons pull, the tip never leaves the line, and
    the damped motion settles where statics puts it, with the same reaction."""
    free = tw.Robot(tendons=tendons(), **ROD, **DAMPED)
    tip = tw.solve_static(free, [[1.0, 0.0, 0.0, 0.0]], nodes=30).tip_position[0]
    rob = tw.Robot(tendons=tendons(), tip_constraint=tw.TipConstraint("line", point=tip, direction=(0, 0, 1)),
                   **ROD, **DAMPED)
    tau = [[3.0, 0.0, 1.0, 0.0]]
    static = tw.solve_static(rob, tau, nodes=30)
    sim = tw.Simulator(rob, [[1.0, 0.0, 0.0, 0.0]], dt=0.005, alpha=-0.2, nodes=30)
    tr = sim.simulate(np.tile(tau, (300, 1)), 300)
    assert tr.converged.all()
    assert np.abs(tr.tip_position[:, 0, :2] - tip[:2]).max() < 1e-10
    assert np.abs(tr.tip_position[-1] - static.tip_position).max() < 1e-9
    assert np.abs(sim.tip_reaction() - static.tip_reaction).max() < 1e-6 * np.abs(static.tip_reaction).max()
    assert np.abs(static.tip_reaction[0, 0]) > 1e-3  # the line takes a real force


def _seed_robot(**kw):
    return tw.Robot(length=0.5, youngs_modulus=190e9, poisson_ratio=0.3, radius=1e-3, density=17189.0,
                    tendons=tendons(), gravity=(0.0, 0.0, -9.81), damping_bending=(0.008,) * 3, drag=(0.01,) * 3, **kw)


def test_controller_stops_at_a_wall_before_a_target_behind_it():
    """The sliding-mode controller drives the tip toward a target behind a wall (at 60% of its
    reach) and toward one on the wall's surface: the tip presses on the wall at the tolerance
    and no further (the tension saturates), and reaches the target on the surface."""
    target = static_target(_seed_robot(), [[3.0, 0.0, 0.0, 0.0]], nodes=20)
    for x_wall, behind in ((0.6 * target[0, 0], True), (target[0, 0] + R, False)):
        sim = tw.Simulator(_seed_robot(obstacles=[wall(x_wall)]), np.zeros((1, 4)), dt=0.005, alpha=-0.2, nodes=20)
        run = run_closed_loop(sim, TipController(sim, target), 200)
        assert run.converged.all() and run.penetration.max() <= 0.01 * R
        assert run.tip_position[:, 0, 0].max() <= x_wall - R + 0.01 * R
        if behind:
            assert abs(run.tip_position[-1, 0, 0] - (x_wall - R)) < 0.01 * R  # on the wall
            assert run.tensions[-1, 0, 0] == pytest.approx(8.0)  # pushing at tension_max
        else:
            assert np.linalg.norm(run.error[-1]) < 2e-5
