"""The elastic stability verdict (tdcr_warp/physics/stability.py) and the search for the stable branch,
against closed forms: Euler's buckling loads of a cantilever, the post-buckled elastica, and
the buckling loads of a tendon-loaded rod under tension and under displacement control."""

import numpy as np
import pytest
from scipy.optimize import brentq
from scipy.special import ellipe, ellipk
from tdcr_warp.kernels import layout

import tdcr_warp as tw

E, NU, RB, L = 190e9, 0.3, 1e-3, 0.5
EI = E * np.pi * RB**4 / 4
P_CR = np.pi**2 * EI / (4 * L**2)  # Euler: a clamped-free column buckles at (pi / 2)^2 EI / L^2
OFF = 0.01
THREE = [(OFF * np.cos(a), OFF * np.sin(a)) for a in (0.0, 2 * np.pi / 3, 4 * np.pi / 3)]


def robot(loads, tendons=(), **kw):
    """One rod per compressive tip load in ``loads`` [units of P_CR], plus a lateral part."""
    lat = kw.pop("lateral", 0.0)
    F = np.zeros((len(loads), 3))
    F[:, 2] = -np.asarray(loads) * P_CR
    F[:, 0] = lat * P_CR
    return tw.Robot(length=L, youngs_modulus=E, poisson_ratio=NU, radius=RB, density=0.0, tip_force=F,
                    tendons=tuple(tendons), **kw)


def elastica_tip(load: float) -> tuple[float, float]:
    """The post-buckled cantilever under a dead axial load P (inextensible): with theta the
    tangent angle, EI theta'' + P sin theta = 0, theta(0) = 0, theta'(L) = 0, so
    EI theta'^2 / 2 = P (cos theta - cos alpha) and, substituting sin(theta / 2) = k sin phi
    (k = sin(alpha / 2)), lambda L = K(k) with lambda^2 = P / EI; the tip lies at
    x = 2 k / lambda to the side and z = (2 E(k) - K(k)) / lambda above the base."""
    lam = np.sqrt(load * P_CR / EI)
    m = brentq(lambda m: ellipk(m) - lam * L, 0.0, 1.0 - 1e-15)
    return 2 * np.sqrt(m) / lam, (2 * ellipe(m) - ellipk(m)) / lam


def test_euler_buckling_loads_of_the_cantilever_within_a_tenth_of_a_percent():
    """The straight rod has a double (round section) conjugate point crossing the clamp at
    each Euler load (2n - 1)^2 P_CR: the index counts both planes."""
    loads = [0.5, 0.999, 1.001, 5.0, 8.99, 9.01]
    sol = tw.solve_static(robot(loads), nodes=40, rod="kirchhoff", stability="check", tol=1e-12)
    assert sol.converged.all()
    assert np.abs(sol.tip_position[:, :2]).max() < 1e-12  # the straight branch
    assert sol.stability_index.tolist() == [0, 0, 2, 2, 2, 4]
    assert sol.lagrangian_error.max() < 1e-5  # see the next test
    assert sol.stable.tolist() == [True, True, False, False, False, False]
    assert all(((st & layout.UNSTABLE) != 0) == (i > 0) for st, i in zip(sol.status, sol.stability_index))
    assert "unstable equilibrium" in sol.failure_reasons()[2]


def test_the_fields_stay_lagrangian_to_the_order_of_the_integrator():
    """U^T V - V^T U is constant along s for exact Jacobi fields, zero from the clamp. RK4's flow
    map is not symplectic, so the computed asymmetry at the tip is its truncation error: it falls
    at fourth order as N doubles (a wrong field, e.g. one missing the tendons' part of V, stays
    near 1e-2). At N = 40 and 80 the verdict keeps its double steps for both rods (phases move
    under pi / 4 a step), so the fields are compared on steps of L / 20 and L / 40; at N = 20 the
    rod at 5 P_cr goes on to the full grid (moves of 1.04 rad), the steps of N = 40."""
    loads = [3.0, 5.0]
    err = [tw.solve_static(robot(loads), nodes=n, rod="kirchhoff", tol=1e-12).lagrangian_error for n in (40, 80)]
    assert (err[0] / err[1] > 10).all(), err
    assert (err[1] < 1e-6).all(), err


def test_the_stable_branch_past_buckling_is_the_elastica():
    """Found from the straight, unstable solve by restarts; RK4's fourth order as N doubles."""
    loads = [1.1, 2.0, 3.0, 10.0]
    exact = np.array([elastica_tip(f) for f in loads])
    errors = []
    for nodes in (30, 60):
        sol = tw.solve_static(robot(loads), nodes=nodes, rod="kirchhoff", stability="stable", tol=1e-13)
        assert sol.converged.all() and (sol.stability_index == 0).all() and (sol.branch == 1).all()
        assert sol.multiple_stable.all()  # a round rod buckles into any plane
        tip = sol.tip_position
        errors.append(np.abs(np.c_[np.hypot(tip[:, 0], tip[:, 1]), tip[:, 2]] - exact).max(axis=1))
    assert (errors[1] < 1e-6).all()  # m, at N = 60 (5.7e-7 m at 10 P_CR, 1.4e-8 m at 1.1 P_CR)
    assert (errors[0] / errors[1] > 12).all(), errors


