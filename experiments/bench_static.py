"""Benchmark of the batched static solver against a per-rod SciPy solver, in one run.

Reference case: the report's robot (4 tendons, gravity), random tensions in [0, 3] N,
RK4, coupled model, float64, CPU. Reports rod-solves/s for each batch size and node count
(median over repeats), the cold (fresh kernel cache) and warm start times, the accuracy of
the stopping rule, and the SciPy per-rod solver (solve_ivp RK45 at rtol 1e-8 inside
fsolve, as a Python user would write it) timed on a sample of the same rods.

    python experiments/bench_static.py [--smoke] [--device cpu] [--out results/bench_static.json]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "experiments")]

from _common import metadata, write_report  # noqa: E402

import tdcr_warp as tw  # noqa: E402

SEED_ROBOT = dict(length=0.5, youngs_modulus=190e9, poisson_ratio=0.3, radius=1e-3, density=17189.0,
                  gravity=(0.0, 0.0, -9.81))
OFFSETS = [(0.01, 0.0), (0.0, 0.01), (-0.01, 0.0), (0.0, -0.01)]

STARTUP = """
import time; t0 = time.perf_counter()
import numpy as np, tdcr_warp as tw
rob = tw.Robot(tendons=[tw.Tendon(offset=(0.01, 0.0))])
tw.solve_static(rob, [[1.0]], device={device!r})
print(time.perf_counter() - t0)
"""


def seed_robot() -> tw.Robot:
    return tw.Robot(tendons=[tw.Tendon(offset=o) for o in OFFSETS], **SEED_ROBOT)


def startup_time(cache_dir: str | None, device: str) -> float:
    env = dict(os.environ)
    if cache_dir is not None:
        env["WARP_CACHE_PATH"] = cache_dir
    out = subprocess.run([sys.executable, "-c", STARTUP.format(device=device)], env=env, check=True,
                         capture_output=True, text=True)
    return float(out.stdout.strip().splitlines()[-1])


def time_solve(rob, tau, repeats, **kw):
    times, sol = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        sol = tw.solve_static(rob, tau, **kw)
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), sol


def scipy_dict(tau_row):
    return dict(length=0.5, youngs_modulus=190e9, poisson_ratio=0.3, radius=1e-3, density=17189.0,
                gravity=[0.0, 0.0, -9.81],
                tendons=[dict(offset=o, tension=float(t)) for o, t in zip(OFFSETS, tau_row)])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true", help="tiny sizes (for the test suite)")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--scipy-sample", type=int, default=8, help="rods solved by the SciPy peer")
    ap.add_argument("--out", default=str(ROOT / "results" / "bench_static.json"))
    args = ap.parse_args(argv)

    from scipy_reference import solve_reference_user_style  # tests/ helper, not in the package

    sizes = [1, 16] if args.smoke else [1, 64, 1024, 16384]
    node_counts = [20] if args.smoke else [50, 20]
    repeats = 1 if args.smoke else args.repeats
    rng = np.random.default_rng(0)
    rob = seed_robot()
    tau_all = rng.uniform(0.0, 3.0, (max(sizes), 4))
    meta = metadata(args.device, dtype="float64")

    with tempfile.TemporaryDirectory() as cache:
        cold = startup_time(cache, args.device)
    warm = startup_time(None, args.device)
    print(f"start-up (import + first 1-rod solve): cold cache {cold:.2f} s, warm cache {warm:.2f} s")

    # the SciPy peer on a sample of the same rods
    sample = min(args.scipy_sample, 2 if args.smoke else args.scipy_sample)
    t_scipy, tips_scipy = [], []
    for b in range(sample):
        t0 = time.perf_counter()
        ref = solve_reference_user_style(scipy_dict(tau_all[b]))
        t_scipy.append(time.perf_counter() - t0)
        tips_scipy.append(ref["tip_position"])
    scipy_per_rod = float(np.median(t_scipy))
    print(f"SciPy per-rod solver (RK45 rtol 1e-8 + fsolve): {scipy_per_rod * 1e3:.1f} ms per rod "
          f"(median of {sample})")

    rows = []
    print(f"{'N':>4} {'B':>6} {'rods/s':>10} {'ms/batch':>10} {'x SciPy':>9} {'iters':>6} "
          f"{'integr.':>8} {'stop err [m]':>13} {'disc err [m]':>13}")
    for N in node_counts:
        for B in sizes:
            tau = tau_all[:B]
            tw.solve_static(rob, tau[:1], nodes=N, device=args.device)  # compile outside the timing
            t, sol = time_solve(rob, tau, repeats, nodes=N, device=args.device)
            k = min(B, 64)
            tight = tw.solve_static(rob, tau[:k], nodes=N, tol=1e-14, device=args.device)
            fine = tw.solve_static(rob, tau[:k], nodes=1024, tol=1e-14, device=args.device)
            stop_err = float(np.abs(sol.tip_position[:k] - tight.tip_position).max())
            disc_err = float(np.abs(tight.tip_position - fine.tip_position).max())
            row = dict(nodes=N, batch=B, seconds=t, rods_per_s=B / t,
                       speedup_vs_scipy=scipy_per_rod / (t / B), converged=float(sol.converged.mean()),
                       iterations_median=float(np.median(sol.iterations)),
                       integrations_mean=float(sol.integrations.mean()), stop_error_m=stop_err,
                       discretisation_error_m=disc_err)
            rows.append(row)
            print(f"{N:>4} {B:>6} {row['rods_per_s']:>10.0f} {t * 1e3:>10.2f} {row['speedup_vs_scipy']:>9.0f} "
                  f"{row['iterations_median']:>6.0f} {row['integrations_mean']:>8.2f} {stop_err:>13.2e} "
                  f"{disc_err:>13.2e}")
    B = sizes[-1] if args.smoke else 1024
    print(f"Jacobian strategy (N = 50, B = {B}):")
    jac_rows = []
    for jac in ("broyden", "newton"):
        t, sol = time_solve(rob, tau_all[:B], repeats, nodes=50, jacobian=jac, device=args.device)
        jac_rows.append(dict(jacobian=jac, rods_per_s=B / t, integrations_mean=float(sol.integrations.mean()),
                             iterations_median=float(np.median(sol.iterations))))
        print(f"  {jac:>8}: {B / t:>8.0f} rods/s, {sol.integrations.mean():.2f} integrations per rod, "
              f"{np.median(sol.iterations):.0f} iterations (median)")
    fine = tw.solve_static(rob, tau_all[:sample], nodes=1024, tol=1e-14, device=args.device)
    scipy_err = float(np.abs(np.array(tips_scipy) - fine.tip_position).max())
    print(f"SciPy peer tip error against RK4 N=1024: {scipy_err:.2e} m")
    report = {"meta": meta, "startup_cold_s": cold, "startup_warm_s": warm,
              "scipy_seconds_per_rod": scipy_per_rod, "scipy_tip_error_m": scipy_err, "rows": rows,
              "jacobian": jac_rows}
    write_report(args.out, report)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
