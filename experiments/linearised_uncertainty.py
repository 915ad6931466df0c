"""Linearised uncertainty propagation (tdcr_warp.apps.uncertainty) against the Monte-Carlo job's
statics on examples/montecarlo.toml, at the scene's scatter and at larger scatter.

Per scatter factor k (every normal std, uniform half-width and lognormal sigma times k) it
draws the sweep's samples (tdcr_warp.apps.sweep.make_samples, the scene's seed), solves them in
chunks as the montecarlo job does (tdcr_warp.apps.chunk.solve_chunk + jobs.static_job; the
[control] part is left out) and compares per axis: the Monte-Carlo tip std with a 95%
interval, the linearised std J Sigma J^T (the distributions' variances) and their ratio; the
linearised std with the samples' own covariance (J Sigma_samples J^T: for a tip linear in the
parameters it equals the Monte-Carlo std exactly, so its ratio isolates the nonlinearity from
the sampling noise of the parameters); and the shift of the Monte-Carlo mean from the nominal
tip (second order: the linearisation has none; beside it the second-order prediction
0.5 sum_j y_jj s_j^2 from central second differences of 2P + 1 solves). Rows whose draws leave the physical range
(E, radius, length <= 0, density < 0: at k = 10 a normal scatter of 50 % in E and 100 % in the
density reaches them) are dropped and counted: that truncates the distribution, which the
samples-covariance column accounts for.

    python experiments/linearised_uncertainty.py [--scene examples/montecarlo.toml] [--samples N]
        [--scales 1,2,3,5,10] [--device cpu] [--smoke] [--out results/linearised_uncertainty.json]
"""

from __future__ import annotations

import argparse
import copy
import shlex
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import ROOT, metadata, write_report  # noqa: E402

from tdcr_warp.apps.chunk import solve_chunk  # noqa: E402
from tdcr_warp.apps.jobs import static_job  # noqa: E402
from tdcr_warp.apps.sweep import SweepSpec, make_samples  # noqa: E402
from tdcr_warp.apps.uncertainty import linearised_spread  # noqa: E402

AXES = "xyz"
POSITIVE = ("youngs_modulus", "radius", "length")  # robot fields that must stay > 0 (density >= 0)


def scaled(data: dict, k: float) -> dict:
    """The scene with every [[uncertainty]] scatter times k (uniform: about its centre)."""
    out = copy.deepcopy(data)
    for u in out["uncertainty"]:
        a, b = u["params"]
        if u["distribution"] == "uniform":
            c, h = 0.5 * (a + b), 0.5 * (b - a)
            u["params"] = [c - k * h, c + k * h]
        else:  # normal [mean, std], lognormal [mu, sigma]
            u["params"] = [a, k * b]
    return out


def physical(rows: dict) -> np.ndarray:
    """Rows whose sampled robot fields are in range."""
    keep = np.ones(len(next(iter(rows.values()))), bool)
    for name, v in rows.items():
        leaf = name.split(".")[-1]
        if name.startswith("robot.") and leaf in POSITIVE:
            keep &= v > 0
        elif name == "robot.density":
            keep &= v >= 0
    return keep


def monte_carlo(data: dict, device) -> tuple[dict, np.ndarray, float, int, int]:
    """The sweep's samples, solved in chunks (statics only): (the rows of the converged rods,
    their tips (n, 3), wall time [s], rows dropped as unphysical, rods that failed)."""
    statics = {k: v for k, v in data.items() if k not in ("control", "dynamics")}
    spec = SweepSpec(statics)
    rows = make_samples(spec)
    keep = physical(rows)
    rows = {k: v[keep] for k, v in rows.items()}
    M, size = int(keep.sum()), spec.chunk
    t0 = time.perf_counter()
    parts = [solve_chunk(lambda sc: static_job(sc, device), statics, {k: v[lo:lo + size] for k, v in rows.items()})
             for lo in range(0, M, size)]
    wall = time.perf_counter() - t0
    ok = np.concatenate([p["ok"] for p in parts]).astype(bool)
    tips = np.concatenate([p["tip_position"] for p in parts])[ok]
    return {k: v[ok] for k, v in rows.items()}, tips, wall, int((~keep).sum()), int((~ok).sum())