def test_a_lateral_load_does_not_save_the_straight_solve_but_the_search_does():
    """With a lateral load of 10% of P_CR the continuation still ends on the nearly straight
    branch above 2 P_CR; the check flags it, the search returns the bent, stable one."""
    rb = robot([2.0, 3.0], lateral=0.1)
    chk = tw.solve_static(rb, nodes=40, rod="kirchhoff", stability="check", tol=1e-12)
    assert chk.converged.all() and (chk.stability_index > 0).all()
    assert (chk.tip_position[:, 0] < 0).all() and (chk.tip_position[:, 0] > -0.1 * L).all()  # leaning against it
    st = tw.solve_static(rb, nodes=40, rod="kirchhoff", stability="stable", tol=1e-12)
    assert st.converged.all() and st.stable.all() and (st.branch == 1).all()
    assert (st.tip_position[:, 0] > 0.6 * L).all()  # bent the way the lateral load pushes
    assert not (st.status & layout.UNSTABLE).any()
    assert (st.iterations > chk.iterations).all()  # the restarts are counted


def test_tendons_under_tension_control_leave_the_euler_load_unchanged():
    """Straight parallel tendons at fixed tension: their potential sum tau ell has no
    second-order bending term on a straight rod (ell = integral of 1 + (u x r)_z, linear in u;
    the total internal force n + sum tau t is the dead load alone), so even tensions of 10 P_CR
    each leave the rod stable, and with a dead load the rod buckles at P_CR as without them."""
    tend = [tw.Tendon(offset=o) for o in THREE]
    sol = tw.solve_static(robot([0.0, 0.0, 0.999, 1.001], tend), [[10 * P_CR] * 3, [1.0] * 3, [5.0] * 3, [5.0] * 3],
                          nodes=40, stability="check", tol=1e-12)
    assert sol.converged.all()
    assert sol.stability_index.tolist() == [0, 0, 0, 2]
    assert sol.lagrangian_error.max() < 1e-8


def test_displacement_controlled_wires_raise_the_buckling_load_fourfold():
    """Three inextensible wires at 120 degrees under displacement control hold each tendon's
    length: to first order d ell_k = -(r_k x theta(L))_z (bending) and compression, so the
    tip cannot rotate. The cantilever becomes a column clamped at the base and guided at the
    tip (free to sway, not to turn), which buckles at pi^2 EI / L^2 = 4 P_CR. Under tension
    control at the same tensions the same rods buckle at P_CR."""
    loads = [3.996, 4.004]  # 4 P_CR within a tenth of a percent
    disp = [tw.Tendon(offset=o, control="displacement", pretension=1.0) for o in THREE]
    sol = tw.solve_static(robot(loads, disp), nodes=40, stability="check", tol=1e-12)
    assert sol.converged.all() and not sol.slack.any()
    assert sol.stability_index.tolist() == [0, 2]
    tens = tw.solve_static(robot(loads, [tw.Tendon(offset=o) for o in THREE]), sol.tendon_tension_base, nodes=40,
                           stability="check", tol=1e-12)
    assert tens.stability_index.tolist() == [2, 2]


def test_phases_that_turn_fast_between_nodes_are_followed_on_finer_steps(monkeypatch):
    """Heavily loaded precurved rods on a coarse grid (N = 20): some phase turns by more than
    pi / 4 between nodes, where matching the phases from node to node can count wrong. The verdict
    then goes on to 2, 4, ... steps an interval, and its count equals that of a grid 4x finer
    (whose phases turn less than pi / 4). Taking the full grid's count as it stands (the rule
    before the moves were checked) miscounts some of them."""
    from tdcr_warp.physics import stability

    rng = np.random.default_rng(20)
    B = 48
    F = np.zeros((B, 3))
    F[:, 2] = -rng.uniform(0.0, 12.0, B) * P_CR
    F[:, :2] = rng.normal(0.0, 0.02, (B, 2)) * P_CR
    rob = tw.Robot(length=L, youngs_modulus=E, poisson_ratio=NU, radius=RB, density=7800.0, gravity=(0.0, 0.0, -9.81),
                   tip_force=F, tendons=tuple(tw.Tendon(offset=o) for o in THREE), precurvature=(2.0, 0.0, 0.5))
    tau = rng.uniform(0.0, 3.0, (B, 3))
    opts = {"rod": "cosserat", "tol": 1e-12, "continuation": 0, "threads": 1}
    fine = tw.solve_static(rob, tau, nodes=80, **opts)
    sol = tw.solve_static(rob, tau, nodes=20, **opts)
    ok = fine.converged & sol.converged
    assert ok.sum() >= 40 and (fine.stability_index[ok] >= 0).all() and (sol.stability_index[ok] >= 0).all()
    assert (sol.stability_index[ok] == fine.stability_index[ok]).all()
    assert set(sol.stability_index[ok].tolist()) >= {0, 2, 4}
    monkeypatch.setattr(stability, "JUMP_MAX", np.inf)  # every pass trusted on its margin: double steps, else the grid
    old = tw.solve_static(rob, tau, nodes=20, **opts)
    assert (old.stability_index[ok] != fine.stability_index[ok]).any()
    monkeypatch.setattr(stability, "JUMP_MAX", 0.0)  # no pass trusted: not assessed, and said why
    none = tw.solve_static(rob, tau, nodes=20, **opts)
    assert (none.stability_index[ok] == -1).all() and np.isnan(none.stability_margin[ok]).all()
    assert {none.stability_reasons()[i] for i in np.flatnonzero(ok)} == {
        "not assessed: the phases turn too fast for the grid (raise nodes)"}


