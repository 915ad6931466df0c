"""What sensitivities cost and buy, in the same run, medians over interleaved repeats.

1. Jacobian outputs vs a plain solve on the report's robot (four straight tendons, gravity,
   coupled Cosserat, RK4, N = 40, random tensions in [0, 4] N): a solve with the tension
   Jacobians and the tip compliance (the issue's goal: <= 2x), with the stability check, and
   both under displacement control. Also the Jacobian's float32 error against float64.
2. Inverse kinematics at B = 4096 (N = 20): targets are the static tips of random tensions;
   IK solves per second and the share reached to 1e-9 m.
3. The tip controller on the gain-grid job (examples/gain_grid.toml, its first rods): the
   analytic Jacobian (one solve with sensitivities per model refresh) against the former
   forward differences of K + 1 full solves (kept here as the peer), wall time and the change
   in the closed-loop metrics.
4. With --cold: the start-up of a solve with sensitivities in a fresh process, with an empty
   kernel cache (compiling) and again with the filled one (loading).

    python experiments/bench_sensitivity.py [--repeats 5] [--cold] [--smoke] [--out results/bench_sensitivity.json]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import ROOT, metadata, write_report  # noqa: E402

import tdcr_warp as tw  # noqa: E402
import tdcr_warp.apps.jobs as jobs  # noqa: E402
from tdcr_warp.apps.chunk import apply_rows  # noqa: E402
from tdcr_warp.apps.control import TipController  # noqa: E402
from tdcr_warp.apps.ik import solve_ik  # noqa: E402
from tdcr_warp.apps.sweep import SweepSpec, make_samples  # noqa: E402
from tdcr_warp.io.scene import scene_from_dict  # noqa: E402
from tdcr_warp.physics.statics import reference_lengths, solve_static  # noqa: E402

OFFSETS = [(0.01, 0.0), (0.0, 0.01), (-0.01, 0.0), (0.0, -0.01)]


def robot(**tendon) -> tw.Robot:
    return tw.Robot(density=7800.0, gravity=(0, 0, -9.81),
                    tendons=[tw.Tendon(offset=o, compliance=2.7e-5, **tendon) for o in OFFSETS])


class DifferencesController(TipController):
    """The former tip controller: J by forward differences of K + 1 full static solves (h = 10 mN)."""

    def _linearise(self, tau):
        h = 1e-2
        opts = self.static_opts.__class__(**{**self.static_opts.__dict__, "sensitivities": False})
        base = solve_static(self.model_robot, tau, options=opts, device=self.sim.dev, initial=self._static)
        J = np.zeros((len(tau), 3, tau.shape[1]))
        for k in range(tau.shape[1]):
            dt = tau.copy()
            dt[:, k] += h
            J[:, :, k] = (solve_static(self.model_robot, dt, options=opts, device=self.sim.dev,
                                       initial=base).tip_position - base.tip_position) / h
        self._static, self._J, self._p0, self._u_lin = base, J, base.tip_position, tau.copy()


def timed(cases: dict, repeats: int) -> dict:
    times = {k: [] for k in cases}
    for _ in range(repeats):
        for k, f in cases.items():
            t = time.perf_counter()
            f()
            times[k].append(time.perf_counter() - t)
    return {k: statistics.median(v) for k, v in times.items()}


def jacobian_costs(rods: int, nodes: int, repeats: int) -> dict:
    rng = np.random.default_rng(0)
    tau = rng.uniform(0.0, 4.0, (rods, 4)) * (rng.random((rods, 4)) < 0.5)
    plain, disp = robot(), robot(control="displacement")
    q = reference_lengths(disp, nodes=nodes) - solve_static(plain, tau, nodes=nodes, tendon_states=True).tendon_free_length
    cases = {"plain": lambda: solve_static(plain, tau, nodes=nodes),
             "jacobians": lambda: solve_static(plain, tau, nodes=nodes, sensitivities=True),
             "jacobians+stability": lambda: solve_static(plain, tau, nodes=nodes, sensitivities=True,
                                                         stability="check"),
             "displacement_plain": lambda: solve_static(disp, displacements=q, nodes=nodes),
             "displacement_jacobians": lambda: solve_static(disp, displacements=q, nodes=nodes, sensitivities=True)}
    sols = {k: f() for k, f in cases.items()}  # warm-up: kernels compiled or loaded
    med = timed(cases, repeats)
    base = {k: "displacement_plain" if k.startswith("displacement") else "plain" for k in cases}
    f32 = solve_static(plain, tau, nodes=nodes, sensitivities=True, precision="float32")
    J64, J32 = sols["jacobians"].tip_jacobian[:, :3], f32.tip_jacobian[:, :3]
    f32_err = float(np.median(np.linalg.norm(J32 - J64, axis=(1, 2)) / np.linalg.norm(J64, axis=(1, 2))))
    out = {k: {"median_s": med[k], "ratio": med[k] / med[base[k]],
               "integrations_per_rod": float(np.mean(sols[k].integrations))} for k in cases}
    out["float32_jacobian_relative_error_median"] = f32_err
    for k, v in out.items():
        if isinstance(v, dict):
            print(f"  {k:24s} {v['median_s'] * 1e3:8.1f} ms / {rods} rods  {v['ratio']:.2f}x  "
                  f"(solve integrations per rod {v['integrations_per_rod']:.1f})")
    print(f"  float32 tension Jacobian: median relative error {f32_err:.1e} against float64")
    return out


def ik_rate(rods: int, nodes: int) -> dict:
    rng = np.random.default_rng(1)
    rb = robot()
    tau = rng.uniform(0.0, 4.0, (rods, 4)) * (rng.random((rods, 4)) < 0.6)
    tips = solve_static(rb, tau, nodes=nodes, tol=1e-13).tip_position
    solve_ik(rb, tips[:8], tension_max=8.0, nodes=nodes)  # warm-up
    t = time.perf_counter()
    res = solve_ik(rb, tips, tension_max=8.0, nodes=nodes)
    wall = time.perf_counter() - t
    out = {"rods": rods, "nodes": nodes, "wall_s": wall, "solves_per_s": rods / wall,
           "reached": float(res.success.mean()), "max_error_reached_m": float(res.position_error[res.success].max()),
           "iterations_median": float(np.median(res.iterations)), "reasons": sorted(set(res.reason))}
    print(f"  IK of {rods} targets (N = {nodes}): {wall:.2f} s, {rods / wall:,.0f} per s, reached "
          f"{100 * out['reached']:.1f}% (max error {out['max_error_reached_m']:.1e} m), median "
          f"{out['iterations_median']:.0f} iterations")
    return out


def controller_speedup(rods: int, steps: int | None) -> dict:
    data = tomllib.loads((ROOT / "examples" / "gain_grid.toml").read_text())
    spec = SweepSpec(data)
    rows = {k: v[:rods] for k, v in make_samples(spec).items()}
    scene = scene_from_dict(apply_rows(data, rows))
    if steps is not None:
        data2 = apply_rows(data, rows)
        data2["dynamics"]["steps"] = steps
        scene = scene_from_dict(data2)
    runs = {}
    for name, cls in (("analytic", TipController), ("differences", DifferencesController)):
        jobs.TipController = cls
        try:
            jobs.control_job(scene)  # warm-up
            t = time.perf_counter()
            res = jobs.control_job(scene)
            runs[name] = (time.perf_counter() - t, res)
        finally:
            jobs.TipController = TipController
    (ta, ra), (td, rd) = runs["analytic"], runs["differences"]
    diff = float(np.abs(ra["final_error"] - rd["final_error"]).max())
    out = {"rods": rods, "steps": scene.dynamics.steps, "analytic_s": ta, "differences_s": td, "speedup": td / ta,
           "max_final_error_change_m": diff,
           "final_error_median_m": {"analytic": float(np.median(ra["final_error"])),
                                    "differences": float(np.median(rd["final_error"]))}}
    print(f"  gain-grid closed loops ({rods} rods x {out['steps']} steps): analytic {ta:.2f} s, differences "
          f"{td:.2f} s, speed-up {td / ta:.2f}x; final errors change by at most {diff:.1e} m")
    return out


def cold_start() -> dict:
    code = ("import time; t = time.perf_counter(); import tdcr_warp as tw; "
            "s = tw.solve_static(tw.Robot(tendons=[tw.Tendon(offset=(0.01, 0))]), [[1.0]], nodes=20, "
            "sensitivities=True, stability='check'); print(time.perf_counter() - t)")
    out = {}
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, WARP_CACHE_PATH=cache)
        for name in ("cold", "warm"):
            r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
            out[name + "_s"] = float(r.stdout.strip().splitlines()[-1])
    print(f"  start-up with sensitivities and stability: cold {out['cold_s']:.1f} s (compiling), warm "
          f"{out['warm_s']:.2f} s")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rods", type=int, default=256)
    ap.add_argument("--nodes", type=int, default=40)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--ik-rods", type=int, default=4096)
    ap.add_argument("--control-rods", type=int, default=16)
    ap.add_argument("--cold", action="store_true", help="also time a fresh process with an empty kernel cache")
    ap.add_argument("--smoke", action="store_true", help="tiny sizes (for the test suite)")
    ap.add_argument("--out", default=str(ROOT / "results" / "bench_sensitivity.json"))
    args = ap.parse_args(argv)
    steps = None
    if args.smoke:
        args.rods, args.repeats, args.nodes, args.ik_rods, args.control_rods, steps = 8, 1, 10, 8, 2, 10
    print("Jacobian outputs vs a plain solve:")
    report = {"meta": metadata("cpu", command=" ".join(sys.argv)), "jacobians": jacobian_costs(args.rods, args.nodes,
                                                                                                args.repeats)}
    print("inverse kinematics:")
    report["ik"] = ik_rate(args.ik_rods, 20)
    print("tip controller:")
    report["controller"] = controller_speedup(args.control_rods, steps)
    if args.cold:
        report["startup"] = cold_start()
    write_report(args.out, report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
