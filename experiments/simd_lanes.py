"""Several rods per thread as SIMD lanes in a Warp CPU kernel: does it use the vector units, and how fast is it?

The route issue 26 named for the vector units, measured on a stand-in before building it into the
solver: the RK4 integration of a Kirchhoff rod (inextensible, unshearable; p' = R e3, R' = R
skew(u), u = K^-1 R^T m, n' = -f, m' = -p' x n: about 110 flops a right-hand side) from a
per-rod base wrench, written twice:

  scalar  one rod per thread, Warp's vec3d / mat33d (as the solver's kernels are written);
  lanes   L rods per thread, every scalar of the scalar kernel a vector of L float64 (vec3 of
          lanes as a 3 x L matrix, a rotation as 9 x L), L = 2, 4, 8, 16.

Both integrate the same B rods (tip forces differ per rod) and must agree to round-off. Reported:
rods/s of each (CPU time of the calling thread, median over repeats, one thread), the speed-up of
the lanes against the scalar kernel in the same run, and the instructions of each compiled kernel
(objdump of the object in Warp's kernel cache: packed double arithmetic on xmm / ymm / zmm, and
scalar). Warp's CPU compiler emits code for the host's instruction set only if its target CPU
says so: the counts show what it did.

    python experiments/simd_lanes.py [--batch 4096] [--nodes 20] [--repeats 5] [--smoke]
        [--out results/simd_lanes.json]
"""


import argparse
import sys
import time
from pathlib import Path

import numpy as np
import warp as wp

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "experiments")]

from _common import metadata, write_report
from peak import vector_use

LANES = (2, 4, 8, 16)
EI, GJ, LENGTH = 0.15, 0.115, 0.5  # N m^2, N m^2, m: the report robot's steel rod, about
GZ = -0.52  # N/m: its weight per length, along z


@wp.func
def _rhs(R: wp.mat33d, n: wp.vec3d, m: wp.vec3d, f: wp.vec3d):
    ml = wp.transpose(R) * m
    u = wp.vec3d(ml[0] / wp.float64(EI), ml[1] / wp.float64(EI), ml[2] / wp.float64(GJ))
    dp = wp.vec3d(R[0, 2], R[1, 2], R[2, 2])
    dR = R * wp.skew(u)
    return dp, dR, -f, -wp.cross(dp, n)


@wp.kernel(module="unique")
def scalar_kernel(wrench: wp.array(dtype=wp.vec3d, ndim=2), nodes: int, tip: wp.array(dtype=wp.vec3d)):
    b = wp.tid()
    h = wp.float64(LENGTH) / wp.float64(nodes)
    half = h * wp.float64(0.5)
    f = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(GZ))
    p = wp.vec3d()
    R = wp.identity(3, dtype=wp.float64)
    n = wrench[b, 0]
    m = wrench[b, 1]
    for _ in range(nodes):
        p1, R1, n1, m1 = _rhs(R, n, m, f)
        p2, R2, n2, m2 = _rhs(R + half * R1, n + half * n1, m + half * m1, f)
        p3, R3, n3, m3 = _rhs(R + half * R2, n + half * n2, m + half * m2, f)
        p4, R4, n4, m4 = _rhs(R + h * R3, n + h * n3, m + h * m3, f)
        s = h / wp.float64(6.0)
        p = p + s * (p1 + wp.float64(2.0) * (p2 + p3) + p4)
        R = R + s * (R1 + wp.float64(2.0) * (R2 + R3) + R4)
        n = n + s * (n1 + wp.float64(2.0) * (n2 + n3) + n4)
        m = m + s * (m1 + wp.float64(2.0) * (m2 + m3) + m4)
    tip[b] = p


