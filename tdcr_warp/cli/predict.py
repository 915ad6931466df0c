"""``tdcr-warp predict SCENE.toml DATA.csv ...``: the measured tips of keypoint CSVs predicted by
a scene with a [hardware] table (tdcr_warp.apps.hardware); metrics.json, predictions.csv and
predict.png."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tdcr_warp.cli.common import (
    CsvWriter,
    OutputRun,
    add_command,
    add_log_arguments,
    add_solver_arguments,
    apply_overrides,
    load_kernels,
    settings,
    write_atomic,
    write_json,
)
from tdcr_warp.model.robot import InputError

# The units of predict's metrics.json entries (hardware.metrics; "1": a count, "%": of the robot's length).
PREDICT_UNITS = {"rows": "1", "converged": "1", "unstable": "1", "rmse_mm": "mm", "rmse_aligned_mm": "mm", "median_mm": "mm",
                 "p95_mm": "mm", "mean_offset_mm": "mm", "rmse_percent_of_length": "%", "wall_time_s": "s",
                 "kernel_load_s": "s", "ms_per_row": "ms", "coverage_95": "1"}
FILES = ("metrics.json", "predictions.csv", "predict.png")  # the completion file first


def add_data_argument(p) -> None:
    """The keypoint CSV files after the scene (predict, fit)."""
    p.add_argument("data", nargs="+", help="keypoint CSV file(s) (tdcr_warp.apps.hardware)")


def register(subparsers) -> None:
    p = add_command(subparsers, "predict", "predict measured tips (a scene with [hardware], a keypoint CSV)", run)
    add_data_argument(p)
    p.add_argument("--recorded-order", action="store_true",
                   help="solve the rows one by one as recorded, each from the last (friction's stick-slip "
                        "memory: hysteresis; tdcr_warp.apps.hardware.predict_recorded) instead of one batch")
    p.add_argument("--residual", metavar="FILE",
                   help="a learned correction (fit --residual's residual.npz): added to the physics, with each "
                        "row's 1-sigma and 95%% interval in predictions.csv and the interval's coverage in metrics.json")
    add_solver_arguments(p)
    add_log_arguments(p)


def run(args) -> int:
    """Predict measured tips of a scene with a [hardware] table (tdcr_warp.apps.hardware)."""
    from tdcr_warp.apps.hardware import read_measurements
    from tdcr_warp.io.scene import load_scene

    scene = apply_overrides(load_scene(args.scene), args)
    if scene.hardware is None:
        raise InputError(f"{args.scene}: predict needs a [hardware] table (servo_columns, marker_offset, base_offset)")
    meas = read_measurements(args.data, scene.hardware["servo_columns"])
    with OutputRun(args, Path("out") / Path(args.scene).stem, FILES) as out:
        return _run(args, scene, meas, out)


def _run(args, scene, meas, out: OutputRun) -> int:
    """Predict the rows, write the files into ``out`` and commit them; the exit status."""
    from tdcr_warp.apps.hardware import metrics
    from tdcr_warp.io.plotting import plot_prediction

    correction = None
    if args.residual:
        from tdcr_warp.apps.residual import Residual

        correction = Residual.load(args.residual)
    load_s = load_kernels(scene, args)
    pred = _solve(scene, meas, args)
    if correction is not None:
        pred |= _corrected(pred, meas, correction)
    m = metrics(pred["error_mm"], pred["converged"], float(np.max(scene.robot.length)))
    if correction is not None:
        m["coverage_95"] = pred["coverage_95"]
    how = "one row at a time, as recorded" if args.recorded_order else "batched solves"
    print(f"predicted {len(meas)} rows in {pred['wall_s']:.2f} s ({1e3 * pred['wall_s'] / len(meas):.2f} ms per row, "
          f"{how}; kernel loading excluded): RMSE {m['rmse_mm']:.2f} mm, "
          f"aligned {m['rmse_aligned_mm']:.2f} mm, "
          f"median {m['median_mm']:.2f} mm, p95 {m['p95_mm']:.2f} mm, {m['converged']} of {m['rows']} converged"
          + (f", {int(pred['unstable'].sum())} of them on unstable equilibria" if pred["unstable"].any() else ""))
    write_predictions(out / "predictions.csv", meas, pred)
    if m["converged"]:
        plot_prediction(meas.tip_mm, pred["point_mm"], pred["converged"], out / "predict.png")
    write_json(out / "metrics.json", m | {"unstable": int(pred["unstable"].sum()),
                                          "scene": str(args.scene), "data": [str(d) for d in args.data],
                                          "wall_time_s": pred["wall_s"], "kernel_load_s": load_s,
                                          "ms_per_row": 1e3 * pred["wall_s"] / len(meas),
                                          "recorded_order": bool(args.recorded_order),
                                          "units": PREDICT_UNITS,
                                          "settings": settings(scene, args.device or "default")})
    out.commit()
    print(f"wrote {out}/metrics.json, predictions.csv, " + ("predict.png" if m["converged"] else
                                                              "no predict.png: no row converged, nothing to plot"))
    return 0 if m["converged"] == m["rows"] else 1


def _solve(scene, meas, args) -> dict:
    """The rows predicted as the arguments say, with a progress bar on stderr (rows) unless --quiet."""
    from tdcr_warp.apps.hardware import predict_in_chunks, predict_recorded
    from tdcr_warp.core.progress import Progress

    bar = None if args.quiet else Progress(len(meas), 1, rate_unit="rows/s")
    try:
        if args.recorded_order:
            return predict_recorded(scene, meas, device=args.device, progress=bar and bar.update)
        return predict_in_chunks(scene, meas, device=args.device, progress=bar and bar.update)
    finally:
        if bar:
            bar.close()


def _corrected(pred: dict, meas, correction) -> dict:
    """The physics' points plus the learned correction, the errors, each row's 1-sigma per axis and the
    share of converged rows' coordinates inside their 95% interval."""
    from tdcr_warp.apps.residual import coverage

    mean, std = correction.predict(meas.servo_mm)
    point = pred["point_mm"] + mean
    ok = pred["converged"]
    return {"point_mm": point, "error_mm": point - meas.tip_mm, "sigma_mm": std,
            "coverage_95": coverage(meas.tip_mm[ok], point[ok], std[ok]) if ok.any() else float("nan")}


