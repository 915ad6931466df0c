"""Sweeps one can trust: checked chunks, one writer per folder, answers independent of the batch,
streaming summaries that equal the all-at-once ones, and outputs that pandas and xarray open."""

import json
import os
import shutil
import tomllib

import numpy as np
import pytest
from scenes import GAIN_GRID_SWEEP, MC_SWEEP, two_tendon_scene

import tdcr_warp as tw
from tdcr_warp.apps.jobs import ERROR_EDGES, Histogram, SweepJob, convex_hull_2d, pareto_front, static_job
from tdcr_warp.apps.sweep import Samples, SweepSpec, make_samples, open_sweep, run_sweep
from tdcr_warp.cli import main
from tdcr_warp.io.files import FolderLock
from tdcr_warp.io.scene import scene_from_dict
from tdcr_warp.io.store import ChunkError
from tdcr_warp.model.robot import InputError


@pytest.fixture
def scene(tmp_path):
    path = tmp_path / "mc.toml"
    path.write_text(MC_SWEEP)  # 40 rods in chunks of 16: parts 0, 1, 2
    return path


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The uninterrupted sweep of MC_SWEEP: its folder and its results."""
    out = tmp_path_factory.mktemp("ref") / "o"
    path = out.parent / "mc.toml"
    path.write_text(MC_SWEEP)
    assert main(["montecarlo", str(path), "--out", str(out), "--quiet"]) == 0
    return out, open_sweep(out).load()


def assert_same(a: dict, b: dict) -> None:
    assert set(a) == set(b)
    for k in a:
        assert np.array_equal(a[k], b[k]), k


def part(out, c: int):
    return out / "results" / f"part-{c:05d}.parquet"


def damage_copy(out):
    shutil.copy(part(out, 0), part(out, 1))


def damage_fewer_rows(out):
    import pyarrow.parquet as pq
    t = pq.read_table(part(out, 1))
    pq.write_table(t.slice(0, 5), part(out, 1))  # its metadata kept: only the rows are fewer


def damage_truncate(out):
    data = part(out, 1).read_bytes()
    part(out, 1).write_bytes(data[: len(data) // 2])


def damage_empty(out):
    part(out, 1).write_bytes(b"")


def damage_value(out):
    import pyarrow as pa
    import pyarrow.parquet as pq
    t = pq.read_table(part(out, 1))
    i = t.column_names.index("tip_position[0]")
    t = t.set_column(i, "tip_position[0]", pa.array(t.column(i).to_numpy() + 1e-9))
    pq.write_table(t, part(out, 1))


def damage_zarr(out):
    import zarr
    a = zarr.open_array(out / "arrays.zarr" / "tip_rotation", mode="r+")
    a[20] = np.eye(3)  # a row of chunk 1


@pytest.mark.parametrize("damage,reason", [(damage_copy, "chunk 0, expected 1"), (damage_fewer_rows, "expected 16"),
                                           (damage_truncate, "unreadable"), (damage_empty, "unreadable"),
                                           (damage_value, "checksum mismatch"), (damage_zarr, "checksum mismatch")])
def test_a_bad_chunk_is_never_merged(scene, tmp_path, reference, capsys, damage, reason):
    """A part copied over another, cut short, emptied or altered (table or Zarr rows): reading
    the sweep names the file (exit 2 from the CLI), and --resume recomputes that chunk."""
    out = tmp_path / "o"
    assert main(["montecarlo", str(scene), "--out", str(out), "--quiet"]) == 0
    damage(out)
    with pytest.raises(ChunkError, match=reason):
        open_sweep(out).load()
    capsys.readouterr()
    assert main(["montecarlo", str(scene), "--out", str(out), "--quiet", "--resume"]) == 0
    err = capsys.readouterr().err
    assert "chunk 1 rejected, recomputing it" in err and "part-00001.parquet" in err and "Traceback" not in err
    assert_same(reference[1], open_sweep(out).load())


def test_a_bad_chunk_found_by_the_summary_is_exit_2(scene, tmp_path, capsys, monkeypatch):
    """A part damaged between the run and its summary: exit 2 naming it, no summary."""
    import tdcr_warp.apps.jobs as jobs
    out = tmp_path / "o"
    real = jobs.summarize_montecarlo

    def damaged_first(run, nominal, where):
        damage_value(out)
        return real(run, nominal, where)
    monkeypatch.setattr(jobs, "summarize_montecarlo", damaged_first)
    assert main(["montecarlo", str(scene), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "part-00001.parquet: checksum mismatch" in err and "Traceback" not in err
    assert not (out / "summary.json").exists()


def test_a_second_writer_is_refused(scene, tmp_path, capsys):
    out = tmp_path / "o"
    out.mkdir()
    with FolderLock(out, "sweep"):  # another sweep writing this folder (a separate open file: flock excludes it)
        assert main(["montecarlo", str(scene), "--out", str(out), "--quiet"]) == 2
    assert f"{out} is being written by another tdcr-warp sweep (pid {os.getpid()} on" in capsys.readouterr().err
    assert not (out / "results").exists()


def test_a_stale_lock_is_taken_over(scene, tmp_path, capsys):
    out = tmp_path / "o"
    out.mkdir()
    (out / ".lock").write_text(json.dumps({"pid": 999999999, "host": "gone", "started": "yesterday"}))
    assert main(["montecarlo", str(scene), "--out", str(out), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "pid 999999999" in err and "taken over" in err


def test_a_linked_lock_is_refused_and_its_target_kept(scene, tmp_path, capsys):
    """A .lock that is a symbolic link (or a hard link) to another file: exit 2 naming it, and the
    file it points to is neither truncated nor written."""
    precious = tmp_path / "precious.txt"
    precious.write_text("keep me\n")
    out = tmp_path / "o"
    out.mkdir()
    (out / ".lock").symlink_to(precious)
    assert main(["montecarlo", str(scene), "--out", str(out), "--quiet"]) == 2
    assert capsys.readouterr().err == (f"tdcr-warp: error: {out / '.lock'}: the lock file is a symbolic link: "
                                       "refusing to follow it; remove it\n")
    (out / ".lock").unlink()
    os.link(precious, out / ".lock")
    assert main(["montecarlo", str(scene), "--out", str(out), "--quiet"]) == 2
    assert "the lock file is a file with 2 hard links: refusing to write it" in capsys.readouterr().err
    assert precious.read_text() == "keep me\n"
    assert sorted(p.name for p in out.iterdir()) == [".lock"]


def test_a_linked_results_folder_is_not_written_through(scene, tmp_path, capsys):
    """On --resume a results/ that is a symbolic link is refused; a new sweep removes the link
    itself (not what it points to) and writes a folder of its own."""
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "mine.txt").write_text("keep me")
    out = tmp_path / "o"
    assert main(["montecarlo", str(scene), "--out", str(out), "--quiet", "--max-chunks", "1"]) == 1
    shutil.rmtree(out / "results")
    (out / "results").symlink_to(elsewhere)
    assert main(["montecarlo", str(scene), "--out", str(out), "--quiet", "--resume"]) == 2
    assert f"{out / 'results'} is a symbolic link" in capsys.readouterr().err
    assert main(["montecarlo", str(scene), "--out", str(out), "--quiet", "--overwrite", "--max-chunks", "1"]) == 1
    assert not (out / "results").is_symlink()
    (out / "results" / "part-00002.parquet").symlink_to(elsewhere / "mine.txt")  # a link inside: refused too
    assert main(["montecarlo", str(scene), "--out", str(out), "--quiet", "--resume"]) == 2
    assert f"{out / 'results' / 'part-00002.parquet'} is a symbolic link" in capsys.readouterr().err
    (out / "results" / "part-00002.parquet").unlink()
    assert main(["montecarlo", str(scene), "--out", str(out), "--quiet", "--resume"]) == 0
    assert len(list((out / "results").iterdir())) == 3
    assert [p.name for p in elsewhere.iterdir()] == ["mine.txt"] and (elsewhere / "mine.txt").read_text() == "keep me"


def test_another_sweep_in_the_folder_needs_overwrite(scene, tmp_path, capsys):
    """A finished sweep's outputs are neither mixed with nor left beside a new sweep's: without
    --overwrite the new one is refused; with it the old outputs go before it starts."""
    out = tmp_path / "o"
    assert main(["montecarlo", str(scene), "--out", str(out), "--quiet"]) == 0
    other = tmp_path / "other.toml"
    other.write_text(MC_SWEEP.replace("seed = 3", "seed = 4"))
    assert main(["montecarlo", str(other), "--out", str(out), "--quiet"]) == 2
    assert "--overwrite replaces it" in capsys.readouterr().err
    assert main(["montecarlo", str(other), "--out", str(out), "--quiet", "--resume"]) == 2
    assert "holds a different sweep" in capsys.readouterr().err
    assert main(["montecarlo", str(other), "--out", str(out), "--quiet", "--overwrite", "--max-chunks", "1"]) == 1
    assert not (out / "summary.json").exists() and not (out / "montecarlo.png").exists()
    assert len(list((out / "results").glob("part-*.parquet"))) == 1
    assert json.loads((out / "sweep.json").read_text())["state"] == "running"
    with pytest.raises(InputError, match="unfinished sweep"):
        open_sweep(out)


def test_the_earlier_npz_layout_is_not_mixed_in(scene, tmp_path, capsys):
    out = tmp_path / "o"
    (out / "chunks").mkdir(parents=True)
    np.savez(out / "results.npz", ok=np.ones(3))
    assert main(["montecarlo", str(scene), "--out", str(out), "--quiet"]) == 2
    assert "earlier tdcr-warp version" in capsys.readouterr().err
    assert main(["montecarlo", str(scene), "--out", str(out), "--quiet", "--overwrite"]) == 0
    assert not (out / "results.npz").exists() and not (out / "chunks").exists()


def test_resuming_a_finished_sweep_computes_nothing(scene, tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["montecarlo", str(scene), "--out", str(out), "--quiet"]) == 0
    capsys.readouterr()
    assert main(["montecarlo", str(scene), "--out", str(out), "--quiet", "--resume"]) == 0
    assert "nothing computed" in capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    assert summary["computed_rods"] == 0 and summary["rods_per_s"] is None


@pytest.mark.parametrize("flag", ["--chunk", "--max-chunks"])
def test_non_positive_counts_are_refused(scene, tmp_path, capsys, flag):
    assert main(["montecarlo", str(scene), "--out", str(tmp_path / "o"), "--quiet", flag, "0"]) == 2
    assert f"{flag} must be a positive integer, got 0" in capsys.readouterr().err


def test_a_chunk_too_large_for_memory_is_refused_up_front(tmp_path):
    data = tomllib.loads(MC_SWEEP.replace("samples = 40", "samples = 900000000").replace("chunk = 16",
                                                                                          "chunk = 900000000"))
    with pytest.raises(InputError, match="use a smaller --chunk"):
        run_sweep(data, static_job, tmp_path / "o", progress=False)
    assert not (tmp_path / "o").exists()


def test_samples_are_the_same_whatever_the_chunks(monkeypatch):
    """Rows lo..hi made on their own equal the whole table's, across block boundaries, with a
    grid, random fields and the total-tension filter."""
    monkeypatch.setattr(Samples, "BLOCK", 7)
    data = tomllib.loads(two_tendon_scene("[[1.0, 0.5]]") + """