def std_interval(x: np.ndarray) -> tuple[float, float, float]:
    """Sample std and its asymptotic 95 % interval, from the sample's own kurtosis (for normal
    data the relative standard error is 1 / sqrt(2 (n - 1)))."""
    n = len(x)
    s = x.std(ddof=1)
    if s == 0:
        return 0.0, 0.0, 0.0
    m4 = np.mean((x - x.mean()) ** 4)
    se_var = np.sqrt(max(m4 - s**4 * (n - 3) / (n - 1), 0.0) / n)
    se = se_var / (2 * s)
    return float(s), float(s - 1.96 * se), float(s + 1.96 * se)


def second_order_shift(data: dict, lin: dict, device) -> np.ndarray | None:
    """The mean shift of the tip to second order, 0.5 sum_j d2y/dp_j^2 s_j^2 (independent
    parameters: the cross terms average out), from central second differences at p0 +- s_j
    (one batch of 2P + 1 rods); None when a step leaves the physical range."""
    statics = {k: v for k, v in data.items() if k not in ("control", "dynamics")}
    std, p0 = np.sqrt(lin["variances"]), lin["nominal_values"]
    vals = np.tile(p0, (2 * len(p0) + 1, 1))
    for j, s in enumerate(std):
        vals[1 + 2 * j, j] += s
        vals[2 + 2 * j, j] -= s
    rows = {f: vals[:, j] for j, f in enumerate(lin["parameters"])}
    if not physical(rows).all():
        return None
    res = solve_chunk(lambda sc: static_job(sc, device), statics, rows)
    y = res["tip_position"]
    return None if not res["ok"].all() else 0.5 * (y[1::2] + y[2::2] - 2 * y[0]).sum(0)


def compare(data: dict, k: float, device) -> dict:
    sd = scaled(data, k)
    t0 = time.perf_counter()
    lin = linearised_spread(sd, device=device)
    t_lin = time.perf_counter() - t0
    rows, tips, t_mc, dropped, failed = monte_carlo(sd, device)
    t0 = time.perf_counter()
    second = second_order_shift(sd, lin, device)
    t_second = time.perf_counter() - t0
    n = len(tips)
    P = np.stack([rows[f] for f in lin["parameters"]], axis=1)
    J = lin["jacobian"][:3]
    lin_emp = np.sqrt(np.diag(J @ np.atleast_2d(np.cov(P.T)) @ J.T))
    shift = tips.mean(0) - lin["nominal_tip"]
    scale = max(lin["tip_std"].max(), 1e-300)
    axes = {}
    for i, a in enumerate(AXES):
        s, lo, hi = std_interval(tips[:, i])
        ls = float(lin["tip_std"][i])
        degenerate = bool(ls < 1e-9 * scale and s < 1e-9 * scale)
        axes[a] = {"mc_std": s, "mc_std_ci95": [lo, hi], "lin_std": ls,
                   "ratio_mc_over_lin": None if degenerate else s / ls,
                   "lin_std_sample_cov": float(lin_emp[i]),
                   "ratio_mc_over_lin_sample_cov": None if degenerate else s / float(lin_emp[i]),
                   "lin_within_ci95": bool(lo <= ls <= hi),
                   "mc_mean_shift": float(shift[i]), "mc_mean_shift_se": float(s / np.sqrt(n)),
                   "lin_mean_offset": float(lin["mean_offset_tip"][i] - lin["nominal_tip"][i]),
                   "second_order_mean_shift": None if second is None else float(second[i]),
                   "degenerate": degenerate}
    share = lin["contributions"] / np.maximum(lin["contributions"].sum(0), 1e-300)
    return {"scale": k, "samples": n, "dropped_unphysical": dropped, "failed": failed,
            "rel_se_std_normal": 1 / np.sqrt(2 * (n - 1)), "wall_linearised_s": t_lin, "wall_montecarlo_s": t_mc,
            "wall_second_order_s": t_second,
            "nominal_tip": lin["nominal_tip"].tolist(), "mc_mean": tips.mean(0).tolist(),
            "variance_share": {f: dict(zip(AXES, map(float, share[j]))) for j, f in enumerate(lin["parameters"])},
            "axes": axes}


