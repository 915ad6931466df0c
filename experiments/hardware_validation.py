"""Predicting two real robots (opencr-mujoco's Franka TDCRs v4 and v6; data: their training files
only, v4_train.csv and v6_train.csv from that project's data/sysid folder, which this repository
does not ship: --data DIR, or $TDCR_HARDWARE_DATA; without them the script says so and skips): calibrate on all training rows (the fitted scenes become
examples/hardware/ftdcr_v4.toml and ftdcr_v6.toml), cross-validate without leaks (FOLDS folds of
whole recorded patterns in consecutive blocks, tdcr_warp.apps.hardware.pattern_folds: fit on the
others, predict the held-out block; the aligned RMSE pooled over folds and each fold's), and compare the
model rungs on the fitted scenes (error and time per rung on all training rows). Writes
results/hardware_validation.json.

    python experiments/hardware_validation.py [--data DIR] [--robots v4 v6] [--no-scenes] [--smoke] [--out FILE]
"""

from __future__ import annotations

import argparse
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import tomli_w

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import (
    HARDWARE_DATA,
    ROOT,
    add_hardware_data_argument,
    metadata,
    no_hardware_data,
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
from tdcr_warp.model.robot import InputError

FOLDS = 5
RUNGS = {"coupled cosserat (fitted)": {}, "coupled kirchhoff": {"rod": "kirchhoff"},
         "point cosserat": {"model": "point"}, "coupled cosserat N = 8": {"nodes": 8},
         "coupled cosserat, friction mu = 0.1": "friction", "constant curvature": {"model": "constant_curvature"}}


def _summary(m: dict) -> dict:
    return {k: m[k] for k in ("rmse_mm", "rmse_aligned_mm", "median_mm", "p95_mm", "rmse_percent_of_length",
                              "converged", "rows")}


def one_robot(name: str, scenes: bool, smoke: bool, data_dir: Path = HARDWARE_DATA) -> dict:
    nominal = ROOT / "examples" / "hardware" / f"ftdcr_{name}_nominal.toml"
    data = tomllib.loads(nominal.read_text())
    cols = data["hardware"]["servo_columns"]
    meas = read_measurements(data_dir / f"{name}_train.csv", cols)
    if smoke:
        meas = meas.subset(np.arange(0, len(meas), max(1, len(meas) // 40)))
    L = data["robot"]["length"]
    out = {"rows": len(meas), "length_m": L}
    start = predict(scene_from_dict(data), meas)
    out["nominal"] = _summary(metrics(start["error_mm"], start["converged"], L))
    t = time.perf_counter()
    res = fit(data, meas, max_iter=2 if smoke else 30)
    out["fit"] = {"wall_s": time.perf_counter() - t, "iterations": res["report"]["iterations"],
                  "parameters": res["report"]["parameters"], "training": _summary(res["report"]["training"])}
    again = fit(data, meas, max_iter=2 if smoke else 30)  # reproducible: the same data, the same parameters
    out["fit"]["reproducible_max_rel"] = max(abs(a["value"] - b["value"]) / max(abs(a["value"]), 1e-12)
                                             for a, b in zip(res["report"]["parameters"].values(),
                                                             again["report"]["parameters"].values()))
    print(f"{name}: nominal RMSE {out['nominal']['rmse_mm']:.2f} mm (aligned {out['nominal']['rmse_aligned_mm']:.2f}); "
          f"fit {out['fit']['wall_s']:.0f} s, training RMSE {out['fit']['training']['rmse_mm']:.2f} mm "
          f"({out['fit']['training']['rmse_percent_of_length']:.2f}% of L), aligned "
          f"{out['fit']['training']['rmse_aligned_mm']:.2f} mm; refit differs by {out['fit']['reproducible_max_rel']:.1e}")
    if scenes and not smoke:
        target = ROOT / "examples" / "hardware" / f"ftdcr_{name}.toml"
        tr = out["fit"]["training"]
        header = (f"# Franka TDCR {name}, fitted by `tdcr-warp fit` (experiments/hardware_validation.py) from\n"
                  f"# ftdcr_{name}_nominal.toml on opencr-mujoco's {name}_train.csv ({len(meas)} rows; MIT licence,\n"
                  f"# github ContinuumRoboticsLab/opencr-mujoco): training RMSE {tr['rmse_mm']:.2f} mm, aligned "
                  f"{tr['rmse_aligned_mm']:.2f} mm.\n# Predict new keypoints: tdcr-warp predict {target.relative_to(ROOT)} NEW.csv\n")
        target.write_text(header + tomli_w.dumps(res["scene"]))
    fold = pattern_folds(meas.labels, 2 if smoke else FOLDS)
    folds = []
    for k in range(fold.max() + 1):
        test = fold == k
        fk = fit(data, meas.subset(np.flatnonzero(~test)), max_iter=2 if smoke else 30)
        pk = predict(scene_from_dict(fk["scene"]), meas.subset(np.flatnonzero(test)))
        patterns = sorted({str(v).removesuffix("_hold") for v in meas.labels[test]})
        folds.append(_summary(metrics(pk["error_mm"], pk["converged"], L)) | {"patterns": patterns,
                                                                              "fit_s": fk["report"]["wall_s"]})
    aligned = np.array([f["rmse_aligned_mm"] for f in folds])
    rows = np.array([f["rows"] for f in folds])
    out["cross_validation"] = {"folds": folds, "split": "whole patterns, consecutive blocks (pattern_folds)",
                               "rmse_mm": float(np.sqrt(np.sum(rows * [f["rmse_mm"] ** 2 for f in folds]) / rows.sum())),
                               "rmse_aligned_mm": float(np.sqrt(np.sum(rows * aligned**2) / rows.sum())),
                               "aligned_min_mm": float(aligned.min()), "aligned_max_mm": float(aligned.max())}
    cv = out["cross_validation"]
    print(f"  cross-validated ({len(folds)} folds of whole patterns): RMSE {cv['rmse_mm']:.2f} mm "
          f"({100 * cv['rmse_mm'] / (1e3 * L):.2f}% of L), aligned {cv['rmse_aligned_mm']:.2f} mm (folds "
          + ", ".join(f"{a:.2f}" for a in aligned) + ")")
    rungs = {}
    fitted = res["scene"]
    for rung, over in RUNGS.items():
        d = tomllib.loads(tomli_w.dumps(fitted))
        if over == "friction":
            for t in d["tendons"]:
                t["friction"] = 0.1
            over = {}
        d["solver"] = d.get("solver", {}) | over
        try:
            sc = scene_from_dict(d)
            predict(sc, meas.subset(np.arange(min(8, len(meas)))))  # kernels loaded
            p = predict(sc, meas)
        except InputError as e:
            rungs[rung] = {"available": False, "reason": str(e)}
            print(f"  {rung:38s} n/a: {e}")
            continue
        m = metrics(p["error_mm"], p["converged"], L)
        rungs[rung] = _summary(m) | {"ms_per_row": 1e3 * p["wall_s"] / len(meas)}
        print(f"  {rung:38s} RMSE {m['rmse_mm']:6.2f} mm, aligned {m['rmse_aligned_mm']:6.2f} mm, "
              f"{m['converged']}/{m['rows']} converged, {1e3 * p['wall_s'] / len(meas):.2f} ms per row")
    out["rungs"] = rungs
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_hardware_data_argument(ap)
    ap.add_argument("--robots", nargs="+", default=["v4", "v6"])
    ap.add_argument("--no-scenes", action="store_true", help="do not write examples/hardware/ftdcr_*.toml")
    ap.add_argument("--smoke", action="store_true", help="40 rows, 2 iterations (for the test suite)")
    ap.add_argument("--out", default=str(ROOT / "results" / "hardware_validation.json"))
    args = ap.parse_args(argv)
    if no_hardware_data(args.data, args.out):
        return 0
    report = {"meta": metadata("cpu", command=" ".join(sys.argv))}
    for name in args.robots:
        report[name] = one_robot(name, not args.no_scenes, args.smoke, args.data)
    write_report(args.out, report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
