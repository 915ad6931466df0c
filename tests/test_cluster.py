"""The Ray backend of sweeps (skipped without the ray extra): a local 2-CPU Ray cluster must give
the in-process results rod for rod, survive a worker that dies, and resume across backends."""

import os
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest
from scenes import GAIN_GRID_SWEEP, MC_SWEEP

from tdcr_warp.apps.jobs import SweepJob, static_job
from tdcr_warp.apps.sweep import open_sweep, run_sweep
from tdcr_warp.cli import main

ray = pytest.importorskip("ray")

TESTS = Path(__file__).resolve().parent

SWEEP = MC_SWEEP.replace("chunk = 16", "chunk = 5").replace("samples = 40", "samples = 23")


class DieOnce:
    """A job whose first call kills its own worker process (as a crash or an OOM kill would);
    every later call, in a new worker, does the real work."""

    def __init__(self, marker: str):
        self.marker = marker

    def __call__(self, scene):
        try:
            os.remove(self.marker)  # atomic: exactly one task wins
        except FileNotFoundError:
            return static_job(scene)
        os._exit(1)


@pytest.fixture(scope="module")
def cluster():
    """One local Ray of 2 CPUs for the module; workers can import this test module."""
    path = os.pathsep.join(filter(None, [str(TESTS), os.environ.get("PYTHONPATH")]))
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False,
             runtime_env={"env_vars": {"PYTHONPATH": path}})
    yield ray.get_runtime_context().gcs_address
    ray.shutdown()


@pytest.fixture(scope="module")
def local(tmp_path_factory):
    """The in-process reference result of SWEEP."""
    return run_sweep(tomllib.loads(SWEEP), SweepJob("workspace"), tmp_path_factory.mktemp("local"),
                     progress=False).load()


def assert_same(a: dict, b: dict) -> None:
    assert set(a) == set(b)
    for k in a:
        assert np.array_equal(a[k], b[k]), k


def test_two_workers_give_the_in_process_result(cluster, local, tmp_path):
    res = run_sweep(tomllib.loads(SWEEP), SweepJob("workspace"), tmp_path, backend="ray", progress=False).load()
    assert res["ok"].all() and len(res["ok"]) == 23
    assert_same(local, res)


def test_workers_are_reused_across_chunks(cluster, tmp_path):
    """Kernels load once per worker process: 10 chunks run on at most the 2 workers' processes."""
    from tdcr_warp.apps.cluster import ray_chunks
    from tdcr_warp.apps.sweep import Samples, SweepSpec
    from tdcr_warp.io.store import ChunkStore

    data = tomllib.loads(SWEEP)
    info = []
    store = ChunkStore(tmp_path, "test", 20, 2)
    done = dict(ray_chunks(data, static_job, list(range(10)), store, Samples(SweepSpec(data)), worker_info=info))
    assert sorted(done) == list(range(10)) and len(info) == 10
    assert len({i["pid"] for i in info}) <= 2


def test_a_killed_worker_is_retried_and_nothing_is_lost(cluster, local, tmp_path):
    marker = tmp_path / "die_once"
    marker.touch()
    res = run_sweep(tomllib.loads(SWEEP), DieOnce(str(marker)), tmp_path / "o", backend="ray", progress=False)
    assert not marker.exists(), "no worker was killed"
    assert_same(local, res.load())


@pytest.mark.parametrize("first,second", [("local", "ray"), ("ray", "local")])
def test_resume_across_backends(cluster, local, tmp_path, first, second):
    data = tomllib.loads(SWEEP)
    job = SweepJob("workspace")
    assert run_sweep(data, job, tmp_path, backend=first, max_chunks=2, progress=False) is None
    assert len(list((tmp_path / "results").glob("part-*.parquet"))) == 2
    assert_same(local, run_sweep(data, job, tmp_path, backend=second, resume=True, progress=False).load())


def test_interrupted_driver_resumes(cluster, local, tmp_path):
    """Ctrl-C of the CLI driver in the middle of a Ray sweep, then --resume in process."""
    scene = tmp_path / "big.toml"
    # 300 chunks of 2 rods at N = 100: a run of seconds, so the interrupt lands in its middle
    scene.write_text(SWEEP.replace("samples = 23", "samples = 600").replace("chunk = 5", "chunk = 2")
                     .replace("nodes = 16", "nodes = 100"))
    out = tmp_path / "o"
    argv = ["workspace", str(scene), "--out", str(out), "--backend", "ray", "--address", cluster, "--quiet"]
    # Ctrl-C raises KeyboardInterrupt even where this test runs as a background job (SIGINT ignored)
    code = ("import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
            f"from tdcr_warp.cli import main; sys.exit(main({argv!r}))")
    proc = subprocess.Popen([sys.executable, "-c", code],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not list((out / "results").glob("part-*.parquet")) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    n_done = len(list((out / "results").glob("part-*.parquet")))
    assert proc.returncode == 130, (n_done, err)
    assert "rerun with --resume" in err
    assert 1 <= n_done < 300 and not (out / "summary.json").exists()
    assert main(["workspace", str(scene), "--out", str(out), "--quiet", "--resume"]) == 0
    full = tmp_path / "full"
    assert main(["workspace", str(scene), "--out", str(full), "--quiet"]) == 0
    assert_same(open_sweep(out).load(), open_sweep(full).load())


def run_both(command: str, text: str, tmp_path, local_args=()) -> tuple:
    """The results of ``command`` on the scene text with --backend ray and in process."""
    scene = tmp_path / "s.toml"
    scene.write_text(text)
    assert main([command, str(scene), "--out", str(tmp_path / "r"), "--quiet", "--backend", "ray"]) == 0
    assert main([command, str(scene), "--out", str(tmp_path / "l"), "--quiet", *local_args]) == 0
    return open_sweep(tmp_path / "r").load(), open_sweep(tmp_path / "l").load()


def test_cli_ray_backend_matches_local(cluster, tmp_path):
    a, b = run_both("montecarlo", SWEEP, tmp_path, ["--shapes"])
    assert "positions" not in a and b["positions"].shape == (23, 17, 3)
    for k in a:
        assert np.array_equal(a[k], b[k]), k


def test_gain_grid_on_ray_matches_local(cluster, tmp_path):
    """Closed-loop control jobs (dynamics + controller in the worker) give the in-process metrics."""
    a, b = run_both("gain-grid", GAIN_GRID_SWEEP, tmp_path)
    assert set(a) == set(b) and "settling_time" in a
    for k in a:
        assert np.array_equal(a[k], b[k], equal_nan=True), k
