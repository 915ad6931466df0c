"""Real robots predicted in motions of a kind the fit never saw (opencr-mujoco's Franka TDCRs v4 and
v6; their training files only: --data DIR or $TDCR_HARDWARE_DATA, skipped without them). For each
model (the fitted physics: the tendons alone, + the robot's weight and mounting, + the tendons'
hole radius per segment) and each split (fit on segments and pulls, predict the pairs; fit on
segments and pairs, predict the single-tendon pulls; FOLDS blocks of whole patterns), fit on the
training side and predict the held-out rows; the aligned RMSE (each held-out block's mean offset
removed, as the blind test does), each block's, and per family. Then the chosen model fitted on all
rows: its parameters with standard deviations and correlations. Draws the held-out error against
the tip's deflection and tilt (docs/figures/ftdcr_<robot>_family_out.png). Writes
results/hardware_families.json.

    python experiments/hardware_families.py [--data DIR] [--robots v4 v6] [--models NAME ...] [--smoke]
"""

from __future__ import annotations

import argparse
import sys
import time
import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import HARDWARE_DATA, ROOT, add_hardware_data_argument, metadata, no_hardware_data, write_report  # noqa: E402

from tdcr_warp.apps.hardware import (  # noqa: E402
    family_out_splits,
    fit,
    motion_families,
    pattern_folds,
    predict,
    read_measurements,
)
from tdcr_warp.apps.residual import coverage, fit_residual  # noqa: E402
from tdcr_warp.io.scene import scene_from_dict  # noqa: E402

FOLDS = 5
MODELS = {"tendons": (), "+ weight": ("weight",), "+ hole radius": ("hole_radius",),
          "+ weight, hole radius": ("weight", "hole_radius"), "+ marker on the tip": ("marker",),
          "+ weight, marker on the tip": ("weight", "marker")}


def _splits(meas, smoke: bool) -> dict[str, np.ndarray]:
    """Each split as (M,) int: the held-out block of each row (-1: always in training)."""
    out = {name: np.where(m, 0, -1) for name, m in family_out_splits(meas.labels).items()}
    if smoke:  # one family-out split: the test suite's check that the script runs end to end
        return dict(list(out.items())[:1])
    out[f"{FOLDS} folds of patterns"] = pattern_folds(meas.labels, FOLDS)
    return out


def _tilt_deflection(scene, meas, p) -> tuple[np.ndarray, np.ndarray]:
    """Each row's predicted tip tilt from the base axis [deg] and the predicted point's distance from
    the zero command's [mm]."""
    one = meas.subset(np.arange(1))
    zero = predict(scene, replace(one, servo_mm=np.zeros_like(one.servo_mm)))
    tilt = np.degrees(np.arccos(np.clip(p["solution"].tip_rotation[:, 2, 2], -1, 1)))
    return tilt, np.linalg.norm(p["point_mm"] - zero["point_mm"][0], axis=1)


RUNGS = ("physics", "physics + residual", "residual alone")


