"""Predicting two real robots (opencr-mujoco's Franka TDCRs v4 and v6; data: their training files
only, v4_train.csv and v6_train.csv from that project's data/sysid folder, which this repository
does not ship: --data DIR, or $TDCR_HARDWARE_DATA; without them the script says so and skips): calibrate on all training rows (the fitted scenes become
examples/hardware/ftdcr_v4.toml and ftdcr_v6.toml), cross-validate without leaks (FOLDS folds of
whole recorded patterns in consecutive blocks, tdcr_warp.apps.hardware.pattern_folds: fit on the
others, predict the held-out block; the aligned RMSE pooled over folds and each fold's), compare the
model rungs on the same held-out rows (each fold's fitted parameters in each rung's physics or
discretisation; error and time per row), and draw the held-out error by pattern
(docs/figures/ftdcr_<robot>_cv_patterns.png). Writes results/hardware_validation.json.

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
from tdcr_warp.model.robot import InputError

FOLDS = 5
BASE = "coupled cosserat (fitted)"
RUNGS = {"coupled cosserat (fitted)": {}, "coupled kirchhoff": {"rod": "kirchhoff"},
         "point cosserat": {"model": "point"}, "coupled cosserat N = 8": {"nodes": 8},
         "coupled cosserat, friction mu = 0.1": "friction", "constant curvature": {"model": "constant_curvature"},
         "disks cosserat (one per link)": "disks"}


def _summary(m: dict) -> dict:
    return {k: m[k] for k in ("rmse_mm", "rmse_aligned_mm", "median_mm", "p95_mm", "rmse_percent_of_length",
                              "converged", "rows")}


def _pooled(parts: list[dict]) -> dict:
    """The RMSE (as is and aligned within each fold) over all converged held-out rows of the folds,
    and the aligned RMSE of each fold."""
    rows = np.array([p["converged"] for p in parts])
    some = rows > 0  # a fold where nothing converged has no error to pool (it counts as unconverged)
    pool = {k: float(np.sqrt(np.sum(rows[some] * np.array([p[k] for p in parts])[some] ** 2) / rows.sum()))
            if rows.sum() else float("nan") for k in ("rmse_mm", "rmse_aligned_mm")}
    return pool | {"folds_aligned_mm": [p["rmse_aligned_mm"] for p in parts], "converged": int(rows.sum()),
                   "rows": int(sum(p["rows"] for p in parts))}


def _rung_scene(fitted: dict, over, name: str) -> dict:
    d = tomllib.loads(tomli_w.dumps(fitted))
    if over == "friction":
        for t in d["tendons"]:
            t["friction"] = 0.1
        over = {}
    if over == "disks":
        return with_disks(d, name)
    d["solver"] = d.get("solver", {}) | over
    return d


def cross_validate(name: str, data: dict, meas, smoke: bool, physics=()) -> tuple[dict, dict]:
    """Leak-free cross-validation (FOLDS blocks of whole patterns, pattern_folds): fit on the other
    blocks, predict the held-out one, for the fitted model and for every rung of RUNGS (the same
    fold's fitted parameters, the rung's physics or discretisation; the disk model warm-started
    from the fitted model's solution of the same rows). Returns the cross-validation
    (pooled and per fold) and the rungs (pooled held-out RMSE, time per row); draws the held-out
    error by pattern into docs/figures/ftdcr_<name>_cv_patterns.png."""
    L = data["robot"]["length"]
    fold = pattern_folds(meas.labels, 2 if smoke else FOLDS)
    parts, per_rung, errors = [], {r: [] for r in RUNGS}, np.full((len(meas), 3), np.nan)
    times = {r: [0.0, 0] for r in RUNGS}
    for k in range(fold.max() + 1):
        test = np.flatnonzero(fold == k)
        fk = fit(data, meas.subset(np.flatnonzero(fold != k)), physics=physics, max_iter=2 if smoke else 30)
        held = meas.subset(test)
        base = None  # the fitted rung's prediction (RUNGS starts with it): the disk model's warm start
        for rung, over in RUNGS.items():
            try:
                sc = scene_from_dict(_rung_scene(fk["scene"], over, name))
                predict(sc, held.subset(np.arange(min(4, len(held)))))  # kernels loaded
                p = predict(sc, held, initial=base["solution"] if over == "disks" and base else None)
            except InputError as e:
                per_rung[rung] = str(e)
                continue
            m = _summary(metrics(p["error_mm"], p["converged"], L))
            if isinstance(per_rung[rung], list):
                per_rung[rung].append(m)
            times[rung][0] += p["wall_s"]
            times[rung][1] += len(held)
            if rung == BASE:
                base = p
                errors[test] = np.where(p["converged"][:, None], p["error_mm"] - p["error_mm"][p["converged"]].mean(0),
                                        np.nan)
                parts.append(m | {"patterns": sorted({str(v).removesuffix("_hold") for v in held.labels}),
                                  "fit_s": fk["report"]["wall_s"]})
    cv = _pooled(parts) | {"folds": parts, "split": "whole patterns, consecutive blocks (pattern_folds)"}
    print(f"  cross-validated ({len(parts)} folds of whole patterns): RMSE {cv['rmse_mm']:.2f} mm "
          f"({100 * cv['rmse_mm'] / (1e3 * L):.2f}% of L), aligned {cv['rmse_aligned_mm']:.2f} mm (folds "
          + ", ".join(f"{a:.2f}" for a in cv["folds_aligned_mm"]) + ")")
    rungs = {}
    for rung, got in per_rung.items():
        if isinstance(got, str):
            rungs[rung] = {"available": False, "reason": got}
            print(f"  {rung:38s} n/a: {got}")
            continue
        rungs[rung] = _pooled(got) | {"ms_per_row": 1e3 * times[rung][0] / max(times[rung][1], 1)}
        r = rungs[rung]
        print(f"  {rung:38s} held out: aligned {r['rmse_aligned_mm']:6.2f} mm, RMSE {r['rmse_mm']:6.2f} mm, "
              f"{r['converged']}/{r['rows']} converged, {r['ms_per_row']:.2f} ms per row")
    if not smoke:
        plot_patterns(meas.labels, errors, ROOT / "docs" / "figures" / f"ftdcr_{name}_cv_patterns.png", name)
    return cv, rungs


def plot_patterns(labels: np.ndarray, errors: np.ndarray, path: Path, name: str) -> None:
    """Held-out aligned error [mm] by pattern family (the label without its repetition, direction,
    circle and hold parts): RMSE bars, with the number of rows."""
    import re

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    family = np.array([re.sub(r"^rep\d+_|_hold$|_dir\d+|_circle|_id\d+", "", str(v)) for v in labels])
    names = list(dict.fromkeys(family))
    d = np.linalg.norm(errors, axis=1)
    rmse = [float(np.sqrt(np.nanmean(d[family == f] ** 2))) for f in names]
    fig, ax = plt.subplots(figsize=(7, 0.28 * len(names) + 1.2))
    ax.barh(range(len(names)), rmse, color="tab:blue")
    ax.set_yticks(range(len(names)), [f"{f} ({int((family == f).sum())})" for f in names], fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel("held-out tip error, aligned RMSE [mm]")
    ax.set_title(f"{name}: error by recorded pattern (5 folds of whole patterns)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def one_robot(name: str, scenes: bool, smoke: bool, data_dir: Path = HARDWARE_DATA, physics=()) -> dict:
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
    res = fit(data, meas, physics=physics, max_iter=2 if smoke else 30)
    out["fit"] = {"wall_s": time.perf_counter() - t, "iterations": res["report"]["iterations"],
                  "parameters": res["report"]["parameters"], "training": _summary(res["report"]["training"])}
    again = fit(data, meas, physics=physics, max_iter=2 if smoke else 30)  # reproducible: the same data, the same parameters
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
        how = f" --physics {' '.join(physics)}" if physics else ""
        header = (f"# Franka TDCR {name}, fitted by `tdcr-warp fit{how}` (experiments/hardware_validation.py) from\n"
                  f"# ftdcr_{name}_nominal.toml on opencr-mujoco's {name}_train.csv ({len(meas)} rows; MIT licence,\n"
                  f"# github ContinuumRoboticsLab/opencr-mujoco): training RMSE {tr['rmse_mm']:.2f} mm, aligned "
                  f"{tr['rmse_aligned_mm']:.2f} mm.\n# Predict new keypoints: tdcr-warp predict {target.relative_to(ROOT)} NEW.csv\n")
        target.write_text(header + tomli_w.dumps(res["scene"]))
    out["cross_validation"], out["rungs"] = cross_validate(name, data, meas, smoke, physics)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_hardware_data_argument(ap)
    ap.add_argument("--robots", nargs="+", default=["v4", "v6"])
    ap.add_argument("--no-scenes", action="store_true", help="do not write examples/hardware/ftdcr_*.toml")
    ap.add_argument("--physics", nargs="*", default=["weight"], choices=["weight", "hole_radius", "marker"],
                    help="the physics fitted beside the tendons (default: weight; experiments/hardware_families.py "
                         "measured which carries over to motions the fit never saw)")
    ap.add_argument("--smoke", action="store_true", help="40 rows, 2 iterations (for the test suite)")
    ap.add_argument("--out", default=str(ROOT / "results" / "hardware_validation.json"))
    args = ap.parse_args(argv)
    if no_hardware_data(args.data, args.out):
        return 0
    report = {"meta": metadata("cpu", command=" ".join(sys.argv))}
    for name in args.robots:
        report[name] = one_robot(name, not args.no_scenes, args.smoke, args.data, tuple(args.physics))
    write_report(args.out, report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
