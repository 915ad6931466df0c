"""Adaptive search of controller gains: CMA-ES where every generation is one batch of closed loops.

The ``gain-grid`` sweep runs one closed loop per point of an exhaustive grid of gains and ranks
them (:func:`tdcr_warp.apps.jobs.summarize_gain_grid`): the fastest settled run, ties broken by least
chatter; if nothing settled, the smallest final error. :func:`search_gains` looks for gains at
least as good by that ranking over the same ranges with far fewer closed loops, by CMA-ES
(Hansen's covariance matrix adaptation evolution strategy, the ``cmaes`` package):

- **Search space.** Each gain g in [lo, hi] is searched in log space, as
  u = ln(g / lo) / ln(hi / lo) in [0, 1] (over ranges of a decade a gain's effect goes with its
  ratio, not its difference). CMA-ES works in the unit box: a candidate outside it is clipped onto
  it (and told as clipped), so no closed loop ever runs outside the ranges, and a gain that wants
  to be at the end of its range gets exactly that end (where a grid has its corner points;
  resampling until inside, the package's default, approaches a corner slowly). It starts at the
  box's centre (the geometric mean of each range) with a step ``sigma`` (a fraction of each log
  range).
- **One batch per generation.** A generation's candidates run as one Simulator of B = population
  rods, each rod with its own gains, through the gain grid's own chunk job
  (:func:`tdcr_warp.apps.chunk.solve_chunk` of the ``gain-grid`` :class:`~tdcr_warp.apps.jobs.SweepJob`:
  the scene with the candidates as per-rod control values, run by
  :func:`~tdcr_warp.apps.jobs.control_job`), so a candidate's metrics are those the grid reports
  for the same gains, bit for bit.
- **Budget.** ``budget`` closed loops exactly: the last generation is cut to what the budget
  leaves (those loops are evaluated but not told to CMA-ES).
- **Restarts.** When CMA-ES has converged (its ``should_stop``) or stagnates (its best has not
  improved for 10 + ceil(30 d / population) generations, the horizon of its own flat-fitness
  test, for d gains) before the budget is spent, it restarts with twice the population from a
  mean drawn uniformly in the box (IPOP-CMA-ES, Auger & Hansen 2005); the best is the best over
  all runs. The stagnation test matters here: within the plateau of the fastest settling time
  the chatter varies by a few percent and has local minima (a corner of the box among them),
  where one CMA-ES run can sit for the rest of the budget.
- **Reproducible.** The seed fixes CMA-ES's draws and the restarts' means, and a rod's closed
  loop does not depend on its neighbours in the batch: the same seed gives the same candidates,
  metrics and result.

The objective (minimised), for a run of duration D = steps dt, settling time t_s [s], chatter
index c [N] and final error e [m] (``tdcr_warp.apps.control.control_metrics``; band = 0.5 mm):

    f = t_s + (dt / 2) c / (c + c_ref)     settled: every step converged, |e| stays in the band
    f = D + dt + e / (e + band)            every step converged, outside the band at the end
    f = D + dt + 1                         some time step failed

with c_ref = 1e-3 N. It orders runs exactly as the grid's ranking: t_s is a whole number of time
steps, so the chatter term (below dt / 2) only breaks ties of t_s; every settled run (f < D + dt/2)
beats every unsettled one (f > D + dt + 1/2, as e > band there), and unsettled runs are ordered by
final error. CMA-ES uses only the ranking of each generation's values, so what makes it workable
for the search is that this ranking has no wide ties: t_s alone is a step function of the gains,
but the chatter term tilts each of its steps; unsettled runs are graded by their final error, which
falls continuously to the band's edge, where the slowest settled runs begin, so the search is
pulled from regions that never settle toward ones that do. Only failed runs tie.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from tdcr_warp.io.scene import Scene, search_options
from tdcr_warp.model.robot import InputError

__all__ = ["BAND", "CHATTER_REF", "ClosedLoops", "SearchResult", "cma_search", "gain_objective", "search_gains"]

BAND = 5e-4  # [m] the settling band of control_metrics
CHATTER_REF = 1e-3  # [N] c_ref of the objective: the chatter that takes half of the tie-break's room
METRICS = ("settling_time", "final_error", "chatter", "overshoot", "peak_tension")  # the grid's best reports these


def gain_objective(ok, settling_time, chatter, final_error, *, dt: float, duration: float) -> np.ndarray:
    """The search's objective (module docstring) of runs: ``ok`` (every step converged),
    settling time [s] (inf: never settled), chatter [N], final error [m] (arrays of one shape),
    time step ``dt`` and run ``duration`` [s]. Lower is better; the order is the gain grid's."""
    ok = np.asarray(ok, dtype=bool)
    ts, c, e = (np.asarray(x, dtype=np.float64) for x in (settling_time, chatter, final_error))
    settled = ok & np.isfinite(ts)
    with np.errstate(invalid="ignore", divide="ignore"):
        f_settled = ts + 0.5 * dt * c / (c + CHATTER_REF)
        f_outside = duration + dt + e / (e + BAND)
    return np.where(settled, f_settled, np.where(ok, f_outside, duration + dt + 1.0))


