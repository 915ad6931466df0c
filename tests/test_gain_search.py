"""The CMA-ES gain search (tdcr_warp.apps.gainsearch): reproducible, inside its bounds, exact in its
budget, ordered as the gain grid, and its [search] table, arguments and CLI outputs."""

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest
from scenes import GAIN_GRID_SWEEP

from tdcr_warp.apps.gainsearch import ClosedLoops, cma_search, gain_objective, search_gains
from tdcr_warp.apps.sweep import open_sweep
from tdcr_warp.cli import main
from tdcr_warp.io.scene import scene_from_dict
from tdcr_warp.model.robot import InputError

ROOT = Path(__file__).resolve().parents[1]
RANGES = {"control.gain_c": (5.0, 40.0), "control.gain_k": (5.0, 40.0), "control.epsilon": (0.005, 0.05),
          "control.phi": (0.001, 0.01)}
# short closed loops (20 steps) of the tests' gain-grid scene, with a search over two gains
SCENE = GAIN_GRID_SWEEP.replace("steps = 100", "steps = 20") + """
[search]
budget = 6
population = 4
seed = 3
[search.ranges]
"control.gain_c[0]" = [10.0, 40.0]
"control.gain_k[0]" = [10.0, 40.0]
"""


def bowl(optimum: dict, calls: list | None = None):
    """A cheap objective: the squared log-distance to ``optimum``; records each generation's rows."""
    def evaluate(rows):
        if calls is not None:
            calls.append({k: v.copy() for k, v in rows.items()})
        return {"objective": sum(np.log(rows[k] / v) ** 2 for k, v in optimum.items())}
    return evaluate


INTERIOR = {"control.gain_c": 13.0, "control.gain_k": 31.0, "control.epsilon": 0.011, "control.phi": 0.0023}


def test_finds_the_optimum_of_a_cheap_objective():
    res = cma_search(bowl(INTERIOR), RANGES, budget=600, seed=0)
    for k, v in INTERIOR.items():
        assert res.gains[k] == pytest.approx(v, rel=1e-4), (k, res.gains[k], v)
    assert res.objective < 1e-8
    best = [h["best_objective"] for h in res.history]
    assert best == sorted(best, reverse=True)  # best so far never gets worse


def test_same_seed_same_search_other_seed_other_search():
    a = cma_search(bowl(INTERIOR), RANGES, budget=40, seed=5)
    b = cma_search(bowl(INTERIOR), RANGES, budget=40, seed=5)
    c = cma_search(bowl(INTERIOR), RANGES, budget=40, seed=6)
    assert a.gains == b.gains and a.history == b.history
    assert all(np.array_equal(a.candidates[k], b.candidates[k]) for k in a.candidates)
    assert not np.array_equal(a.candidates["control.gain_c"], c.candidates["control.gain_c"])


def test_never_evaluates_outside_the_bounds():
    """An optimum outside the box pulls the search onto its corner; no candidate leaves it."""
    calls = []
    outside = {"control.gain_c": 100.0, "control.gain_k": 1.0, "control.epsilon": 0.5, "control.phi": 1e-4}
    res = cma_search(bowl(outside, calls), RANGES, budget=300, seed=1, sigma=1.0)
    for k, (lo, hi) in RANGES.items():
        v = np.concatenate([c[k] for c in calls])
        assert len(v) == 300 and v.min() >= lo and v.max() <= hi, (k, v.min(), v.max())
    corner = {"control.gain_c": 40.0, "control.gain_k": 5.0, "control.epsilon": 0.05, "control.phi": 0.001}
    assert res.gains == corner  # clipped onto the bounds: exactly the range ends