[sweep]
seed = 5
max_total_tension = 3.0
[sweep.grid]
"actuation.tensions[0]" = [0.0, 3.0, 7]
"actuation.tensions[1]" = [0.0, 3.0, 5]
[[uncertainty]]
field = "robot.youngs_modulus"
distribution = "lognormal"
params = [26.0, 0.05]
""")
    samples = Samples(SweepSpec(data))
    whole = make_samples(SweepSpec(data))
    total = whole["actuation.tensions[0]"] + whole["actuation.tensions[1]"]
    assert len(samples) == int((total <= 3.0 + 1e-12).sum()) == len(total) and (total <= 3.0 + 1e-12).all()
    rng = np.random.default_rng(0)
    for _ in range(30):
        lo = int(rng.integers(0, len(samples)))
        hi = int(rng.integers(lo + 1, len(samples) + 1))
        got = samples(lo, hi)
        for k, v in whole.items():
            assert np.array_equal(got[k], v[lo:hi]), (k, lo, hi)


# -- batch-independent answers -------------------------------------------------------------------

def _solve(tau, threads=None):
    d = tomllib.loads(two_tendon_scene("[[1.0, 0.5]]", nodes=16))
    d["actuation"]["tensions"] = tau.tolist()
    if threads:
        d["solver"]["threads"] = threads
    s = scene_from_dict(d)
    return tw.solve_static(s.robot, s.tensions, options=s.options)


def test_an_extreme_neighbour_changes_no_other_rod():
    """One rod at 400 N (it converges, after a long continuation) among 300 ordinary ones:
    every other rod's tip and iteration count are bit-identical to the batch without it, on
    one thread and on two."""
    tau = np.random.default_rng(1).uniform(0.0, 3.0, (300, 2))
    extreme = tau.copy()
    extreme[150, 0] = 400.0
    for threads in (1, 2):
        a, b = _solve(tau, threads), _solve(extreme, threads)
        assert b.converged[150] and b.iterations[150] > a.iterations.max()
        others = np.arange(300) != 150
        assert np.array_equal(a.tip_position[others], b.tip_position[others])
        assert np.array_equal(a.iterations[others], b.iterations[others])
    one, two = _solve(extreme, 1), _solve(extreme, 2)
    assert np.array_equal(one.tip_position, two.tip_position) and np.array_equal(one.iterations, two.iterations)


def test_chunk_size_changes_no_answer(tmp_path):
    data = tomllib.loads(MC_SWEEP.replace("samples = 40", "samples = 160"))
    big = run_sweep(data, SweepJob("montecarlo"), tmp_path / "a", chunk=160, progress=False).load()
    small = run_sweep(data, SweepJob("montecarlo"), tmp_path / "b", chunk=7, progress=False).load()
    assert_same(big, small)


# -- streaming summaries and the file formats ----------------------------------------------------

def test_streaming_montecarlo_summary_equals_the_whole_table(reference):
    out, res = reference
    summary = json.loads((out / "summary.json").read_text())
    ok = res["ok"].astype(bool)
    tips = res["tip_position"][ok]
    assert np.allclose(summary["tip_mean"], tips.mean(0), rtol=1e-14, atol=0)
    assert np.allclose(summary["tip_covariance"], np.cov(tips.T), rtol=1e-9, atol=1e-22)
    err = np.linalg.norm(tips - np.array(summary["nominal_tip"]), axis=1)
    for p, v in summary["tip_error_percentiles_m"].items():  # a quantile of the sample, to a bin's width
        assert (err < v / 1.012).mean() <= float(p) / 100 <= (err <= v * 1.012).mean(), p


def test_histogram_percentiles_are_within_a_bin():
    v = np.random.default_rng(2).lognormal(-8, 1.5, 100_000)
    h = Histogram(ERROR_EDGES)
    for chunk in np.array_split(v, 13):
        h.add(chunk)
    for p in (1, 5, 50, 95, 99.9):
        assert h.percentile(p) == pytest.approx(np.percentile(v, p), rel=0.012)
    assert h.max == v.max() and h.percentile(100) == v.max()


def test_streaming_workspace_hulls_equal_the_whole_cloud(tmp_path):
    path = tmp_path / "ws.toml"
    path.write_text(two_tendon_scene("[[0.0, 0.0]]", nodes=10) + """
