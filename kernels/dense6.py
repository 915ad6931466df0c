"""Dense 6 x 6 linear algebra for one thread, on its slices of a work array ``wk`` (B, slots,
6, 6) written in place (a component write to a local Warp matrix copies the whole matrix): the
determinant and inverse (partial pivoting) and the eigenvalues of a symmetric matrix (cyclic
Jacobi). Used by the stability verdict (kernels/jacobi.py).
"""

import functools
from types import SimpleNamespace

import warp as wp

QR_STEPS = 60  # implicit QR steps at most (a 6 x 6 converges in about 2 per eigenvalue)
EPS = {wp.float64: 2.2e-16, wp.float32: 1.2e-7}  # unit round-off: a subdiagonal below it deflates


@functools.cache
def make_lu(dtype):
    """The determinant (LU) and the inverse (Gauss-Jordan) of a 6 x 6 slot, partial pivoting."""
    zero = dtype(0.0)
    one = dtype(1.0)
    Work = wp.array4d(dtype=dtype)

    @wp.func
    def pivot(wk: Work, b: int, s: int, c: int):
        """The row from c on with the largest |entry| in column c."""
        piv = c
        for r in range(c + 1, 6):
            if wp.abs(wk[b, s, r, c]) > wp.abs(wk[b, s, piv, c]):
                piv = r
        return piv

    @wp.func
    def swap_rows(wk: Work, b: int, s: int, r1: int, r2: int):
        for k in range(6):
            t = wk[b, s, r1, k]
            wk[b, s, r1, k] = wk[b, s, r2, k]
            wk[b, s, r2, k] = t

    @wp.func
    def abs_det(wk: Work, b: int, s: int):
        """|det| of the matrix in slot s (overwritten by its LU factors)."""
        det = one
        for c in range(6):
            piv = pivot(wk, b, s, c)
            d = wk[b, s, piv, c]
            if d == zero:
                return zero
            if piv != c:
                swap_rows(wk, b, s, piv, c)
            det = det * wp.abs(d)
            for r in range(c + 1, 6):
                f = wk[b, s, r, c] / d
                for k in range(c + 1, 6):
                    wk[b, s, r, k] = wk[b, s, r, k] - f * wk[b, s, c, k]
        return det

    @wp.func
    def invert(wk: Work, b: int, s: int, t: int):
        """Slot t = the inverse of slot s (overwritten); the identity if s is exactly singular."""
        for i in range(6):
            for k in range(6):
                wk[b, t, i, k] = wp.where(i == k, one, zero)
        for c in range(6):
            piv = pivot(wk, b, s, c)
            d = wk[b, s, piv, c]
            if d == zero:
                return
            if piv != c:
                swap_rows(wk, b, s, piv, c)
                swap_rows(wk, b, t, piv, c)
            for k in range(6):
                wk[b, s, c, k] = wk[b, s, c, k] / d
                wk[b, t, c, k] = wk[b, t, c, k] / d
            for r in range(6):
                f = wk[b, s, r, c]
                if r != c and f != zero:
                    for k in range(6):
                        wk[b, s, r, k] = wk[b, s, r, k] - f * wk[b, s, c, k]
                        wk[b, t, r, k] = wk[b, t, r, k] - f * wk[b, t, c, k]

    return SimpleNamespace(abs_det=abs_det, invert=invert)


@functools.cache
def make_tridiagonal(dtype):
    """Householder reduction of a symmetric 6 x 6 slot to a tridiagonal matrix (Golub & Van Loan,
    Matrix Computations, section 8.3.1)."""
    zero = dtype(0.0)
    two = dtype(2.0)
    Work = wp.array4d(dtype=dtype)

    @wp.func
    def tridiagonalise(wk: Work, b: int, s: int):
        """Slot s reduced in place by Householder reflections: the diagonal d_i at (i, i), the
        subdiagonal e_i at (i + 1, i) (the rest of the lower triangle and row k's upper part used
        as scratch)."""
        for k in range(4):
            tail = zero  # |x|^2 over the rows below k + 1: nothing to reflect when it is 0
            for i in range(k + 2, 6):
                tail = tail + wk[b, s, i, k] * wk[b, s, i, k]
            if tail > zero:
                x0 = wk[b, s, k + 1, k]
                alpha = -wp.sqrt(tail + x0 * x0)
                if x0 < zero:
                    alpha = -alpha
                wk[b, s, k + 1, k] = x0 - alpha  # v = x - alpha e_1, in column k
                vv = two * (tail + x0 * x0 - x0 * alpha)
                for i in range(k + 1, 6):  # p = 2 A v / v^T v, in row k
                    acc = zero
                    for j in range(k + 1, 6):
                        acc = acc + wk[b, s, i, j] * wk[b, s, j, k]
                    wk[b, s, k, i] = two * acc / vv
                kk = zero
                for i in range(k + 1, 6):
                    kk = kk + wk[b, s, i, k] * wk[b, s, k, i]
                kk = kk / vv
                for i in range(k + 1, 6):  # w = p - K v
                    wk[b, s, k, i] = wk[b, s, k, i] - kk * wk[b, s, i, k]
                for i in range(k + 1, 6):  # A <- A - v w^T - w v^T
                    for j in range(k + 1, 6):
                        wk[b, s, i, j] = wk[b, s, i, j] - wk[b, s, i, k] * wk[b, s, k, j] - wk[b, s, k, i] * wk[b, s, j, k]
                wk[b, s, k + 1, k] = alpha
                for i in range(k + 2, 6):
                    wk[b, s, i, k] = zero

    return tridiagonalise


