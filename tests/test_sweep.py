"""Chunked sweeps and the three users' jobs at small size."""

import json
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
from scenes import GAIN_GRID_SWEEP, two_tendon_scene
from scenes import MC_SWEEP as MC

import tdcr_warp as tw
from tdcr_warp.apps.jobs import constant_curvature_tip, convex_hull_2d, pareto_front, static_job
from tdcr_warp.apps.sweep import open_sweep, run_sweep
from tdcr_warp.cli import main
from tdcr_warp.io.scene import scene_from_dict

ROOT = Path(__file__).resolve().parents[1]

BASE = two_tendon_scene("[[1.0, 0.5]]", nodes=16)


def assert_documented(*groups):
    """Every key and column a sweep wrote appears in docs/outputs.md (a vector column
    ``name[i]`` as `name` or `name[...]`, a sample column as `sample:<field>`)."""
    doc = (ROOT / "docs" / "outputs.md").read_text()

    def base(k):
        return "sample:<field>" if k.startswith("sample:") else k.split("[")[0]

    missing = sorted({k for keys in groups for k in keys
                      if f"`{base(k)}`" not in doc and f"`{base(k)}[" not in doc})
    assert not missing, f"outputs not documented in docs/outputs.md: {missing}"


GRID = BASE + """
[sweep]
chunk = 7
[sweep.grid]
"actuation.tensions[0]" = [0.0, 3.0, 4]
"robot.youngs_modulus" = [150e9, 200e9, 5]
"""



def test_sweep_rows_equal_direct_solves(tmp_path):
    data = tomllib.loads(GRID)
    res = run_sweep(data, static_job, tmp_path, progress=False).load()
    assert len(res["ok"]) == 20 and res["ok"].all()
    tau0 = res["sample:actuation.tensions[0]"]
    E = res["sample:robot.youngs_modulus"]
    assert np.allclose(np.unique(tau0), [0, 1, 2, 3]) and np.allclose(np.unique(E), np.linspace(150e9, 200e9, 5))
    for i in (0, 7, 19):
        rob = tw.Robot(length=0.5, youngs_modulus=E[i], poisson_ratio=0.3, radius=1e-3, density=7800.0,
                       tendons=[tw.Tendon(offset=(0.01, 0.0)), tw.Tendon(offset=(0.0, 0.01))],
                       gravity=(0.0, 0.0, -9.81))
        one = tw.solve_static(rob, [[tau0[i], 0.5]], nodes=16)
        assert np.abs(one.tip_position[0] - res["tip_position"][i]).max() < 1e-12


def test_chunk_size_does_not_change_results(tmp_path):
    data = tomllib.loads(MC)
    a = run_sweep(data, static_job, tmp_path / "a", chunk=5, progress=False).load()
    b = run_sweep(data, static_job, tmp_path / "b", chunk=40, progress=False).load()
    assert np.array_equal(a["tip_position"], b["tip_position"])
    assert np.array_equal(a["sample:robot.youngs_modulus"], b["sample:robot.youngs_modulus"])


def test_resume_after_interruption_gives_the_same_output(tmp_path):
    scene = tmp_path / "mc.toml"
    scene.write_text(MC)
    full, part = tmp_path / "full", tmp_path / "part"
    assert main(["montecarlo", str(scene), "--out", str(full), "--quiet"]) == 0
    assert main(["montecarlo", str(scene), "--out", str(part), "--quiet", "--max-chunks", "1"]) == 1
    assert len(list((part / "results").glob("part-*.parquet"))) == 1 and not (part / "summary.json").exists()
    assert main(["montecarlo", str(scene), "--out", str(part), "--quiet", "--resume"]) == 0
    a, b = open_sweep(full).load(), open_sweep(part).load()
    assert set(a) == set(b)
    for k in a:
        assert np.array_equal(a[k], b[k]), k
    sa = json.loads((full / "summary.json").read_text())
    sb = json.loads((part / "summary.json").read_text())
    assert sa["tip_mean"] == sb["tip_mean"] and sa["tip_covariance"] == sb["tip_covariance"]


