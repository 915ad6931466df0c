"""Closed-loop success under model error: the Monte-Carlo plants of examples/montecarlo_robust.toml
(2,000 rods; the controller keeps the nominal model) under the integral sliding-mode controller and
under the boundary layer (the same scene with method = "boundary_layer"), 1 s each. Success: the
tip within 0.5 mm of the target at the end. Also the final-error percentiles, the peak tension
(the limit is 8 N) and the fraction of saturated tension samples.

    python experiments/robust_control.py [--smoke] [--out results/robust_control.json]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import tomllib
from pathlib import Path

import tomli_w

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "experiments")]

from _common import metadata, write_report  # noqa: E402

from tdcr_warp.apps.sweep import open_sweep  # noqa: E402


def main(argv=None) -> int:
    from tdcr_warp.cli import main as cli

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true", help="16 rods, 20 steps")
    ap.add_argument("--out", default=str(ROOT / "results" / "robust_control.json"))
    args = ap.parse_args(argv)
    data = tomllib.loads((ROOT / "examples" / "montecarlo_robust.toml").read_text())
    if args.smoke:
        data["sweep"].update(samples=16, chunk=16)
        data["dynamics"]["steps"] = 20
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        for method in ("integral", "boundary_layer"):
            data["control"]["method"] = method
            scene = Path(tmp) / f"{method}.toml"
            scene.write_text(tomli_w.dumps(data))
            out = Path(tmp) / method
            if cli(["montecarlo", str(scene), "--out", str(out), "--quiet"]) != 0:
                raise SystemExit(f"montecarlo failed for {method}")
            res = open_sweep(out).load()
            ok = res["control_ok"].astype(bool)
            fin = res["final_error"][ok]
            rows[method] = {"rods": int(len(ok)), "success_rate": float(((res["final_error"] < 5e-4) & ok).mean()),
                            "final_error_p50_m": float(sorted(fin)[len(fin) // 2]) if len(fin) else None,
                            "final_error_max_m": float(fin.max()) if len(fin) else None,
                            "peak_tension_n": float(res["peak_tension"].max()),
                            "saturation_fraction": float(res["saturation_fraction"].mean()),
                            "failed_runs": int((~ok).sum())}
            r = rows[method]
            print(f"{method:15s}: {100 * r['success_rate']:.2f}% within 0.5 mm of {r['rods']} rods, "
                  f"peak tension {r['peak_tension_n']:.2f} N, {r['failed_runs']} runs failed")
    write_report(args.out, {"meta": metadata("cpu"), "steps": data["dynamics"]["steps"], "results": rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
