"""One timed measurement of experiments/bench_ab.py, in the Python (and tdcr_warp install) that runs it.

    python _ab_worker.py MEASUREMENT JSON_ARGS

Run it with a working directory that holds no tdcr_warp folder, so that the installed package is the
one imported. It warms up (kernel compilation, first call) before timing and prints one line
``AB_RESULT {"metrics": {...}, "info": {...}}`` last on stdout; the info holds the path of the
imported package and a hash of its sources. The robot is the report's
(experiments/bench_static.py, experiments/bench_dynamics.py); only the public API is used.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import tdcr_warp.kernels

import tdcr_warp as tw

MARKER = "AB_RESULT "
OFFSETS = [(0.01, 0.0), (0.0, 0.01), (-0.01, 0.0), (0.0, -0.01)]
ROBOT = dict(length=0.5, youngs_modulus=190e9, poisson_ratio=0.3, radius=1e-3, density=17189.0,
             gravity=(0.0, 0.0, -9.81))
DAMPING = dict(damping_bending=(0.008, 0.008, 0.008), drag=(0.01, 0.01, 0.01))
DT, ALPHA = 0.005, -0.2


def robot(dynamic: bool = False):
    return tw.Robot(tendons=[tw.Tendon(offset=o) for o in OFFSETS], **ROBOT, **(DAMPING if dynamic else {}))


def static1(nodes: int, calls: int, warmup: int):
    """One rod, the same Robot object, solve_static called repeatedly: median ms per call, with a
    new random tension row each call and with the same row each call (the two calls alternated)."""
    rob = robot()
    tau = np.random.default_rng(0).uniform(0.0, 3.0, (calls + warmup, 1, 4))
    for row in tau[:warmup]:
        tw.solve_static(rob, row, nodes=nodes)
    times = {"static1_random": [], "static1_same": []}
    for row in tau[warmup:]:
        for key, tensions in (("static1_random", row), ("static1_same", tau[0])):
            t0 = time.perf_counter()
            tw.solve_static(rob, tensions, nodes=nodes)
            times[key].append(time.perf_counter() - t0)
    return {key: 1e3 * float(np.median(v)) for key, v in times.items()}, {}


def static_batch(batch: int, nodes: int, inner: int):
    """B rods, random tensions, default tol, on 1 and 2 threads (alternated, median of `inner`)."""
    rob = robot()
    tau = np.random.default_rng(1).uniform(0.0, 3.0, (batch, 4))
    tw.solve_static(rob, tau, nodes=nodes, threads=2)
    times = {1: [], 2: []}
    for _ in range(inner):
        for threads in times:
            t0 = time.perf_counter()
            sol = tw.solve_static(rob, tau, nodes=nodes, threads=threads)
            times[threads].append(time.perf_counter() - t0)
    rate = {t: batch / float(np.median(v)) for t, v in times.items()}
    return ({"static_b_t1": rate[1], "static_b_t2": rate[2], "static_b_t2_over_t1": rate[2] / rate[1]},
            {"converged": float(sol.converged.mean()), "iterations_mean": float(sol.iterations.mean())})


def sens_batch(batch: int, nodes: int, inner: int):
    """B rods with their sensitivities (tip, tension and slack Jacobians), random commands: rods/s
    under tension control (tensions in [0, 3] N) and under displacement control (elastic wires at
    1 N of pretension, displacements in [-1, 1.5] mm), alternated, median of `inner`."""
    rng = np.random.default_rng(2)
    disp = tw.Robot(tendons=[tw.Tendon(offset=o, control="displacement", pretension=1.0, compliance=2.7e-5)
                             for o in OFFSETS], **ROBOT)
    cases = {"sens_b_tension": (robot(), dict(tensions=rng.uniform(0.0, 3.0, (batch, 4)))),
             "sens_b_displacement": (disp, dict(tensions=np.zeros((batch, 4)),
                                                displacements=rng.uniform(-1e-3, 1.5e-3, (batch, 4))))}
    for rob, kw in cases.values():
        tw.solve_static(rob, nodes=nodes, sensitivities=True, **{k: v[:2] for k, v in kw.items()})
    times = {k: [] for k in cases}
    for _ in range(inner):
        for key, (rob, kw) in cases.items():
            t0 = time.perf_counter()
            sol = tw.solve_static(rob, nodes=nodes, sensitivities=True, **kw)
            times[key].append(time.perf_counter() - t0)
    return {k: batch / float(np.median(v)) for k, v in times.items()}, {"converged": float(sol.converged.mean())}


def dyn1(nodes: int, warmup: int, steps: int, tension: list[float]):
    """One rod from rest at zero tension, `warmup` steps under `tension`, then `steps` more timed:
    the real-time factor (simulated seconds per wall second)."""
    sim = tw.Simulator(robot(dynamic=True), np.zeros((1, 4)), dt=DT, alpha=ALPHA, nodes=nodes)
    row = np.array([tension], dtype=float)
    for _ in range(warmup):
        sim.step(row)
    t0 = time.perf_counter()
    for _ in range(steps):
        res = sim.step(row)
    wall = time.perf_counter() - t0
    return {"dyn1_rtf": steps * DT / wall}, {"converged": bool(np.all(res.converged))}


def dyn_batch(batch: int, nodes: int, steps: int):
    """B rods, experiments/bench_dynamics.py's scenario and schedule: rod-steps/s of simulate()."""
    rng = np.random.default_rng(0)
    sched = np.zeros((batch, steps, 4))
    sched[:, 4:, 0] = rng.uniform(0.5, 3.0, batch)[:, None]
    sched[:, 4:, 1] = rng.uniform(0.0, 1.0, batch)[:, None]
    rob = robot(dynamic=True)
    warm = tw.Simulator(rob, np.zeros((2, 4)), dt=DT, alpha=ALPHA, nodes=nodes)
    warm.simulate(sched[:2, :2], 2)
    sim = tw.Simulator(rob, np.zeros((batch, 4)), dt=DT, alpha=ALPHA, nodes=nodes)
    t0 = time.perf_counter()
    tr = sim.simulate(sched, steps)
    wall = time.perf_counter() - t0
    return ({"dyn_b": batch * steps / wall},
            {"failed": int((tr.failed_step >= 0).sum()), "iterations_mean": float(tr.iterations.mean())})


