"""Linearised uncertainty propagation (tdcr_warp/apps/uncertainty.py): against the Monte-Carlo
job's statics on examples/montecarlo.toml, against the closed form of a straight cantilever,
and its input errors."""

import copy
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from tdcr_warp.apps.chunk import solve_chunk
from tdcr_warp.apps.jobs import static_job
from tdcr_warp.apps.sweep import SweepSpec, make_samples
from tdcr_warp.apps.uncertainty import distribution_moments, linearised_spread
from tdcr_warp.model.robot import InputError

ROOT = Path(__file__).resolve().parents[1]
E, NU, R, L, F = 190e9, 0.3, 1e-3, 0.5, 1e-3


@pytest.fixture(scope="module")
def montecarlo():
    data = tomllib.loads((ROOT / "examples" / "montecarlo.toml").read_text())
    for key in ("control", "dynamics"):  # statics only
        data.pop(key)
    return data


def test_linearised_std_matches_the_monte_carlo_std(montecarlo):
    """400 samples of the scene's [[uncertainty]] (its seed), solved as the montecarlo job
    does. The relative standard error of a sample std is ~1 / sqrt(2 (n - 1)) = 3.5 % at
    n = 400: allow 3 of them plus 4 % for the nonlinearity (measured with 2000 samples and the
    samples' own covariance, experiments/linearised_uncertainty.py: 1 % in x, 3.5 % in z)."""
    n = 400
    data = copy.deepcopy(montecarlo)
    data["sweep"]["samples"] = n
    lin = linearised_spread(data)
    res = solve_chunk(static_job, data, make_samples(SweepSpec(data)))
    assert res["ok"].all()
    mc = res["tip_position"].std(axis=0, ddof=1)
    tol = 3 / math.sqrt(2 * (n - 1)) + 0.04
    for i in (0, 2):  # tendon 0 bends the rod in x-z
        assert abs(mc[i] / lin["tip_std"][i] - 1) < tol, (i, mc[i], lin["tip_std"][i], tol)
    # every perturbation keeps the x-z plane of symmetry: no spread in y, either way
    assert mc[1] == 0 and lin["tip_std"][1] == 0
    # the nominal tip is the scene's; the scene's values are the distributions' means here
    assert np.allclose(lin["nominal_values"], [E, R, 0.01, 7800.0])
    assert np.allclose(lin["means"], lin["nominal_values"])
    assert np.allclose(lin["mean_offset_tip"], lin["nominal_tip"])
    assert abs(res["tip_position"][:, 0].mean() - lin["nominal_tip"][0]) < 4 * mc[0] / math.sqrt(n)
    # the contributions add up to the variances; the radius dominates x (EI ~ r^4)
    assert np.allclose(lin["contributions"].sum(axis=0), np.diag(lin["tip_covariance"]), rtol=1e-12)
    assert lin["parameters"][int(np.argmax(lin["contributions"][:, 0]))] == "robot.radius"
    assert np.allclose(lin["tip_covariance"], lin["pose_covariance"][:3, :3])


def cantilever(distribution: str, params: list) -> dict:
    return {"robot": dict(length=L, youngs_modulus=E, poisson_ratio=NU, radius=R, density=7800.0),
            "tendons": [{"offset": [0.01, 0.0]}], "loads": {"tip_force": [F, 0.0, 0.0]},
            "actuation": {"tensions": [[0.0]]}, "solver": {"nodes": 20, "tol": 1e-12},
            "uncertainty": [{"field": "robot.youngs_modulus", "distribution": distribution, "params": params}]}


