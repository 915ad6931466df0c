"""The float64 peak of one core of this CPU, scalar and vector, and whether Warp's CPU kernels use the vector units.

Peaks: a small C kernel (written to a temporary folder, compiled with the system C compiler, called
through ctypes in this process, on one core) runs 12 independent chains of multiply-adds on
registers, so that neither memory nor the latency of one chain limits it:

  scalar, no FMA   x86-64 baseline (-O2 -fno-tree-vectorize, no -march): a multiply and an add per step
  scalar FMA       one double per instruction (vfmadd...sd), -mfma
  AVX2 FMA         4 doubles per instruction (256-bit, _mm256_fmadd_pd), -mavx2 -mfma
  AVX-512 FMA      8 doubles per instruction (512-bit, _mm512_fmadd_pd), -mavx512f

(each variant only if the CPU has the instructions), counting 2 flops per multiply-add and element;
best of ``--repeats``, timed in CPU time of the thread (time.thread_time), so that other processes
sharing the core do not count (on a shared machine wall time would measure the share, not the core). And numpy's matmul of two 1024 x 1024 float64 matrices on one thread
(OPENBLAS/OMP/MKL_NUM_THREADS=1, set before numpy loads its BLAS only if this script is the first
to import numpy; the BLAS thread count is reported as seen): what a tuned library reaches.

Vector use of Warp's kernels: the object file of the report robot's fused statics kernel in Warp's
kernel cache, disassembled with objdump: the count of instructions on 512-bit (zmm), 256-bit
(ymm) registers, and of packed (...pd) against scalar (...sd) double arithmetic.

    python experiments/peak.py [--repeats 5] [--smoke] [--out results/peak.json]
"""

from __future__ import annotations

import argparse
import ctypes
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "experiments")]

from _common import metadata, write_report

CHAINS = 12  # independent chains: enough to hide the FMA latency, few enough for 16 registers
C_SOURCE = r"""
#include <stddef.h>
#ifdef __AVX2__
#include <immintrin.h>
#endif
#define CH 12
double run_scalar(long iters, double x, double y) {
    double a[CH];
    for (int c = 0; c < CH; c++) a[c] = c * 1e-3;
    for (long i = 0; i < iters; i++) {
        #pragma GCC unroll 12
        for (int c = 0; c < CH; c++) a[c] = a[c] * x + y;
    }
    double s = 0; for (int c = 0; c < CH; c++) s += a[c]; return s;
}
#ifdef __AVX2__
double run_avx2(long iters, double x, double y) {
    __m256d a[CH], vx = _mm256_set1_pd(x), vy = _mm256_set1_pd(y);
    for (int c = 0; c < CH; c++) a[c] = _mm256_set1_pd(c * 1e-3);
    for (long i = 0; i < iters; i++) {
        #pragma GCC unroll 12
        for (int c = 0; c < CH; c++) a[c] = _mm256_fmadd_pd(a[c], vx, vy);
    }
    __m256d s = a[0]; for (int c = 1; c < CH; c++) s = _mm256_add_pd(s, a[c]);
    double o[4]; _mm256_storeu_pd(o, s); return o[0] + o[1] + o[2] + o[3];
}
#endif
#ifdef __AVX512F__
double run_avx512(long iters, double x, double y) {
    __m512d a[CH], vx = _mm512_set1_pd(x), vy = _mm512_set1_pd(y);
    for (int c = 0; c < CH; c++) a[c] = _mm512_set1_pd(c * 1e-3);
    for (long i = 0; i < iters; i++) {
        #pragma GCC unroll 12
        for (int c = 0; c < CH; c++) a[c] = _mm512_fmadd_pd(a[c], vx, vy);
    }
    __m512d s = a[0]; for (int c = 1; c < CH; c++) s = _mm512_add_pd(s, a[c]);
    return _mm512_reduce_add_pd(s);
}
#endif
"""

# name: (compiler flags, function, doubles per instruction, CPU flag needed)
VARIANTS = {
    "scalar, no FMA (x86-64 baseline)": (["-O2", "-fno-tree-vectorize", "-ffp-contract=off"], "run_scalar", 1, None),
    "scalar FMA": (["-O2", "-fno-tree-vectorize", "-mfma", "-ffp-contract=fast"], "run_scalar", 1, "fma"),
    "AVX2 FMA (256-bit)": (["-O2", "-mavx2", "-mfma"], "run_avx2", 4, "avx2"),
    "AVX-512 FMA (512-bit)": (["-O2", "-mavx512f", "-mavx2", "-mfma"], "run_avx512", 8, "avx512f"),
}


def cpu_flags() -> set[str]:
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return set()
    line = next((ln for ln in text.splitlines() if ln.startswith("flags")), "")
    return set(line.split(":", 1)[-1].split())


def compiler() -> str | None:
    return next((c for c in (os.environ.get("CC"), "gcc", "cc", "clang") if c and shutil.which(c)), None)


def _cpu_seconds(func, n: int) -> float:
    t0 = time.thread_time()
    func(n, 0.999999, 1e-9)
    return time.thread_time() - t0


