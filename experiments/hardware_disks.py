"""The spacer-disk model on the real robots, fitted in its own physics: for each robot
(opencr-mujoco's Franka TDCRs; their training files only, --data DIR or $TDCR_HARDWARE_DATA,
skipped without them) the same leak-free folds as experiments/hardware_validation.py (whole
recorded patterns in consecutive blocks), each fold fitted and its held-out block predicted twice:
with the continuous coupled model and with the disk model (a disk at the end of each of
opencr-mujoco's links, one RK4 step between two), both fitted by `tdcr-warp fit`'s
Levenberg-Marquardt from the same nominal scene. Reports the pooled held-out aligned RMSE, each
fold's, the training RMSE, and the fit and prediction times of both in the same run.

    python experiments/hardware_disks.py [--data DIR] [--robots v4 v6] [--folds 5] [--smoke] [--out FILE]
"""

from __future__ import annotations

import argparse
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import (
    LINKS,
    ROOT,
    add_hardware_data_argument,
    metadata,
    no_hardware_data,
    with_disks,
    write_report,
)

from tdcr_warp.apps.hardware import (
    fit,
    metrics,
    pattern_folds,
    predict,
    read_measurements,
)
from tdcr_warp.io.scene import scene_from_dict


def _models(nominal: dict, name: str) -> dict:
    """The nominal scene in either model (the disk model: disks at the links' ends)."""
    return {"coupled": nominal, "disks": with_disks(nominal, name)}


def one_robot(name: str, folds: int, smoke: bool, data_dir: Path) -> dict:
    nominal = tomllib.loads((ROOT / "examples" / "hardware" / f"ftdcr_{name}_nominal.toml").read_text())
    meas = read_measurements(data_dir / f"{name}_train.csv", nominal["hardware"]["servo_columns"])
    if smoke:
        meas = meas.subset(np.arange(0, len(meas), max(1, len(meas) // 40)))
    L = nominal["robot"]["length"]
    fold = pattern_folds(meas.labels, 2 if smoke else folds)
    out = {"links_per_section": LINKS[name], "rows": len(meas)}
    aligned = {}  # per model, each held-out row's error less its fold's mean (NaN: not converged)
    for model, data in _models(nominal, name).items():
        held, fits, pred_s, rows = [], [], 0.0, 0
        aligned[model] = np.full((len(meas), 3), np.nan)
        for k in range(fold.max() + 1):
            train, test = np.flatnonzero(fold != k), np.flatnonzero(fold == k)
            t = time.perf_counter()
            fk = fit(data, meas.subset(train), max_iter=2 if smoke else 30)
            fits.append({"wall_s": time.perf_counter() - t,
                         "training_aligned_mm": fk["report"]["training"]["rmse_aligned_mm"]})
            p = predict(scene_from_dict(fk["scene"]), meas.subset(test))
            pred_s, rows = pred_s + p["wall_s"], rows + len(test)
            held.append(metrics(p["error_mm"], p["converged"], L) | {"rows": len(test)})
            ok = p["converged"]
            aligned[model][test[ok]] = p["error_mm"][ok] - p["error_mm"][ok].mean(axis=0)
        conv = np.array([h["converged"] for h in held])
        pooled = float(np.sqrt(np.sum(conv * np.array([h["rmse_aligned_mm"] for h in held]) ** 2) / conv.sum()))
        out[model] = {"held_out_aligned_mm": pooled, "folds_aligned_mm": [h["rmse_aligned_mm"] for h in held],
                      "converged": int(conv.sum()), "fits": fits, "predict_ms_per_row": 1e3 * pred_s / rows}
        print(f"{name} {model:8s} held out aligned {pooled:6.2f} mm (folds "
              + ", ".join(f"{h['rmse_aligned_mm']:.2f}" for h in held) + f"), {conv.sum()}/{rows} converged, "
              f"fit {np.median([f['wall_s'] for f in fits]):.0f} s (median), {1e3 * pred_s / rows:.2f} ms/row",
              flush=True)
    both = np.isfinite(aligned["coupled"]).all(axis=1) & np.isfinite(aligned["disks"]).all(axis=1)
    out["rows_both_converged"] = int(both.sum())
    for model, err in aligned.items():
        out[model]["held_out_aligned_mm_common_rows"] = float(np.sqrt(np.mean(np.sum(err[both] ** 2, axis=1))))
    print(f"{name} on the {both.sum()} rows both converged: coupled "
          f"{out['coupled']['held_out_aligned_mm_common_rows']:.2f} mm, disks "
          f"{out['disks']['held_out_aligned_mm_common_rows']:.2f} mm")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_hardware_data_argument(ap)
    ap.add_argument("--robots", nargs="+", default=["v4", "v6"])
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--smoke", action="store_true", help="40 rows, 2 folds, 2 iterations (for the test suite)")
    ap.add_argument("--out", default=str(ROOT / "results" / "hardware_disks.json"))
    args = ap.parse_args(argv)
    if no_hardware_data(args.data, args.out):
        return 0
    report = {"meta": metadata("cpu", command=" ".join(sys.argv))}
    for name in args.robots:
        report[name] = one_robot(name, args.folds, args.smoke, args.data)
    write_report(args.out, report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
