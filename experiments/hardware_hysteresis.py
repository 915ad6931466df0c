"""Hysteresis on the real robots: their training rows predicted in the order they were recorded,
each a quasi-static step from the last with capstan friction's stick-slip memory
(tdcr_warp.apps.hardware.predict_recorded), at several friction coefficients on every tendon,
against the batched prediction of the same fitted scene (no memory). Data: opencr-mujoco's
v4_train.csv and v6_train.csv (--data DIR or $TDCR_HARDWARE_DATA; without them the script says so
and skips). The scenes are the committed fits (examples/hardware/ftdcr_v*.toml, fitted without
friction). Writes results/hardware_hysteresis.json.

    python experiments/hardware_hysteresis.py [--data DIR] [--robots v4 v6] [--mu 0 0.05 0.1 0.2]
        [--smoke] [--out FILE]
"""

from __future__ import annotations

import argparse
import sys
import tomllib
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import (
    ROOT,
    add_hardware_data_argument,
    metadata,
    no_hardware_data,
    write_report,
)

from tdcr_warp.apps.hardware import (
    metrics,
    predict,
    predict_recorded,
    read_measurements,
)
from tdcr_warp.io.scene import scene_from_dict


def _row(pred: dict, L: float) -> dict:
    m = metrics(pred["error_mm"], pred["converged"], L)
    return {k: m[k] for k in ("rmse_mm", "rmse_aligned_mm", "p95_mm", "converged", "rows")} | {
        "retried": int(pred["retried"].sum()), "ms_per_row": 1e3 * pred["wall_s"] / len(pred["converged"])}


def one_robot(name: str, mus: list[float], smoke: bool, data_dir: Path) -> dict:
    data = tomllib.loads((ROOT / "examples" / "hardware" / f"ftdcr_{name}.toml").read_text())
    meas = read_measurements(data_dir / f"{name}_train.csv", data["hardware"]["servo_columns"])
    if smoke:
        meas = meas.subset(np.arange(min(40, len(meas))))
    L = data["robot"]["length"]
    out = {"batch, no friction": _row(predict(scene_from_dict(data), meas), L)}
    for mu in mus:
        for t in data["tendons"]:
            t["friction"] = mu
        out[f"recorded order, mu = {mu:g}"] = _row(predict_recorded(scene_from_dict(data), meas), L)
    for k, r in out.items():
        print(f"{name} {k:28s} aligned {r['rmse_aligned_mm']:.3f} mm, RMSE {r['rmse_mm']:.3f} mm, p95 "
              f"{r['p95_mm']:.2f} mm, {r['converged']}/{r['rows']} converged ({r['retried']} retried), "
              f"{r['ms_per_row']:.2f} ms per row", flush=True)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_hardware_data_argument(ap)
    ap.add_argument("--robots", nargs="+", default=["v4", "v6"])
    ap.add_argument("--mu", nargs="+", type=float, default=[0.0, 0.05, 0.1, 0.2])
    ap.add_argument("--smoke", action="store_true", help="40 rows of v4, mu 0 and 0.1 (for the test suite)")
    ap.add_argument("--out", default=str(ROOT / "results" / "hardware_hysteresis.json"))
    args = ap.parse_args(argv)
    if no_hardware_data(args.data, args.out):
        return 0
    robots, mus = (["v4"], [0.0, 0.1]) if args.smoke else (args.robots, args.mu)
    report = {"meta": metadata("cpu", command=" ".join(sys.argv))}
    for name in robots:
        report[name] = one_robot(name, mus, args.smoke, args.data)
    write_report(args.out, report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