@pytest.mark.parametrize("budget", [1, 7, 8, 9, 45])
def test_budget_is_spent_exactly(budget):
    calls = []
    res = cma_search(bowl(INTERIOR, calls), RANGES, budget=budget, population=8, seed=0)
    sizes = [len(c["control.gain_c"]) for c in calls]
    assert sum(sizes) == res.closed_loops == budget == len(res.candidates["objective"])
    assert sizes == [h["population"] for h in res.history] and max(sizes) <= 8
    assert [h["closed_loops"] for h in res.history] == list(np.cumsum(sizes))
    assert res.generations == len(calls) == -(-budget // 8)


def test_restarts_double_the_population():
    """CMA-ES converged on a bowl long before the budget: IPOP restarts, population x 2 each."""
    res = cma_search(bowl({"control.phi": 0.003}), {"control.phi": (0.001, 0.01)}, budget=2000, seed=0)
    pops = [h["population"] for h in res.history]
    assert res.restarts >= 1 and res.population == 4 and pops[0] == 4
    assert sorted(set(pops[:-1])) == [4 * 2**r for r in range(res.restarts + 1)]
    assert res.closed_loops == 2000


def test_objective_orders_runs_as_the_gain_grid():
    """Sorted by the objective, runs come in the grid's order: settled by settling time, then
    chatter; then unsettled by final error; failed last."""
    rng = np.random.default_rng(0)
    dt, steps = 0.005, 200
    t = dt * np.arange(steps + 1)
    n = 4000
    ok = rng.random(n) > 0.05
    ts = np.where(rng.random(n) > 0.3, t[rng.integers(0, steps + 1, n)], np.inf)
    chatter = 10.0 ** rng.uniform(-12, 1, n)
    chatter[:50] = chatter[50:100]  # equal chatter at other settling times
    ts[100:150] = ts[150:200]  # equal settling times, other chatter
    settled = np.isfinite(ts)
    error = np.where(settled, rng.uniform(0, 5e-4, n), 5e-4 + 10.0 ** rng.uniform(-9, 0, n))
    f = gain_objective(ok, ts, chatter, error, dt=dt, duration=steps * dt)
    key = [(0, ts[i], chatter[i]) if ok[i] and settled[i] else (1, error[i], 0.0) if ok[i] else (2, 0.0, 0.0)
           for i in range(n)]
    order = np.argsort(f, kind="stable")
    ranked = [key[i] for i in order]
    assert all(a <= b for a, b in zip(ranked[:-1], ranked[1:]))
    assert np.isfinite(f).all()


GOOD_RANGES = '[search.ranges]\n"control.gain_c" = [5.0, 40.0]\n'
BAD_TABLES = [
    ("[search]\nbudget = 0\n" + GOOD_RANGES, "[search].budget"),
    ("[search]\nbudget = 2.5\n" + GOOD_RANGES, "[search].budget"),
    ("[search]\n" + GOOD_RANGES, "'budget'"),
    ("[search]\nbudget = 6\npopulation = 2\n" + GOOD_RANGES, "[search].population"),
    ("[search]\nbudget = 6\nseed = -1\n" + GOOD_RANGES, "[search].seed"),
    ("[search]\nbudget = 6\nsigma = 0.0\n" + GOOD_RANGES, "[search].sigma"),
    ("[search]\nbudget = 6\nsteps = 3\n" + GOOD_RANGES, "'steps'"),
    ('[search]\nbudget = 6\n[search.ranges]\n"control.gain_c" = [40.0, 5.0]\n', "'control.gain_c'"),
    ('[search]\nbudget = 6\n[search.ranges]\n"control.phi" = [0.0, 0.01]\n', "'control.phi'"),
    ('[search]\nbudget = 6\n[search.ranges]\n"control.epsilon" = [-1.0, 0.01]\n', "'control.epsilon'"),
    ('[search]\nbudget = 6\n[search.ranges]\n"control.gain_c" = [5.0]\n', "'control.gain_c'"),
    ('[search]\nbudget = 6\n[search.ranges]\n"control.tension_max" = [1.0, 8.0]\n', "'control.tension_max'"),
    ('[search]\nbudget = 6\n[search.ranges]\n"control.gain_x" = [1.0, 8.0]\n', "'control.gain_x'"),
    ('[search]\nbudget = 6\n[search.ranges]\n"control.gain_c" = [5.0, 40.0]\n"control.gain_c[1]" = [5.0, 40.0]\n',
     "'control.gain_c[1]'"),
    ('[search]\nbudget = 6\n[search.ranges]\n"control.gain_i" = [1.0, 8.0]\n', "[control].gain_i"),
]


@pytest.mark.parametrize("table,named", BAD_TABLES, ids=[f"{i}-{b[1]}" for i, b in enumerate(BAD_TABLES)])
def test_bad_search_tables_name_the_field(table, named):
    with pytest.raises(InputError) as e:
        scene_from_dict(tomllib.loads(GAIN_GRID_SWEEP + table))
    assert named in str(e.value), str(e.value)


def test_search_needs_its_tables():
    base = GAIN_GRID_SWEEP.split("[control]")[0].split("[dynamics]")[0]
    with pytest.raises(InputError, match=r"\[search\] needs a \[control\]"):
        scene_from_dict(tomllib.loads(base + '[search]\nbudget = 4\n[search.ranges]\n"control.phi" = [1e-3, 1e-2]\n'))
    with pytest.raises(InputError, match=r"\[search.ranges\]: expected a table"):
        scene_from_dict(tomllib.loads(GAIN_GRID_SWEEP + "[search]\nbudget = 4\n"))
    with pytest.raises(InputError, match=r"needs a \[search\] table"):
        search_gains(scene_from_dict(tomllib.loads(GAIN_GRID_SWEEP)))


@pytest.mark.parametrize("kw,named", [
    ({"budget": 0}, "budget"), ({"budget": -3}, "budget"), ({"population": 3}, "population"),
    ({"seed": 2**32}, "seed"), ({"sigma": 1.5}, "sigma"),
    ({"ranges": {"control.gain_c": (40.0, 5.0)}}, "'control.gain_c'"),
    ({"ranges": {"control.gain_c": (5.0, 5.0)}}, "'control.gain_c'"),
    ({"ranges": {"control.phi": (-1e-3, 1e-2)}}, "'control.phi'"),
    ({"ranges": {"gain_c": (5.0, 40.0)}}, "'gain_c'"),
    ({"ranges": {}}, "ranges"),
])
def test_bad_arguments_name_the_argument(kw, named):
    args = {"ranges": RANGES, "budget": 8} | kw
    with pytest.raises(InputError) as e:
        cma_search(bowl(INTERIOR), args.pop("ranges"), **args)
    assert named in str(e.value), str(e.value)


def assert_documented(*groups):
    doc = (ROOT / "docs" / "outputs.md").read_text()
    missing = sorted({k for keys in groups for k in keys if f"`{k}`" not in doc})
    assert not missing, f"outputs not documented in docs/outputs.md: {missing}"


def test_cli_search_beside_the_grid(tmp_path, capsys):
    """`tdcr-warp search --grid`: the budget of closed loops, reproducible, inside the ranges, its
    closed loops the grid's, every key documented."""
    scene = tmp_path / "gs.toml"
    scene.write_text(SCENE)
    grid = tmp_path / "grid"
    assert main(["gain-grid", str(scene), "--out", str(grid), "--quiet"]) == 0
    outs = [tmp_path / "a", tmp_path / "b"]
    for out, quiet in zip(outs, (["--quiet"], [])):  # the second with its progress bar
        assert main(["search", str(scene), "--out", str(out), "--grid", str(grid), *quiet]) == 0
    a, b = (json.loads((o / "results.json").read_text()) for o in outs)
    assert (outs[0] / "search.png").exists()
    assert "loops/s" in capsys.readouterr().err
    assert a["closed_loops"] == a["budget"] == 6 and a["history"][-1]["closed_loops"] == 6
    assert a["best"] == b["best"] and a["history"] == b["history"]  # same seed, same search
    assert a["gains"] == ["control.gain_c[0]", "control.gain_k[0]"]
    for g, (lo, hi) in a["ranges"].items():
        assert lo <= a["best"]["gains"][g] <= hi
    assert a["grid"]["closed_loops"] == 4
    assert a["grid"]["search_at_least_as_good"] == (a["best"]["objective"] <= a["grid"]["best"]["objective"])
    assert_documented(a, a["best"], a["history"][0], a["grid"], a["grid"]["best"])
    # the search's closed loops are the grid's: its evaluator on two grid points gives their rows bit for bit
    rows = open_sweep(grid).load()
    pick = [0, 3]
    got = ClosedLoops(scene_from_dict(tomllib.loads(SCENE)))({g: rows[f"sample:{g}"][pick] for g in a["gains"]})
    for key in ("settling_time", "final_error", "chatter", "overshoot", "peak_tension"):
        assert np.array_equal(got[key], rows[key][pick]), key


def test_cli_refuses_bad_input(tmp_path, capsys):
    scene = tmp_path / "gs.toml"
    scene.write_text(SCENE)
    assert main(["search", str(scene), "--out", str(tmp_path / "o"), "--grid", str(tmp_path / "nowhere")]) == 2
    assert "--grid" in capsys.readouterr().err
    scene.write_text(SCENE.replace("budget = 6", "budget = 0"))
    assert main(["search", str(scene), "--out", str(tmp_path / "o")]) == 2
    assert "[search].budget" in capsys.readouterr().err
    assert not (tmp_path / "o" / "results.json").exists()


def test_cli_interrupted_writes_no_results(tmp_path, monkeypatch, capsys):
    import tdcr_warp.apps.gainsearch as gs

    def interrupt(self, rows):
        raise KeyboardInterrupt
    monkeypatch.setattr(gs.ClosedLoops, "__call__", interrupt)
    scene = tmp_path / "gs.toml"
    scene.write_text(SCENE)
    assert main(["search", str(scene), "--out", str(tmp_path / "o"), "--quiet"]) == 130
    assert "interrupted" in capsys.readouterr().err
    assert not (tmp_path / "o" / "results.json").exists()