def _rungs(fk: dict, train, held, p: dict) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each rung's predicted point and 1-sigma per axis (M, 3) [mm] on the held-out rows: the physics
    (its training RMSE per axis as the sigma), the physics plus a residual fitted on what it missed
    in training, and a residual alone fitted on the measured points."""
    tr = fk["prediction"]
    ok = tr["converged"]
    sigma = np.sqrt(np.mean(tr["error_mm"][ok] ** 2, axis=0))
    corr = fit_residual(train.servo_mm[ok], -tr["error_mm"][ok])
    mu, sd = corr.predict(held.servo_mm)
    alone = fit_residual(train.servo_mm, train.tip_mm)
    return {"physics": (p["point_mm"], np.broadcast_to(sigma, p["point_mm"].shape)),
            "physics + residual": (p["point_mm"] + mu, sd), "residual alone": alone.predict(held.servo_mm)}


def held_out(data: dict, meas, physics, block: np.ndarray, smoke: bool, rungs: bool = False) -> dict:
    """Fit on the rows of block -1 and of the other blocks, predict each block; per-row aligned
    errors (NaN where not converged), tilt and deflection, each block's aligned RMSE, fit times;
    with ``rungs``, each of RUNGS's aligned RMSE and 95% coverage over the held-out rows."""
    M = len(meas)
    err, tilt, defl = np.full((M, 3), np.nan), np.full(M, np.nan), np.full(M, np.nan)
    rung = {r: (np.full((M, 3), np.nan), np.full((M, 3), np.nan), np.full((M, 3), np.nan)) for r in RUNGS}
    blocks, fit_s = [], []
    for k in range(block.max() + 1):
        test = np.flatnonzero(block == k)
        train = meas.subset(np.flatnonzero(block != k))
        fk = fit(data, train, physics=physics, max_iter=2 if smoke else 30)
        fit_s.append(fk["report"]["wall_s"])
        sc = scene_from_dict(fk["scene"])
        held = meas.subset(test)
        p = predict(sc, held)
        ok = p["converged"]
        err[test] = np.where(ok[:, None], p["error_mm"] - p["error_mm"][ok].mean(0), np.nan)
        tilt[test], defl[test] = _tilt_deflection(sc, held, p)
        blocks.append(float(np.sqrt(np.nanmean(np.sum(err[test] ** 2, axis=1)))))
        for r, (point, sd) in (_rungs(fk, train, held, p) if rungs else {}).items():
            e = np.where(ok[:, None], point - held.tip_mm, np.nan)
            rung[r][0][test], rung[r][1][test], rung[r][2][test] = e - np.nanmean(e, axis=0), point, sd
    d = np.linalg.norm(err, axis=1)
    held_rows = block >= 0
    fam = motion_families(meas.labels)
    out = {}
    if rungs:
        out["rungs"] = {r: {"rmse_aligned_mm": float(np.sqrt(np.nanmean(np.sum(e[held_rows] ** 2, axis=1)))),
                            "coverage_95": coverage(meas.tip_mm[held_rows], pt[held_rows], sd[held_rows]),
                            "sigma_mean_mm": float(np.nanmean(sd[held_rows]))}
                        for r, (e, pt, sd) in rung.items()}
    return out | {"rmse_aligned_mm": float(np.sqrt(np.nanmean(d[held_rows] ** 2))), "blocks_mm": blocks,
            "converged": int(np.isfinite(d[held_rows]).sum()), "rows": int(held_rows.sum()),
            "families_mm": {f: float(np.sqrt(np.nanmean(d[held_rows & (fam == f)] ** 2)))
                            for f in np.unique(fam[held_rows])},
            "fit_s_median": float(np.median(fit_s)), "_d": d, "_tilt": tilt, "_defl": defl}


def parameters(data: dict, meas, physics, smoke: bool) -> dict:
    """The model fitted on all rows: values, standard deviations, the correlations of its parameters
    (from sigma^2 (J^T J)^-1), the unidentifiable ones, training error."""
    res = fit(data, meas, physics=physics, max_iter=2 if smoke else 30)
    rep = res["report"]
    J = res["prediction"]["jacobian"]
    keep = [i for i, n in enumerate(rep["parameters"]) if n not in rep["unidentifiable"]]
    cov = np.linalg.inv(J[:, keep].T @ J[:, keep])
    sd = np.sqrt(np.diag(cov))
    corr = cov / np.outer(sd, sd)
    names = [list(rep["parameters"])[i] for i in keep]
    return {"parameters": rep["parameters"], "unidentifiable": rep["unidentifiable"],
            "training_aligned_mm": rep["training"]["rmse_aligned_mm"], "fit_s": rep["wall_s"],
            "correlation": {"names": names, "matrix": corr.round(3).tolist()}, "scene": res["scene"]}