def fma_peaks(repeats: int, iters: int, min_s: float) -> dict:
    """Gflop/s of each variant on one core (best of ``repeats``); a variant the CPU or compiler
    lacks is reported with its reason."""
    cc, flags = compiler(), cpu_flags()
    out = {}
    if cc is None:
        return {name: {"error": "no C compiler (gcc, cc, clang)"} for name in VARIANTS}
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "peak.c"
        src.write_text(C_SOURCE)
        for i, (name, (cflags, fn, width, need)) in enumerate(VARIANTS.items()):
            if need and need not in flags:
                out[name] = {"error": f"this CPU has no {need}"}
                continue
            lib = Path(tmp) / f"peak{i}.so"
            res = subprocess.run([cc, *cflags, "-shared", "-fPIC", "-o", str(lib), str(src)], check=False,
                                 capture_output=True, text=True)
            if res.returncode != 0:
                out[name] = {"error": f"{cc} failed: {res.stderr.strip()[-300:]}"}
                continue
            func = getattr(ctypes.CDLL(str(lib)), fn)
            func.restype, func.argtypes = ctypes.c_double, [ctypes.c_long, ctypes.c_double, ctypes.c_double]
            n = iters // width
            while _cpu_seconds(func, n) < min_s:  # long enough for the CPU clock's resolution
                n *= 4
            best = min(_cpu_seconds(func, n) for _ in range(repeats))
            flops = 2.0 * CHAINS * width * n
            out[name] = {"gflops": flops / best / 1e9, "flags": " ".join(cflags), "compiler": cc}
    return out


def matmul_peak(repeats: int, n: int) -> dict:
    import numpy as np

    a = np.random.default_rng(0).standard_normal((n, n))
    b = a.T.copy()
    a @ b
    best = float("inf")
    for _ in range(repeats):  # ~0.1 s or more each at any plausible speed
        t0 = time.process_time()
        a @ b
        best = min(best, time.process_time() - t0)
    threads = None
    try:
        from threadpoolctl import threadpool_info
        threads = [i.get("num_threads") for i in threadpool_info() if i.get("user_api") == "blas"]
    except ImportError:
        pass
    return {"gflops": 2.0 * n**3 / best / 1e9, "n": n, "blas_threads": threads}


def statics_object() -> Path | None:
    """The compiled object of the report robot's fused float64 RK4 statics kernel (built here if
    the cache lacks it)."""
    import warp as wp
    from tdcr_warp.kernels.shooting import make_shooting_kernels

    import tdcr_warp as tw

    rob = tw.Robot(tendons=[tw.Tendon(offset=o) for o in ((0.01, 0.0), (0.0, 0.01), (-0.01, 0.0), (0.0, -0.01))],
                   length=0.5, youngs_modulus=190e9, poisson_ratio=0.3, radius=1e-3, density=17189.0,
                   gravity=(0.0, 0.0, -9.81))
    tw.solve_static(rob, [[1.0, 0.5, 0.0, 0.0]], nodes=20, threads=1, stability="off")
    from tdcr_warp.core.build import Tables

    feats = Tables.of(rob, 20).features
    module = make_shooting_kernels(wp.float64, "rk4", "coupled", False, "cosserat", feats).solve.module
    paths = [Path(ex.binary_path) for ex in module.execs.values() if getattr(ex, "binary_path", None)]
    return next((p for p in paths if p.suffix == ".o" and p.is_file()), None)


def vector_use(obj: Path | None) -> dict:
    """Instruction counts of the object file: zmm / ymm operands, packed vs scalar double arithmetic."""
    if obj is None or not shutil.which("objdump"):
        return {"error": "no kernel object file or no objdump"}
    text = subprocess.run(["objdump", "-d", "--no-show-raw-insn", str(obj)], check=False, capture_output=True,
                          text=True).stdout
    ins = [ln.split("\t", 1)[-1] for ln in text.splitlines() if re.match(r"\s+[0-9a-f]+:\t", ln)]
    arith = r"(?:add|sub|mul|div|sqrt|fmadd\d*|fmsub\d*|fnmadd\d*|fnmsub\d*|min|max)"
    packed = [i for i in ins if re.match(rf"v?{arith}pd\b", i)]
    return {"object": str(obj), "instructions": len(ins),
            "zmm": sum("zmm" in i for i in ins), "ymm": sum("ymm" in i for i in ins),
            "packed_double_arith": len(packed),
            "packed_double_arith_by_width": {w: sum(w in i for i in packed) for w in ("xmm", "ymm", "zmm")},
            "scalar_double_arith": sum(bool(re.match(rf"v?{arith}sd\b", i)) for i in ins)}


def measure(repeats: int = 5, smoke: bool = False) -> dict:
    return {"fma": fma_peaks(1 if smoke else repeats, 100_000, 0.01 if smoke else 0.3),
            "matmul": matmul_peak(1 if smoke else repeats, 256 if smoke else 1024)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--smoke", action="store_true", help="short runs (for the test suite)")
    ap.add_argument("--out", default=str(ROOT / "results" / "peak.json"))
    args = ap.parse_args(argv)
    peaks = measure(args.repeats, args.smoke)
    vec = vector_use(statics_object())
    print("| float64, one core | Gflop/s |\n|---|---:|")
    for name, r in peaks["fma"].items():
        print(f"| {name} | {r['gflops']:.1f} |" if "gflops" in r else f"| {name} | {r['error']} |")
    print(f"| numpy matmul {peaks['matmul']['n']}^3 (BLAS threads {peaks['matmul']['blas_threads']}) | "
          f"{peaks['matmul']['gflops']:.1f} |")
    if "error" in vec:
        print("Warp kernel:", vec["error"])
    else:
        print(f"\nWarp statics kernel {Path(vec['object']).name}: {vec['instructions']} instructions, "
              f"{vec['zmm']} on zmm, {vec['ymm']} on ymm; double arithmetic {vec['packed_double_arith']} packed, "
              f"{vec['scalar_double_arith']} scalar; packed by register width {vec['packed_double_arith_by_width']}")
    write_report(args.out, {"meta": metadata("cpu", cpu_flags_avx512=("avx512f" in cpu_flags())),
                            "peaks": peaks, "warp_kernel": vec})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
