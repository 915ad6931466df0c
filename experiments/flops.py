"""Flops of the statics kernel, counted in the C++ that Warp generated for it, and the Gflop/s a solve achieves.

Counting: the report robot's fused float64 RK4 statics kernel (4 straight tendons, gravity; the
module the solve just ran, found through its loaded binary in Warp's kernel cache) is read as
C++: every forward function, its typed variables, and each statement ``var = wp::op(args)`` or call
of another function. An operation costs what it executes in float64 for its argument types: add,
sub, component-wise products and quotients one flop per element; mat33 * vec3 15 (9 multiplies, 6
adds), mat33 * mat33 45; cross 9, dot3 5, outer 9, length 6 (with sqrt 1), normalize 9, inverse of
a 3x3 51 (Warp's: determinant 14, 27 for the adjugate, a reciprocal and 9 multiplies); negation,
comparisons, min/max/abs, selects, copies, transposes and constructors none. The 6x6
elimination of a Newton step is counted from its formula (its loops have runtime bounds). A loop over the
tendons (``range(md.n_tendons)``) counts its body K times, the stage loop of an interval once per
stage; a runtime branch counts as taken except where the report robot does not take it (no
tendon is slack on an interval, ``pulls == 0``; the tip node is busy, and no tendon goes on past it). Operations
the table does not know are listed (they would be missed, not guessed).

Per solve: the integrations a solve spent (StaticSolution.integrations), of which, where the solve
made a first Jacobian (since the robot's unloaded Jacobian is kept, only the first solve of a
problem does), the 7 probes run over double steps at N >= 16 (``--coarse``) at about half
the intervals, times the flops of an integration (N intervals, the tip's node loads and the
residual), plus Newton's linear algebra (a 6x6 elimination and a Broyden update per iteration, a
Jacobian from its probes). Achieved: that times the rods/s of a B = 4096 solve on one thread
(stability off), timed in wall time and in the process's CPU time (the share a busy machine
gives us does not count there), against the peaks of experiments/peak.py (measured in this run).
Sides: this working tree in process, and today's main (``--old-path``) in a subprocess, each
counting the kernel it compiled.

    python experiments/flops.py [--batch 4096] [--nodes 20] [--old-path /tmp/h1/oldpkg] [--smoke]
        [--out results/flops.json]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "experiments")]

from _common import metadata, write_report

MARKER = "FLOPS_RESULT "
OFFSETS = [(0.01, 0.0), (0.0, 0.01), (-0.01, 0.0), (0.0, -0.01)]
ROD = {"length": 0.5, "youngs_modulus": 190e9, "poisson_ratio": 0.3, "radius": 1e-3, "density": 17189.0,
       "gravity": (0.0, 0.0, -9.81)}
NOT_TAKEN = ("pulls == 0", "term_node(md, b, k) > node", "busy == 0")  # branches the report robot does not take
FREE = {"neg", "transpose", "skew", "diag", "extract", "copy", "where", "load", "range", "iter_next", "int",
        "identity", "abs", "min", "max", "float64", "float32", "int32", "address", "isfinite", "assign", "select",
        "view", "index", "mod", "bool", "assign_inplace", "array_store"}
HEAD = re.compile(r"^static (?:WP_FORCEINLINE |CUDA_CALLABLE |inline )*(?P<ret>.+?) (?P<name>make_\w+)\($")
DECL = re.compile(r"^\s*(?:const )?(?P<type>wp::[\w:<>, ]+?|bool) (?P<var>(?:var|ret)_\w+)\s*(?:[,;=)]|$)")
PARAM = re.compile(r"^\s*(?P<type>wp::[\w:<>, ]+?|bool|make_\w+)\s*&?\s*(?P<var>(?:var|ret)_\w+)")
OP = re.compile(r"^\s*(?:(?P<out>var_\w+|ret_\w+) = )?(?:wp::(?P<op>\w+)|(?P<call>make_\w+))(?:<[^>]*>)?\((?P<args>.*)\);")


def shape(typ: str) -> tuple[int, ...]:
    """() scalar, (n,) vector, (r, c) matrix; None: not a float."""
    if m := re.match(r"wp::vec_t<(\d+), wp::float(?:32|64)>", typ):
        return (int(m.group(1)),)
    if m := re.match(r"wp::mat_t<(\d+), (\d+), wp::float(?:32|64)>", typ):
        return (int(m.group(1)), int(m.group(2)))
    if typ in ("wp::float64", "wp::float32"):
        return ()
    return None


def op_cost(op: str, args: list, out) -> int | None:
    """float64 flops of one Warp builtin for its argument shapes (None: unknown to this table)."""
    if op in FREE or op.startswith(("vec_t", "mat_t")):
        return 0
    size = (lambda s: int(np.prod(s)) if s is not None else 0)
    a = args[0] if args else None
    b = args[1] if len(args) > 1 else None
    if op in ("add", "sub", "cw_mul", "cw_div"):
        return size(out if out is not None else a)
    if op == "div":
        return size(a)
    if op == "mul":
        if a is None or b is None:  # integer arithmetic
            return 0
        if a == () or b == ():
            return size(a) * size(b) if a == () and b == () else max(size(a), size(b))
        if len(a) == 2 and len(b) == 1:
            return a[0] * (2 * a[1] - 1)
        if len(a) == 1 and len(b) == 2:
            return b[1] * (2 * b[0] - 1)
        if len(a) == 2 and len(b) == 2:
            return a[0] * b[1] * (2 * a[1] - 1)
        return None
    table = {"cross": 9, "outer": size(a) * size(b) if b is not None else None, "sqrt": 1, "dot": 2 * size(a) - 1,
             "length": 2 * size(a), "length_sq": 2 * size(a) - 1, "normalize": 3 * size(a),
             "inverse": 51 if a == (3, 3) else None, "determinant": 14 if a == (3, 3) else None}
    return table.get(op)


def parse_functions(cpp: str) -> dict:
    """name -> (variable shapes, body lines) of every forward function of the module."""
    lines = cpp.splitlines()
    funcs, i = {}, 0
    while i < len(lines):
        m = HEAD.match(lines[i])
        if not m:
            i += 1
            continue
        types, j = {}, i + 1
        while lines[j].strip() != "{":
            if p := PARAM.match(lines[j]):
                types[p.group("var")] = shape(p.group("type"))
            j += 1
        k = j + 1
        while lines[k] != "}":
            k += 1
        body = lines[j + 1:k]
        for ln in body:
            if d := DECL.match(ln):
                types[d.group("var")] = shape(d.group("type"))
        funcs[m.group("name")] = (types, body)
        i = k + 1
    return funcs


class Counter:
    """Flops of a function and its callees (see the module docstring for the rules)."""

    def __init__(self, funcs: dict, trips: dict[str, int]):
        self.funcs, self.trips, self.unknown = funcs, trips, {}

    def count(self, name: str) -> int:
        types, body = self.funcs[name]
        total, stack, mult, comment, conds, skip = 0, [], 1, "", {}, 0
        for ln in body:
            s = ln.strip()
            if s.startswith("//"):
                comment = s
                continue
            if skip:  # inside a branch not taken: track braces only
                skip += s.count("{") - s.count("}")
                continue
            if s == "return;":  # on the path counted, nothing after it runs (code after a static return)
                break
            if m := re.match(r"if \((!?)(var_\w+)\) \{$", s):
                if not m.group(1):
                    conds.setdefault(m.group(2), not any(p in comment for p in NOT_TAKEN))
                taken = conds.get(m.group(2), True) != bool(m.group(1))
                if not taken:
                    skip = 1
                continue
            if m := re.match(r"start_for_(\d+):", s):
                n = next((v for k, v in self.trips.items() if k in comment), None)
                if n is None:
                    raise ValueError(f"{name}: a loop of unknown trip count ({comment})")
                stack.append(n)
                mult *= n
                continue
            if re.match(r"end_for_(\d+):", s):
                mult //= stack.pop()
                continue
            if m := OP.match(ln):
                if m.group("call"):
                    total += mult * self.count(m.group("call"))
                    continue
                args = [types.get(a.strip().lstrip("&")) for a in m.group("args").split(",") if a.strip()]
                cost = op_cost(m.group("op"), args, types.get(m.group("out")))
                if cost is None:
                    self.unknown[m.group("op")] = self.unknown.get(m.group("op"), 0) + 1
                    continue
                total += mult * cost
        return total


def dense_solve_flops(n: int) -> int:
    """Gaussian elimination with partial pivoting of an n x n system and its back substitution
    (kernels/newton.py solve_dense; its loops have runtime bounds, so it is counted here)."""
    elim = sum((n - c - 1) * (1 + 2 * (n - c) + 2) for c in range(n))
    return elim + sum(2 * (n - 1 - i) + 1 for i in range(n))


def kernel_counts(module, tendons: int, stages: int) -> dict:
    """Flops of the RHS, an interval, the tip and the Newton pieces in ``module``'s generated C++."""
    paths = [Path(ex.binary_path) for ex in module.execs.values() if getattr(ex, "binary_path", None)]
    cpp = next((p.parent / (p.name.split(".")[0] + ".cpp") for p in paths), None)
    if cpp is None or not cpp.is_file():
        raise FileNotFoundError(f"no generated C++ beside {paths}")
    funcs = parse_functions(cpp.read_text())
    ctr = Counter(funcs, {"n_tendons": tendons, "range(stages": stages})

    def one(prefix: str) -> int:
        names = [n for n in funcs if n.startswith(prefix)]
        if not names:
            raise KeyError(f"no function {prefix}* in {cpp.name}")
        return ctr.count(names[0])

    rhs = one("make_rhs__locals__rhs_")
    out = {"cpp": str(cpp), "rhs": rhs, "interval": one("make_interval__locals__interval_"),
           "node_jumps_tip": one("make_node_jumps__locals__node_jumps_"),
           "tip_residual": one("make_residual__locals__tip_residual_"),
           "solve_dense": dense_solve_flops(6),
           "new_jacobian": one("make_probes__locals__new_jacobian_"),
           "take_point": one("make_probes__locals__take_point_"), "unknown_ops": ctr.unknown}
    out["interval_extra"] = out["interval"] - stages * rhs  # stage sums, orthonormalisation
    return out