@dataclass(frozen=True)
class SearchResult:
    """A finished search. gains: the best candidate {gain: value}; objective: its value;
    metrics: what the evaluator returned for it (closed loops: ``ok`` and the metrics of the gain
    grid's best, settling_time [s] (inf: never), final_error [m], chatter [N], overshoot [m],
    peak_tension [N]); closed_loops: candidates evaluated (the budget); population: the first
    CMA-ES's; generations, restarts; history: per generation {generation, closed_loops (spent so
    far), population (evaluated in it), best_objective (so far)}; candidates: every evaluated
    candidate in evaluation order, {gain: (n,), "generation": (n,), and each key evaluate
    returned: "objective" and the metrics}."""

    gains: dict[str, float]
    objective: float
    metrics: dict
    closed_loops: int
    population: int
    generations: int
    restarts: int
    history: list[dict] = field(default_factory=list)
    candidates: dict[str, np.ndarray] = field(default_factory=dict)


def cma_search(evaluate, ranges: dict, *, budget: int, population: int | None = None, seed: int = 0,
               sigma: float = 0.3, on_generation=None) -> SearchResult:
    """CMA-ES over the gains of ``ranges`` {gain: (lo, hi)} in log space (module docstring),
    spending exactly ``budget`` evaluations. ``evaluate(rows)`` gets a generation's candidates
    {gain: (n,) values} and returns a dict of (n,) arrays with at least ``"objective"`` (minimised,
    finite) and any metrics to keep for the best. ``population``: candidates a generation (None:
    4 + floor(3 ln d)); ``seed``; ``sigma``: the initial step as a fraction of each log range.
    ``on_generation(result_so_far)`` is called after each generation. Bad options raise an
    InputError naming the argument (the checks of a scene's [search] table)."""
    from cmaes import CMA

    opts = search_options({"ranges": ranges, "budget": budget, "population": population, "seed": seed,
                           "sigma": sigma}, where="")
    names = list(opts["ranges"])
    lo = np.array([opts["ranges"][n][0] for n in names])
    hi = np.array([opts["ranges"][n][1] for n in names])
    log_lo, log_span = np.log(lo), np.log(hi / lo)
    d = len(names)
    box = np.stack([np.zeros(d), np.ones(d)], axis=1)
    rng = np.random.default_rng(opts["seed"])
    pop = first = opts["population"] or 4 + math.floor(3 * math.log(d))
    cma = CMA(mean=np.full(d, 0.5), sigma=opts["sigma"], bounds=box, seed=opts["seed"], population_size=pop,
              n_max_resampling=0)  # clip, never resample (module docstring)
    spent = generations = restarts = 0
    run_best, stalled = math.inf, 0  # the current CMA-ES run's best, generations since it improved
    best: dict | None = None
    history: list[dict] = []
    seen: dict[str, list] = {k: [] for k in (*names, "generation")}

    def result() -> SearchResult:
        return SearchResult(gains=dict(best["gains"]), objective=best["objective"], metrics=dict(best["metrics"]),
                            closed_loops=spent, population=first, generations=generations, restarts=restarts,
                            history=list(history), candidates={k: np.array(v) for k, v in seen.items()})

    while spent < opts["budget"]:
        n = min(cma.population_size, opts["budget"] - spent)
        u = np.array([cma.ask() for _ in range(n)])
        # a clipped coordinate is exactly its bound (exp(log(lo)) may round off lo)
        gains = np.where(u <= 0.0, lo, np.where(u >= 1.0, hi, np.clip(np.exp(log_lo + u * log_span), lo, hi)))
        rows = {name: gains[:, j] for j, name in enumerate(names)}
        out = evaluate(rows)
        f = np.asarray(out["objective"], dtype=np.float64)
        if f.shape != (n,) or not np.isfinite(f).all():
            raise ValueError(f"evaluate must return a finite 'objective' of shape ({n},), got {f!r}")
        spent += n
        generations += 1
        for j, name in enumerate(names):
            seen[name].extend(gains[:, j].tolist())
        seen["generation"].extend([generations] * n)
        for k, v in out.items():
            seen.setdefault(k, []).extend(np.asarray(v).tolist())
        i = int(np.argmin(f))
        run_best, stalled = (f[i], 0) if f[i] < run_best else (run_best, stalled + 1)
        if best is None or f[i] < best["objective"]:
            best = {"gains": {name: float(gains[i, j]) for j, name in enumerate(names)}, "objective": float(f[i]),
                    "metrics": {k: np.asarray(v)[i].item() for k, v in out.items() if k != "objective"}}
        history.append({"generation": generations, "closed_loops": spent, "population": n,
                        "best_objective": best["objective"]})
        if n == cma.population_size:
            cma.tell(list(zip(u, f.tolist())))
            horizon = 10 + math.ceil(30 * d / pop)
            if spent < opts["budget"] and (cma.should_stop() or stalled >= horizon):
                restarts += 1
                pop *= 2
                run_best, stalled = math.inf, 0
                cma = CMA(mean=rng.uniform(0.0, 1.0, d), sigma=opts["sigma"], bounds=box,
                          seed=int(rng.integers(2**32)), population_size=pop, n_max_resampling=0)
        if on_generation is not None:
            on_generation(result())
    return result()


