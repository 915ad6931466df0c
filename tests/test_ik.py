"""Batched inverse kinematics (tdcr_warp/apps/ik.py): round trips through the forward statics,
unreachable targets with the closest reachable point, orientation targets, displacement
control, and the messages for bad input."""

import numpy as np
import pytest

import tdcr_warp as tw
from tdcr_warp.apps.ik import box_least_squares, solve_ik

OFF = 0.01
FOUR = [(OFF, 0.0), (0.0, OFF), (-OFF, 0.0), (0.0, -OFF)]


def robot(**kw):
    return tw.Robot(length=0.5, radius=1e-3, tendons=tuple(kw.pop("tendons", [tw.Tendon(offset=o) for o in FOUR])),
                    gravity=(0, 0, -9.81), **kw)


def test_round_trip_of_random_tensions_to_a_nanometre():
    rng = np.random.default_rng(0)
    tau = rng.uniform(0, 3, (48, 4)) * (rng.uniform(size=(48, 4)) < 0.6)
    rb = robot()
    tips = tw.solve_static(rb, tau, nodes=20, tol=1e-13).tip_position
    res = solve_ik(rb, tips, tension_max=10.0, nodes=20)
    assert res.success.all(), set(res.reason)
    assert res.position_error.max() < 1e-9
    assert (res.command >= 0).all() and (res.command <= 10.0).all()
    again = tw.solve_static(rb, res.command, nodes=20, tol=1e-13).tip_position  # independent of the IK's own solves
    assert np.abs(again - tips).max() < 1e-9


def test_unreachable_targets_return_the_closest_reachable_point():
    rb = robot()
    far = tw.solve_static(rb, [[6.0, 0.0, 0.0, 0.0]], nodes=20).tip_position[0]  # needs 6 N on tendon 0
    targets = np.array([[0.0, 0.0, 0.6], far])  # beyond the rod's length; beyond tension_max = 2 N
    res = solve_ik(rb, targets, tension_max=2.0, nodes=20)
    assert not res.success.any() and res.reason == ["unreachable", "unreachable"]
    straight = tw.solve_static(rb, [[0.0] * 4], nodes=20).tip_position[0]
    assert abs(res.position_error[0] - np.linalg.norm(targets[0] - straight)) < 1e-9
    # the closest point over a grid of bounded tensions in the target's plane is no closer
    grid = np.array([[a, 0.0, c, 0.0] for a in np.linspace(0, 2, 21) for c in np.linspace(0, 2, 21)])
    tips = tw.solve_static(rb, grid, nodes=20).tip_position
    assert res.position_error[1] <= np.linalg.norm(tips - far, axis=1).min() + 1e-9
    assert np.isclose(res.command[1, 0], 2.0)  # at the bound


def test_position_and_orientation_round_trip():
    rb = robot()
    tau = np.array([[2.0, 0.5, 0.0, 0.0], [0.0, 1.0, 0.0, 2.5]])
    fw = tw.solve_static(rb, tau, nodes=20, tol=1e-13)
    res = solve_ik(rb, fw.tip_position, target_rotation=fw.tip_rotation, tension_max=10.0, nodes=20)
    assert res.success.all() and res.position_error.max() < 1e-9 and res.orientation_error.max() < 2e-9 / 0.5


def test_displacement_control_round_trip():
    ang = np.array([0.0, 2.0, 4.0]) * np.pi / 3
    rb = robot(tendons=[tw.Tendon(offset=(OFF * np.cos(a), OFF * np.sin(a)), control="displacement",
                                  compliance=1e-4, pretension=0.5) for a in ang])
    q = np.array([[0.003, 0.0, 0.0], [0.001, 0.002, -0.001]])
    tips = tw.solve_static(rb, displacements=q, nodes=20, tol=1e-13).tip_position
    res = solve_ik(rb, tips, nodes=20)
    assert res.success.all() and res.position_error.max() < 1e-9
    again = tw.solve_static(rb, displacements=res.command, nodes=20, tol=1e-13).tip_position
    assert np.abs(again - tips).max() < 1e-9


def test_box_least_squares_is_the_bounded_optimum():
    """Against exhaustive coordinate descent on random bounded problems."""
    rng = np.random.default_rng(3)
    B, K = 200, 4
    A, b = rng.normal(size=(B, 3, K)), 5 * rng.normal(size=(B, 3))
    lo, hi = np.zeros((B, K)), np.full((B, K), 2.0)
    x = box_least_squares(A, b, lo, hi, 1e-9 * K)
    Q = np.einsum("bik,bil->bkl", A, A)
    Q = Q + 1e-9 * np.trace(Q, axis1=1, axis2=2)[:, None, None] * np.eye(K)
    g = np.einsum("bik,bi->bk", A, b)
    y = np.zeros((B, K))
    for _ in range(3000):
        for k in range(K):
            y[:, k] = np.clip((g[:, k] - np.einsum("bl,bl->b", Q[:, k], y) + Q[:, k, k] * y[:, k]) / Q[:, k, k], 0, 2)
    assert np.abs(x - y).max() < 1e-9


def test_bad_input_gets_a_clear_message():
    rb = robot()
    with pytest.raises(tw.InputError, match="target: expected a number, shape"):
        solve_ik(rb, [0.0, 0.1])
    with pytest.raises(tw.InputError, match="non-finite"):
        solve_ik(rb, [0.0, np.nan, 0.4])
    with pytest.raises(tw.InputError, match="not a rotation"):
        solve_ik(rb, [0.0, 0.0, 0.4], target_rotation=2 * np.eye(3))
    with pytest.raises(tw.InputError, match="tension_max must be positive"):
        solve_ik(rb, [0.0, 0.0, 0.4], tension_max=0.0)
    with pytest.raises(tw.InputError, match="at least one tendon"):
        solve_ik(tw.Robot(), [0.0, 0.0, 0.4])
