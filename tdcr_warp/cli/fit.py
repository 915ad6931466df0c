"""``tdcr-warp fit SCENE.toml DATA.csv ...``: calibrate a [hardware] scene on keypoint CSVs
(tdcr_warp.apps.hardware.fit); fitted.toml, fit.json, predictions.csv and (--residual) residual.npz."""

from __future__ import annotations

from pathlib import Path

from tdcr_warp.cli.common import (
    OutputRun,
    add_command,
    add_log_arguments,
    add_solver_arguments,
    positive_int,
    settings,
    write_atomic,
    write_json,
)
from tdcr_warp.cli.predict import add_data_argument, write_predictions
from tdcr_warp.io.files import printable
from tdcr_warp.model.robot import InputError

FILES = ("fit.json", "fitted.toml", "predictions.csv", "residual.npz")  # the completion files (fit.json last) first


def register(subparsers) -> None:
    p = add_command(subparsers, "fit", "calibrate a [hardware] scene on keypoint CSVs; writes fitted.toml", run)
    add_data_argument(p)
    p.add_argument("--max-iter", type=positive_int, default=30,
                   help="Levenberg-Marquardt iterations (default 30)")
    p.add_argument("--detail", choices=["segment", "tendon"], default="tendon",
                   help="a rotation per tendon and a compliance per segment (default), or one per segment "
                        "and one compliance")
    p.add_argument("--physics", nargs="+", choices=["weight", "hole_radius", "marker"], default=[],
                   help="also fit the robot's weight and mounting (needs [robot] density: its weight per length "
                        "as gravity), each segment's tendon hole radius, and/or the marker's offset carried by "
                        "the tip (in its body frame)")
    p.add_argument("--residual", action="store_true",
                   help="also fit a learned correction with an uncertainty on what the fitted physics misses "
                        "(a Gaussian process over the commands; residual.npz, for predict --residual)")
    add_solver_arguments(p)
    add_log_arguments(p)


def run(args) -> int:
    """Calibrate a [hardware] scene on measured rows (tdcr_warp.apps.hardware.fit); writes fitted.toml."""
    from tdcr_warp.apps.hardware import read_measurements
    from tdcr_warp.io.scene import load_scene

    scene = load_scene(args.scene)
    if scene.hardware is None:
        raise InputError(f"{args.scene}: fit needs a [hardware] table (servo_columns, marker_offset, base_offset)")
    meas = read_measurements(args.data, scene.hardware["servo_columns"])
    with OutputRun(args, Path("out") / (Path(args.scene).stem + "_fit"), FILES, complete=2) as out:
        return _run(args, scene, meas, out)


def _run(args, scene, meas, out: OutputRun) -> int:
    """Fit, write the files into ``out`` and commit them; the exit status."""
    import tomli_w

    from tdcr_warp.apps.hardware import fit

    print(f"fitting {printable(Path(args.scene).name)} on {len(meas)} rows ...", flush=True)
    res = fit(scene.source, meas, detail=args.detail, physics=tuple(args.physics), device=args.device,
              max_iter=args.max_iter,
              progress=None if args.quiet else _print_iteration)
    rep = res["report"]
    header = (f"# Fitted by tdcr-warp fit from {printable(Path(args.scene).name)} on "  # one comment line each
              f"{printable(', '.join(Path(d).name for d in args.data))}\n"
              f"# ({len(meas)} rows): training RMSE {rep['training']['rmse_mm']:.3f} mm, aligned "
              f"{rep['training']['rmse_aligned_mm']:.3f} mm; parameters and uncertainty in fit.json.\n")
    write_atomic(out / "fitted.toml", lambda tmp: Path(tmp).write_text(header + tomli_w.dumps(res["scene"])))
    write_predictions(out / "predictions.csv", meas, res["prediction"])
    if args.residual:
        from tdcr_warp.apps.residual import fit_residual

        pr = res["prediction"]
        ok = pr["converged"]
        correction = fit_residual(meas.servo_mm[ok], -pr["error_mm"][ok])
        write_atomic(out / "residual.npz", correction.save)
    write_json(out / "fit.json", rep | {"scene": str(args.scene), "data": [str(d) for d in args.data],
                                        "settings": settings(scene, args.device or "default")})
    out.commit()  # fitted.toml, then fit.json last
    t = rep["training"]
    print(f"fit in {rep['wall_s']:.0f} s, {rep['iterations']} iterations: training RMSE {t['rmse_mm']:.3f} mm "
          f"({t['rmse_percent_of_length']:.2f}% of the length), aligned {t['rmse_aligned_mm']:.3f} mm")
    for name, v in rep["parameters"].items():
        lost = name in rep["unidentifiable"]
        print(f"  {name:16s} {v['value']: .6g} " + ("NOT IDENTIFIABLE from these data (left at this value)" if lost
                                                    else f"+- {v['std']:.2g}"))
    if "weight" in rep:
        w = rep["weight"]
        print(f"  weight {w['per_length_N_per_m']:.4g} N/m ({w['total_N']:.4g} N in all) along "
              + (f"[{', '.join(f'{v:.3f}' for v in w['direction'])}] in the base frame; with g = 9.81 m/s^2 and this "
                 f"density it implies E = {w['implied_youngs_modulus_Pa']:.4g} Pa" if w["direction"] else "no direction"))
    print(f"wrote {out}/fitted.toml, fit.json, predictions.csv" + (", residual.npz" if args.residual else ""))
    if rep["unidentifiable"]:
        print(f"tdcr-warp fit: the data cannot determine {', '.join(rep['unidentifiable'])} (more rows or other "
              "motions, or a coarser --detail); the fit is flagged (exit 1)", flush=True)
        return 1
    return 0


def _print_iteration(h: dict) -> None:
    """The progress line of one Levenberg-Marquardt iteration."""
    print(f"  iteration {h['iteration']}: RMSE {h['rmse_mm']:.3f} mm{'' if h['accepted'] else ' (no step lowered it)'}",
          flush=True)