def startup(scene: str):
    """Wall time of `tdcr-warp static SCENE` (this venv's console script) with a fresh kernel cache
    (cold), again with that cache (warm), and of `python -c "import tdcr_warp"`."""
    cli = Path(sys.executable).parent / "tdcr-warp"

    def wall(cmd, env):
        t0 = time.perf_counter()
        out = subprocess.run(cmd, env=env, capture_output=True, text=True)
        t = time.perf_counter() - t0
        if out.returncode != 0:
            raise RuntimeError(f"{' '.join(map(str, cmd))} exited {out.returncode}: {out.stderr[-2000:]}")
        return t

    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, WARP_CACHE_PATH=str(Path(tmp) / "cache"))
        cold = wall([cli, "static", scene, "--out", Path(tmp) / "cold"], env)
        warm = wall([cli, "static", scene, "--out", Path(tmp) / "warm"], env)
        imp = wall([sys.executable, "-c", "import tdcr_warp"], env)
    return {"cli_cold": cold, "cli_warm": warm, "import": imp}, {}


MEASUREMENTS = {"static1": static1, "static_batch": static_batch, "sens_batch": sens_batch, "dyn1": dyn1,
                "dyn_batch": dyn_batch, "startup": startup}


def source_digest() -> str:
    """A hash of the imported package's Python sources (tdcr_warp and its kernels)."""
    h = hashlib.sha256()
    for pkg in (tw, tdcr_warp.kernels):
        for f in sorted(Path(pkg.__file__).parent.glob("*.py")):
            h.update(f.name.encode() + f.read_bytes())
    return h.hexdigest()[:12]


def main(argv: list[str]) -> int:
    name, kwargs = argv[0], json.loads(argv[1])
    digest = source_digest()
    metrics, info = MEASUREMENTS[name](**kwargs)
    info.update(tdcr_warp=tw.__file__, sources=digest)
    print(MARKER + json.dumps({"metrics": metrics, "info": info}), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