class ClosedLoops:
    """The evaluator of :func:`cma_search` for a scene with [dynamics] and [control]: a
    generation's candidates as one batch of closed loops (the gain grid's chunk job), returning
    the objective, ``ok`` and the grid's best-run metrics per candidate. ``progress(step, steps)``
    is called after every time step; ``device``: the Warp device."""

    def __init__(self, scene: Scene, *, device=None, progress=None):
        from tdcr_warp.apps.jobs import SweepJob

        if scene.dynamics is None or scene.control is None:
            raise InputError("a gain search needs [dynamics] and [control] tables")
        self.data, self.progress = scene.source, progress
        self.job = SweepJob("gain-grid", device=device)
        self.dt, self.duration = scene.dynamics.dt, scene.dynamics.steps * scene.dynamics.dt

    def __call__(self, rows: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        from tdcr_warp.apps.chunk import solve_chunk

        res = solve_chunk(self.job, self.data, rows, progress=self.progress)
        ok = np.asarray(res["ok"], dtype=bool)
        f = gain_objective(ok, res["settling_time"], res["chatter"], res["final_error"], dt=self.dt,
                           duration=self.duration)
        return {"objective": f, "ok": ok, **{k: np.asarray(res[k], dtype=np.float64) for k in METRICS}}


def search_gains(scene: Scene, *, device=None, progress=None, on_generation=None) -> SearchResult:
    """CMA-ES over the gains of the scene's [search] table (budget, population, seed, sigma and
    ranges), each generation one batch of closed loops (:class:`ClosedLoops`); ``progress`` and
    ``on_generation`` as there and in :func:`cma_search`."""
    if scene.search is None:
        raise InputError("a gain search needs a [search] table (budget, [search.ranges])")
    s = scene.search
    return cma_search(ClosedLoops(scene, device=device, progress=progress), s["ranges"], budget=s["budget"],
                      population=s["population"], seed=s["seed"], sigma=s["sigma"], on_generation=on_generation)
