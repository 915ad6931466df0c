"""The scene loader and the CLI: outputs, agreement with the API, and clear errors."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import warp as wp
from scenes import two_tendon_scene

import tdcr_warp as tw
from tdcr_warp.apps.control import METRIC_UNITS
from tdcr_warp.cli import main
from tdcr_warp.io.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"

BASE = two_tendon_scene("[[2.0, 0.5]]", nodes=20)


def write(tmp_path, text, name="scene.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def assert_documented(*groups):
    """Every key the CLI wrote appears, as `key`, in docs/outputs.md (the documented outputs)."""
    doc = (ROOT / "docs" / "outputs.md").read_text()
    missing = sorted({k for keys in groups for k in keys if f"`{k}`" not in doc})
    assert not missing, f"outputs not documented in docs/outputs.md: {missing}"


def test_displacement_example_reports_each_tendon(tmp_path):
    """examples/displacement_pair.toml: tendon 1 pulled 2 mm, its antagonist released 2 mm."""
    out = tmp_path / "out"
    assert main(["static", str(EXAMPLES / "displacement_pair.toml"), "--out", str(out), "--no-figures"]) == 0
    tendons = json.loads((out / "results.json").read_text())["rods"][0]["tendons"]
    assert_documented(tendons[0], np.load(out / "shapes.npz").files)
    assert [t["slack"] for t in tendons] == [False, False, True, False]
    assert tendons[2]["tension_base"] == 0.0 and tendons[0]["tension_base"] > 5.0
    assert tendons[1]["tension_base"] == pytest.approx(tendons[3]["tension_base"], rel=1e-9)
    assert all(t["free_length"] > 0.49 for t in tendons)


@pytest.mark.parametrize("name,code", [("friction_converging", 3), ("spline_route", 0)])
def test_tendon_examples_solve(tmp_path, name, code):
    """Friction is not conservative: no stability verdict, exit status 3."""
    out = tmp_path / "out"
    assert main(["static", str(EXAMPLES / f"{name}.toml"), "--out", str(out), "--no-figures"]) == code
    rod = json.loads((out / "results.json").read_text())["rods"][0]
    assert rod["converged"] and len(rod["tendons"]) == 2


def test_static_example_outputs_agree_with_api(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["static", str(EXAMPLES / "seed_robot.toml"), "--out", str(out)]) == 0
    res = json.loads((out / "results.json").read_text())
    assert {"scene", "settings", "batch_size", "rods", "tip_position", "converged", "iterations",
            "residual"} <= res.keys()
    assert res["scene"] == str(EXAMPLES / "seed_robot.toml")
    settings = res["settings"]
    for key in ("nodes", "integrator", "model", "precision", "tolerance_m", "max_iter", "device", "warp", "tdcr_warp",
                "scene_text"):
        assert key in settings, key
    assert "warp_version" not in settings and "tol" not in settings  # the Warp version once; the tolerance used
    assert settings["warp"] == wp.__version__ and settings["tdcr_warp"] == tw.__version__
    assert settings["tolerance_m"] == 1e-10  # float64's default (the scene gives no tol)
    assert settings["scene_text"] == (EXAMPLES / "seed_robot.toml").read_text()
    assert (settings["nodes"], settings["integrator"], settings["model"]) == (50, "rk4", "coupled")
    assert settings["device"] == str(wp.get_device(None))
    assert res["batch_size"] == 1 and res["converged"] == [True]
    assert np.shape(res["tip_position"]) == (1, 3) and len(res["iterations"]) == len(res["residual"]) == 1
    rod = res["rods"][0]
    assert rod.keys() == {"tip_position", "tip_rotation", "success", "converged", "status", "iterations", "residual",
                          "orthogonality_error", "tendons", "stability_index", "stable", "stability_margin", "stability"}
    assert rod["success"] and rod["stability"] == "stable"  # the verdict is on by default
    assert rod["tendons"][0] == {"tension_base": 3.0, "tension_end": 3.0}  # tension control, no friction
    assert np.shape(rod["tip_position"]) == (3,) and np.shape(rod["tip_rotation"]) == (3, 3)
    assert rod["status"] == "converged" and rod["converged"] is True
    assert (out / "shapes.png").stat().st_size > 1000
    assert sorted(p.name for p in out.iterdir()) == ["results.json", "shapes.npz", "shapes.png"]  # no temp files
    shapes = np.load(out / "shapes.npz")
    assert shapes["positions"].shape == (1, 51, 3)
    assert_documented(res, settings, rod, rod["tendons"][0], shapes.files)
    scene = load_scene(EXAMPLES / "seed_robot.toml")
    sol = tw.solve_static(scene.robot, scene.tensions, options=scene.options)
    assert np.abs(np.array(res["tip_position"]) - sol.tip_position).max() < 1e-15
    assert np.abs(np.array(rod["tip_rotation"]) - sol.tip_rotation[0]).max() < 1e-15
    assert np.abs(shapes["positions"] - sol.positions).max() < 1e-15
    assert res["iterations"] == sol.iterations.tolist() and res["residual"] == sol.residual.tolist()
    assert rod["orthogonality_error"] == float(sol.orthogonality_error[0])
    printed = capsys.readouterr().out
    assert "rod 0: tip" in printed and " s " in printed  # per-rod summary and the wall time


def test_per_rod_lists_match_rods_alone(tmp_path):
    text = BASE.replace("youngs_modulus = 190e9", "youngs_modulus = [190e9, 100e9]").replace(
        "tensions = [[2.0, 0.5]]", "tensions = [[2.0, 0.5], [1.0, 1.0]]")
    scene = load_scene(write(tmp_path, text))
    batch = tw.solve_static(scene.robot, scene.tensions, options=scene.options)
    for b, (E, tau) in enumerate([(190e9, [2.0, 0.5]), (100e9, [1.0, 1.0])]):
        one = load_scene(write(tmp_path, BASE.replace("190e9", repr(E)).replace("[[2.0, 0.5]]", repr([tau])),
                               f"one{b}.toml"))
        alone = tw.solve_static(one.robot, one.tensions, options=one.options)
        assert np.abs(alone.tip_position[0] - batch.tip_position[b]).max() < 1e-12


def test_two_section_helix_example_solves(tmp_path):
    assert main(["static", str(EXAMPLES / "helix_two_sections.toml"), "--out", str(tmp_path)]) == 0
    res = json.loads((tmp_path / "results.json").read_text())
    assert res["batch_size"] == 3 and all(res["converged"])


def test_simulate_seed_dynamics(tmp_path):
    assert main(["simulate", str(EXAMPLES / "seed_dynamics.toml"), "--out", str(tmp_path), "--quiet",
                 "--nodes", "20"]) == 0
    res = json.loads((tmp_path / "results.json").read_text())
    traj = np.load(tmp_path / "trajectory.npz")
    assert traj["tip_position"].shape == (101, 1, 3)
    # no tension for steps 1-4: the tip has not moved; from step 5 on, 3 N on tendon 1
    assert np.abs(traj["tip_position"][4, 0] - traj["tip_position"][0, 0]).max() < 1e-12
    assert traj["tensions"][4, 0, 0] == 3.0 and traj["tensions"][3, 0, 0] == 0.0
    assert res["completed"] == [True] and res["failed_step"] == [None]
    assert_documented(res, res["settings"], traj.files)
    for name in ("tip_position.png", "tip_rates.png"):
        assert (tmp_path / name).stat().st_size > 1000


def test_nonconverged_rod_exits_1_with_reason(tmp_path, capsys):
    scene = write(tmp_path, BASE + "max_iter = 1\n")
    assert main(["static", str(scene), "--out", str(tmp_path / "o")]) == 1
    res = json.loads((tmp_path / "o" / "results.json").read_text())
    assert res["converged"] == [False]
    assert res["rods"][0]["converged"] is False
    assert res["rods"][0]["status"] == "iteration cap reached"
    assert (tmp_path / "o" / "shapes.npz").exists() and (tmp_path / "o" / "shapes.png").exists()
    err = capsys.readouterr().err
    assert "1 of 1 rods did not converge" in err and "iteration cap reached" in err, err


def test_rods_without_a_stability_verdict_are_counted_and_exit_3(tmp_path, capsys):
    """A converged rod the stability test cannot assess (here the point model's follower loads) is
    counted apart from the successes, with its reason; with the test off nothing is counted."""
    scene = write(tmp_path, two_tendon_scene("[[2.0, 0.5], [0.0, 0.0]]") + 'model = "point"\n')
    assert main(["static", str(scene), "--out", str(tmp_path / "o"), "--no-figures"]) == 3
    res = json.loads((tmp_path / "o" / "results.json").read_text())
    reason = "point-model tendon loads (follower forces)"
    assert (res["failed_rods"], res["unassessed_rods"], res["unassessed_reasons"]) == (0, 2, {reason: 2})
    assert [r["stability"] for r in res["rods"]] == [f"not assessed: {reason}"] * 2
    assert_documented(res)
    err = capsys.readouterr().err
    assert f"2 of 2 rods converged but their stability was not assessed: 2 x {reason}" in err, err
    off = write(tmp_path, two_tendon_scene() + 'model = "point"\nstability = "off"\n', "off.toml")
    assert main(["static", str(off), "--out", str(tmp_path / "p"), "--no-figures"]) == 0
    assert json.loads((tmp_path / "p" / "results.json").read_text())["unassessed_rods"] == 0
    failed = write(tmp_path, two_tendon_scene() + 'model = "point"\nmax_iter = 1\n', "failed.toml")
    assert main(["static", str(failed), "--out", str(tmp_path / "q"), "--no-figures"]) == 1  # a failure first


@pytest.mark.parametrize("edit,message", [
    (("length = 0.5\n", ""), "missing key 'length' in [robot]"),
    (("length = 0.5", "length = -1"), "length must be positive, got -1.0"),
    (("poisson_ratio = 0.3", "poisson_ratio = 0.7"), "poisson_ratio must be in (-1, 0.5), got 0.7"),
    (("radius = 0.001", 'radius = "thin"'), "[robot].radius: expected a number or a list of numbers, got 'thin'"),
    (("[[2.0, 0.5]]", "[[2.0, -0.5]]"), "[actuation].tensions[0][1] must be a finite number >= 0"),
    (("[[2.0, 0.5]]", "[[2.0, 0.5, 1.0]]"), "expected shape (B, 2) for 2 tendons"),
    (("density = 7800", "density = 7800\nlenght = 0.5"), "unknown key 'lenght' in [robot]"),
    (("nodes = 20", "nodes = 0"), "solver nodes must be an integer in [1, 100000], got 0"),
    (("[loads]", "[loads"), "invalid TOML"),
])
def test_bad_scene_exits_2_naming_field_and_value(tmp_path, capsys, edit, message):
    old, new = edit
    assert old in BASE
    scene = write(tmp_path, BASE.replace(old, new, 1))
    assert main(["static", str(scene), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert message in err, err
    assert "Traceback" not in err
    assert not (tmp_path / "o" / "results.json").exists()


def test_default_out_dir_and_overrides(tmp_path, monkeypatch):
    scene = write(tmp_path, BASE, "my_scene.toml")
    monkeypatch.chdir(tmp_path)
    assert main(["static", str(scene), "--nodes", "12", "--integrator", "euler", "--model", "point",
                 "--precision", "float32", "--device", "cpu"]) == 3  # point-model tendons: not assessed
    out = tmp_path / "out" / "my_scene"
    for name in ("results.json", "shapes.npz", "shapes.png"):
        assert (out / name).exists(), name
    settings = json.loads((out / "results.json").read_text())["settings"]
    assert (settings["nodes"], settings["integrator"], settings["model"], settings["precision"],
            settings["device"]) == (12, "euler", "point", "float32", "cpu")
    assert np.load(out / "shapes.npz")["positions"].shape == (1, 13, 3)


def test_bad_flags_and_out_dir(tmp_path, capsys):
    scene = write(tmp_path, BASE)
    with pytest.raises(SystemExit) as e:  # argparse's own usage error
        main(["static", str(scene), "--integrator", "rk5"])
    assert e.value.code == 2 and "invalid choice: 'rk5'" in capsys.readouterr().err
    assert main(["static", str(scene), "--nodes", "100001", "--out", str(tmp_path / "o")]) == 2
    assert "solver nodes must be an integer in [1, 100000], got 100001" in capsys.readouterr().err
    blocker = write(tmp_path, "not a directory", "file")
    assert main(["static", str(scene), "--out", str(blocker / "o")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("tdcr-warp: error: --out") and "Traceback" not in err, err


def test_paths_reach_the_terminal_escaped(tmp_path, monkeypatch, capsys):
    """A scene or folder named with escape sequences is shown escaped, in errors and in what
    the command wrote: no control character reaches the terminal."""
    monkeypatch.chdir(tmp_path)
    scene = write(tmp_path, BASE, "\x1b[2J\x1b]0;pwned\x07.toml")
    assert main(["static", scene.name, "--no-figures"]) == 2  # no default folder from that name
    assert main(["static", "nope\x1b[31m.toml"]) == 2
    out = "o\x1b[2Jut"
    assert main(["static", scene.name, "--no-figures", "--out", out]) == 0
    printed = capsys.readouterr()
    assert not any(c in printed.out + printed.err for c in "\x1b\x07")
    err = printed.err.splitlines()
    assert err[0].startswith("tdcr-warp: error: \\x1b[2J\\x1b]0;pwned\\x07.toml: the scene file's name gives no safe")
    assert err[1].startswith("tdcr-warp: error: cannot read scene") and "nope\\x1b[31m.toml" in err[1]
    assert "wrote o\\x1b[2Jut/results.json, shapes.npz" in printed.out
    assert (tmp_path / out / "results.json").exists()


@pytest.mark.parametrize("argv", [["simulate", "--steps", "0"], ["control", "--steps", "-3"],
                                  ["static", "--nodes", "0"], ["fit", "data.csv", "--max-iter", "0"]])
def test_counts_below_one_exit_2_naming_the_option(tmp_path, capsys, argv):
    """Refused before anything runs (--steps 0 used to run the scene's steps: 0 read as unset)."""
    command, *rest = argv
    scene = write(tmp_path, BASE + "[dynamics]\ndt = 0.005\nsteps = 3\n[control]\ntarget = [0.0, 0.0, 0.5]\n")
    with pytest.raises(SystemExit) as e:
        main([command, str(scene), *rest, "--out", str(tmp_path / "o")])
    assert e.value.code == 2
    assert f"argument {rest[-2]}: must be a positive integer, got {rest[-1]!r}" in capsys.readouterr().err


def test_missing_file_and_subprocess_exit_status(tmp_path, capsys):
    assert main(["static", str(tmp_path / "nope.toml")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("tdcr-warp: error: cannot read scene") and "nope.toml" in err, err
    bad = write(tmp_path, BASE.replace("radius = 0.001", "radius = 0.0"))
    proc = subprocess.run([sys.executable, "-m", "tdcr_warp", "static", str(bad), "--out", str(tmp_path / "o")],
                          capture_output=True, text=True, check=False)
    assert proc.returncode == 2
    assert "radius must be positive, got 0.0" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_control_examples(tmp_path):
    for name in ("our_control", "seed_control", "wall_control"):
        out = tmp_path / name
        assert main(["control", str(EXAMPLES / f"{name}.toml"), "--out", str(out), "--quiet", "--steps", "30",
                     "--nodes", "20"]) == 0
        res = json.loads((out / "metrics.json").read_text())
        for key in ("final_error", "rms_error", "settling_time", "overshoot", "chatter", "reversal_fraction",
                    "saturation_fraction", "peak_tension", "mean_tension"):
            assert len(res["metrics"][key]) == 1, key
        assert res["units"] == {k: METRIC_UNITS[k] for k in res["metrics"]} and res["units"]["final_error"] == "m"
        assert res["settings"]["scene_text"] == (EXAMPLES / f"{name}.toml").read_text()
        run = np.load(out / "control.npz")
        assert run["tensions"].shape == (30, 1, 4)
        assert_documented(res, res["settings"], res["metrics"], run.files)
        for png in ("control_tip.png", "control_tension.png", "control_error_phase.png"):
            assert (out / png).stat().st_size > 1000


def test_wall_control_example(tmp_path):
    """examples/wall_control.toml: the tip driven toward a target behind a rigid wall stops on the
    wall (within the contact tolerance, 0.01 radii) and no further; the scene's obstacle is drawn."""
    out = tmp_path / "wall"
    assert main(["control", str(EXAMPLES / "wall_control.toml"), "--out", str(out), "--quiet", "--nodes", "20"]) == 0
    res = json.loads((out / "metrics.json").read_text())
    run = np.load(out / "control.npz")
    wall = 0.016 - 1e-3  # the plane less the rod's radius
    assert res["metrics"]["max_penetration"][0] <= 1e-5 and run["penetration"].max() <= 1e-5
    assert run["tip_position"][:, 0, 0].max() <= wall + 1e-5
    assert abs(run["tip_position"][-1, 0, 0] - wall) < 1e-5  # pressed on the wall
    assert res["metrics"]["final_error"][0] > 0.01  # the target stays out of reach


def test_version(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.strip() == f"tdcr-warp {tw.__version__} (Warp {wp.__version__})"
    assert tw.__version__ != "unknown"


def test_status_decoder_is_exported():
    from tdcr_warp.kernels import layout
    assert tw.status_names(layout.CONVERGED | layout.UNSTABLE) == ["converged", "unstable equilibrium"]
    assert tw.describe_status(layout.MAX_ITER | layout.STALLED) == "iteration cap reached, line search stalled"
    assert tw.describe_status(0) == "not converged"


def test_control_table_errors(tmp_path, capsys):
    text = (EXAMPLES / "our_control.toml").read_text().replace("target_tensions", "target_tension")
    assert main(["control", str(write(tmp_path, text)), "--out", str(tmp_path / "o")]) == 2
    assert "unknown key 'target_tension' in [control]" in capsys.readouterr().err


def test_ik_example_reaches_three_targets_and_reports_the_unreachable_one(tmp_path):
    """examples/ik_targets.toml: three static tips of known tensions and one out of reach."""
    out = tmp_path / "ik"
    assert main(["ik", str(EXAMPLES / "ik_targets.toml"), "--out", str(out)]) == 1
    res = json.loads((out / "ik.json").read_text())
    rods = res["rods"]
    assert [r["reason"] for r in rods] == ["reached"] * 3 + ["unreachable"]
    assert res["settings"]["scene_text"] == (EXAMPLES / "ik_targets.toml").read_text()
    assert res["settings"]["tdcr_warp"] == tw.__version__ and "warp_version" not in res["settings"]
    assert_documented(res, rods[0], np.load(out / "ik.npz").files)
    assert max(r["position_error_m"] for r in rods[:3]) < 1e-9 and rods[3]["position_error_m"] > 0.3
    assert all(0.0 <= c <= 8.0 for r in rods for c in r["command"])
    sc = load_scene(EXAMPLES / "ik_targets.toml")  # the commands put the tips there, by an independent solve
    tips = tw.solve_static(sc.robot, [r["command"] for r in rods[:3]], nodes=20, tol=1e-13).tip_position
    assert np.abs(tips - [r["target"] for r in rods[:3]]).max() < 1e-9


def test_static_reports_stability_and_sensitivities(tmp_path):
    scene = write(tmp_path, BASE.replace("[solver]", '[solver]\nstability = "check"\nsensitivities = true'))
    out = tmp_path / "o"
    assert main(["static", str(scene), "--out", str(out), "--no-figures"]) == 0
    rod = json.loads((out / "results.json").read_text())["rods"][0]
    assert rod["stability_index"] == 0 and rod["stable"]
    assert np.array(rod["tip_jacobian"]).shape == (6, 2) and np.array(rod["tip_compliance"]).shape == (6, 6)
    assert np.load(out / "shapes.npz")["tip_compliance"].shape == (1, 6, 6)
    assert_documented(rod, np.load(out / "shapes.npz").files)


@pytest.mark.parametrize("edit, message", [
    ("[ik]\ntension_max = 8.0", "missing key 'targets' in [ik]"),
    ("[ik]\ntargets = [[0.0, 0.1]]", "target: expected a number, shape"),
    ("[ik]\ntargets = 'far'", "[ik].targets"),
    ("[ik]\ntargets = [[0.0, 0.0, 0.5]]\nspeed = 1", "speed"),
])
def test_ik_table_errors(tmp_path, capsys, edit, message):
    scene = write(tmp_path, BASE + "\n" + edit + "\n")
    assert main(["ik", str(scene), "--out", str(tmp_path / "o")]) == 2
    assert message in capsys.readouterr().err


def test_command_line_defers_figure_and_storage_libraries():
    """Importing the package loads neither Warp nor a figure library (``tw.solve_static`` and the
    other names load on first use); importing the CLI and building its parser (every command
    registered) loads no Warp, figure, storage or search library: a command imports them when it
    solves, draws, stores or searches."""
    heavy = ("warp", "matplotlib", "plotly", "pyarrow", "zarr", "tomli_w", "cmaes", "ray", "scipy", "pandas")
    for code in ("import sys, tdcr_warp", "import sys, tdcr_warp.cli as cli; cli.build_parser()"):
        code += f"; print([m for m in {heavy!r} if m in sys.modules])"
        run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
        assert run.stdout.strip() == "[]", code


def test_package_names_load_on_first_use_and_warp_stays_quiet():
    code = ("import sys, tdcr_warp as tw; assert 'warp' not in sys.modules; tw.Robot; import warp; "
            "print(tw.solve_static.__module__, warp.config.log_level == warp.LOG_WARNING, sorted(set(tw.__all__) - set(dir(tw))))")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert run.stdout.split() == ["tdcr_warp.physics.statics", "True", "[]"]


def test_only_the_process_command_line_freezes_the_heap_at_its_end(tmp_path, monkeypatch):
    """main() without argv (tdcr-warp, python -m tdcr_warp: the process ends after it) freezes the
    objects left, so that the exit skips a garbage collection over Warp's; a caller's main(argv) not."""
    import gc
    frozen = []
    monkeypatch.setattr(gc, "freeze", lambda: frozen.append(True))
    missing = str(tmp_path / "missing.toml")
    assert main(["static", missing]) == 2 and not frozen
    monkeypatch.setattr(sys, "argv", ["tdcr-warp", "static", missing])
    assert main() == 2 and frozen == [True]