@functools.cache
def make_eigen(dtype):
    """The eigenvalues of a symmetric 6 x 6 slot: the tridiagonal reduction, then implicit QR steps
    with Wilkinson's shift and deflation (Golub & Van Loan, sections 8.3.2-8.3.3). About 10x fewer
    flops than cyclic Jacobi sweeps; backward stable: the eigenvalues to a few units of round-off
    times the matrix's norm."""
    vec6 = wp.types.vector(6, dtype)
    zero = dtype(0.0)
    one = dtype(1.0)
    two = dtype(2.0)
    eps = dtype(EPS[dtype])
    Work = wp.array4d(dtype=dtype)
    tridiagonalise = make_tridiagonal(dtype)

    @wp.func
    def qr_step(wk: Work, b: int, s: int, lo: int, hi: int):
        """One implicit QR step with Wilkinson's shift on the unreduced block lo..hi."""
        d = (wk[b, s, hi - 1, hi - 1] - wk[b, s, hi, hi]) / two
        ee = wk[b, s, hi, hi - 1] * wk[b, s, hi, hi - 1]
        root = wp.sqrt(d * d + ee)
        if d < zero:
            root = -root
        x = wk[b, s, lo, lo] - (wk[b, s, hi, hi] - ee / (d + root))
        z = wk[b, s, lo + 1, lo]
        for k in range(lo, hi):
            r = wp.sqrt(x * x + z * z)
            c = one
            sn = zero
            if r > zero:
                c = x / r
                sn = z / r
            if k > lo:
                wk[b, s, k, k - 1] = r
            ak = wk[b, s, k, k]
            ak1 = wk[b, s, k + 1, k + 1]
            bk = wk[b, s, k + 1, k]
            wk[b, s, k, k] = c * c * ak + two * c * sn * bk + sn * sn * ak1
            wk[b, s, k + 1, k + 1] = sn * sn * ak - two * c * sn * bk + c * c * ak1
            wk[b, s, k + 1, k] = c * sn * (ak1 - ak) + (c * c - sn * sn) * bk
            if k < hi - 1:
                z = sn * wk[b, s, k + 2, k + 1]  # the bulge at (k + 2, k)
                wk[b, s, k + 2, k + 1] = c * wk[b, s, k + 2, k + 1]
                x = wk[b, s, k + 1, k]

    @wp.func
    def negligible(wk: Work, b: int, s: int, i: int):
        """Is the subdiagonal e_i = (i + 1, i) below round-off of its two diagonal neighbours?"""
        return wp.abs(wk[b, s, i + 1, i]) <= eps * (wp.abs(wk[b, s, i, i]) + wp.abs(wk[b, s, i + 1, i + 1]))

    @wp.func
    def symmetric_eigenvalues(wk: Work, b: int, s: int):
        """The eigenvalues of the symmetric matrix in slot s (overwritten), unordered."""
        tridiagonalise(wk, b, s)
        hi = int(5)  # noqa: UP018, RUF046 (a dynamic variable for Warp)
        steps = int(0)  # noqa: UP018, RUF046
        while hi > 0 and steps < QR_STEPS:
            if negligible(wk, b, s, hi - 1):
                hi = hi - 1
            else:
                lo = hi - 1  # the unreduced block ending at hi starts after the next negligible e
                while lo > 0:
                    if negligible(wk, b, s, lo - 1):
                        break
                    lo = lo - 1
                qr_step(wk, b, s, lo, hi)
                steps = steps + 1
        ev = vec6()
        for i in range(6):
            ev[i] = wk[b, s, i, i]
        return ev

    return SimpleNamespace(symmetric_eigenvalues=symmetric_eigenvalues)


@functools.cache
def make_dense6(dtype):
    """The 6 x 6 helpers of one precision and the work array type (B, slots, 6, 6)."""
    lu, eig = make_lu(dtype), make_eigen(dtype)
    return SimpleNamespace(vec6=wp.types.vector(6, dtype), Work=wp.array4d(dtype=dtype), abs_det=lu.abs_det,
                           invert=lu.invert, symmetric_eigenvalues=eig.symmetric_eigenvalues)
