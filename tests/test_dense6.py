"""The 6 x 6 linear algebra of the stability verdict (kernels/dense6.py) against NumPy's LAPACK,
one thread per matrix: eigenvalues of symmetric matrices (random, with repeated and zero
eigenvalues, already diagonal or tridiagonal, of mixed scales), |det| and the inverse."""

import numpy as np
import warp as wp
from tdcr_warp.kernels.dense6 import make_dense6

DTYPE = wp.float64
dn = make_dense6(DTYPE)


@wp.kernel
def eigen_kernel(wk: dn.Work, out: wp.array(dtype=dn.vec6)):
    b = wp.tid()
    out[b] = dn.symmetric_eigenvalues(wk, b, 0)


@wp.kernel
def det_inverse_kernel(wk: dn.Work, det: wp.array(dtype=DTYPE)):
    b = wp.tid()
    det[b] = dn.abs_det(wk, b, 0)
    dn.invert(wk, b, 1, 2)


def symmetric_cases(rng) -> np.ndarray:
    """Random symmetric matrices with prescribed spectra that are hard for a QR iteration."""
    Q = np.linalg.qr(rng.normal(size=(8, 6, 6)))[0]
    spectra = [rng.normal(size=6), [1, 1, 1, 2, 2, 3], [0, 0, 0, 0, 0, 1], [1e-8, 1, 1e3, -1e3, 5, -5],
               [7] * 6, [-1, 1, -1, 1, -1, 1], [0] * 6, rng.normal(size=6) * 1e4]
    A = np.einsum("bij,bj,bkj->bik", Q, np.array(spectra, dtype=float), Q)
    tri = np.diag(rng.normal(size=6)) + np.diag(rng.normal(size=5), 1)
    diag = np.diag(rng.normal(size=6))
    dense = rng.normal(size=(32, 6, 6))
    return np.concatenate([A, [tri + np.triu(tri, 1).T, diag], dense + dense.transpose(0, 2, 1)])


def test_the_eigenvalues_of_symmetric_matrices_agree_with_lapack():
    A = symmetric_cases(np.random.default_rng(0))
    wk = np.zeros((len(A), 1, 6, 6))
    wk[:, 0] = A
    out = wp.zeros(len(A), dtype=dn.vec6, device="cpu")
    wp.launch(eigen_kernel, dim=len(A), inputs=[wp.array(wk, dtype=DTYPE, device="cpu"), out], device="cpu")
    ours = np.sort(out.numpy(), axis=1)
    exact = np.linalg.eigvalsh(A)
    scale = np.maximum(np.abs(exact).max(axis=1, keepdims=True), 1e-300)
    error = np.abs(ours - exact) / scale  # relative to the matrix's norm: what a backward-stable method promises
    assert error.max() < 2e-15, error.max(axis=1)


def test_the_determinant_and_inverse_agree_with_lapack():
    rng = np.random.default_rng(1)
    A = rng.normal(size=(16, 6, 6))
    A[0] = np.eye(6)[[3, 1, 0, 5, 4, 2]] * np.arange(1, 7)  # a permutation: every pivot swaps
    wk = np.zeros((len(A), 3, 6, 6))
    wk[:, 0] = A
    wk[:, 1] = A
    arr = wp.array(wk, dtype=DTYPE, device="cpu")
    det = wp.zeros(len(A), dtype=DTYPE, device="cpu")
    wp.launch(det_inverse_kernel, dim=len(A), inputs=[arr, det], device="cpu")
    assert np.allclose(det.numpy(), np.abs(np.linalg.det(A)), rtol=1e-12, atol=0.0)
    assert np.abs(arr.numpy()[:, 2] - np.linalg.inv(A)).max() < 1e-10 * np.abs(np.linalg.inv(A)).max()