def test_what_the_test_does_not_assess_is_said():
    fr = [tw.Tendon(offset=o, friction=0.2) for o in THREE]
    sol = tw.solve_static(robot([0.5], fr), [[1.0, 0.0, 0.0]], nodes=20, stability="check")
    assert sol.converged.all() and sol.stability_index.tolist() == [-1] and not sol.stable.any()
    pt = tw.solve_static(robot([0.5], [tw.Tendon(offset=o) for o in THREE]), [[1.0, 0.0, 0.0]], nodes=20,
                         model="point", stability="check")
    assert pt.stability_index.tolist() == [-1]
    bad = tw.solve_static(robot([0.5], lateral=2.0), nodes=20, stability="check", max_iter=1, continuation=0)
    assert not bad.converged.any() and bad.stability_index.tolist() == [-1]
    with pytest.raises(tw.InputError, match="stability must be one of"):
        tw.solve_static(robot([0.5]), stability="yes")


def test_the_verdict_kernels_load_before_the_chunks_threads(monkeypatch):
    """Two threads loading one Warp module at once can unload the code the other runs (a crash
    in threaded sweeps): the evaluation module loads before the threads start."""
    from tdcr_warp.core import solver
    from tdcr_warp.physics import statics

    events = []
    real_load, real_parallel = solver._load_modules, statics.parallel
    monkeypatch.setattr(solver, "_load_modules", lambda kernels, device: events.extend(
        "load evaluate" if "_evaluate_" in k.module.name else "load" for k in kernels) or real_load(kernels, device))
    monkeypatch.setattr(statics, "parallel", lambda fn, items: events.append(f"threads {len(items)}")
                        or real_parallel(fn, items))
    sol = tw.solve_static(robot([0.0]), np.full((64, 0), 0.0), nodes=10, threads=2)
    assert events.count("load evaluate") == 2 and events.index("threads 2") > max(
        i for i, e in enumerate(events) if e == "load evaluate")  # one per chunk's Shooting, all before
    assert (sol.stability_index == 0).all()


@pytest.mark.parametrize("segments", [2, 5, 8])
def test_a_split_euler_column_gets_the_verdict_of_single_shooting(segments):
    """Solved in segments (multiple shooting), the straight cantilever keeps Euler's counts: its
    Jacobi fields are carried over the segments' starts (kernels/jacobi.py, ``restart``) and
    their phases are those of single shooting's fields to round-off."""
    loads = [0.5, 0.999, 1.001, 5.0, 8.99, 9.01]
    one = tw.solve_static(robot(loads), nodes=40, rod="kirchhoff", tol=1e-12)
    split = tw.solve_static(robot(loads), nodes=40, rod="kirchhoff", tol=1e-12, segments=segments)
    assert split.converged.all() and (split.segments == segments).all()
    assert split.stability_index.tolist() == one.stability_index.tolist() == [0, 0, 2, 2, 2, 4]
    assert np.abs(split.stability_margin - one.stability_margin).max() < 1e-9
    assert split.lagrangian_error.max() < 1e-5
    assert split.success.tolist() == [True, True, False, False, False, False]
    assert split.stability_reasons()[2] == "unstable: 2 directions"


