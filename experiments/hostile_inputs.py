"""Hostile input campaign against the CLI: random malformed and extreme scenes and garbage files.

Each input mutates a valid scene (1-4 keys of robot/tendons/actuation/solver/loads/dynamics/sweep/
obstacles set to hostile values: NaN, inf, huge, tiny, negative, wrong types and shapes, strings
such as "disks" or "1_0", or deleted) or is random bytes/text, and runs `tdcr-warp
static|simulate|workspace` on it, the whole campaign under an address-space cap (--cap-gib, so that
an input that allocates without bound fails the campaign, not the machine). Counted
outcomes: exit 0 (complete), 1 (rods failed, reasons recorded), 2 (clean message, no
results.json). Violations: a traceback or any other exception, a missing results.json after
exit 0/1, a non-finite number in a rod reported converged, a results.json after exit 2.

    python experiments/hostile_inputs.py [--smoke] [--count 1000] [--seed 0] [--cap-gib 4]
                                         [--out results/hostile_inputs.json]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "experiments")]

from _common import _to_toml, metadata, write_report  # noqa: E402

from tdcr_warp.cli import main as cli  # noqa: E402

GOOD = {"robot": {"length": 0.5, "youngs_modulus": 190e9, "poisson_ratio": 0.3, "radius": 1e-3, "density": 7800.0},
        "tendons": [{"offset": [0.01, 0.0]}, {"offset": [0.0, 0.01]}],
        "actuation": {"tensions": [[1.0, 0.5]]}, "solver": {"nodes": 10}}
KEYS = {"robot": ["length", "youngs_modulus", "poisson_ratio", "radius", "density", "precurvature", "disks", "bogus"],
        "tendons": ["offset", "length", "turns", "radius", "phase", "friction", "bogus"],
        "actuation": ["tensions", "steps", "bogus"],
        "solver": ["nodes", "integrator", "model", "precision", "tol", "max_iter", "max_step", "continuation",
                   "preset", "threads", "bogus"],
        "loads": ["gravity", "tip_force", "tip_moment", "point_forces", "bogus"],
        "dynamics": ["dt", "alpha", "steps", "damping_bending", "damping_shear", "drag", "shapes_every", "bogus"],
        "obstacles": ["kind", "point", "normal", "radius", "stiffness", "bogus"],
        "sweep": ["chunk", "seed", "samples", "grid", "max_total_tension", "bogus"]}


def hostile_value(rng):
    pick = rng.integers(12)
    if pick == 0:
        return float("nan")
    if pick == 1:
        return float(rng.choice([math.inf, -math.inf]))
    if pick == 2:
        return float(rng.choice([1e300, -1e300, 1e-300, 0.0, -1.0, 5e-324]))
    if pick == 3:
        return int(rng.integers(-10**9, 10**9))
    if pick == 4:
        return str(rng.choice(["", "rk4", "x", "float16", "nan", "1e3", "1_0", "disks", "constant_curvature", "plane"]))
    if pick == 5:
        return bool(rng.integers(2))
    if pick == 6:
        return [float(x) for x in rng.normal(size=rng.integers(0, 5)) * 10.0 ** rng.integers(-5, 12)]
    if pick == 7:
        return [[float(x) for x in rng.normal(size=rng.integers(0, 4))] for _ in range(rng.integers(0, 4))]
    if pick == 8:
        return {"a": 1.0}
    return float(rng.normal() * 10.0 ** rng.integers(-8, 13))


def mutate(rng) -> tuple[str, dict]:
    scene = json.loads(json.dumps(GOOD))
    command = str(rng.choice(["static", "static", "simulate", "workspace"]))
    if command == "simulate":
        scene["dynamics"] = {"dt": 0.005, "alpha": -0.2, "steps": 3}
    if command == "workspace":
        scene["sweep"] = {"chunk": 4, "grid": {"actuation.tensions[0]": [0.0, 2.0, 3]}}
    for _ in range(rng.integers(1, 5)):
        table = str(rng.choice(list(KEYS)))
        key = str(rng.choice(KEYS[table]))
        if table == "obstacles":
            scene.setdefault("obstacles", [{"kind": "plane", "point": [0.05, 0.0, 0.0], "normal": [-1.0, 0.0, 0.0]}])
            target = scene["obstacles"][0]
        else:
            target = scene["tendons"][int(rng.integers(2))] if table == "tendons" else scene.setdefault(table, {})
        if rng.random() < 0.2:
            target.pop(key, None)
        else:
            target[key] = hostile_value(rng)
    return command, scene


def garbage(rng) -> str:
    if rng.random() < 0.5:
        return bytes(rng.integers(0, 256, rng.integers(0, 200)).astype(np.uint8)).decode("latin-1")
    return _to_toml(GOOD)[: rng.integers(0, 200)] + str(rng.choice(["[[", "= =", "\x00", "]", "tensions = [[1, 2"]))


def finite_converged(out: Path) -> bool:
    res = json.loads((out / "results.json").read_text())
    if "rods" in res:
        return all(np.isfinite(r["tip_position"]).all() for r in res["rods"] if r["converged"])
    if "final_tip_position" in res:
        tips = np.array(res["final_tip_position"], dtype=float)
        return bool(np.isfinite(tips[np.array(res["completed"], dtype=bool)]).all())
    return True


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true")
    ap.add_argument("--count", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--trace", action="store_true", help="print each input to stderr before running it")
    ap.add_argument("--cap-gib", type=float, default=4.0, help="address-space cap of this process (0: none)")
    ap.add_argument("--out", default=str(ROOT / "results" / "hostile_inputs.json"))
    args = ap.parse_args(argv)
    if args.cap_gib > 0:
        hard = resource.getrlimit(resource.RLIMIT_AS)[1]
        cap = int(args.cap_gib * 2**30) if hard == resource.RLIM_INFINITY else min(int(args.cap_gib * 2**30), hard)
        resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    rng = np.random.default_rng(args.seed)
    count = 12 if args.smoke else args.count
    outcomes = {"exit 0": 0, "exit 1": 0, "exit 2": 0}
    violations = []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(count):
            path, out = Path(tmp) / f"s{i}.toml", Path(tmp) / f"o{i}"
            if rng.random() < 0.1:
                command, text = "static", garbage(rng)
            else:
                command, scene = mutate(rng)
                text = _to_toml(scene)
            path.write_text(text, encoding="latin-1")
            if args.trace:
                print(f"{i} {command} {text!r}", file=sys.stderr, flush=True)
            err = io.StringIO()
            try:
                with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
                    rc = cli([command, str(path), "--out", str(out)] + (["--quiet"] if command != "static" else []))
            except SystemExit as e:  # argparse
                rc = e.code
            except Exception as e:  # noqa: BLE001 - counting exactly these is the point
                violations.append({"input": text[:4000], "command": command, "error": repr(e)})
                continue
            outcomes[f"exit {rc}"] = outcomes.get(f"exit {rc}", 0) + 1
            produced = (out / ("summary.json" if command == "workspace" else "results.json")).exists()
            bad = ("Traceback" in err.getvalue() or (rc == 2 and produced) or (rc in (0, 1) and not produced)
                   or (rc in (0, 1) and command != "workspace" and not finite_converged(out)))
            if bad:
                violations.append({"input": text[:4000], "command": command, "rc": rc, "stderr": err.getvalue()[-300:]})
    wall = time.perf_counter() - t0
    print(f"{count} hostile inputs in {wall:.0f} s: {outcomes}; violations: {len(violations)}")
    for v in violations[:5]:
        print("  ", v)
    write_report(args.out, {"meta": metadata("cpu", count=count, seed=args.seed), "outcomes": outcomes,
                            "violations": violations[:50], "seconds": wall})
    return 0 if not violations else 1


if __name__ == "__main__":
    raise SystemExit(main())
