"""``tdcr-warp warmup``: the kernels of the runs it names land in Warp's kernel cache."""

import os
import subprocess
import sys
from pathlib import Path

from tdcr_warp.cli import build_parser
from tdcr_warp.cli.warmup import DEFAULT_RUNS, EXAMPLES, runs_of

SEED = Path(__file__).resolve().parents[1] / "examples" / "seed_robot.toml"


def test_default_runs_are_example_commands():
    commands = build_parser()._subparsers._group_actions[0].choices
    assert EXAMPLES.is_dir()
    for command, scene in runs_of([]):
        assert command in commands and Path(scene).is_file(), (command, scene)
    assert len(runs_of([])) == len(DEFAULT_RUNS)
    assert runs_of(["a.toml"]) == [("static", "a.toml")]


def test_warmup_fills_the_kernel_cache_then_compiles_nothing(tmp_path):
    env = dict(os.environ, WARP_CACHE_PATH=str(tmp_path / "cache"))
    cmd = [sys.executable, "-m", "tdcr_warp", "warmup", str(SEED)]
    first = subprocess.run(cmd, env=env, cwd=tmp_path, capture_output=True, text=True, check=False)
    assert first.returncode == 0, first.stdout + first.stderr
    assert "building the kernels of 1 run(s)" in first.stdout
    built = [p.name for p in (tmp_path / "cache").glob("*/wp_tdcr_warp_fused_float64_rk4_coupled_static_*")]
    assert built, list((tmp_path / "cache").rglob("*"))
    again = subprocess.run(cmd, env=env, cwd=tmp_path, capture_output=True, text=True, check=False)
    assert again.returncode == 0 and "0 kernel module(s) compiled" in again.stdout, again.stdout + again.stderr


def test_a_failing_run_is_reported_and_fails_warmup(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[robot]\nlength = -1\n")
    env = dict(os.environ, WARP_CACHE_PATH=str(tmp_path / "cache"))
    run = subprocess.run([sys.executable, "-m", "tdcr_warp", "warmup", str(bad)], env=env, cwd=tmp_path,
                         capture_output=True, text=True, check=False)
    assert run.returncode == 1
    assert "FAILED (exit status 2)" in run.stdout and "missing key 'youngs_modulus'" in run.stderr
