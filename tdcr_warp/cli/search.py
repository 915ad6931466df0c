"""``tdcr-warp search SCENE.toml``: CMA-ES over the [search.ranges] control gains, a batch of
closed loops a generation (tdcr_warp.apps.gainsearch); with --grid beside the best run of a
finished gain-grid sweep; results.json and search.png."""

from __future__ import annotations

import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from tdcr_warp.cli.common import (
    OutputRun,
    add_command,
    add_log_arguments,
    add_solver_arguments,
    apply_overrides,
    overridden_source,
    positive_int,
    settings,
    write_json,
)
from tdcr_warp.core.progress import Progress
from tdcr_warp.model.robot import InputError

OBJECTIVE_NOTE = ("settled: settling time + (dt/2) c/(c + 1e-3 N) (c: chatter); outside the 0.5 mm band at the end: "
                  "duration + dt + e/(e + 5e-4 m) (e: final error); a failed step: duration + dt + 1; lower is "
                  "better, in the gain grid's order (tdcr_warp.apps.gainsearch)")


def register(subparsers) -> None:
    p = add_command(subparsers, "search", "CMA-ES over the [search.ranges] control gains, a batch of closed loops a "
                                          "generation", run)
    add_solver_arguments(p)
    add_log_arguments(p)
    p.add_argument("--budget", type=positive_int, help="closed loops to spend (default [search].budget)")
    p.add_argument("--grid", help="a finished gain-grid sweep folder over the same gains: its best run "
                                  "beside the search's (results.json, search.png)")


def run(args) -> int:
    """CMA-ES over the [search] gains, each generation one batch of closed loops
    (tdcr_warp.apps.gainsearch); with --grid beside the best of a finished gain-grid sweep."""
    from tdcr_warp.io.scene import load_scene, scene_from_dict

    base = apply_overrides(load_scene(args.scene), args, dynamic=True)
    if base.search is None or base.dynamics is None:
        raise InputError(f"{args.scene}: search needs [dynamics], [control] and [search] tables")
    scene = replace(scene_from_dict(overridden_source(base, args)), text=base.text)
    opts = scene.search | ({} if args.budget is None else {"budget": args.budget})
    spec = scene.dynamics
    duration = spec.steps * spec.dt
    grid = None if args.grid is None else _grid_reference(args.grid, list(opts["ranges"]), spec.dt, duration)
    with OutputRun(args, Path("out") / f"{Path(args.scene).stem}_search", ("results.json", "search.png")) as out:
        return _run(args, scene, opts, grid, out)


def _run(args, scene, opts: dict, grid: dict | None, out: OutputRun) -> int:
    """Search, write the files into ``out`` and commit them; the exit status."""
    from tdcr_warp.apps.gainsearch import search_gains
    from tdcr_warp.io.plotting import plot_search

    spec = scene.dynamics
    duration = spec.steps * spec.dt
    t0 = time.perf_counter()
    res = _search(search_gains, replace(scene, search=opts), args)
    wall = time.perf_counter() - t0
    failed = int((~res.candidates["ok"]).sum())
    loops_at = np.array([h["closed_loops"] for h in res.history])[res.candidates["generation"] - 1]
    plot_search(res.history, (loops_at, res.candidates["objective"]),
                None if grid is None else (grid["best"]["objective"], grid["closed_loops"]), duration + spec.dt,
                out / "search.png")
    results = {
        "scene": str(args.scene), "settings": settings(scene, args.device or "default")
        | {"dt": spec.dt, "alpha": spec.alpha, "steps": spec.steps},
        "gains": list(opts["ranges"]), "ranges": {g: list(r) for g, r in opts["ranges"].items()},
        "budget": opts["budget"], "population": res.population, "seed": opts["seed"], "sigma": opts["sigma"],
        "closed_loops": res.closed_loops, "failed_loops": failed, "generations": res.generations,
        "restarts": res.restarts, "wall_time_s": wall,
        "best": {"gains": res.gains, "objective": res.objective, **res.metrics}, "history": res.history,
        "objective_note": OBJECTIVE_NOTE,
    }
    if grid is not None:
        results["grid"] = grid | {"search_at_least_as_good": res.objective <= grid["best"]["objective"]}
    write_json(out / "results.json", results)
    out.commit()
    _report(res, wall, failed, results.get("grid"))
    print(f"wrote {out}/results.json, search.png")
    return 0


def _search(search_gains, scene, args):
    """search_gains(scene) with, unless --quiet, a progress bar in closed loops."""
    bar = None if args.quiet else Progress(scene.search["budget"], 1, rate_unit="loops/s")
    done = {"loops": 0, "failed": 0, "generations": 0}

    def step(i: int, n: int) -> None:
        bar.update(done["loops"], done["failed"], f" (generation {done['generations'] + 1}: step {i}/{n})")

    def generation(res) -> None:
        done.update(loops=res.closed_loops, failed=int((~res.candidates["ok"]).sum()), generations=res.generations)
        bar.update(res.closed_loops, done["failed"], f" (generation {res.generations}, best {res.objective:.4f})")

    try:
        return search_gains(scene, device=args.device, progress=step if bar else None,
                            on_generation=generation if bar else None)
    finally:
        if bar:
            bar.close()


def _settle(t) -> str:
    return f"{t:.3f} s" if t is not None and np.isfinite(t) else "never"


def _report(res, wall: float, failed: int, grid: dict | None) -> None:
    """The search's lines: its cost, its best gains and (--grid) the grid's best beside them."""
    m = res.metrics
    print(f"search: {res.closed_loops:,} closed loops in {res.generations} generations ({res.restarts} restarts), "
          f"{wall:.1f} s, {failed} failed")
    print(f"best gains {res.gains}: settling {_settle(m['settling_time'])}, final error "
          f"{m['final_error'] * 1e3:.3f} mm, chatter {m['chatter']:.2e} N")
    if grid is not None:
        g = grid["best"]
        verdict = "at least as good" if grid["search_at_least_as_good"] else "worse"
        print(f"grid ({grid['closed_loops']:,} closed loops): best gains {g['gains']}: settling "
              f"{_settle(g['settling_time'])}, chatter {g['chatter']:.2e} N; the search is {verdict}")


def _grid_reference(path: str, gains: list[str], dt: float, duration: float) -> dict:
    """The best run of the finished gain-grid sweep in ``path`` (its summary.json), with the
    search's objective of it (tdcr_warp.apps.gainsearch.gain_objective): ``search --grid``."""
    from tdcr_warp.apps.gainsearch import gain_objective
    from tdcr_warp.io.store import read_manifest

    out = Path(path)
    man = read_manifest(out)
    if man is None or man.get("job") != "gain-grid" or man.get("state") != "complete":
        raise InputError(f"--grid {path!r}: not a finished gain-grid sweep (tdcr-warp gain-grid SCENE --out {path})")
    if sorted(man["fields"]) != sorted(gains):
        raise InputError(f"--grid {path!r}: its grid is over {man['fields']}, the search over {gains}")
    try:
        summary = json.loads((out / "summary.json").read_text())
    except (OSError, ValueError) as e:
        raise InputError(f"--grid {path!r}: cannot read its summary.json: {e}") from None
    best = summary["best"]
    settle, error = (float("inf") if best[k] is None else best[k] for k in ("settling_time", "final_error"))
    f = gain_objective(best["final_error"] is not None, settle, best["chatter"], error, dt=dt, duration=duration)
    return {"path": str(out), "closed_loops": summary["rods"], "wall_time_s": summary["wall_time_s"],
            "best": best | {"objective": float(f)}}