@pytest.mark.parametrize("distribution, params, variance", [
    ("normal", [E, 0.01 * E], (0.01 * E) ** 2),
    ("uniform", [0.98 * E, 1.02 * E], (0.04 * E) ** 2 / 12),
    ("lognormal", [math.log(E), 0.01], math.expm1(1e-4) * E**2 * math.exp(1e-4)),
])
def test_cantilever_closed_form(distribution, params, variance):
    """A straight cantilever under a small lateral tip force F, only E uncertain (no Jacobian
    of ours): x = F L^3 / (3 E I) + F L / (G A), G = E / 2 (1 + nu), so to first order
    std_x = (F L^3 / (3 E^2 I) + F L / (G A E)) std_E, and the tip tilt F L^2 / (2 E I) has
    std F L^2 / (2 E^2 I) std_E. The shear term is 7.8e-6 of the bending one: the tolerance
    (geometric nonlinearity (x / L)^2 ~ 3e-7, finite differences) is below it."""
    lin = linearised_spread(cantilever(distribution, params))
    I, A, G = math.pi * R**4 / 4, math.pi * R**2, E / (2 * (1 + NU))
    std_e = math.sqrt(variance)
    bending, shear = F * L**3 / (3 * E**2 * I), F * L / (G * A * E)
    assert shear / bending > 7e-6
    assert abs(lin["tip_std"][0] / ((bending + shear) * std_e) - 1) < 4e-6
    assert abs(math.sqrt(lin["pose_covariance"][4, 4]) / (F * L**2 / (2 * E**2 * I) * std_e) - 1) < 1e-5
    assert lin["tip_std"][1] == 0 and lin["tip_std"][2] < 1e-2 * lin["tip_std"][0]
    assert lin["nominal_values"][0] == E
    x0 = F * L**3 / (3 * E * I) + F * L / (G * A)
    assert abs(lin["nominal_tip"][0] / x0 - 1) < 1e-5
    # a mean away from the scene's value shifts the cloud to first order (the lognormal's)
    mean = distribution_moments(distribution, *params)[0]
    assert lin["mean_offset_tip"][0] - lin["nominal_tip"][0] == pytest.approx(-(bending + shear) * (mean - E),
                                                                              rel=1e-5, abs=1e-18)


def test_distribution_variances_match_sampling():
    """The closed-form moments against a million draws of numpy's generators (as make_samples)."""
    rng = np.random.default_rng(0)
    for dist, (a, b), draw in (("normal", (2.0, 0.3), rng.normal), ("uniform", (1.0, 4.0), rng.uniform),
                               ("lognormal", (0.5, 0.4), rng.lognormal)):
        x = draw(a, b, 1_000_000)
        mean, var = distribution_moments(dist, a, b)
        assert abs(x.mean() / mean - 1) < 3e-3 and abs(x.var() / var - 1) < 1e-2, dist


def test_errors(montecarlo):
    def without(**change):
        d = copy.deepcopy(montecarlo)
        d.update(change)
        return d

    with pytest.raises(InputError, match=r"needs \[\[uncertainty\]\]"):
        linearised_spread({k: v for k, v in montecarlo.items() if k != "uncertainty"})
    with pytest.raises(InputError, match="needs \\[\\[uncertainty\\]\\]"):
        linearised_spread(without(uncertainty=[]))
    with pytest.raises(InputError, match="'beta'"):
        linearised_spread(without(uncertainty=[{"field": "robot.radius", "distribution": "beta", "params": [2, 5]}]))
    with pytest.raises(InputError, match="'beta'"):
        distribution_moments("beta", 2.0, 5.0)
    # fields the sensitivity code cannot differentiate: its own InputError comes through
    for field, message in (("tendons[0].length", "must be one of"), ("loads.gravity", "name a component"),
                           ("control.epsilon", "cannot parse")):
        bad = without(uncertainty=[{"field": field, "distribution": "normal", "params": [0.0, 1.0]}])
        with pytest.raises(InputError, match=message):
            linearised_spread(bad)
    with pytest.raises(InputError, match="params"):
        linearised_spread(without(uncertainty=[{"field": "robot.radius", "distribution": "normal",
                                                "params": [1e-3, -1.0]}]))
    twice = montecarlo["uncertainty"] + montecarlo["uncertainty"][:1]
    with pytest.raises(InputError, match="more than once"):
        linearised_spread(without(uncertainty=twice))
    with pytest.raises(InputError, match="grid"):
        linearised_spread(without(sweep={"grid": {"actuation.tensions[0]": [0.0, 3.0, 4]}}))
    with pytest.raises(InputError, match="single-rod"):
        linearised_spread(without(actuation={"tensions": [[3.0, 0, 0, 0], [2.0, 0, 0, 0]]}))


def test_a_tension_field_uses_the_tension_jacobian():
    """actuation.tensions[k] (a sweep field, not a robot one): the column of the tension
    Jacobian. A straight tendon at offset r bends the rod by the moment tau r: x = tau r L^2 / 2EI."""
    d = cantilever("normal", [E, 0.0])  # E certain: a zero variance
    d["loads"]["tip_force"] = [0.0, 0.0, 0.0]
    d["actuation"]["tensions"] = [[0.1]]
    d["uncertainty"].append({"field": "actuation.tensions[0]", "distribution": "normal", "params": [0.1, 1e-3]})
    lin = linearised_spread(d)
    assert lin["nominal_values"][1] == 0.1 and lin["contributions"][0].max() == 0
    assert abs(lin["tip_std"][0] / (0.01 * L**2 / (2 * E * math.pi * R**4 / 4) * 1e-3) - 1) < 1e-4
    d["tendons"][0]["control"] = "displacement"
    with pytest.raises(InputError, match="tension control"):
        linearised_spread(d)