def show(r: dict) -> None:
    print(f"\nscatter x{r['scale']:g}: {r['samples']} rods ({r['dropped_unphysical']} draws dropped as unphysical, "
          f"{r['failed']} failed); linearised {r['wall_linearised_s'] * 1e3:.0f} ms, Monte Carlo "
          f"{r['wall_montecarlo_s']:.2f} s")
    print(f"  {'axis':4} {'MC std [mm]':>12} {'95% CI [mm]':>20} {'lin std':>9} {'MC/lin':>7} {'MC/lin(S_smp)':>13} "
          f"{'MC mean shift [mm]':>22} {'2nd-order shift':>15}")
    for a, v in r["axes"].items():
        if v["degenerate"]:
            print(f"  {a:4} {'0 (both; symmetric)':>12}")
            continue
        print(f"  {a:4} {v['mc_std'] * 1e3:12.5f} [{v['mc_std_ci95'][0] * 1e3:8.5f}, {v['mc_std_ci95'][1] * 1e3:8.5f}]"
              f" {v['lin_std'] * 1e3:9.5f} {v['ratio_mc_over_lin']:7.4f} {v['ratio_mc_over_lin_sample_cov']:13.4f} "
              f"{v['mc_mean_shift'] * 1e3:+10.5f} +- {v['mc_mean_shift_se'] * 1e3:.5f} "
              + (f"{v['second_order_mean_shift'] * 1e3:+15.5f}" if v["second_order_mean_shift"] is not None
                 else f"{'-':>15}"))
    bad = [a for a, v in r["axes"].items() if not v["degenerate"] and not v["lin_within_ci95"]]
    shifted = [a for a, v in r["axes"].items() if not v["degenerate"]
               and abs(v["mc_mean_shift"] - v["lin_mean_offset"]) > 2 * v["mc_mean_shift_se"]]
    second = [a for a, v in r["axes"].items() if not v["degenerate"] and v["second_order_mean_shift"] is not None
              and abs(v["mc_mean_shift"] - v["lin_mean_offset"] - v["second_order_mean_shift"])
              <= 2 * v["mc_mean_shift_se"]]
    print(f"  linearised std outside the MC 95% interval: {', '.join(bad) or 'none'}; "
          f"mean shift beyond 2 standard errors: {', '.join(shifted) or 'none'}; "
          f"2nd-order shift within them: {', '.join(second) or 'none'}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default=str(ROOT / "examples" / "montecarlo.toml"))
    ap.add_argument("--samples", type=int, help="override [sweep].samples")
    ap.add_argument("--scales", default="1,2,3,5,10", help="scatter factors, comma-separated")
    ap.add_argument("--device", default=None, help="cpu or cuda:0 (default: Warp's default device)")
    ap.add_argument("--smoke", action="store_true", help="tiny sizes (for the test suite)")
    ap.add_argument("--out", default=str(ROOT / "results" / "linearised_uncertainty.json"))
    args = ap.parse_args(argv)
    command = shlex.join([sys.executable, str(Path(__file__).resolve()),
                          *(sys.argv[1:] if argv is None else argv)])
    print(f"command: {command}")
    data = tomllib.loads(Path(args.scene).read_text())
    if args.smoke:
        args.samples, args.scales = 64, "1,3"
    if args.samples:
        data["sweep"]["samples"] = args.samples
    compare(scaled(data, 1.0) | {"sweep": dict(data["sweep"], samples=8)}, 1.0, args.device)  # warm-up: kernels
    results = [compare(data, float(k), args.device) for k in args.scales.split(",")]
    for r in results:
        show(r)
    write_report(args.out, {"meta": metadata(args.device or "default", command=command, scene=args.scene),
                            "results": results})
    return 0


if __name__ == "__main__":
    sys.exit(main())