def write_predictions(path: Path, meas, pred: dict) -> None:
    """predictions.csv: one row per input row, predicted and measured tip [mm], error, flags; with a
    learned correction, each axis's 1-sigma and 95% interval [mm]."""
    K = pred["slack"].shape[1] if pred["slack"] is not None else 0
    sigma = pred.get("sigma_mm")
    band = [] if sigma is None else [f"{w}_{a}_mm" for w in ("sigma", "low95", "high95") for a in "xyz"]
    def write(tmp):
        with open(tmp, "w", newline="") as f:
            w = CsvWriter(f)  # labels and file names neutralised (csv_cell)
            w.writerow(["row", "source", "pattern_label", "pred_x_mm", "pred_y_mm", "pred_z_mm", "meas_x_mm",
                        "meas_y_mm", "meas_z_mm", "error_mm", "converged", "unstable", "retried"]
                       + [f"slack_{k}" for k in range(K)] + band)
            err = np.linalg.norm(pred["error_mm"], axis=1)
            for i in range(len(meas)):
                w.writerow([i, meas.source[i], meas.labels[i], *np.round(pred["point_mm"][i], 6).tolist(),
                            *meas.tip_mm[i].tolist(), round(float(err[i]), 6), int(pred["converged"][i]),
                            int(pred["unstable"][i]), int(pred["retried"][i])] + [int(x) for x in (pred["slack"][i] if K else [])]
                           + ([] if sigma is None else _band(pred["point_mm"][i], sigma[i])))
    write_atomic(path, write)


def _band(point: np.ndarray, sigma: np.ndarray) -> list[float]:
    """One row's sigma, 95% low and high per axis [mm]."""
    from tdcr_warp.apps.residual import Z95

    return np.round(np.concatenate([sigma, point - Z95 * sigma, point + Z95 * sigma]), 6).tolist()