def test_resume_refuses_a_different_sweep(tmp_path, capsys):
    scene = tmp_path / "mc.toml"
    scene.write_text(MC)
    assert main(["montecarlo", str(scene), "--out", str(tmp_path / "o"), "--quiet", "--max-chunks", "1"]) == 1
    scene.write_text(MC.replace("samples = 40", "samples = 41"))
    assert main(["montecarlo", str(scene), "--out", str(tmp_path / "o"), "--quiet", "--resume"]) == 2
    assert "holds a different sweep" in capsys.readouterr().err


def test_montecarlo_with_zero_variance_equals_nominal(tmp_path):
    scene = tmp_path / "mc.toml"
    scene.write_text(MC.replace("params = [190e9, 10e9]", "params = [190e9, 0.0]").replace(
        "params = [0.009, 0.011]", "params = [0.01, 0.01]"))
    assert main(["montecarlo", str(scene), "--out", str(tmp_path / "o"), "--quiet"]) == 0
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    base = scene_from_dict(tomllib.loads(BASE))
    nominal = tw.solve_static(base.robot, base.tensions, options=base.options).tip_position[0]
    assert np.abs(np.array(summary["tip_mean"]) - nominal).max() < 1e-12
    assert summary["tip_error_percentiles_m"]["99"] < 1e-12
    assert (tmp_path / "o" / "montecarlo.png").exists()
    manifest = json.loads((tmp_path / "o" / "sweep.json").read_text())
    assert_documented(summary, summary["linearised"], manifest, open_sweep(tmp_path / "o").load())
    assert summary["settings"]["scene_text"] == scene.read_text()


def test_workspace_of_a_single_tendon_lies_in_its_plane(tmp_path):
    text = BASE.replace("[[tendons]]\noffset = [0.0, 0.01]\n", "").replace("[[1.0, 0.5]]", "[[1.0]]").replace(
        'gravity = [0.0, 0.0, -9.81]', 'gravity = [0.0, 0.0, 0.0]') + """
[sweep]
chunk = 8
[sweep.grid]
"actuation.tensions[0]" = [0.0, 10.0, 21]
"""
    scene = tmp_path / "ws.toml"
    scene.write_text(text)
    assert main(["workspace", str(scene), "--out", str(tmp_path / "o"), "--quiet"]) == 0
    res = open_sweep(tmp_path / "o").load()
    assert res["ok"].all()
    assert np.abs(res["tip_position"][:, 1]).max() < 1e-12, "tip left the tendon's x-z plane"
    assert (res["tip_position"][1:, 0] > 0).all()
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["rods"] == 21 and summary["peak_memory_mb"] > 0
    assert_documented(summary, summary["boundary_slices"][0], res)


def test_constant_curvature_matches_coupled_single_tendon_without_load():
    rob = tw.Robot(length=0.5, tendons=[tw.Tendon(offset=(0.0, 0.01))])
    tau = np.array([[2.0]])
    cc = constant_curvature_tip(rob, tau)[0]
    sol = tw.solve_static(rob, tau).tip_position[0]
    # the coupled model bends a straight tendon into an arc; the rest is shear and extension
    assert np.abs(cc - sol).max() < 1e-5, (cc, sol)


def test_gain_grid_pipeline(tmp_path):
    text = GAIN_GRID_SWEEP
    scene = tmp_path / "gg.toml"
    scene.write_text(text)
    assert main(["gain-grid", str(scene), "--out", str(tmp_path / "o"), "--quiet"]) == 0
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["rods"] == 4 and set(summary["best"]["gains"]) == {"control.gain_c[0]", "control.gain_k[0]"}
    assert len(summary["pareto"]) >= 1
    assert (tmp_path / "o" / "gain_grid.png").exists()
    assert_documented(summary, summary["best"], summary["pareto"][0], open_sweep(tmp_path / "o").load())


def test_helpers():
    pts = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 0.5]])
    assert len(convex_hull_2d(pts)) == 4
    front = pareto_front(np.array([1.0, 2.0, 3.0, 1.5]), np.array([3.0, 1.0, 0.5, 3.5]))
    assert list(front) == [0, 1, 2]


