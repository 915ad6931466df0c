"""Dense 6 x 6 linear algebra for one thread, on its slices of a work array ``wk`` (B, slots,
6, 6) written in place (a component write to a local Warp matrix copies the whole matrix): the
determinant and inverse (partial pivoting) and the eigenvalues of a symmetric matrix (cyclic
Jacobi). Used by the stability verdict (kernels/jacobi.py).
"""

import functools
from types import SimpleNamespace

import warp as wp

SWEEPS = 12  # cyclic Jacobi sweeps at most (a 6 x 6 converges in 5-7)


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
def make_eigen(dtype):
    """The eigenvalues of a symmetric 6 x 6 slot (cyclic Jacobi)."""
    vec6 = wp.types.vector(6, dtype)
    zero = dtype(0.0)
    one = dtype(1.0)
    Work = wp.array4d(dtype=dtype)

    @wp.func
    def symmetric_eigenvalues(wk: Work, b: int, s: int):
        """The eigenvalues of the symmetric matrix in slot s (overwritten)."""
        for _sweep in range(SWEEPS):
            off = zero
            scale = zero
            for i in range(6):
                scale = scale + wk[b, s, i, i] * wk[b, s, i, i]
                for j in range(i + 1, 6):
                    off = off + wk[b, s, i, j] * wk[b, s, i, j]
            if off <= dtype(1e-24) * scale:  # eigenvalues to ~1e-12 relative
                break
            for p in range(5):
                for q in range(p + 1, 6):
                    apq = wk[b, s, p, q]
                    if apq != zero:
                        theta = (wk[b, s, q, q] - wk[b, s, p, p]) / (dtype(2.0) * apq)
                        t = one
                        if theta != zero:
                            t = wp.sign(theta) / (wp.abs(theta) + wp.sqrt(theta * theta + one))
                        c = one / wp.sqrt(t * t + one)
                        sn = t * c
                        for k in range(6):
                            akp = wk[b, s, k, p]
                            akq = wk[b, s, k, q]
                            wk[b, s, k, p] = c * akp - sn * akq
                            wk[b, s, k, q] = sn * akp + c * akq
                        for k in range(6):
                            apk = wk[b, s, p, k]
                            aqk = wk[b, s, q, k]
                            wk[b, s, p, k] = c * apk - sn * aqk
                            wk[b, s, q, k] = sn * apk + c * aqk
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
