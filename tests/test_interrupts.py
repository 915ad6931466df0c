"""Ctrl-C at every phase of every command: exit status 130, one line on stderr, no traceback and
no completion file (one that an earlier run left in the same --out is removed before anything is
computed, so that an interrupted run never leaves it beside its own partial outputs)."""

import importlib
import signal
import subprocess
import sys
import time

import pytest
from scenes import ROBOT, two_tendon_scene

from tdcr_warp.cli import main

# every module the commands import, imported before any name is patched (a module first imported
# under a patch would keep the patched function for good)
for module in ("apps.control", "apps.hardware", "apps.ik", "apps.jobs", "io.plotting", "apps.sweep", "apps.uncertainty"):
    importlib.import_module(f"tdcr_warp.{module}")

STATIC = two_tendon_scene(nodes=10)
DYNAMIC = STATIC + "[dynamics]\ndt = 0.005\nsteps = 3\n"
CONTROL = DYNAMIC + "[control]\ntarget_tensions = [[1.5, 0.5]]\n"
IK = STATIC + "[ik]\ntargets = [[0.02, 0.0, 0.499]]\nmax_iter = 2\n"
HARDWARE = ROBOT + """[[tendons]]
offset = [0.01, 0.0]
control = "displacement"
compliance = 2e-4
pretension = 0.5
[[tendons]]
offset = [0.0, 0.01]
control = "displacement"
compliance = 2e-4
pretension = 0.5
[actuation]
tensions = [[0.0, 0.0]]
[solver]
nodes = 10
[hardware]
servo_columns = ["a", "b"]
"""
CSV = "timestamp,pattern_label,a,b,tip_x,tip_y,tip_z\n0,p,0.5,0,-1,0,500\n1,p,0,0.5,0,-1,500\n2,p,0.3,0.3,-1,-1,500\n"
STALE = "an earlier run's"

# command: scene, arguments after it, completion files (written last: their presence means complete)
COMMANDS = {
    "static": (STATIC, [], ["results.json"]),
    "simulate": (DYNAMIC, ["--quiet"], ["results.json"]),
    "control": (CONTROL, ["--quiet"], ["metrics.json"]),
    "ik": (IK, [], ["ik.json"]),
    "predict": (HARDWARE, ["data.csv"], ["metrics.json"]),
    "fit": (HARDWARE, ["data.csv", "--max-iter", "1", "--detail", "segment", "--quiet"], ["fit.json", "fitted.toml"]),
}
SOLVE = {"static": "tdcr_warp.physics.statics.solve_static", "simulate": "tdcr_warp.physics.dynamics.Simulator.simulate",
         "control": "tdcr_warp.apps.control.run_closed_loop", "ik": "tdcr_warp.apps.ik.solve_ik",
         "predict": "tdcr_warp.apps.hardware.predict", "fit": "tdcr_warp.apps.hardware.fit"}
FIGURES = {"static": "plot_robot", "simulate": "plot_tip_history", "control": "plot_control",
           "predict": "plot_prediction"}
PHASES = ([(c, "scene", "tdcr_warp.io.scene.scene_from_dict") for c in COMMANDS]
          + [(c, "kernels", "tdcr_warp.core.solver.load_kernels") for c in ("static", "simulate", "ik", "predict")]
          + [(c, "solve", target) for c, target in SOLVE.items()]
          + [(c, "figures", f"tdcr_warp.io.plotting.{f}") for c, f in FIGURES.items()]
          + [(c, "results", f"tdcr_warp.cli.{c}.write_json") for c in COMMANDS])  # where each command looks it up


def interrupt(*args, **kwargs):
    raise KeyboardInterrupt


def run(argv) -> int:
    """main(argv), failing the test (rather than ending the session) if Ctrl-C escapes it."""
    try:
        return main(argv)
    except KeyboardInterrupt:
        pytest.fail("KeyboardInterrupt escaped main()")


