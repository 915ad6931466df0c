"""``tdcr-warp montecarlo|workspace|gain-grid SCENE.toml``: a [sweep] over the scene, run in
resumable chunks (tdcr_warp.apps.sweep); summary.json, results/ (Parquet), arrays.zarr with
--shapes, and the figures."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from tdcr_warp.cli.common import (
    add_command,
    add_log_arguments,
    add_solver_arguments,
    apply_overrides,
    number_type,
    output_folder,
    overridden_source,
    settings,
    write_json,
)
from tdcr_warp.io.files import printable
from tdcr_warp.model.robot import InputError

SWEEPS = (("montecarlo", "tip distribution (and control success) under [[uncertainty]]"),
          ("workspace", "tip cloud over a [sweep] of tensions"),
          ("gain-grid", "controller metrics over a [sweep.grid] of control gains"))


def register(subparsers) -> None:
    for name, helptext in SWEEPS:
        p = add_command(subparsers, name, helptext, run)
        add_solver_arguments(p)
        add_log_arguments(p)
        p.add_argument("--chunk", type=number_type(integer=True), help="rods per chunk (default [sweep].chunk)")
        p.add_argument("--resume", action="store_true", help="continue an interrupted sweep in --out")
        p.add_argument("--overwrite", action="store_true",
                       help="replace the results of another sweep in --out (removed before this one starts)")
        p.add_argument("--max-chunks", type=number_type(integer=True), help="stop after computing this many chunks")
        p.add_argument("--backend", choices=["local", "ray"], default="local",
                       help="local: in this process (default); ray: chunks as Ray tasks (pip install -e .[ray])")
        p.add_argument("--address", help="Ray cluster address (default: start a local Ray for the run)")
        p.add_argument("--workers", type=number_type(1, integer=True),
                       help="CPUs of the local Ray (default: all cores)")
        p.add_argument("--gpus-per-task", type=number_type(0),
                       help="GPUs per Ray task (default 1 with --device cuda..., else 0)")
        p.add_argument("--shapes", action="store_true", help="also save every rod's backbone positions")


def run(args) -> int:
    """montecarlo, workspace and gain-grid: a [sweep] over the scene, run in chunks."""
    from tdcr_warp.apps.jobs import SweepJob
    from tdcr_warp.apps.sweep import peak_memory_mb, run_sweep
    from tdcr_warp.io.scene import load_scene

    job_name = args.command
    scene = load_scene(args.scene)
    base = apply_overrides(scene, args, dynamic=job_name == "gain-grid" or (job_name == "montecarlo"
                                                                           and scene.control is not None))
    data = overridden_source(base, args)
    dev = args.device
    if job_name == "gain-grid" and (base.control is None or base.dynamics is None):
        raise InputError("gain-grid needs [dynamics] and [control] tables")
    if args.shapes and job_name == "gain-grid":
        raise InputError("--shapes: gain-grid returns metrics, not shapes (use montecarlo or workspace)")
    gpus = args.gpus_per_task
    if gpus is None:
        gpus = 1.0 if args.backend == "ray" and str(dev or "").startswith("cuda") else 0.0
    if args.backend == "ray" and gpus > 0:
        dev = "cuda:0"  # Ray makes the task's GPU the first visible one
    job = SweepJob(job_name, device=dev, nominal=data if job_name == "montecarlo" else None, shapes=args.shapes)
    out = output_folder(args, Path("out") / f"{Path(args.scene).stem}_{job_name}")
    shown = printable(out)
    try:
        swept = run_sweep(data, job, out, chunk=args.chunk, resume=args.resume, overwrite=args.overwrite,
                          progress=not args.quiet, max_chunks=args.max_chunks, job_name=job_name,
                          backend=args.backend, address=args.address, workers=args.workers, gpus_per_task=gpus,
                          meta={"shapes": args.shapes})
        if swept is None:
            print(f"stopped after {args.max_chunks} new chunk(s); rerun with --resume to finish ({shown})")
            return 1
        if not args.quiet:
            print("summarising the chunks ...", flush=True)
        summary = _summary(job_name, swept, base, data, dev, out)
        rate = swept.computed_rods / swept.wall_s if swept.computed_rods and swept.wall_s > 0 else None
        summary.update(scene=str(args.scene), wall_time_s=swept.wall_s, computed_rods=swept.computed_rods,
                       rods_per_s=rate, chunk=swept.store.chunk, peak_memory_mb=peak_memory_mb(),
                       settings=settings(base, dev or "default"))
        write_json(out / "summary.json", summary)  # last: its presence means the sweep is complete
    except KeyboardInterrupt:
        print(f"tdcr-warp: interrupted; the finished chunks are kept in {shown}: rerun with --resume to finish",
              file=sys.stderr)
        return 130
    done = (f"{swept.computed_rods:,} computed in {swept.wall_s:.1f} s ({rate:,.0f} rods/s)" if rate else
            "every chunk was already done: nothing computed")
    print(f"{job_name}: {swept.rods:,} rods, {done}, {swept.failed} failed, peak memory {peak_memory_mb():.0f} MB")
    if job_name == "gain-grid":
        best = summary["best"]
        print(f"best gains {best['gains']}: settling {best['settling_time']:.3f} s, final error "
              f"{best['final_error'] * 1e3:.3f} mm, chatter {best['chatter']:.2e} N")
    print(f"wrote {shown}/summary.json, results/ (Parquet){', arrays.zarr' if (out / 'arrays.zarr').exists() else ''}, "
          "figures")
    return 0


def _summary(job_name: str, swept, base, data: dict, device, out: Path) -> dict:
    """The job's summary of the finished chunks (tdcr_warp.apps.jobs), with the failures counted
    by reason; a Monte-Carlo summary also holds the linearised spread beside the sampled one."""
    from tdcr_warp.apps.jobs import (
        failure_counts,
        summarize_gain_grid,
        summarize_montecarlo,
        summarize_workspace,
    )
    from tdcr_warp.apps.sweep import SweepSpec
    from tdcr_warp.physics.statics import solve_static

    if job_name == "montecarlo":
        nominal = solve_static(base.robot, base.tensions, options=base.options, device=device).tip_position[0]
        summary = summarize_montecarlo(swept, nominal, out)
        summary["linearised"] = _linearised(data, device, summary)
    elif job_name == "workspace":
        summary = summarize_workspace(swept, base.robot, out)
    else:
        summary = summarize_gain_grid(swept, [name for name, _ in SweepSpec(data).grid], out)
    if swept.failed:
        summary["failure_reasons"] = failure_counts(swept)
    return summary


def _linearised(data: dict, device, summary: dict) -> dict:
    """The first-order tip spread of the Monte-Carlo scene (tdcr_warp.apps.uncertainty) beside the
    sampled one: per axis the standard deviations [m] and their ratio, or why it is not there."""
    from tdcr_warp.apps.uncertainty import linearised_spread

    try:
        lin = linearised_spread(data, device)
    except InputError as e:
        return {"available": False, "reason": str(e)}
    mc = np.sqrt(np.diag(summary["tip_covariance"])) if summary.get("tip_covariance") else None
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = None if mc is None else np.where(lin["tip_std"] > 0, mc / lin["tip_std"], np.nan)
    return {"available": True, "tip_std_m": lin["tip_std"].tolist(),
            "montecarlo_tip_std_m": None if mc is None else mc.tolist(),
            "montecarlo_over_linearised": None if ratio is None else [None if not np.isfinite(r) else float(r)
                                                                      for r in ratio],
            "contributions_m2": dict(zip(lin["parameters"], lin["contributions"].tolist())),
            "note": "first order: J Sigma J^T from one solve; the Monte-Carlo spread departs from it as the "
                    "scatter grows (docs/sensitivities.md)"}
