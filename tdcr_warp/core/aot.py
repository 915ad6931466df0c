"""Ahead-of-time CUDA builds of the package's kernels, on any machine (no GPU needed: Warp
carries NVRTC), to show that every kernel variant builds for a GPU and to ship cubins.

    python -m tdcr_warp.core.aot [--arch 90] [--out DIR] [--all] [--jobs N]

A variant is one (precision, integrator, tendon model, rod model, statics/dynamics, feature
set); each builds three Warp modules (fused driver, probe driver, evaluation) plus the
BDF-alpha history and energy monitor modules of its precision, the contact outputs' where it has obstacles, and
where it can be split into segments the segments' module and the banded Newton solve's. Without
--all a covering set is built: every value of every option at least once, the general kernel
(all features) and the leanest (none).
"""

from __future__ import annotations

import argparse
import itertools
import multiprocessing
import os
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import NamedTuple

from tdcr_warp.io.files import printable
from tdcr_warp.kernels.variants import ALL, INTEGRATORS, MODELS, RODS, Features

__all__ = ["Variant", "compile_variant", "covering_variants", "all_variants", "group", "main", "segmented"]

PRECISIONS = ("float64", "float32")
NONE = Features(gravity=False, point_loads=False, helix=False, drag=False, kinks=False)
TENDON_STATES = ((False, 0, 0), (True, 4, 2))  # (friction, tendons, displaced): none, or all of them
DISK_STATES = ((False, 16, 0), (False, 16, 2))  # the disk model: 4 tendons' states and holes, frictionless


class Variant(NamedTuple):
    precision: str
    integrator: str
    model: str
    rod: str
    dynamic: bool
    features: Features

    def __str__(self) -> str:
        feats = "+".join(n if on is True else f"{n}={on}" for n, on in self.features._asdict().items() if on) or \
            "no features"
        return (f"{self.precision} {self.integrator} {self.model} {self.rod} "
                f"{'dynamics' if self.dynamic else 'statics'} [{feats}]")


def all_variants() -> list[Variant]:
    """Every variant the package can build (tendon states: statics only, each tendon count
    compiles like K = 4 with 2 displaced tendons; the disk model: statics with its states)."""
    return [Variant(prec, integ, model, rod, dyn, Features(*flags, *states))
            for prec, integ, model, rod, dyn in itertools.product(PRECISIONS, INTEGRATORS, MODELS, RODS, (False, True))
            if not (dyn and model == "disks")
            for flags in itertools.product((True, False), repeat=5)
            for states in (DISK_STATES if model == "disks" else TENDON_STATES if not dyn else TENDON_STATES[:1])]


def covering_variants() -> list[Variant]:
    """Every precision, integrator, tendon model, rod model, statics and dynamics, both extreme
    feature sets, and tendon states (friction, displacement unknowns) with either tendon model,
    each at least once, the disk model, and obstacles with a held tip in statics and dynamics (9
    variants; spline routes in the first with tendon states)."""
    states = dict(friction=True, tendons=4, displaced=2, spline=True)
    return [Variant("float64", "rk4", "coupled", "cosserat", False, ALL),
            Variant("float32", "midpoint", "point", "kirchhoff", True, ALL),
            Variant("float64", "euler", "coupled", "kirchhoff", True, NONE),
            Variant("float32", "rk4", "point", "cosserat", False, NONE),
            Variant("float64", "rk4", "coupled", "cosserat", False, ALL._replace(**states)),
            Variant("float32", "midpoint", "point", "kirchhoff", False, NONE._replace(**states)),
            Variant("float64", "rk4", "disks", "cosserat", False, ALL._replace(tendons=16, displaced=2)),
            Variant("float64", "rk4", "coupled", "cosserat", True, ALL._replace(contact=True, tip=3)),
            Variant("float32", "midpoint", "point", "kirchhoff", False, NONE._replace(contact=True, tip=1))]