@pytest.mark.parametrize("command,phase,target", PHASES, ids=[f"{c}-{p}" for c, p, _ in PHASES])
def test_interrupt_exits_130_leaving_nothing_complete(tmp_path, monkeypatch, capsys, command, phase, target):
    text, extra, complete = COMMANDS[command]
    (tmp_path / "scene.toml").write_text(text)
    (tmp_path / "data.csv").write_text(CSV)
    out = tmp_path / "out"
    out.mkdir()
    for name in complete:
        (out / name).write_text(STALE)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(target, interrupt)
    assert run([command, "scene.toml", *extra, "--out", "out"]) == 130
    printed = capsys.readouterr()
    assert printed.err.splitlines()[-1] == "tdcr-warp: interrupted" and "Traceback" not in printed.err
    assert "wrote" not in printed.out
    if phase == "scene":  # nothing written into --out yet: the earlier run's outputs stay as they were
        assert all((out / name).read_text() == STALE for name in complete)
    else:
        assert not (out / complete[0]).exists()
        assert all(not (out / name).exists() or (out / name).read_text() != STALE for name in complete)


@pytest.mark.parametrize("command", ["montecarlo", "workspace", "gain-grid"])
def test_interrupted_sweep_while_loading_exits_130(tmp_path, monkeypatch, capsys, command):
    (tmp_path / "scene.toml").write_text(STATIC)
    monkeypatch.setattr("tdcr_warp.io.scene.scene_from_dict", interrupt)
    assert run([command, str(tmp_path / "scene.toml"), "--out", str(tmp_path / "out"), "--quiet"]) == 130
    err = capsys.readouterr().err
    assert err.splitlines()[-1].startswith("tdcr-warp: interrupted") and "Traceback" not in err


def test_interrupt_leaves_sigint_as_it_was(tmp_path, monkeypatch):
    """In process, main() hands SIGINT back as it found it (unless a real one arrived: then the
    process is ending, and SIGINT stays ignored)."""
    (tmp_path / "scene.toml").write_text(STATIC)
    monkeypatch.setattr("tdcr_warp.physics.statics.solve_static", interrupt)
    found = signal.getsignal(signal.SIGINT)  # the default handler, or SIG_IGN where pytest runs as a background job
    assert run(["static", str(tmp_path / "scene.toml"), "--out", str(tmp_path / "out")]) == 130
    assert signal.getsignal(signal.SIGINT) is found


@pytest.mark.parametrize("signals", [1, 2])
def test_sigint_during_simulate(tmp_path, signals):
    """A real Ctrl-C (and a second one 1 ms later, while the first unwinds) in the middle of a long
    simulation: exit 130, the message on a line of its own after the progress bar, no results."""
    (tmp_path / "long.toml").write_text(DYNAMIC.replace("steps = 3", "steps = 100000"))
    out = tmp_path / "out"
    out.mkdir()
    (out / "results.json").write_text(STALE)
    argv = ["simulate", str(tmp_path / "long.toml"), "--out", str(out), "--no-figures"]
    # Ctrl-C raises KeyboardInterrupt even where this test runs as a background job (SIGINT ignored)
    code = ("import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
            f"from tdcr_warp.cli import main; sys.exit(main({argv!r}))")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    # the progress bar: the steps have begun (after the kernels compile, which on a loaded machine
    # with an empty kernel cache can take minutes)
    err, deadline = b"", time.monotonic() + 600
    while b"rod-steps" not in err and proc.poll() is None and time.monotonic() < deadline:
        err += proc.stderr.read1(4096)
    assert b"rod-steps" in err, err.decode()
    for _ in range(signals):
        proc.send_signal(signal.SIGINT)
        time.sleep(0.001)
    rest, more = proc.communicate(timeout=60)
    err = (err + more).decode()
    assert proc.returncode == 130, err
    assert "Traceback" not in err and err.endswith("\ntdcr-warp: interrupted\n"), err
    assert not (out / "results.json").exists() and b"wrote" not in rest