def per_solve(c: dict, nodes: int, integrations: float, iterations: float, coarse: int) -> float:
    """Flops of an average rod's solve."""
    full = c["interval"] * nodes + c["node_jumps_tip"] + c["tip_residual"]
    half = c["interval"] * (nodes + 1) // 2 + c["node_jumps_tip"] + c["tip_residual"]
    probed = integrations >= iterations + coarse  # a first Jacobian made in the solve (not the robot's kept one)
    n_coarse = coarse if nodes >= 16 and probed else 0
    newton = iterations * (c["solve_dense"] + c["take_point"]) + (c["new_jacobian"] if probed else 0)
    return (integrations - n_coarse) * full + n_coarse * half + newton


def measure_side(batch: int, nodes: int, repeats: int, coarse: int) -> dict:
    """This process's tdcr_warp: the kernel's counts and a timed B-rod solve on one thread."""
    import warp as wp
    from tdcr_warp.kernels.shooting import make_shooting_kernels

    import tdcr_warp as tw
    from tdcr_warp.core.build import Tables

    rob = tw.Robot(tendons=[tw.Tendon(offset=o) for o in OFFSETS], **ROD)
    tau = np.random.default_rng(1).uniform(0.0, 3.0, (batch, 4))
    kw = {"nodes": nodes, "threads": 1, "stability": "off"}
    tw.solve_static(rob, tau[:8], **kw)
    wall, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        sol = tw.solve_static(rob, tau, **kw)
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    kern = make_shooting_kernels(wp.float64, "rk4", "coupled", False, "cosserat", Tables.of(rob, nodes).features)
    counts = kernel_counts(kern.solve.module, len(OFFSETS), kern.stages)
    its, ints = float(sol.iterations.mean()), float(sol.integrations.mean())
    flops = per_solve(counts, nodes, ints, its, coarse)
    rate_wall, rate_cpu = batch / statistics.median(wall), batch / statistics.median(cpu)
    return {"counts": counts, "iterations": its, "integrations": ints, "flops_per_solve": flops,
            "rods_per_s_wall": rate_wall, "rods_per_s_cpu": rate_cpu, "gflops_wall": flops * rate_wall / 1e9,
            "gflops_cpu": flops * rate_cpu / 1e9, "statics": sys.modules["tdcr_warp.physics.statics"].__file__}


