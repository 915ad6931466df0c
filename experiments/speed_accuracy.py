"""Speed against accuracy: every rung of the fidelity ladder on standard scenes.

Static scenes (0.5 m steel rod, r = 1 mm, tendons at 10 mm): planar bend (3 N, one tendon),
two tendons out of plane (2 N + 1.5 N), helical tendon (0.5 turn, 2 N, plus 1 N straight),
lateral gravity sag (1 N, gravity along -y), large deflection (90 N: about 3 rad, a half
curl). Dynamic scene: the report's step response (3 N at t = 0, Bbt = 0.008, 0.2 s).
Error: tip distance to a converged reference (RK4, N = 1024, float64, coupled Cosserat;
dynamics RK4, N = 100, dt = 0.625 ms); time per rod at B = 4096 (statics, median of 2) or per
rod-step at B = 256 (dynamics). Writes JSON and a Pareto plot per scene.

    python experiments/speed_accuracy.py [--smoke] [--out results/speed_accuracy.json]
    python experiments/speed_accuracy.py --replot results/speed_accuracy.json   # figure and table from a saved run
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "experiments")]

from _common import metadata, write_report  # noqa: E402

import tdcr_warp as tw  # noqa: E402
from tdcr_warp.apps.jobs import pareto_front  # noqa: E402

BASE = dict(length=0.5, youngs_modulus=190e9, poisson_ratio=0.3, radius=1e-3, density=7800.0)


def scenes():
    x, y = tw.Tendon(offset=(0.01, 0.0)), tw.Tendon(offset=(0.0, 0.01))
    helix = tw.Tendon(routing="helix", helix_radius=0.01, turns=0.5)
    return {
        "planar bend": (tw.Robot(**BASE, tendons=[x]), [3.0]),
        "two tendons out of plane": (tw.Robot(**BASE, tendons=[x, y]), [2.0, 1.5]),
        "helical tendon": (tw.Robot(**BASE, tendons=[helix, x]), [2.0, 1.0]),
        "lateral gravity sag": (tw.Robot(**BASE, tendons=[x], gravity=(0.0, -9.81, 0.0)), [1.0]),
        "large deflection": (tw.Robot(**BASE, tendons=[x]), [90.0]),
    }


def static_settings(smoke: bool):
    out = [dict(integrator="rk4", nodes=n) for n in ((5, 10) if smoke else (5, 10, 20, 40, 50))]
    if not smoke:
        out += [dict(integrator="midpoint", nodes=n) for n in (5, 10, 20, 40, 80)]
        out += [dict(integrator="euler", nodes=n) for n in (20, 40, 80, 160)]
    out += [dict(integrator="rk4", nodes=10, rod="kirchhoff"), dict(integrator="rk4", nodes=20, model="point"),
            dict(integrator="rk4", nodes=20, precision="float32"), dict(integrator="rk4", nodes=20, specialize=False),
            dict(model="constant_curvature", nodes=20)]
    if not smoke:
        out += [dict(integrator="rk4", nodes=20, rod="kirchhoff"), dict(integrator="rk4", nodes=5, rod="kirchhoff")]
    return out


def label(setting: dict) -> str:
    return ", ".join(f"{k}={v}" for k, v in setting.items())


def run_static(B: int, repeats: int, smoke: bool) -> list[dict]:
    rows = []
    for name, (robot, tau) in scenes().items():
        tensions = np.tile(tau, (B, 1))
        ref = tw.solve_static(robot, tensions[:1], nodes=1024, tol=1e-13).tip_position[0]
        for setting in static_settings(smoke):
            try:
                tw.solve_static(robot, tensions[:1], **setting)  # compile outside the timing
            except tw.InputError as e:  # a rung that does not apply to this scene
                rows.append(dict(scene=name, setting=label(setting), applicable=False, reason=str(e)))
                continue
            times = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                sol = tw.solve_static(robot, tensions, **setting)
                times.append(time.perf_counter() - t0)
            err = float(np.linalg.norm(sol.tip_position[0] - ref))
            rows.append(dict(scene=name, setting=label(setting), applicable=True, tip_error_m=err,
                             converged=bool(sol.converged.all()), us_per_rod=1e6 * float(np.median(times)) / B))
            print(f"{name:26s} {label(setting):45s} error {err:9.2e} m  {rows[-1]['us_per_rod']:8.1f} us/rod")
    return rows


def run_dynamic(B: int, smoke: bool) -> list[dict]:
    robot = tw.Robot(**BASE, tendons=[tw.Tendon(offset=(0.01, 0.0))], gravity=(0.0, 0.0, -9.81),
                     damping_bending=(0.008, 0.008, 0.008), drag=(0.01, 0.01, 0.01))
    T = 0.05 if smoke else 0.2

    def tip(dt, alpha, b, **kw):
        sim = tw.Simulator(robot, np.zeros((b, 1)), dt=dt, alpha=alpha, **kw)
        steps = int(round(T / dt))
        t0 = time.perf_counter()
        tr = sim.simulate(np.full((b, steps, 1), 3.0), steps)
        return tr.tip_position[-1, 0], (time.perf_counter() - t0) / (b * steps), bool(tr.converged.all())

    ref = tip(T / 320, -0.2, 1, nodes=100)[0]
    rows = []
    settings = [dict(dt=dt, alpha=a, nodes=n) for dt in (0.02, 0.01, 0.005, 0.0025) for a in (0.0, -0.2)
                for n in (10, 20)]
    settings += [dict(dt=0.005, alpha=-0.2, nodes=20, integrator="midpoint"),
                 dict(dt=0.005, alpha=-0.2, nodes=40, integrator="euler"),
                 dict(dt=0.005, alpha=-0.2, nodes=20, rod="kirchhoff")]
    if smoke:
        settings = settings[:2]
    for st in settings:
        kw = dict(st)
        dt, alpha = kw.pop("dt"), kw.pop("alpha")
        tip(dt, alpha, 1, **kw)
        end, per, ok = tip(dt, alpha, B, **kw)
        err = float(np.linalg.norm(end - ref))
        rows.append(dict(scene="dynamic step response", setting=label(st), applicable=True, tip_error_m=err,
                         converged=ok, us_per_rod_step=1e6 * per))
        print(f"{'dynamic step response':26s} {label(st):45s} error {err:9.2e} m  {1e6 * per:8.1f} us/rod-step")
    return rows


BUDGETS = (1e-3, 1e-5, 1e-7, 1e-9)
ACCURATE = "integrator=rk4, nodes=50"


def pick_table(rows: list[dict]) -> list[dict]:
    """Per scene and tip-error budget [m]: the fastest setting within it, and its speed-up over
    the "accurate" preset (RK4, N = 50) on the same scene."""
    out = []
    for name in dict.fromkeys(r["scene"] for r in rows):
        pts = [r for r in rows if r["scene"] == name and r.get("applicable") and r.get("converged")]
        cost = lambda r: r.get("us_per_rod", r.get("us_per_rod_step"))  # noqa: E731
        acc = next((cost(r) for r in pts if r["setting"] == ACCURATE), None)
        for budget in BUDGETS:
            ok = [r for r in pts if r["tip_error_m"] <= budget]
            if ok:
                best = min(ok, key=cost)
                out.append(dict(scene=name, budget_m=budget, setting=best["setting"], tip_error_m=best["tip_error_m"],
                                cost_us=cost(best), speedup_vs_accurate=(acc / cost(best)) if acc else None))
            else:
                out.append(dict(scene=name, budget_m=budget, setting=None))
    return out


def markdown(table: list[dict]) -> str:
    """pick_table's rows as the Markdown table of docs/accuracy.md: a row per scene, a column per budget,
    each cell the fastest setting within it, its cost and its speed-up over "accurate" ("-": none)."""
    names = list(dict.fromkeys(t["scene"] for t in table))
    lines = ["| scene | " + " | ".join(f"{b:.0e} m" for b in BUDGETS) + " |", "|---" * (len(BUDGETS) + 1) + "|"]
    for name in names:
        cells = []
        for t in (t for t in table if t["scene"] == name):
            if t["setting"] is None:
                cells.append("-")
                continue
            unit = "us per rod-step" if "dynamic" in name else "us"
            speedup = f" ({t['speedup_vs_accurate']:.1f}x)" if t["speedup_vs_accurate"] else ""
            cells.append(f"{short_label(t['setting'])}: {t['cost_us']:.3g} {unit}{speedup}, {t['tip_error_m']:.1e} m")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def short_label(setting: str) -> str:
    """'integrator=rk4, nodes=20, rod=kirchhoff' -> 'rk4 N=20 kirchhoff' (a point's label on the figure)."""
    words = [w.split("=", 1) for w in setting.split(", ")]
    return " ".join(f"N={v}" if k == "nodes" else v if k in ("integrator", "model", "rod", "precision") else f"{k}={v}"
                    for k, v in words)


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FormatStrFormatter, LogLocator, NullFormatter
    names = list(dict.fromkeys(r["scene"] for r in rows))
    fig, axes = plt.subplots(2, 3, figsize=(16, 9))
    for ax, name in zip(axes.ravel(), names):
        pts = [r for r in rows if r["scene"] == name and r.get("applicable")]
        t = np.array([r.get("us_per_rod", r.get("us_per_rod_step")) for r in pts])
        e = np.array([max(r["tip_error_m"], 1e-16) for r in pts])
        ax.loglog(t, e, "o", ms=4, color="C0", alpha=0.5, label="setting")
        front = pareto_front(t, e)  # the settings no other beats in both time and error
        ax.loglog(t[front], e[front], "r.-", lw=1, label="Pareto front")
        for rank, i in enumerate(sorted(front, key=lambda j: t[j])):  # the front only, in time order,
            # alternately right-above and left-below, so neighbours on the front do not overlap
            ax.annotate(short_label(pts[i]["setting"]), (t[i], e[i]), fontsize=6.5,
                        xytext=(5, 5) if rank % 2 == 0 else (-5, -11), textcoords="offset points",
                        ha="left" if rank % 2 == 0 else "right")
        if t.max() < 10 * t.min():  # within a decade: plain numbers at 1, 2, 5 x 10^k
            ax.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
            ax.xaxis.set_major_formatter(FormatStrFormatter("%g"))
        ax.xaxis.set_minor_formatter(NullFormatter())  # no colliding minor labels
        ax.margins(x=0.15, y=0.1)
        ax.legend(fontsize=7)
        ax.set_title(name)
        ax.set_xlabel("time per rod [us]" if "dynamic" not in name else "time per rod-step [us]")
        ax.set_ylabel("tip error [m]")
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--out", default=str(ROOT / "results" / "speed_accuracy.json"))
    ap.add_argument("--replot", metavar="JSON", help="redraw the figure from a saved report (its --out) and stop")
    args = ap.parse_args(argv)
    fig = ROOT / "docs" / "figures" / "speed_accuracy.png"
    if args.replot:
        rows = json.loads(Path(args.replot).read_text())["rows"]
        plot(rows, fig)
        print(markdown(pick_table(rows)))
        return 0
    rows = run_static(16 if args.smoke else 4096, 1 if args.smoke else 2, args.smoke)
    rows += run_dynamic(2 if args.smoke else 256, args.smoke)
    if not args.smoke:
        plot(rows, fig)
    table = pick_table(rows)
    print(markdown(table))
    write_report(args.out, {"meta": metadata(args.device), "rows": rows, "table": table})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