[sweep]
chunk = 9
[sweep.grid]
"actuation.tensions[0]" = [0.0, 4.0, 9]
"actuation.tensions[1]" = [0.0, 4.0, 9]
""")
    out = tmp_path / "o"
    assert main(["workspace", str(path), "--out", str(out), "--quiet"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    tips = open_sweep(out).load()["tip_position"]
    edges = np.linspace(tips[:, 2].min(), tips[:, 2].max() + 1e-12, 9)
    which = np.searchsorted(edges, tips[:, 2], side="right") - 1
    want = [convex_hull_2d(tips[which == k, :2]) for k in range(8) if (which == k).sum() >= 3]
    got = [np.array(s["hull_xy"]) for s in summary["boundary_slices"]]
    assert len(got) == len(want)
    for g, w in zip(got, want):
        assert np.array_equal(g, w)


def test_streaming_gain_grid_equals_the_whole_table(tmp_path):
    path = tmp_path / "gg.toml"
    path.write_text(GAIN_GRID_SWEEP.replace('"control.gain_k[0]" = [10.0, 40.0, 2]',
                                            '"control.gain_k[0]" = [10.0, 40.0, 3]').replace("steps = 100", "steps = 60"))
    out = tmp_path / "o"
    assert main(["gain-grid", str(path), "--out", str(out), "--quiet"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    res = open_sweep(out).load()
    ok = res["ok"].astype(bool)
    settle = np.where(ok, res["settling_time"], np.inf)
    chatter = np.where(ok, res["chatter"], np.inf)
    front = pareto_front(np.where(np.isfinite(settle), settle, 1e9), chatter)
    front = front[np.isfinite(settle[front])]
    assert [p["settling_time"] for p in summary["pareto"]] == settle[front].tolist()
    best = (np.lexsort((chatter, settle)) if np.isfinite(settle).any() else
            np.argsort(np.where(ok, res["final_error"], np.inf), kind="stable"))[0]
    assert summary["best"]["final_error"] == res["final_error"][best]


def test_results_open_in_pandas_and_xarray(tmp_path, scene):
    pd = pytest.importorskip("pandas")
    xr = pytest.importorskip("xarray")
    out = tmp_path / "o"
    assert main(["montecarlo", str(scene), "--out", str(out), "--quiet", "--shapes"]) == 0
    df = pd.read_parquet(out / "results")
    assert len(df) == 40 and df["row"].tolist() == list(range(40))
    assert {"tip_position[2]", "ok", "iterations", "sample:robot.youngs_modulus"} <= set(df.columns)
    ds = xr.open_zarr(out / "arrays.zarr")
    assert ds["positions"].dims == ("row", "node", "xyz") and ds["positions"].shape == (40, 17, 3)
    assert np.array_equal(ds["positions"].values[:, -1, :], df[[f"tip_position[{i}]" for i in range(3)]].to_numpy())


def test_an_interrupt_while_summarising_leaves_nothing_complete_looking(scene, tmp_path, capsys, monkeypatch):
    """Ctrl-C in the summary phase: exit 130, one line, no summary; --resume then summarises
    the kept chunks without computing any."""
    import tdcr_warp.apps.jobs as jobs
    out = tmp_path / "o"

    def interrupted(*args):
        raise KeyboardInterrupt
    with monkeypatch.context() as m:
        m.setattr(jobs, "summarize_montecarlo", interrupted)
        assert main(["montecarlo", str(scene), "--out", str(out), "--quiet"]) == 130
    err = capsys.readouterr().err
    assert "interrupted" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (out / "summary.json").exists()
    assert main(["montecarlo", str(scene), "--out", str(out), "--quiet", "--resume"]) == 0
    assert json.loads((out / "summary.json").read_text())["computed_rods"] == 0
