"""The banded solve of multiple shooting's Newton steps (kernels/banded.py): LAPACK's answers on
systems of its structure, pivoting where a diagonal entry vanishes, and a per-system verdict on
singular or overflowed systems that leaves the other systems untouched."""

import numpy as np
import pytest

from tdcr_warp.physics.segments import BandSystems


def staircase(rng, b: int, d: int, M: int, decades: float = 8.0) -> np.ndarray:
    """(b, nz, nz) random systems of multiple shooting's pattern: the gap into segment s
    (rows d (s - 1) ..) depends on segment s - 1's unknowns (the base's 6 for s = 1) and on its
    own; the 6 tip rows on the last segment's; the columns' scales span ``decades``."""
    nz = 6 + d * (M - 1)
    seg = np.concatenate([np.zeros(6, dtype=int), 1 + np.arange(nz - 6) // d])
    row_block = np.minimum(np.arange(nz) // d + 1, M)  # gap into segment s; M: the tip rows
    mask = (seg[None, :] == row_block[:, None]) | (seg[None, :] == row_block[:, None] - 1)
    mask[d * (M - 1):] = seg[None, :] == M - 1
    scale = 10.0 ** rng.uniform(-decades / 2, decades / 2, size=nz)
    return rng.normal(size=(b, nz, nz)) * mask * scale


def load(systems: BandSystems, J: np.ndarray) -> None:
    rows, cols = np.nonzero(np.abs(J).sum(axis=0))
    systems.put(rows, cols, J[:, rows, cols])


@pytest.mark.parametrize("d, M", [(12, 2), (12, 7), (18, 2), (18, 5)])
def test_lapacks_answers_on_multiple_shooting_systems(d, M):
    """Statics (d = 12) and dynamics (18), 1 to 6 gaps: the solution of each system matches
    numpy.linalg.solve to 1e-9 relative and its residual is at round-off (1e-13 of |J| |x|)."""
    rng = np.random.default_rng(d * M)
    J = staircase(rng, 4, d, M)
    rhs = rng.normal(size=J.shape[:2])
    systems = BandSystems(4, J.shape[1], d, "cpu")
    load(systems, J)
    x, ok = systems.solve(rhs, np.ones(4, dtype=bool))
    assert ok.all()
    ref = np.linalg.solve(J, rhs[..., None])[..., 0]
    assert np.abs(x - ref).max() / np.abs(ref).max() < 1e-9
    back = np.einsum("bij,bj->bi", J, x) - rhs
    assert np.abs(back).max() / (np.abs(J).max() * np.abs(x).max()) < 1e-13


def test_pivoting_where_a_diagonal_entry_vanishes():
    """Zero diagonal entries throughout (solvable only with row swaps), columns of one scale: the
    exact answer to 1e-10 (its condition number is ~1e3)."""
    rng = np.random.default_rng(3)
    J = staircase(rng, 1, 12, 4, decades=0.0)
    J[0][np.diag_indices(J.shape[1])] = 0.0
    x_true = rng.normal(size=(1, J.shape[1]))
    systems = BandSystems(1, J.shape[1], 12, "cpu")
    load(systems, J)
    x, ok = systems.solve(np.einsum("bij,bj->bi", J, x_true), np.ones(1, dtype=bool))
    assert np.linalg.cond(J[0]) < 1e5
    assert ok.all() and np.abs(x - x_true).max() < 1e-10


def test_a_singular_or_non_finite_system_fails_alone():
    """A system with a zero column and one holding a NaN fail (ok False, a zero answer); the
    systems beside them get the answer they get alone, bit for bit; an inactive one is skipped."""
    rng = np.random.default_rng(5)
    J = staircase(rng, 4, 12, 3)
    rhs = rng.normal(size=J.shape[:2])
    alone = BandSystems(1, J.shape[1], 12, "cpu")
    load(alone, J[:1])
    x0, _ = alone.solve(rhs[:1], np.ones(1, dtype=bool))
    J[1, :, 7] = 0.0
    J[2, 4, 4] = np.nan
    systems = BandSystems(4, J.shape[1], 12, "cpu")
    load(systems, J)
    x, ok = systems.solve(rhs, np.array([True, True, True, False]))
    assert ok.tolist() == [True, False, False, False]
    assert np.array_equal(x[0], x0[0])
    assert not x[1:].any()