def _modules(v: Variant):
    import warp as wp

    from tdcr_warp.kernels.banded import band_solve
    from tdcr_warp.kernels.contact import make_contact_kernel, make_interval_kernels
    from tdcr_warp.kernels.energy import make_energy_kernels
    from tdcr_warp.kernels.history import make_history_kernels
    from tdcr_warp.kernels.segments import make_segment_kernel
    from tdcr_warp.kernels.shooting import make_shooting_kernels

    dtype = wp.float64 if v.precision == "float64" else wp.float32
    k = make_shooting_kernels(dtype, v.integrator, v.model, v.dynamic, v.rod, v.features)
    mods = [k.solve.module, k.probe.module, k.evaluate.module]  # evaluate: dynamics, and the probes of sensitivities
    if v.dynamic:
        mods.append(make_history_kernels(dtype).end_step.module)
        mods.append(make_energy_kernels(dtype, v.features.helix, v.features.spline).energy.module)
    if v.features.contact:  # the contact outputs (one module for every precision and variant)
        make_interval_kernels(dtype, v.dynamic)  # the same module: built with it
        mods.append(make_contact_kernel(dtype, v.dynamic).module)
    if segmented(v) is not None:  # multiple shooting: its segments, and the banded Newton solve (one module)
        mods.append(make_segment_kernel(dtype, v.integrator, v.model, v.dynamic, v.rod, segmented(v)).module)
        mods.append(band_solve.module)
    return mods


def compile_variant(v: Variant, arch: int, out_dir: str) -> list[tuple[str, float, list[str]]]:
    """Build the variant's modules for sm_<arch> into out_dir: (module, seconds, files) each."""
    import warp as wp

    wp.init()
    done = []
    for m in _modules(v):
        t0 = time.perf_counter()
        paths = wp.compile_aot_module(m, arch=arch, module_dir=out_dir, use_ptx=False)
        done.append((m.name, time.perf_counter() - t0, [str(p) for p in paths]))
    return done


def segmented(v: Variant):
    """The features of the variant's multiple-shooting kernel (tdcr_warp/physics/segments.py), or
    None: dynamics splits rods without tendon states or a held tip, statics rods on obstacles (with
    obstacles, the scene without the held tip stands in for a held-tip variant)."""
    from tdcr_warp.kernels.segments import segmentable

    f = v.features
    if not (v.dynamic or f.contact):
        return None
    f = f._replace(tip=0) if f.contact else f
    return f if segmentable(v.model, f) else None


def group(module: str) -> str:
    """A built module's kind: fused, probes, evaluate, history, energy, contact, segments or banded."""
    return module.split("_")[2] if module.startswith("tdcr_warp_") else module.rsplit(".", 1)[-1]


def compile_all(variants: list[Variant], arch: int, out_dir: str, jobs: int, log=print) -> list:
    """compile_variant for each variant, ``jobs`` processes at a time (NVRTC is single-threaded)."""
    results = []
    # spawned, not forked: a forked worker would inherit every kernel its parent has built into
    # the shared modules (in the test suite, several times the covering set's)
    with ProcessPoolExecutor(max(1, jobs), mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = [(v, pool.submit(compile_variant, v, arch, out_dir)) for v in variants]
        for v, fut in futures:
            mods = fut.result()
            results.append((v, mods))
            log(f"  {v}: " + ", ".join(f"{group(name)} {sec:.0f} s" for name, sec, _ in mods))
    return results


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tdcr_warp.core.aot", description=__doc__.splitlines()[0])
    ap.add_argument("--arch", type=int, default=90, help="CUDA compute capability (90: H100/H200)")
    ap.add_argument("--out", help="directory for the cubins (default: a temporary one, removed)")
    ap.add_argument("--all", action="store_true", help=f"every variant ({len(all_variants())}), not the covering set")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="compiles at a time")
    args = ap.parse_args(argv)
    variants = all_variants() if args.all else covering_variants()
    print(f"building {len(variants)} kernel variant(s) for sm_{args.arch} ({args.jobs} at a time) ...", flush=True)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or tmp
        Path(out).mkdir(parents=True, exist_ok=True)
        results = compile_all(variants, args.arch, out, args.jobs)
        files = sum(len(f) for _, mods in results for _, _, f in mods)
    print(f"built {files} cubins in {time.perf_counter() - t0:.0f} s" + (f" into {printable(args.out)}" if args.out else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