def plot(name: str, runs: dict, path: Path) -> None:
    """Held-out aligned error against the predicted tip deflection and tilt, binned RMSE per model
    (the family-out splits pooled)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for model, splits in runs.items():
        fam = [s for k, s in splits.items() if "out" in k]
        d = np.concatenate([s["_d"][np.isfinite(s["_d"])] for s in fam])
        for ax, key, edges in ((axes[0], "_defl", np.arange(0, 161, 20)), (axes[1], "_tilt", np.arange(0, 121, 15))):
            x = np.concatenate([s[key][np.isfinite(s["_d"])] for s in fam])
            idx = np.digitize(x, edges) - 1
            y = [np.sqrt(np.mean(d[idx == i] ** 2)) if (idx == i).sum() >= 5 else np.nan for i in range(len(edges) - 1)]
            ax.plot(0.5 * (edges[1:] + edges[:-1]), y, "o-", label=model)
    axes[0].set_xlabel("predicted tip deflection from the zero command [mm]")
    axes[1].set_xlabel("predicted tip tilt from the base axis [deg]")
    for ax in axes:
        ax.set_ylabel("held-out aligned RMSE [mm]")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"{name}: error on motion families the fit never saw (pairs out, pulls out)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def one_robot(name: str, models: list[str], smoke: bool, data_dir: Path, residual: str | None = None) -> dict:
    data = tomllib.loads((ROOT / "examples" / "hardware" / f"ftdcr_{name}_nominal.toml").read_text())
    meas = read_measurements(data_dir / f"{name}_train.csv", data["hardware"]["servo_columns"])
    if smoke:
        meas = meas.subset(np.arange(0, len(meas), max(1, len(meas) // 60)))
    runs = {}
    models = models[:1] if smoke else models
    for model in models:
        runs[model] = {}
        for split, block in _splits(meas, smoke).items():
            t0 = time.perf_counter()
            r = runs[model][split] = held_out(data, meas, MODELS[model], block, smoke, rungs=model == residual)
            print(f"{name} | {model} | {split} | {r['rmse_aligned_mm']:.2f} mm (blocks "
                  + ", ".join(f"{b:.2f}" for b in r["blocks_mm"]) + f") | {r['converged']}/{r['rows']} | "
                  + ", ".join(f"{f} {v:.2f}" for f, v in r["families_mm"].items())
                  + f" | fit {r['fit_s_median']:.0f} s | {time.perf_counter() - t0:.0f} s", flush=True)
            for rung, v in r.get("rungs", {}).items():
                print(f"{name} | {model} | {split} | {rung}: aligned {v['rmse_aligned_mm']:.2f} mm, 95% interval "
                      f"holds {100 * v['coverage_95']:.1f}% (mean sigma {v['sigma_mean_mm']:.2f} mm)", flush=True)
    if not smoke:
        plot(name, runs, ROOT / "docs" / "figures" / f"ftdcr_{name}_family_out.png")
    out = {"rows": len(meas), "splits": {m: {k: {a: b for a, b in v.items() if not a.startswith("_")}
                                             for k, v in s.items()} for m, s in runs.items()}}
    out["fitted"] = {m: parameters(data, meas, MODELS[m], smoke) for m in models}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_hardware_data_argument(ap)
    ap.add_argument("--robots", nargs="+", default=["v4", "v6"])
    ap.add_argument("--models", nargs="+", default=list(MODELS), choices=list(MODELS))
    ap.add_argument("--residual", choices=list(MODELS), help="the model whose held-out rows also get the rungs "
                    "physics, physics + residual, residual alone (experiments: apps/residual.py)")
    ap.add_argument("--smoke", action="store_true", help="60 rows, 2 iterations, the first model and split "
                    "(for the test suite)")
    ap.add_argument("--out", default=str(ROOT / "results" / "hardware_families.json"))
    args = ap.parse_args(argv)
    if no_hardware_data(args.data, args.out):
        return 0
    report = {"meta": metadata("cpu", command=" ".join(sys.argv))}
    print("| robot | model | split | held-out aligned RMSE (blocks) | converged | per family | fit | wall |")
    for name in args.robots:
        report[name] = one_robot(name, args.models, args.smoke, args.data, args.residual)
        write_report(args.out, report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
