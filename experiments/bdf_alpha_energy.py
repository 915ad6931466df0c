"""The mechanical energy of undamped free motion under BDF-alpha, over the allowed alpha range.

Scenario: a steel wire (L = 0.5 m, radius 1 mm, 7800 kg/m^3, no damping, no drag, no tendons),
clamped along +z, gravity along -x, held bent by a tip force and released at t = 0 (``plane``:
F = (3, 0, 0) N, a planar swing; ``spatial``: F = (3, 1.5, 0) N, out of plane). Nothing does
work on it after the release, so its energy H (kinetic + elastic + gravity's potential,
``Simulator.energy``) is conserved by the motion; BDF-alpha's own damping may only take some
away. Per alpha, dt and start: the largest relative gain max (H - H1) / M1 (H1, M1: the energy
and its kinetic plus elastic part after the first step, in which the tendon start's pull is let
go), the gain at step 100, the first failed step and the first
step the energy monitor flags (status ENERGY), with the monitor off (``energy_tolerance = 0``)
to see the motion itself, and then on.

Resolution map: the "tendon" start at N = 5..40 and dt = 1 and 4 ms, 600 steps: the gain against
h / l_b, the grid's interval over the bending layer l_b = (EI / (rho A c0^2))^(1/4) of one step's
problem in s. Cost: experiments/bench_dynamics.py's scenario with the monitor off and on.

    python experiments/bdf_alpha_energy.py [--smoke] [--steps 1500] [--part all|cost] [--repeats 5]
                                           [--out results/bdf_alpha_energy.json]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "experiments")]

from _common import interleaved_times, metadata, write_report  # noqa: E402

import tdcr_warp as tw  # noqa: E402
from tdcr_warp.kernels import layout  # noqa: E402
from tdcr_warp.physics.dynamics import bending_layer_ratio  # noqa: E402

WIRE = dict(length=0.5, youngs_modulus=190e9, poisson_ratio=0.3, radius=1e-3, density=7800.0, gravity=(-9.81, 0.0, 0.0))
STARTS = {"plane": (3.0, 0.0, 0.0), "spatial": (3.0, 1.5, 0.0), "tendon": None}
OFFSETS = [(0.01, 0.0), (0.0, 0.01), (-0.01, 0.0), (0.0, -0.01)]
PULL = 3.0  # the "tendon" start: this tension [N] on tendon 1 of 4 (1 cm off the axis), released at t = 0
ALPHAS = (0.0, -0.1, -0.2, -0.3, -0.4, -0.45, -0.47, -0.49)


def release(start: str, dt: float, alpha: float, nodes: int, **overrides) -> tuple[tw.Simulator, np.ndarray]:
    """The wire at rest in its static shape under the start's tip force (or tendon pull), free from
    then on: the simulator and the command of its steps (no tension)."""
    if STARTS[start] is None:
        rob = tw.Robot(tendons=[tw.Tendon(offset=o) for o in OFFSETS], **WIRE)
        sim = tw.Simulator(rob, [[PULL, 0.0, 0.0, 0.0]], dt=dt, alpha=alpha, nodes=nodes, **overrides)
        return sim, np.zeros((1, 4))
    held = tw.solve_static(tw.Robot(tip_force=STARTS[start], **WIRE), np.zeros((1, 0)), nodes=nodes)
    return tw.Simulator(tw.Robot(**WIRE), np.zeros((1, 0)), dt=dt, alpha=alpha, nodes=nodes, initial=held,
                        **overrides), np.zeros((1, 0))


def run(start: str, dt: float, alpha: float, steps: int, nodes: int, tolerance: float | None) -> dict:
    """One release: the energy per step relative to M1 and what the steps report."""
    sim, free = release(start, dt, alpha, nodes, **({} if tolerance is None else {"energy_tolerance": tolerance}))
    gain, flagged, t0 = [0.0], -1, time.perf_counter()
    for i in range(steps):
        r = sim.step(free)
        if i == 0:  # the reference: after the release (the tendon start's pull did work until then)
            e0 = sim.energy()
            h0, m0 = e0["energy"][0], e0["motion"][0]
        if r.status[0] & layout.ENERGY and flagged < 0:
            flagged = i
        if not r.converged[0]:
            break
        gain.append((sim.energy()["energy"][0] - h0) / m0)
    gain = np.array(gain)
    ratio = float(bending_layer_ratio(tw.Robot(**WIRE), WIRE["length"] / nodes, dt, alpha)[0])
    return {"start": start, "dt": dt, "alpha": alpha, "nodes": nodes, "h_over_lb": ratio,
            "steps": steps, "energy_tolerance": tolerance,
            "M1_J": float(m0), "max_gain": float(gain.max()),
            "gain_at_100": float(gain[100]) if len(gain) > 100 else None,
            "final_gain": float(gain[-1]), "failed_step": int(sim.failed_step[0]), "flagged_step": flagged,
            "max_step_gain": float(np.diff(gain).max()) if len(gain) > 1 else 0.0,
            "wall_s": time.perf_counter() - t0}


def sweep(cases, alphas, steps: int) -> list[dict]:
    """Every (start, dt, nodes) of ``cases`` at every alpha, the monitor off and then on."""
    rows = []
    for tolerance in (0.0, None):  # the monitor off (the motion itself), then at its default
        for start, dt, nodes in cases:
            for alpha in alphas:
                rows.append(r := run(start, dt, alpha, steps, nodes, tolerance))
                print(f"{start:8s} dt {dt:g} N {nodes:3d} h/lb {r['h_over_lb']:.2f} alpha {alpha:+.2f} monitor "
                      f"{'off' if tolerance == 0 else 'on ':3s}: max gain {r['max_gain']:+.2e}, at step 100 "
                      f"{r['gain_at_100'] or 0:+.2e}, failed at {r['failed_step']}, flagged at {r['flagged_step']} "
                      f"({r['wall_s']:.0f} s)", flush=True)
    return rows


def monitor_cost(repeats: int, smoke: bool) -> dict:
    """The stepping time of experiments/bench_dynamics.py's scenario (the report's damped run, a
    random held tension from step 5, N = 50) with the monitor off and on, interleaved: medians [s]
    of the static start and the steps."""
    import bench_dynamics as bd

    cases, rng = {}, np.random.default_rng(0)
    for B, steps in ((1, 100), (256, 20)) if not smoke else ((1, 10),):
        sched = bd.schedule(B, steps, rng)
        rob = tw.Robot(tendons=[tw.Tendon(offset=o) for o in bd.OFFSETS], **bd.ROD)
        for tol in (0.0, None):
            over = {} if tol is None else {"energy_tolerance": tol}

            def go(B=B, steps=steps, sched=sched, over=over):
                sim = tw.Simulator(rob, np.zeros((B, 4)), dt=bd.DT, alpha=bd.ALPHA, nodes=50, **over)
                assert sim.simulate(sched, steps).converged.all()

            cases[f"B={B} monitor {'off' if over else 'on'}"] = go
    for f in cases.values():  # compile and warm outside the timing
        f()
    times, medians = interleaved_times(cases, repeats)
    for name, t in medians.items():
        print(f"{name}: median {t:.3f} s over {repeats} runs", flush=True)
    return {"times_s": times, "medians_s": medians}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--smoke", action="store_true", help="two alphas, 120 steps, one case of each part")
    ap.add_argument("--steps", type=int, default=1500, help="steps of the swings (the resolution map: 600)")
    ap.add_argument("--repeats", type=int, default=5, help="of the monitor's cost")
    ap.add_argument("--part", choices=("all", "cost"), default="all", help="cost: only the monitor's cost")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "bdf_alpha_energy.json")
    a = ap.parse_args(argv)
    swings = [(start, dt, 20) for start in STARTS for dt in (1e-3, 5e-3)]
    grids = [("tendon", dt, n) for dt in (1e-3, 4e-3) for n in (5, 10, 20, 40)]
    alphas, steps, map_steps = ALPHAS, a.steps, 600
    if a.smoke:
        swings, grids, alphas, steps, map_steps = swings[:1], grids[:1], (0.0, -0.45), 120, 60
    report = {"meta": metadata("cpu", wire=WIRE, starts=STARTS, pull=PULL)}
    if a.part == "all":
        report |= {"swings": sweep(swings, alphas, steps), "resolution": sweep(grids, alphas, map_steps)}
    report["cost"] = monitor_cost(1 if a.smoke else a.repeats, a.smoke)
    write_report(a.out, report)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