@pytest.mark.parametrize("edit,message", [
    ('"robot.youngs_modulus" = [150e9, 200e9, 5]', "[sweep.grid].'robot.youngs_modulus'"),
    ('"actuation.tensions[0]"', "sweep field"),
])
def test_bad_sweeps_exit_2(tmp_path, capsys, edit, message):
    bad = {"[sweep.grid].'robot.youngs_modulus'": GRID.replace(edit, '"robot.youngs_modulus" = [150e9, 5]'),
           "sweep field": GRID.replace(edit, '"robot.stiffness[0]"')}[message]
    scene = tmp_path / "bad.toml"
    scene.write_text(bad)
    assert main(["workspace", str(scene), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    assert message in capsys.readouterr().err


def test_ray_backend_without_ray_is_a_clear_error(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray fails, as without the extra
    scene = tmp_path / "g.toml"
    scene.write_text(GRID)
    assert main(["workspace", str(scene), "--out", str(tmp_path / "o"), "--quiet", "--backend", "ray"]) == 2
    assert 'pip install -e ".[ray]"' in capsys.readouterr().err


DISPLACED = """
[robot]
length = 0.5
youngs_modulus = 190e9
poisson_ratio = 0.3
radius = 0.001
density = 7800
[[tendons]]
offset = [0.01, 0.0]
control = "displacement"
pretension = 0.5
compliance = 2.7e-5
friction = 0.1
[[tendons]]
offset = [-0.01, 0.0]
control = "displacement"
pretension = 0.5
compliance = 2.7e-5
friction = 0.1
[actuation]
tensions = [[0.0, 0.0]]
displacements = [[0.0, 0.0]]
[solver]
nodes = 16
[sweep]
chunk = 5
[sweep.grid]
"actuation.displacements[0]" = [-0.003, 0.003, 3]
"actuation.displacements[1]" = [-0.003, 0.003, 3]
"tendons[0].friction" = [0.0, 0.3, 2]
"""


def test_sweep_over_displacements_and_friction_reports_slack(tmp_path):
    """Displacements and mu swept like any field: every row equals its direct solve, and a
    tendon released by 3 mm is slack with exactly zero tension."""
    scene = tmp_path / "d.toml"
    scene.write_text(DISPLACED)
    assert main(["workspace", str(scene), "--out", str(tmp_path / "o"), "--quiet"]) == 0
    res = open_sweep(tmp_path / "o").load()
    assert res["ok"].all() and res["slack"].shape == (18, 2)
    q = np.c_[res["sample:actuation.displacements[0]"], res["sample:actuation.displacements[1]"]]
    released = q < -0.002
    assert res["slack"][released].all() and (res["tension_base"][released] == 0).all()
    data = tomllib.loads(DISPLACED)
    for i in (0, 7, 17):
        d = {k: v for k, v in data.items() if k != "sweep"}
        d["tendons"] = [dict(t) for t in data["tendons"]]
        d["tendons"][0]["friction"] = float(res["sample:tendons[0].friction"][i])
        d["actuation"] = dict(tensions=[[0.0, 0.0]], displacements=[q[i].tolist()])
        sc = scene_from_dict(d)
        sol = tw.solve_static(sc.robot, sc.tensions, options=sc.options, **sc.static_command())
        assert np.abs(sol.tip_position[0] - res["tip_position"][i]).max() < 1e-12


def test_sweep_over_an_obstacles_pose_flags_contact(tmp_path):
    """A grid over where a wall stands (the plane x = w, facing -x) in front of a rod bending
    toward +x: the near walls are touched and hold the tip back (their penetration within the
    tolerance), the far ones leave the free tip as it is."""
    data = tomllib.loads(BASE + """
[[obstacles]]
kind = "plane"
point = [0.2, 0.0, 0.0]
normal = [-1.0, 0.0, 0.0]
[sweep.grid]
"obstacles[0].point[0]" = [0.002, 0.02, 5]
""")
    res = run_sweep(data, static_job, tmp_path, progress=False).load()
    wall = res["sample:obstacles[0].point[0]"]
    free = scene_from_dict(tomllib.loads(BASE))
    tip = tw.solve_static(free.robot, free.tensions, options=free.options).tip_position[0]
    assert res["ok"].all()
    touched = res["in_contact"].astype(bool)
    assert touched.any() and not touched.all()
    assert np.array_equal(touched, wall < tip[0] + 1e-3)
    assert np.all(res["tip_position"][touched, 0] <= wall[touched] - 1e-3 + 0.01 * 1e-3 + 1e-12)
    assert np.abs(res["tip_position"][~touched] - tip).max() < 1e-12
    assert np.all(res["penetration"] <= 0.01 * 1e-3)
    assert_documented(res)
