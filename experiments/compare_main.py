"""Answers before and after a change of the solver: run a fixed set of cases, save every output,
and compare a later run against the saved reference rod by rod.

    python experiments/compare_main.py save --out results/reference.npz [--device cpu] [--smoke]
    python experiments/compare_main.py compare --reference results/reference.npz [--tol 1e-12] [--tol32 T]
        [--out report.json]
    python experiments/compare_main.py --smoke [--out report.json]   # the two tiny cases: save, then compare

Run it with the interpreter whose tdcr_warp is to be measured, from a directory without a
tdcr_warp folder (the working directory would shadow an installed package).

Cases (statics, dynamics, closed-loop control; see CASES): every examples/*.toml solved as
``tdcr-warp static`` does; the report's robot with 64 random tension rows in [0, 3] N under each
solver option; helical routing; two sections with a point force, tip loads and precurvature;
per-rod parameters; a mixed batch with heavy rods that need load continuation; rods that fail
beside one that converges; a warm start; tendons by displacement with slack, with friction (slip
+1 and -1, a kink), a stick-slip pull-release sequence, routes through points and converging
routes without kink loads; the report's dynamic scene, a 16-rod batch of random tension steps,
alpha = 0 and -0.45, the point-load model, the lightly damped soft rod rescued by the damping
homotopy, rods flagged below the single-shooting dt limit, a displaced pair with friction; closed
loops on examples/our_control.toml, examples/seed_control.toml and a 3-rod batch. Batches hold at most 64
rods, so the CPU splits them the same way on every machine with 2 cores or more.

``save`` writes one .npz: "<case>/<field>" arrays, rod first (trajectories: rod, step, ...), plus
"__cases__" (JSON: name and description of each case) and "__meta__"
(JSON: tdcr_warp and Warp versions, where tdcr_warp was imported from, git sha, device).

``compare`` reruns the reference's cases and prints one line per case: the max |difference| of
positions [m] (shapes, tips, control targets), of forces [N] (internal force n, control tensions)
and of moments [N m] (internal moment m) over the rods converged in the reference; whether the
flags (converged, failed_step) are equal; how many rods changed their iteration count or status
bits (informational). A case passes when the flags are equal and every position is within --tol
(float32 cases: --tol32) [m]; forces, moments and tensions are reported beside (their natural
scales, EI/L^3 and EI/L^2, are those of the solver's stopping rule L |r| < tol).
Rods that did not converge in the reference are compared on their flags only. The worst rod of
each failing case is listed; a case that raises fails with its error. Exit status 1 if any case
fails, else 0.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
import warnings
from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "experiments")]

from _common import metadata, write_report  # noqa: E402

import tdcr_warp as tw  # noqa: E402
from tdcr_warp.apps.control import TipController, run_closed_loop, static_target  # noqa: E402
from tdcr_warp.io.scene import load_scene  # noqa: E402

EXAMPLES = ROOT / "examples"
SEED_ROBOT = dict(length=0.5, youngs_modulus=190e9, poisson_ratio=0.3, radius=1e-3, density=17189.0,
                  gravity=(0.0, 0.0, -9.81))
OFFSETS = [(0.01, 0.0), (0.0, 0.01), (-0.01, 0.0), (0.0, -0.01)]
SEED_DAMPING = dict(damping_bending=(0.008, 0.008, 0.008), drag=(0.01, 0.01, 0.01))
CONTROL_KEYS = ("method", "input_model", "gain_c", "gain_k", "epsilon", "phi", "tension_max", "model_every")

# field -> what it measures; "flag" must be equal, "count" is informational
KINDS = {"positions": "position", "tip_position": "position", "target": "position", "n": "force", "contact_force": "force",
         "tensions": "force", "m": "moment", "converged": "flag", "failed_step": "flag",
         "iterations": "count", "status": "count", "segments": "count"}
MEASURES = ("position", "force", "moment")


class Case(NamedTuple):  # not a dataclass: tests/test_experiments.py loads this file outside sys.modules
    name: str
    about: str
    run: Callable[[str], tuple[tw.Robot, dict[str, np.ndarray]]]  # device -> (robot, fields)


def seed_robot(**kw) -> tw.Robot:
    return tw.Robot(**(dict(SEED_ROBOT, tendons=[tw.Tendon(offset=o) for o in OFFSETS]) | kw))


def uniform(rows: int, cols: int, high: float = 3.0, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(0.0, high, (rows, cols))


def static_fields(sol) -> dict[str, np.ndarray]:
    return {"positions": sol.positions, "n": sol.n, "m": sol.m, "converged": sol.converged,
            "status": sol.status, "iterations": sol.iterations}


def rod_major(a) -> np.ndarray:
    """(T, B, ...) -> (B, T, ...)."""
    return np.moveaxis(np.asarray(a), 1, 0)


def trajectory_fields(tr) -> dict[str, np.ndarray]:
    return {"tip_position": rod_major(tr.tip_position), "positions": rod_major(tr.positions),
            "converged": rod_major(tr.converged), "iterations": rod_major(tr.iterations),
            "failed_step": tr.failed_step}


def control_fields(run) -> dict[str, np.ndarray]:
    return {"tip_position": rod_major(run.tip_position), "tensions": rod_major(run.tensions),
            "converged": rod_major(run.converged), "target": run.target}


# --- statics -------------------------------------------------------------------------------------

def scene_static(stem: str) -> Case:
    def run(device):
        scene = load_scene(EXAMPLES / f"{stem}.toml")
        command = scene.static_command() if hasattr(scene, "static_command") else {}  # (older versions: none)
        return scene.robot, static_fields(tw.solve_static(scene.robot, scene.tensions, options=scene.options,
                                                          device=device, **command))
    return Case(f"static/scene_{stem}", f"examples/{stem}.toml solved as `tdcr-warp static` does", run)


def report_static(label: str, **opts) -> Case:
    def run(device):
        rob = seed_robot()
        return rob, static_fields(tw.solve_static(rob, uniform(64, 4), device=device, **opts))
    return Case(f"static/report_{label}", f"report robot, 64 rows U[0, 3] N (seed 0), {opts}", run)


def helix_static(device):
    rob = seed_robot(tendons=[tw.Tendon(offset=(0.01, 0.0)),
                              tw.Tendon(routing="helix", helix_radius=0.008, turns=0.5, phase=0.3)])
    return rob, static_fields(tw.solve_static(rob, uniform(16, 2, seed=1), nodes=40, device=device))


def two_section_static(device):
    rob = seed_robot(tendons=[tw.Tendon(offset=(0.01, 0.0)), tw.Tendon(offset=(0.0, 0.01), length=0.25),
                              tw.Tendon(offset=(-0.01, 0.0), length=0.3)],
                     point_forces=[tw.PointForce(s=0.375, force=(0.02, -0.01, 0.0))],
                     precurvature=(0.4, -0.2, 0.1), tip_force=(0.01, 0.0, 0.0), tip_moment=(0.0, 0.0, 1e-3))
    return rob, static_fields(tw.solve_static(rob, uniform(16, 3, high=2.0, seed=2), nodes=30, device=device))


def per_rod_static(device):
    B = 32
    rng = np.random.default_rng(3)
    rob = seed_robot(youngs_modulus=np.linspace(150e9, 200e9, B), density=rng.uniform(7000, 18000, B),
                     precurvature=np.c_[rng.uniform(-1, 1, B), np.zeros(B), np.zeros(B)],
                     tendons=[tw.Tendon(offset=np.c_[rng.uniform(0.005, 0.012, B), np.zeros(B)]),
                              tw.Tendon(offset=(0.0, 0.01)), tw.Tendon(offset=(0.0, -0.01), length=0.2)])
    return rob, static_fields(tw.solve_static(rob, uniform(B, 3, seed=4), nodes=20, device=device))


def heavy_static(device):
    tau = uniform(8, 4, seed=5)
    tau[3] = (400.0, 0.0, 0.0, 0.0)
    tip_force = np.zeros((8, 3))
    tip_force[5], tip_force[6], tip_force[7] = (3.0, 0.0, 0.0), (12.0, 0.0, 0.0), (0.0, -6.0, 2.0)
    rob = seed_robot(tip_force=tip_force)
    return rob, static_fields(tw.solve_static(rob, tau, nodes=40, device=device))


def failing_static(device):
    """tests/test_robustness.py: a rod among rods that fail (soft rods at 5 kN, 8 iterations)."""
    E, tau = np.full(8, 1e5), np.full((8, 1), 5e3)
    E[0], tau[0] = 190e9, 3.0
    rob = tw.Robot(length=0.5, youngs_modulus=E, tendons=[tw.Tendon(offset=(0.01, 0.0))], gravity=(0, -9.81, 0))
    return rob, static_fields(tw.solve_static(rob, tau, nodes=20, max_iter=8, continuation=2, device=device))


def contact_static(device):
    """Rods pulled toward a rigid plane and a compliant sphere (experiments/bench_contact.py's
    robot), each contact short enough for single shooting."""
    offsets = [(0.01, 0.0), (0.0, 0.01), (-0.01, 0.0), (0.0, -0.01)]
    rob = tw.Robot(length=0.2, radius=0.5e-3, youngs_modulus=60e9, density=6450.0, gravity=(0, 0, -9.81),
                   tendons=[tw.Tendon(offset=o) for o in offsets],
                   obstacles=[tw.Obstacle("plane", point=(-0.05, 0.0, 0.0), normal=(1.0, 0.0, 0.0)),
                              tw.Obstacle("sphere", center=(0.0, 0.06, 0.15), radius=0.02, stiffness=1e5)])
    sol = tw.solve_static(rob, uniform(16, 4, seed=8), nodes=20, device=device)
    return rob, static_fields(sol) | {"contact_force": sol.contact_force}


def long_contact_static(device):
    """A wire sagging onto the wall of a straight tube over most of its 0.5 m (experiments/
    long_contact.py): split into segments during the contact stiffness climb."""
    tube = tw.Obstacle("tube", start=(0, 0, -0.01), end=(0, 0, 0.51), radius=0.7e-3)
    rob = tw.Robot(length=0.5, radius=0.5e-3, youngs_modulus=60e9, density=6450.0, gravity=(-9.81, 0.0, 0.0),
                   obstacles=[tube])
    sol = tw.solve_static(rob, np.zeros((1, 0)), nodes=100, device=device)
    return rob, static_fields(sol) | {"contact_force": sol.contact_force, "segments": sol.segments}


def warm_static(device):
    rob, tau = seed_robot(), uniform(16, 4, seed=6)
    cold = tw.solve_static(rob, tau, nodes=20, device=device)
    return rob, static_fields(tw.solve_static(rob, tau + 0.05, nodes=20, initial=cold, device=device))


def tendon_fields(sol) -> dict[str, np.ndarray]:
    return static_fields(sol) | {"tensions": np.stack([sol.tendon_tension_base, sol.tendon_tension_end], axis=1)}


def displaced_static(device):
    """The report robot by displacement, wires of 0.3 mm steel, pretension 0.5 N: random
    displacements in [-3, 4] mm (released tendons go slack), N = 30."""
    rob = seed_robot(tendons=[tw.Tendon(offset=o, control="displacement", compliance=2.7e-5, pretension=0.5)
                              for o in OFFSETS])
    q = np.random.default_rng(8).uniform(-0.003, 0.004, (16, 4))
    return rob, tendon_fields(tw.solve_static(rob, displacements=q, nodes=30, device=device))


def friction_static(device):
    """A helical tendon past a straight one ending at 0.25 m (a kink), mu = 0.25, tip force,
    slip +1 on 8 rows and -1 on 8, N = 40."""
    rob = seed_robot(tendons=[tw.Tendon(offset=(0.004, 0.0), routing="helix", helix_radius=0.006, turns=0.75,
                                        friction=0.25),
                              tw.Tendon(offset=(0.0, -0.01), length=0.25, friction=0.25)], tip_force=(0.02, 0, 0))
    slip = np.repeat([[1.0, 1.0], [-1.0, -1.0]], 8, axis=0)
    return rob, tendon_fields(tw.solve_static(rob, uniform(16, 2, seed=9), slip=slip, nodes=40, device=device))


def stick_slip_static(device):
    """A pull-release cycle of a displaced tendon with mu = 0.3, each step from the last
    (history): 0 -> 4 -> 1 mm in 6 steps; the fields of every step."""
    rob = seed_robot(tendons=[tw.Tendon(offset=(0.0, 0.01), control="displacement", friction=0.3, pretension=0.2)])
    sol, steps = None, []
    for q in (0.0, 0.002, 0.004, 0.0035, 0.0025, 0.001):
        sol = tw.solve_static(rob, displacements=[q], history=sol, nodes=30, device=device)
        steps.append(tendon_fields(sol))
    return rob, {k: np.concatenate([f[k][:, None] for f in steps], axis=1) for k in steps[0]}


def routes_static(device):
    """A converging route and a route through points to 0.25 m, kink loads off, N = 40."""
    pts = [(0.0, 0.01, 0.0), (0.0625, 0.0092, 0.0038), (0.125, 0.0071, 0.0071), (0.1875, 0.0038, 0.0092),
           (0.25, 0.0, 0.01)]
    rob = seed_robot(tendons=[tw.Tendon(routing="points", points=pts, length=0.25),
                              tw.Tendon(offset=(0.0, -0.01), routing="linear", offset_end=(0.0, -0.004))])
    return rob, tendon_fields(tw.solve_static(rob, uniform(16, 2, seed=10), nodes=40, kink_loads=False,
                                              device=device))


def tendon_dynamics(device):
    """An antagonistic displaced pair with mu = 0.2 pulled at 5 mm/s for 20 steps of 5 ms."""
    rob = seed_robot(tendons=[tw.Tendon(offset=(0, 0.01), control="displacement", pretension=0.5,
                                        compliance=2.7e-5, friction=0.2),
                              tw.Tendon(offset=(0, -0.01), control="displacement", pretension=0.5,
                                        compliance=2.7e-5, friction=0.2)], **SEED_DAMPING)
    sim = tw.Simulator(rob, np.zeros((2, 2)), displacements=np.zeros((2, 2)), dt=0.005, alpha=-0.2, nodes=20,
                       device=device)
    q = 0.005 * 0.005 * np.arange(1, 21)[:, None] * np.array([[1.0, -1.0]])
    return rob, trajectory_fields(sim.simulate(np.zeros((20, 2)), 20, shapes_every=5, displacements=q))


# --- dynamics ------------------------------------------------------------------------------------

def seed_dynamics(device):
    scene = load_scene(EXAMPLES / "seed_dynamics.toml")
    spec, steps = scene.dynamics, 30
    sim = tw.Simulator(scene.robot, scene.tensions, dt=spec.dt, alpha=spec.alpha, options=scene.options,
                       device=device)
    return scene.robot, trajectory_fields(sim.simulate(spec.schedule[:, :steps], steps, shapes_every=10))


def step_dynamics(rods: int, steps: int, alpha: float, **opts):
    """The report robot with damping, at rest under zero tension, then a new random tension
    level on every tendon every 5 steps."""
    def run(device):
        rob = seed_robot(**SEED_DAMPING)
        levels = uniform(rods, 4 * (steps // 5 + 1), seed=7).reshape(rods, -1, 4)
        schedule = np.repeat(levels, 5, axis=1)[:, :steps]
        sim = tw.Simulator(rob, np.zeros((rods, 4)), dt=0.005, alpha=alpha, nodes=20, device=device, **opts)
        return rob, trajectory_fields(sim.simulate(schedule, steps, shapes_every=5))
    return run


def soft_dynamics(device):
    """tests/test_robustness.py: a soft, lightly damped rod that needs the damping homotopy."""
    rob = tw.Robot(length=1.0478, youngs_modulus=2.0295e6, radius=0.02, density=7800.0,
                   tendons=[tw.Tendon(offset=(0.0, 0.174))], damping_bending=np.full(3, 0.011379))
    sim = tw.Simulator(rob, np.zeros((1, 1)), dt=0.11591, alpha=-0.24344, nodes=20, device=device)
    return rob, trajectory_fields(sim.simulate(np.full((12, 1), 1.58365), 12, shapes_every=4))


def small_dt_dynamics(device):
    """dt below the single-shooting limit of the report rod (docs/accuracy.md), single shooting only
    (segments = 1; by default the failing rods are split): the steps of the softer rods fail and are
    flagged, the stiffest rod goes on."""
    rob = seed_robot(youngs_modulus=np.array([190e9, 1e12, 5e12]))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the single-shooting warning: expected here
        sim = tw.Simulator(rob, np.zeros((3, 4)), dt=2e-4, alpha=-0.2, nodes=20, device=device, segments=1)
    return rob, trajectory_fields(sim.simulate(np.tile([[1.0, 0.0, 0.0, 0.0]], (8, 1)), 8, shapes_every=4))


def split_dynamics(device):
    """The rods of small_dt_dynamics by default: the rods that single shooting fails are split
    into segments (multiple shooting), and their steps converge."""
    rob = seed_robot(youngs_modulus=np.array([190e9, 1e12, 5e12]))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the single-shooting warning: expected here
        sim = tw.Simulator(rob, np.zeros((3, 4)), dt=2e-4, alpha=-0.2, nodes=20, device=device)
    return rob, trajectory_fields(sim.simulate(np.tile([[1.0, 0.0, 0.0, 0.0]], (8, 1)), 8, shapes_every=4))


# --- control -------------------------------------------------------------------------------------

def scene_control(stem: str, steps: int = 20) -> Case:
    def run(device):
        scene = load_scene(EXAMPLES / f"{stem}.toml")
        spec, ctl = scene.dynamics, scene.control
        if "target_tensions" in ctl:
            target = static_target(scene.robot, ctl["target_tensions"], options=scene.options, device=device)
        else:
            target = ctl["target"]
        sim = tw.Simulator(scene.robot, scene.tensions, dt=spec.dt, alpha=spec.alpha, options=scene.options,
                           device=device)
        controller = TipController(sim, target, **{k: ctl[k] for k in CONTROL_KEYS if k in ctl})
        return scene.robot, control_fields(run_closed_loop(sim, controller, steps))
    return Case(f"control/scene_{stem}", f"examples/{stem}.toml, {steps} steps as `tdcr-warp control` does", run)


def batch_control(device):
    rob = seed_robot(**SEED_DAMPING)
    target = static_target(rob, [[3.0, 0.0, 0.0, 0.0], [1.0, 2.0, 0.0, 0.0], [0.0, 0.0, 1.5, 0.5]], nodes=20,
                           device=device)
    sim = tw.Simulator(rob, np.zeros((3, 4)), dt=0.005, alpha=-0.2, nodes=20, device=device)
    controller = TipController(sim, target, method="smc", gain_c=[[20.0] * 3, [10.0] * 3, [30.0] * 3])
    return rob, control_fields(run_closed_loop(sim, controller, 20))


CASES = [
    *(scene_static(p.stem) for p in sorted(EXAMPLES.glob("*.toml"))),
    report_static("rk4_n20", nodes=20),
    report_static("rk4_n50", nodes=50),
    report_static("euler_n20", nodes=20, integrator="euler"),
    report_static("midpoint_n20", nodes=20, integrator="midpoint"),
    report_static("point_n20", nodes=20, model="point"),
    report_static("kirchhoff_n20", nodes=20, rod="kirchhoff"),
    report_static("float32_n20", nodes=20, precision="float32"),
    report_static("newton_n20", nodes=20, jacobian="newton"),
    Case("static/helix", "straight + helical tendon (r 8 mm, 0.5 turn), gravity, 16 rows U[0, 3] N, N = 40",
         helix_static),
    Case("static/two_sections", "tendons ending at 0.25, 0.3 and 0.5 m, point force at 0.375 m, tip force and "
         "moment, precurvature, gravity, 16 rows U[0, 2] N, N = 30", two_section_static),
    Case("static/per_rod", "32 rods: per-rod E, density, precurvature and tendon offset, N = 20", per_rod_static),
    Case("static/heavy_mixed", "8 rods: one at 400 N, tip forces of 3, 12 and 6.3 N (load continuation), N = 40",
         heavy_static),
    Case("static/failing_rods", "7 soft rods (E 1e5 Pa) at 5 kN that fail beside a converging one, max_iter 8",
         failing_static),
    Case("static/contact", "16 rows U[0, 3] N toward a rigid plane and a compliant sphere, N = 20", contact_static),
    Case("static/long_contact", "a wire sagging onto a straight tube's wall, L = 0.5 m, N = 100 (split into "
         "segments)", long_contact_static),
    Case("static/warm_start", "16 rows U[0, 3] N + 0.05 N from the solution at the rows, N = 20", warm_static),
    Case("static/tendons_displacement", "report robot by displacement, 16 rows U[-3, 4] mm, slack where released",
         displaced_static),
    Case("static/tendons_friction", "helical + straight tendon with mu = 0.25, a kink, slip +1 and -1",
         friction_static),
    Case("static/tendons_stick_slip", "pull-release cycle of a displaced tendon with mu = 0.3 (history), 6 steps",
         stick_slip_static),
    Case("static/tendons_routes", "a route through points and a converging route, kink loads off", routes_static),
    Case("dynamics/seed_dynamics", "examples/seed_dynamics.toml, 30 steps, shapes every 10", seed_dynamics),
    Case("dynamics/batch16_alpha-0.2", "16 rods, random tension steps every 5 steps, 20 steps of 5 ms, N = 20",
         step_dynamics(16, 20, -0.2)),
    Case("dynamics/alpha0", "4 rods, random tension steps, alpha = 0, 20 steps", step_dynamics(4, 20, 0.0)),
    Case("dynamics/alpha-0.45", "4 rods, random tension steps, alpha = -0.45, 20 steps", step_dynamics(4, 20, -0.45)),
    Case("dynamics/point_model", "4 rods, random tension steps, point-load model, 20 steps",
         step_dynamics(4, 20, -0.2, model="point")),
    Case("dynamics/soft_damping_homotopy", "soft lightly damped rod of tests/test_robustness.py, 12 steps",
         soft_dynamics),
    Case("dynamics/flagged_small_dt", "3 rods (E 190e9, 1e12, 5e12 Pa) at dt = 2e-4 s: two flagged, 8 steps",
         small_dt_dynamics),
    Case("dynamics/split_small_dt", "the rods of flagged_small_dt by default: the failing rods split, 8 steps",
         split_dynamics),
    scene_control("our_control"),
    scene_control("seed_control"),
    scene_control("wall_control"),
    Case("dynamics/tendons", "displaced pair with mu = 0.2 pulled at 5 mm/s, 20 steps", tendon_dynamics),
    Case("control/batch3_smc", "3 rods, per-rod targets and gain_c, sgn(S), 20 steps, N = 20", batch_control),
]
BY_NAME = {c.name: c for c in CASES}
SMOKE = ["static/scene_seed_robot", "dynamics/soft_damping_homotopy"]


def run_cases(names: list[str], device: str, keep_going: bool = False) -> dict[str, dict]:
    """name -> {"fields", "seconds"}, printing a line per case. keep_going: a case
    that raises gets {"error": message} instead of stopping the run."""
    out = {}
    for name in names:
        t0 = time.perf_counter()
        try:
            _, fields = BY_NAME[name].run(device)
        except Exception as e:
            if not keep_going:
                raise
            out[name] = {"error": f"{type(e).__name__}: {e}"}
            print(f"  ran {name:<36} raised {out[name]['error']}", flush=True)
            continue
        seconds = time.perf_counter() - t0
        out[name] = {"fields": {k: np.asarray(v) for k, v in fields.items()}, "seconds": seconds}
        print(f"  ran {name:<36} {seconds:7.2f} s", flush=True)
    return out


def run_meta(device: str) -> dict:
    return metadata(device, tdcr_warp=tw.__version__, tdcr_warp_path=str(Path(tw.__file__).parent),
                    numpy=np.__version__, platform=platform.platform())


def save(names: list[str], path: Path, device: str) -> None:
    t0 = time.perf_counter()
    results = run_cases(names, device)
    arrays = {f"{name}/{field}": a for name, r in results.items() for field, a in r["fields"].items()}
    cases = [{"name": n, "about": BY_NAME[n].about} for n in names]
    arrays["__cases__"] = np.array(json.dumps(cases))
    arrays["__meta__"] = np.array(json.dumps(run_meta(device)))
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        np.savez_compressed(f, **arrays)
    os.replace(tmp, path)
    print(f"saved {len(names)} cases in {time.perf_counter() - t0:.1f} s to {path}")


def abs_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """|a - b|, 0 where both are equal (also inf == inf, nan vs nan), inf where only one is nan."""
    a, b = a.astype(np.float64), b.astype(np.float64)
    with np.errstate(invalid="ignore"):
        d = np.abs(a - b)
    same = (a == b) | (np.isnan(a) & np.isnan(b))
    return np.where(same, 0.0, np.where(np.isnan(d), np.inf, d))


def compare_case(ref: dict[str, np.ndarray], new: dict[str, np.ndarray], tol: float) -> dict:
    """Differences of one case, per measure and per rod (rod = first axis of every field)."""
    rods = len(ref["converged"])
    ok = ref["converged"].reshape(rods, -1).all(axis=1)
    per_rod = {k: np.zeros(rods) for k in MEASURES}
    flags_differ = np.zeros(rods, bool)
    changed = {"iterations": 0, "status": 0}
    problems = sorted(f"field {f!r} is missing" for f in set(ref) - set(new))
    problems += sorted(f"unexpected field {f!r}" for f in set(new) - set(ref))
    for field in sorted(set(ref) & set(new)):
        a, b = ref[field], new[field]
        if a.shape != b.shape:
            problems.append(f"{field}: shape {b.shape}, reference {a.shape}")
            continue
        kind = KINDS[field]
        if kind == "flag":
            flags_differ |= (a != b).reshape(rods, -1).any(axis=1)
        elif kind == "count":
            changed[field] = int((a != b).reshape(rods, -1).any(axis=1).sum())
        else:
            d = abs_diff(a, b).reshape(rods, -1).max(axis=1, initial=0.0)
            per_rod[kind] = np.maximum(per_rod[kind], np.where(ok, d, 0.0))
    excess = per_rod["position"] / tol  # forces, moments and tensions are reported, not judged
    excess[flags_differ] = np.inf
    worst = int(np.argmax(excess))
    within = bool(excess[worst] <= 1.0)
    return {"rods": rods, "reference_failed_rods": int((~ok).sum()),
            **{k: float(per_rod[k].max()) for k in MEASURES},
            "flags_equal": not flags_differ.any(), "iterations_changed": changed["iterations"],
            "status_changed": changed["status"], "problems": problems, "passed": within and not problems,
            "worst_rod": None if within else {
                "rod": worst, **{k: float(per_rod[k][worst]) for k in MEASURES},
                "converged_in_reference": bool(ok[worst]), "flags_differ": bool(flags_differ[worst])}}


def compare(reference: Path, tol: float, device: str, tol32: float | None = None) -> dict:
    """tol32: the position tolerance of the float32 cases (None: tol)."""
    with np.load(reference) as z:
        data = {k: z[k] for k in z.files}
    ref_cases = json.loads(str(data.pop("__cases__")))
    ref_meta = json.loads(str(data.pop("__meta__")))
    print(f"reference {reference}: tdcr_warp from {ref_meta.get('tdcr_warp_path')}, Warp {ref_meta.get('warp')}, "
          f"git {ref_meta.get('git')}")
    meta = run_meta(device)
    print(f"this run:  tdcr_warp from {meta['tdcr_warp_path']}, Warp {meta['warp']}, git {meta['git']}")
    known = [c for c in ref_cases if c["name"] in BY_NAME and c["about"] == BY_NAME[c["name"]].about]
    t0 = time.perf_counter()
    results = run_cases([c["name"] for c in known], device, keep_going=True)
    seconds = time.perf_counter() - t0
    rows = []
    for c in ref_cases:
        name = c["name"]
        if name not in results:
            rows.append({"case": name, "passed": False, "problems": ["this script no longer defines the case "
                                                                      "(or its description changed)"]})
            continue
        if "error" in results[name]:
            rows.append({"case": name, "passed": False, "problems": [f"raised {results[name]['error']}"]})
            continue
        prefix = name + "/"
        ref = {k[len(prefix):]: v for k, v in data.items() if k.startswith(prefix)}
        rows.append({"case": name, "seconds": results[name]["seconds"],
                     **compare_case(ref, results[name]["fields"],
                                    tol32 if tol32 is not None and "float32" in name else tol)})
    print_table(rows, tol)
    passed = all(r["passed"] for r in rows)
    print(f"{sum(r['passed'] for r in rows)} of {len(rows)} cases pass at tol {tol:g} (rerun {seconds:.1f} s)")
    return {"meta": meta, "reference": {"path": str(reference), "meta": ref_meta}, "tol": tol, "tol32": tol32,
            "seconds": seconds, "passed": passed, "cases": rows}


def print_table(rows: list[dict], tol: float) -> None:
    print(f"{'case':<36} {'rods':>5} {'pos [m]':>9} {'n [N]':>9} {'m [N m]':>9} {'flags':>6} {'iter chg':>8}  result")
    for r in rows:
        if "rods" not in r:
            print(f"{r['case']:<36} {'-':>5} {'-':>9} {'-':>9} {'-':>9} {'-':>6} {'-':>8}  FAIL")
            continue
        print(f"{r['case']:<36} {r['rods']:>5} {r['position']:>9.1e} {r['force']:>9.1e} {r['moment']:>9.1e} "
              f"{'equal' if r['flags_equal'] else 'DIFF':>6} {r['iterations_changed']:>8}  "
              f"{'PASS' if r['passed'] else 'FAIL'}")
    failing = [r for r in rows if not r["passed"]]
    if failing:
        print(f"failing cases (positions beyond tol {tol:g} m, or flags differ):")
    for r in failing:
        for p in r["problems"]:
            print(f"  {r['case']}: {p}")
        w = r.get("worst_rod")
        if w:
            print(f"  {r['case']}: worst rod {w['rod']}: pos {w['position']:.2e} m, n {w['force']:.2e} N, "
                  f"m {w['moment']:.2e} N m, flags {'differ' if w['flags_differ'] else 'equal'}"
                  f"{'' if w['converged_in_reference'] else ' (not converged in the reference)'}")


def json_safe(obj):
    """Non-finite floats as strings (strict JSON has no inf or nan)."""
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [json_safe(v) for v in obj]
    if isinstance(obj, float) and not np.isfinite(obj):
        return str(obj)
    return obj


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mode", nargs="?", choices=["save", "compare"],
                    help="save a reference, or compare against one (none: --smoke's round trip)")
    ap.add_argument("--out", help="save: the .npz to write; compare and --smoke: the JSON report")
    ap.add_argument("--reference", help="compare: the .npz written by save")
    ap.add_argument("--tol", type=float, default=1e-12, help="position tolerance [m] (default 1e-12)")
    ap.add_argument("--tol32", type=float, help="position tolerance of the float32 cases [m] (default --tol)")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--smoke", action="store_true",
                    help="only the two tiny cases; without a mode: save them and compare in a temporary folder")
    args = ap.parse_args(argv)
    if args.mode == "save":
        if not args.out:
            ap.error("save needs --out FILE.npz")
        save(SMOKE if args.smoke else [c.name for c in CASES], Path(args.out), args.device)
        return 0
    if args.mode == "compare":
        if not args.reference or args.smoke:
            ap.error("compare needs --reference FILE.npz (and runs the reference's cases, so no --smoke)")
        report = compare(Path(args.reference), args.tol, args.device, args.tol32)
    elif args.smoke:
        with tempfile.TemporaryDirectory() as tmp:
            ref = Path(tmp) / "reference.npz"
            save(SMOKE, ref, args.device)
            report = compare(ref, args.tol, args.device)
    else:
        ap.error("give a mode (save or compare) or --smoke")
    if args.out:
        write_report(args.out, json_safe(report))
    return 0 if report["passed"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
