"""The optional learned correction (tdcr_warp/apps/residual.py): a Gaussian process over the
commands that learns a smooth miss from noisy rows, whose 95% interval holds about 95% of fresh
measurements, saved and loaded as a plain .npz without a pickle."""

import numpy as np
import pytest

import tdcr_warp as tw
from tdcr_warp.apps.residual import Residual, coverage, fit_residual


def miss(q):
    """A smooth 3-D miss [mm] of three commands [mm], as a model error might be."""
    return np.stack([np.sin(q[:, 0]) + 0.3 * q[:, 1], 0.5 * q[:, 0] * q[:, 2] / 3, np.cos(0.5 * q[:, 1])], axis=1)


def rows(n, seed, noise=0.1):
    rng = np.random.default_rng(seed)
    q = rng.uniform(-3, 3, (n, 3))
    return q, miss(q) + rng.normal(0, noise, (n, 3))


def test_the_residual_learns_a_smooth_miss_and_its_interval_is_calibrated():
    q, y = rows(300, 0)
    res = fit_residual(q, y)
    qt, yt = rows(400, 1)  # fresh rows from the same commands' range
    mean, std = res.predict(qt)
    # the miss itself is recovered well below the noise (0.1 mm), and far better than its spread
    assert np.sqrt(np.mean((mean - miss(qt)) ** 2)) < 0.05
    # each axis: the noise (0.1 mm) learned from 300 rows (its estimate scatters by a few per cent)
    assert (0.085 < std.mean(axis=0)).all() and (std.mean(axis=0) < 0.13).all()
    assert 0.92 <= coverage(yt, mean, std) <= 0.98  # 95% of fresh measurements in the 95% interval


def test_far_from_its_training_rows_the_residual_says_it_does_not_know():
    q, y = rows(300, 0)
    res = fit_residual(q, y)
    _, near = res.predict(np.zeros((1, 3)))
    _, far = res.predict(np.full((1, 3), 12.0))
    assert far[0, 0] > 5 * near[0, 0]


def test_saved_and_loaded_it_predicts_the_same_and_hostile_files_are_refused(tmp_path):
    q, y = rows(120, 2)
    res = fit_residual(q, y)
    res.save(tmp_path / "r.npz")
    back = Residual.load(tmp_path / "r.npz")
    qt, _ = rows(20, 3)
    for a, b in zip(res.predict(qt), back.predict(qt)):
        assert np.allclose(a, b, rtol=1e-9, atol=1e-12)
    np.save(tmp_path / "p.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    for bad, words in ((tmp_path / "p.npy", "not a tdcr-warp residual"), (tmp_path / "none.npz", "not a tdcr-warp"),):
        with pytest.raises(tw.InputError, match=words):
            Residual.load(bad)
    np.savez(tmp_path / "shape.npz", format=np.array("tdcr-warp residual 1"), commands=q, targets=y[:, :2],
             theta=res.theta)
    with pytest.raises(tw.InputError, match="wrong shapes"):
        Residual.load(tmp_path / "shape.npz")
    with pytest.raises(tw.InputError, match="fitted on 3 commands"):
        res.predict(np.zeros((2, 4)))


def test_too_few_rows_are_refused():
    q, y = rows(8, 4)
    with pytest.raises(tw.InputError, match="too few"):
        fit_residual(q, y)
