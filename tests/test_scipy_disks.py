"""Self-checks of the independent spacer-disk reference solver (tests/scipy_disks.py) only: global
balance of rod plus tendons, a single-disk beam-column closed form, symmetry, and the approach to
the continuous tendon model's circular arc as the disks get dense."""

import numpy as np
import pytest
from scipy_disks import solve_disks

L, E, NU, RADIUS = 0.2, 50e9, 0.3, 0.5e-3
EI = E * np.pi * RADIUS**4 / 4
EA = E * np.pi * RADIUS**2
OFFSET = 4.5e-3


def rod(**overrides):
    description = {"length": L, "youngs_modulus": E, "poisson_ratio": NU, "radius": RADIUS,
                   "density": 0.0, "gravity": (0, 0, 0), "tip_force": (0, 0, 0), "tip_moment": (0, 0, 0),
                   "disks": list(np.linspace(L / 5, L, 5)), "tendons": [], "point_forces": []}
    description.update(overrides)
    return description


def first_chords(result, description):
    """tau_k u_1k (the base plate's pull on each tendon reversed) and the base holes r_k."""
    pulls, offsets = [], []
    for k, tendon in enumerate(description["tendons"]):
        offset = np.array([*tendon["offset"], 0.0])
        chord = result["holes"][k, 0] - offset
        pulls.append(tendon["tension"] * chord / np.linalg.norm(chord))
        offsets.append(offset)
    return np.array(pulls), np.array(offsets)


def test_global_balance_of_rod_and_tendons():
    tip_force, tip_moment = np.array([0.05, -0.02, 0.1]), np.array([0.0, 0.0, 1e-3])
    description = rod(tip_force=tip_force, tip_moment=tip_moment, tendons=[
        {"offset": (OFFSET, 0), "length": L, "tension": 2.0},
        {"offset": (0, -OFFSET), "length": 3 * L / 5, "tension": 1.5}])
    result = solve_disks(description)
    assert result["residual"] < 1e-9
    assert np.all(np.isnan(result["holes"][1, 3:])) and not np.any(np.isnan(result["holes"][1, :3]))
    pulls, offsets = first_chords(result, description)
    force_balance = result["n0"] + pulls.sum(axis=0) - tip_force
    moment_balance = (result["m0"] + np.cross(offsets, pulls).sum(axis=0)
                      - tip_moment - np.cross(result["tip"], tip_force))
    assert np.linalg.norm(force_balance) < 1e-9 * np.abs(pulls).sum()
    assert np.linalg.norm(moment_balance) < 1e-9 * np.abs(pulls).sum() * L
    chains = [np.vstack([offsets[k], result["holes"][k, :end]]) for k, end in enumerate((5, 3))]
    lengths = [np.linalg.norm(np.diff(chain, axis=0), axis=1).sum() for chain in chains]
    assert np.allclose(result["path_lengths"], lengths, rtol=1e-14)
    assert np.allclose(result["p"][-1], result["tip"]) and result["s"][-1] == L


def test_single_disk_at_tip_is_a_beam_column():
    # The tendon pulls the tip hole straight at the base hole (d, 0, 0): a force of magnitude tau
    # whose line passes through the base hole. Linear beam-column with P-delta, beta^2 = tau / EI:
    # EI x'' = tau (d - x + s x_tip / L), x(0) = x'(0) = 0  =>  x_tip = d beta L tan(beta L / 2).
    tension = 0.06
    description = rod(disks=[L], tendons=[{"offset": (OFFSET, 0), "length": L, "tension": tension}])
    result = solve_disks(description)
    beta_length = np.sqrt(tension / EI) * L
    closed_form = OFFSET * beta_length * np.tan(beta_length / 2)
    assert abs(result["tip"][0] / closed_form - 1) < 2e-3
    assert abs(closed_form / (tension * OFFSET * L**2 / (2 * EI)) - 1) > 0.05  # P-delta matters
    assert abs(result["tip"][1]) < 1e-14
    hole, base_hole = result["holes"][0, 0], np.array([OFFSET, 0.0, 0.0])
    tip_load = -tension * (hole - base_hole) / np.linalg.norm(hole - base_hole)
    assert np.allclose(result["n0"], tip_load, rtol=0, atol=1e-11 * tension)
    assert np.allclose(result["m0"], np.cross(hole, tip_load), rtol=0, atol=1e-11 * tension * L)
    assert np.allclose(result["m0"], np.cross(base_hole, tip_load), rtol=0, atol=1e-11 * tension * L)


def test_antagonistic_pair_keeps_the_rod_straight():
    tension = 2.0
    result = solve_disks(rod(tendons=[{"offset": (OFFSET, 0), "length": L, "tension": tension},
                                      {"offset": (-OFFSET, 0), "length": L, "tension": tension}]))
    assert np.allclose(result["tip"][:2], 0, atol=1e-12)
    assert result["tip"][2] == pytest.approx(L * (1 - 2 * tension / EA), rel=1e-12)
    assert np.allclose(result["n0"], [0, 0, -2 * tension], rtol=0, atol=1e-11)
    assert np.allclose(result["m0"], 0, atol=1e-12)
    assert np.allclose(result["path_lengths"], L * (1 - 2 * tension / EA), rtol=1e-12)


def test_dense_disks_approach_the_continuous_arc():
    tension = 1.0
    tendons = [{"offset": (OFFSET, 0), "length": L, "tension": tension}]
    curvature = tension * OFFSET / EI
    arc_tip = np.array([(1 - np.cos(curvature * L)) / curvature, 0, np.sin(curvature * L) / curvature])
    result = solve_disks(rod(disks=list(np.linspace(L / 40, L, 40)), tendons=tendons))
    assert result["tip"][0] > 0
    assert np.linalg.norm(result["tip"] - arc_tip) < 0.02 * arc_tip[0]
