"""Banded linear systems, one per thread: the Newton steps of multiple shooting.

Multiple shooting (tdcr_warp/physics/segments.py) couples each segment's unknowns only to the gap
into that segment and the gap out of it, so its Jacobian is banded: with d unknowns per segment
start (12 in statics, 18 in dynamics) and 6 at the base, ``kl = 2 d - 7`` sub- and ``ku = d + 5``
super-diagonals (``band_widths``). A system of n unknowns is stored by rows, each row i keeping
the columns i - kl .. i + ku + kl at ``a[b, i, j - i + kl]`` (width 2 kl + ku + 1: the kl extra
columns take the fill-in of the row swaps); entries outside 0 <= j < n are ignored.

  band_solve   kernel over systems b with ``active[b]`` != 0: scale the columns, then the rows,
               to a largest entry of 1 (the unknowns span 8 decades of scale at small dt), LU
               with partial pivoting (rows k .. k + kl hold column k's nonzeros, so the pivots
               are dense LU's), then back substitution; the solution replaces ``rhs``. Each
               row's last nonzero column is tracked (``reach``, work space) and bounds its
               updates: a gap's rows end with their own segment, half the band on average.
               ``ok[b]`` = 0 where a pivot is zero or not finite (a singular or overflowed
               Jacobian; the system's ``a`` and ``rhs`` are then left part-way).

Work and memory are O(n kl (kl + ku)) and O(n (2 kl + ku)) per system, against O(n^3) and O(n^2)
for a dense solve; float64 only (the host's Newton is float64 in either precision).
"""

import warp as wp

__all__ = ["band_solve", "band_widths"]


def band_widths(d: int) -> tuple[int, int]:
    """(kl, ku): the sub- and super-diagonals of a multiple-shooting Jacobian with d unknowns per
    later segment start (and 6 at the base): a gap's rows reach back over the previous segment's
    unknowns (the base's 6 for the first gap) and on over its own segment's."""
    return 2 * d - 7, d + 5


@wp.func
def _at(i: int, j: int, kl: int):
    return j - i + kl


@wp.kernel(module="tdcr_warp_banded", enable_backward=False)
def band_solve(a: wp.array3d(dtype=wp.float64), rhs: wp.array2d(dtype=wp.float64),
               col_scale: wp.array2d(dtype=wp.float64), reach: wp.array2d(dtype=int), kl: int,
               active: wp.array(dtype=int), ok: wp.array(dtype=int)):
    b = wp.tid()
    if active[b] == 0:
        return
    n = a.shape[1]
    w = a.shape[2]
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    for j in range(n):
        col_scale[b, j] = zero
    for i in range(n):
        for c in range(w):
            j = i + c - kl
            if j >= 0 and j < n:
                col_scale[b, j] = wp.max(col_scale[b, j], wp.abs(a[b, i, c]))
    for j in range(n):
        if col_scale[b, j] == zero:
            col_scale[b, j] = one
    for i in range(n):
        big = zero
        for c in range(w):
            j = i + c - kl
            if j >= 0 and j < n:
                a[b, i, c] = a[b, i, c] / col_scale[b, j]
                big = wp.max(big, wp.abs(a[b, i, c]))
        if big == zero:
            big = one
        last = i
        for c in range(w):
            a[b, i, c] = a[b, i, c] / big
            if a[b, i, c] != zero:
                last = wp.min(n - 1, i + c - kl)
        reach[b, i] = last  # the row's last nonzero column (a gap's rows end with their segment)
        rhs[b, i] = rhs[b, i] / big
    ok[b] = 1
    for k in range(n):
        last = wp.min(n - 1, k + kl)  # the rows that can hold column k
        p = k
        best = wp.abs(a[b, k, _at(k, k, kl)])
        for i in range(k + 1, last + 1):
            v = wp.abs(a[b, i, _at(i, k, kl)])
            if v > best:
                best = v
                p = i
        if not (best > zero and best < wp.float64(1.0e300)):  # zero, inf or NaN
            ok[b] = 0
            return
        if p != k:
            rk = reach[b, k]
            reach[b, k] = reach[b, p]
            reach[b, p] = rk
            for j in range(k, wp.max(rk, reach[b, k]) + 1):
                t = a[b, k, _at(k, j, kl)]
                a[b, k, _at(k, j, kl)] = a[b, p, _at(p, j, kl)]
                a[b, p, _at(p, j, kl)] = t
            t = rhs[b, k]
            rhs[b, k] = rhs[b, p]
            rhs[b, p] = t
        right = reach[b, k]
        piv = a[b, k, kl]
        for i in range(k + 1, last + 1):
            f = a[b, i, _at(i, k, kl)] / piv
            if f != zero:
                for j in range(k + 1, right + 1):
                    a[b, i, _at(i, j, kl)] = a[b, i, _at(i, j, kl)] - f * a[b, k, _at(k, j, kl)]
                rhs[b, i] = rhs[b, i] - f * rhs[b, k]
                reach[b, i] = wp.max(reach[b, i], right)
    for kk in range(n):
        k = n - 1 - kk
        s = rhs[b, k]
        for j in range(k + 1, reach[b, k] + 1):
            s = s - a[b, k, _at(k, j, kl)] * rhs[b, j]
        rhs[b, k] = s / a[b, k, kl]
    for j in range(n):
        rhs[b, j] = rhs[b, j] / col_scale[b, j]