def old_side(old_path: str, batch: int, nodes: int, repeats: int, coarse: int) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["PYTHONPATH"] = old_path
    kw = json.dumps({"batch": batch, "nodes": nodes, "repeats": repeats, "coarse": coarse})
    out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--worker", kw], check=False, cwd="/tmp",
                         env=env, capture_output=True, text=True, timeout=900)
    lines = [ln[len(MARKER):] for ln in out.stdout.splitlines() if ln.startswith(MARKER)]
    if out.returncode == 0 and lines:
        return json.loads(lines[-1])
    return {"error": f"exit {out.returncode}: " + "\n".join((out.stdout + out.stderr).strip().splitlines()[-10:])}


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["--worker"]:
        print(MARKER + json.dumps(measure_side(**json.loads(argv[1]))), flush=True)
        return 0
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, default=4096)
    ap.add_argument("--nodes", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--coarse", type=int, default=7, help="coarse probes of a first Jacobian at N >= 16 (7)")
    ap.add_argument("--old-path", default="/tmp/h1/oldpkg", help="PYTHONPATH of today's main ('' : none)")
    ap.add_argument("--smoke", action="store_true", help="tiny sizes, no old side (for the test suite)")
    ap.add_argument("--out", default=str(ROOT / "results" / "flops.json"))
    args = ap.parse_args(argv)
    import peak

    if args.smoke:
        args.batch, args.repeats, args.old_path = 16, 1, ""
    peaks = peak.measure(5, args.smoke)
    sides = {"new": measure_side(args.batch, args.nodes, args.repeats, args.coarse)}
    if args.old_path and os.path.isdir(args.old_path):
        sides["old"] = old_side(args.old_path, args.batch, args.nodes, args.repeats, args.coarse)
    scalar = peaks["fma"].get("scalar FMA", {}).get("gflops")
    vector = max((r["gflops"] for r in peaks["fma"].values() if "gflops" in r), default=None)
    for name, s in sides.items():
        if "error" in s:
            print(f"{name}: FAILED {s['error']}")
            continue
        c = s["counts"]
        s["fraction_scalar_peak"] = s["gflops_cpu"] / scalar if scalar else None
        s["fraction_vector_peak"] = s["gflops_cpu"] / vector if vector else None
        print(f"{name}: RHS {c['rhs']} flops (4 tendons), interval {c['interval']} (+{c['interval_extra']} beyond "
              f"its 4 RHS), tip {c['node_jumps_tip'] + c['tip_residual']}, 6x6 elimination {c['solve_dense']}, "
              f"Jacobian {c['new_jacobian']}, Broyden {c['take_point']}; unknown ops {c['unknown_ops'] or 'none'}")
        print(f"  per solve (N = {args.nodes}, {s['iterations']:.2f} iterations, {s['integrations']:.2f} "
              f"integrations): {s['flops_per_solve'] / 1e3:.0f} kflop; {s['rods_per_s_wall']:,.0f} rods/s wall, "
              f"{s['rods_per_s_cpu']:,.0f} rods/s CPU time: {s['gflops_wall']:.2f} / {s['gflops_cpu']:.2f} Gflop/s "
              f"= {100 * (s['fraction_scalar_peak'] or 0):.0f}% of the scalar FMA peak ({scalar:.1f}), "
              f"{100 * (s['fraction_vector_peak'] or 0):.1f}% of the vector peak ({vector:.1f})")
    write_report(args.out, {"meta": metadata("cpu", dtype="float64", batch=args.batch, nodes=args.nodes,
                                             smoke=args.smoke), "peaks": peaks, "sides": sides})
    return 1 if any("error" in s for s in sides.values()) else 0


if __name__ == "__main__":
    raise SystemExit(main())