def lane_kernel(L: int):
    """The kernel integrating L rods a thread: a vec3 of lanes is a 3 x L matrix (rows x, y, z), a
    rotation 9 x L (row 3 i + j: entry (i, j))."""
    lv = wp.types.vector(length=L, dtype=wp.float64)
    l3 = wp.types.matrix(shape=(3, L), dtype=wp.float64)
    l9 = wp.types.matrix(shape=(9, L), dtype=wp.float64)

    @wp.func
    def cross(a: l3, b: l3):
        return wp.matrix_from_rows(wp.cw_mul(a[1], b[2]) - wp.cw_mul(a[2], b[1]),
                                   wp.cw_mul(a[2], b[0]) - wp.cw_mul(a[0], b[2]),
                                   wp.cw_mul(a[0], b[1]) - wp.cw_mul(a[1], b[0]))

    @wp.func
    def rhs(R: l9, n: l3, m: l3, f: l3):
        # R^T m, divided by the stiffnesses
        u0 = (wp.cw_mul(R[0], m[0]) + wp.cw_mul(R[3], m[1]) + wp.cw_mul(R[6], m[2])) / wp.float64(EI)
        u1 = (wp.cw_mul(R[1], m[0]) + wp.cw_mul(R[4], m[1]) + wp.cw_mul(R[7], m[2])) / wp.float64(EI)
        u2 = (wp.cw_mul(R[2], m[0]) + wp.cw_mul(R[5], m[1]) + wp.cw_mul(R[8], m[2])) / wp.float64(GJ)
        dp = wp.matrix_from_rows(R[2], R[5], R[8])
        # (R skew(u))_ij: column 0 = R u2 col1 - R u1 col2 ... row by row
        dR = wp.matrix_from_rows(
            wp.cw_mul(R[1], u2) - wp.cw_mul(R[2], u1), wp.cw_mul(R[2], u0) - wp.cw_mul(R[0], u2),
            wp.cw_mul(R[0], u1) - wp.cw_mul(R[1], u0),
            wp.cw_mul(R[4], u2) - wp.cw_mul(R[5], u1), wp.cw_mul(R[5], u0) - wp.cw_mul(R[3], u2),
            wp.cw_mul(R[3], u1) - wp.cw_mul(R[4], u0),
            wp.cw_mul(R[7], u2) - wp.cw_mul(R[8], u1), wp.cw_mul(R[8], u0) - wp.cw_mul(R[6], u2),
            wp.cw_mul(R[6], u1) - wp.cw_mul(R[7], u0))
        return dp, dR, -f, -cross(dp, n)

    @wp.kernel(module="unique")
    def kernel(wrench: wp.array(dtype=wp.vec3d, ndim=2), nodes: int, tip: wp.array(dtype=wp.vec3d)):
        t = wp.tid()
        h = wp.float64(LENGTH) / wp.float64(nodes)
        half = h * wp.float64(0.5)
        one = lv()
        for k in range(L):
            one[k] = wp.float64(1.0)
        zero = lv()
        f = wp.matrix_from_rows(zero, zero, one * wp.float64(GZ))
        p = wp.matrix_from_rows(zero, zero, zero)
        R = wp.matrix_from_rows(one, zero, zero, zero, one, zero, zero, zero, one)
        n = l3()
        m = l3()
        for k in range(L):
            w0 = wrench[t * L + k, 0]
            w1 = wrench[t * L + k, 1]
            for i in range(3):
                n[i, k] = w0[i]
                m[i, k] = w1[i]
        for _ in range(nodes):
            p1, R1, n1, m1 = rhs(R, n, m, f)
            p2, R2, n2, m2 = rhs(R + half * R1, n + half * n1, m + half * m1, f)
            p3, R3, n3, m3 = rhs(R + half * R2, n + half * n2, m + half * m2, f)
            p4, R4, n4, m4 = rhs(R + h * R3, n + h * n3, m + h * m3, f)
            s = h / wp.float64(6.0)
            p = p + s * (p1 + wp.float64(2.0) * (p2 + p3) + p4)
            R = R + s * (R1 + wp.float64(2.0) * (R2 + R3) + R4)
            n = n + s * (n1 + wp.float64(2.0) * (n2 + n3) + n4)
            m = m + s * (m1 + wp.float64(2.0) * (m2 + m3) + m4)
        for k in range(L):
            tip[t * L + k] = wp.vec3d(p[0, k], p[1, k], p[2, k])

    return kernel


KERNELS = {1: scalar_kernel} | {L: lane_kernel(L) for L in LANES}


def _object(kernel) -> Path | None:
    paths = [Path(ex.binary_path) for ex in kernel.module.execs.values() if getattr(ex, "binary_path", None)]
    return next((p for p in paths if p.suffix == ".o" and p.is_file()), None)


def measure(batch: int, nodes: int, repeats: int) -> dict:
    """Rods/CPU-s of every kernel (median over repeats, alternating), their tips' largest
    difference from the scalar kernel's, and their instructions."""
    rng = np.random.default_rng(0)
    w = np.zeros((batch, 2, 3))
    w[:, 0] = rng.uniform(-1.0, 1.0, (batch, 3))  # n(0) [N]
    w[:, 1] = rng.uniform(-0.2, 0.2, (batch, 3))  # m(0) [N m]
    wrench = wp.array(w, dtype=wp.vec3d, device="cpu")
    tips = {L: wp.zeros(batch, dtype=wp.vec3d, device="cpu") for L in KERNELS}
    times = {L: [] for L in KERNELS}
    for r in range(repeats + 1):
        for L, kern in KERNELS.items():
            c0 = time.thread_time()
            wp.launch(kern, dim=batch // L, inputs=[wrench, nodes, tips[L]], device="cpu")
            wp.synchronize_device("cpu")
            if r:  # the first round compiles and loads
                times[L].append(time.thread_time() - c0)
    ref = tips[1].numpy()
    out = {}
    for L in KERNELS:
        t = float(np.median(times[L]))
        out[str(L)] = {"rods_per_cpu_s": batch / t, "speedup": float(np.median(times[1])) / t,
                       "max_tip_difference_m": float(np.abs(tips[L].numpy() - ref).max()),
                       "instructions": vector_use(_object(KERNELS[L]))}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, default=4096)
    ap.add_argument("--nodes", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--smoke", action="store_true", help="a small batch, one repeat (for the test suite)")
    ap.add_argument("--out", default=str(ROOT / "results" / "simd_lanes.json"))
    args = ap.parse_args(argv)
    batch, repeats = (64, 1) if args.smoke else (args.batch, args.repeats)
    batch -= batch % max(LANES)
    wp.config.quiet = True
    wp.init()
    res = measure(batch, args.nodes, repeats)
    print(f"B = {batch}, N = {args.nodes}, one thread, float64 RK4 Kirchhoff rod")
    print("| rods a thread | rods/CPU-s | vs scalar | max tip diff [m] | packed double arith (xmm/ymm/zmm) | scalar |")
    print("|---|---:|---:|---:|---|---:|")
    for L, r in res.items():
        ins = r["instructions"]
        by = ins.get("packed_double_arith_by_width", {})
        print(f"| {L} | {r['rods_per_cpu_s']:,.0f} | {r['speedup']:.2f}x | {r['max_tip_difference_m']:.1e} | "
              f"{by.get('xmm', '-')}/{by.get('ymm', '-')}/{by.get('zmm', '-')} | {ins.get('scalar_double_arith', '-')} |")
    write_report(args.out, {"meta": metadata("cpu", batch=batch, nodes=args.nodes, repeats=repeats), "lanes": res})
    worst = max(r["max_tip_difference_m"] for r in res.values())
    if worst > 1e-12:
        print(f"the lanes' tips differ from the scalar kernel's by {worst:.1e} m (> 1e-12 m)")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