def test_split_rods_under_tension_keep_their_fields_resolved():
    """A cantilever under a dead tension is stable at any load. Its Jacobi fields grow like
    exp(lambda s): from lambda L = 31 single shooting's probes, run base to tip, lose them (not
    assessed); a split rod's, restarted at every node from an orthonormal basis, keep them. At
    lambda L = 63 on double steps and at 126 on the full grid (lambda times the step: 3.1) phases
    ran backwards to a count of -2, which is no count: finer passes give 0."""
    loads = [-100.0, -400.0, -1600.0, -6400.0]  # lambda L = 15.7, 31.4, 62.8, 125.7
    one = tw.solve_static(robot(loads), nodes=40, rod="kirchhoff", tol=1e-10)
    split = tw.solve_static(robot(loads), nodes=40, rod="kirchhoff", tol=1e-10, segments=8)
    assert one.converged.all() and split.converged.all()
    assert one.stability_index.tolist() == [0, -1, -1, -1]
    assert split.stability_index.tolist() == [0, 0, 0, 0] and split.success.all()
    assert split.lagrangian_error.max() < 1e-9


def test_a_split_rods_verdict_does_not_depend_on_its_batch():
    alone = tw.solve_static(robot([1.001]), nodes=40, rod="kirchhoff", tol=1e-12, segments=4)
    batch = tw.solve_static(robot([0.5, 1.001, -1600.0, 9.01]), nodes=40, rod="kirchhoff", tol=1e-12, segments=4)
    assert batch.stability_index.tolist() == [0, 2, 0, 4]
    for key in ("stability_index", "stability_margin", "lagrangian_error", "positions"):
        assert np.array_equal(getattr(alone, key)[0], getattr(batch, key)[1]), key


def tip_disk(loads, offset):
    """One rod per tendon tension in ``loads`` [units of P_CR] under the disk model: a single disk,
    at the tip, and the tendon at ``offset`` [m] along x, from the base plate straight to it."""
    rod = tw.Robot(length=L, youngs_modulus=E, poisson_ratio=NU, radius=RB, density=0.0,
                   tendons=(tw.Tendon(offset=(offset, 0.0)),), disks=(L,))
    return tw.solve_static(rod, np.asarray(loads)[:, None] * P_CR, nodes=40, model="disks", rod="kirchhoff",
                           tol=1e-12, continuation=0)


def test_a_single_tip_disk_buckles_the_column_like_a_load_through_the_base():
    """The chord pulls the tip toward the fixed hole in the base plate: a load through a fixed
    point, whose line turns with the tip (a lateral stiffness tau / L there), buckles the rod at
    tau = pi^2 EI / L^2 = 4 P_CR (EI w'' = tau (w(L) s / L - w): sin(kL) = 0), not at P_CR as a
    dead load does. The disk's jump of the fields is followed as a stiffness (kernels/jacobi.py,
    ``shear``)."""
    sol = tip_disk([0.5, 2.0, 3.9, 4.1, 6.0], 0.0)
    assert sol.converged.all() and np.abs(sol.tip_position[:, :2]).max() < 1e-12
    assert sol.stability_index.tolist() == [0, 0, 0, 2, 2]
    assert sol.success.tolist() == [True, True, True, False, False] and sol.assessed.all()
    assert sol.lagrangian_error.max() < 1e-6


def test_a_single_tip_disk_with_an_offset_tendon_is_an_eccentric_column():
    """With the tendon r off the axis the chord's line runs from (r, 0) to the tip's hole: EI w'' =
    tau (r + w(L) s / L - w), so w(L) = r kL tan(kL / 2) (k^2 = tau / EI; small deflections): bent
    toward the tendon below the load, stable; past it (kL > pi) the equilibrium from the straight
    start bends the other way, unstable in that plane and, nearly straight, in the other (index 2).
    Measured at r = 0.1 mm: 1.5e-12 m apart at 0.5 P_CR, 4e-10 m at 2, 2e-9 m at 6; near the load
    (tips of 16 mm) 0.6% (the large deflections' terms)."""
    loads = np.array([0.5, 2.0, 3.9, 4.1, 6.0])
    r = 1e-4
    sol = tip_disk(loads, r)
    kL = np.sqrt(loads * P_CR / EI) * L
    assert sol.converged.all() and sol.stability_index.tolist() == [0, 0, 0, 2, 2]
    err = np.abs(sol.tip_position[:, 0] - r * kL * np.tan(kL / 2))
    assert err[[0, 1, 4]].max() < 1e-8, err
    assert (err[[2, 3]] / np.abs(sol.tip_position[[2, 3], 0])).max() < 0.01, err


def test_the_disk_model_with_more_disks_is_not_assessed():
    rod = tw.Robot(length=L, youngs_modulus=E, poisson_ratio=NU, radius=RB, density=0.0,
                   tendons=(tw.Tendon(offset=(0.01, 0.0)),), disks=(L / 2, L))
    sol = tw.solve_static(rod, [[1.0]], nodes=20, model="disks")
    assert sol.converged.all() and sol.success.all() and not sol.assessed.any()
    assert sol.stability_reasons() == [
        "not assessed: disk model with more than one disk (a chord's pull depends on both holes it joins)"]
