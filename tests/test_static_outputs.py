"""The per-rod outputs at every batch size: `static`, `ik`, `simulate` and `control` write their
JSON per rod up to JSON_RODS rods, above a summary and a Parquet table, and .npz arrays
(uncompressed); tests/test_table_files.py reads per-rod tables as input."""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest
from scenes import two_tendon_scene

import tdcr_warp as tw
from tdcr_warp.cli import main
from tdcr_warp.cli.static import JSON_RODS
from tdcr_warp.io.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
B = JSON_RODS + 28  # above the per-rod JSON: rods.parquet
TAU = np.random.default_rng(7).uniform(0.0, 2.0, (B, 2))


def inline(tau) -> str:
    return two_tendon_scene("[" + ", ".join(f"[{float(a)!r}, {float(b)!r}]" for a, b in tau) + "]", nodes=8)


def from_file(name: str) -> str:
    return two_tendon_scene(f'"{name}"', nodes=8)


def documented(names) -> list[str]:
    """The names (a column `key[i]` by its `key`) that docs/outputs.md does not mention as `key..."""
    doc = (ROOT / "docs" / "outputs.md").read_text()
    return sorted(n for n in names if f"`{n.split('[')[0]}" not in doc)


@pytest.fixture(scope="module")
def large(tmp_path_factory):
    """A batch of B rods from a .npy table, solved by the command and by the API."""
    tmp = tmp_path_factory.mktemp("large")
    np.save(tmp / "tau.npy", TAU)
    (tmp / "scene.toml").write_text(from_file("tau.npy"))
    out = tmp / "out"
    assert main(["static", str(tmp / "scene.toml"), "--out", str(out), "--no-figures"]) == 0
    scene = load_scene(tmp / "scene.toml")
    sol = tw.solve_static(scene.robot, scene.tensions, options=scene.options)
    return tmp, out, sol


def test_large_batch_writes_the_table_and_a_summary(large):
    _, out, sol = large
    assert sorted(p.name for p in out.iterdir()) == ["results.json", "rods.parquet", "shapes.npz"]
    res = json.loads((out / "results.json").read_text())
    assert "rods" not in res and "tip_position" not in res
    assert (res["batch_size"], res["converged_rods"], res["unstable_rods"], res["failed_rods"],
            res["failure_reasons"]) == (B, B, 0, 0, {})
    rods = pd.read_parquet(out / "rods.parquet")
    assert res["files"]["rods.parquet"] == {"rows": B, "columns": {
        c: "string" if c.endswith("_text") else str(rods[c].dtype) for c in rods.columns}}
    assert res["files"]["shapes.npz"]["positions"] == [[B, 9, 3], "float64"]
    assert not documented([*res, *rods.columns]), documented([*res, *rods.columns])
    assert rods["row"].tolist() == list(range(B))
    assert np.array_equal(rods[[f"tip_position[{i}]" for i in range(3)]].to_numpy(), sol.tip_position)
    assert np.array_equal(rods[["tensions[0]", "tensions[1]"]].to_numpy(), TAU)
    assert np.array_equal(rods[["tension_base[0]", "tension_base[1]"]].to_numpy(), sol.tendon_tension_base)
    for key in ("success", "converged", "status", "iterations", "integrations", "residual", "orthogonality_error"):
        assert np.array_equal(rods[key].to_numpy(), getattr(sol, key)), key
    assert set(rods["status_text"]) == {"converged"}
    meta = json.loads(pq.read_schema(out / "rods.parquet").metadata[b"tdcr_warp"])
    assert meta == {"command": "static", "rows": B, "widths": {"tip_position": 3, "tensions": 2, "tension_base": 2,
                                                               "tension_end": 2}}


def test_shapes_npz_holds_the_solution_uncompressed(large):
    _, out, sol = large
    with np.load(out / "shapes.npz") as z:
        assert {i.compress_type for i in z.zip.infolist()} == {0}  # ZIP_STORED
        for key in z.files:
            assert np.array_equal(z[key], getattr(sol, key)), key
        assert "positions" in z.files and "tendon_tension_end" in z.files


def test_the_table_round_trips_as_a_scene_input(large, tmp_path):
    """rods.parquet's tensions[k] columns, named as the scene's tensions, give the same rods."""
    _, out, sol = large
    (tmp_path / "again.toml").write_text(from_file(str(out / "rods.parquet")))
    scene = load_scene(tmp_path / "again.toml")
    assert np.array_equal(scene.tensions, TAU)
    again = tw.solve_static(scene.robot, scene.tensions, options=scene.options)
    assert np.array_equal(again.tip_position, sol.tip_position)


def test_small_batch_stays_json_and_drops_a_stale_table(large, tmp_path):
    _, out, _ = large
    small = tmp_path / "small.toml"
    small.write_text(inline(TAU[:3]))
    (tmp_path / "o").mkdir()
    (tmp_path / "o" / "rods.parquet").write_bytes((out / "rods.parquet").read_bytes())  # a larger run's
    assert main(["static", str(small), "--out", str(tmp_path / "o"), "--no-figures"]) == 0
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["results.json", "shapes.npz"]
    res = json.loads((tmp_path / "o" / "results.json").read_text())
    assert len(res["rods"]) == 3 and list(res["files"]) == ["shapes.npz"]
    with np.load(tmp_path / "o" / "shapes.npz") as z:
        assert res["tip_position"] == z["positions"][:, -1].tolist()


def test_failed_rods_are_counted_by_reason(tmp_path, capsys):
    (tmp_path / "s.toml").write_text(inline(TAU) + "max_iter = 1\n")
    assert main(["static", str(tmp_path / "s.toml"), "--out", str(tmp_path / "o"), "--no-figures"]) == 1
    res = json.loads((tmp_path / "o" / "results.json").read_text())
    rods = pd.read_parquet(tmp_path / "o" / "rods.parquet")
    failed = rods[~rods["success"]]
    assert res["failed_rods"] == len(failed) > 0 and res["converged_rods"] == B - len(failed)
    assert not failed["converged"].any() and res["unstable_rods"] == 0
    assert res["failure_reasons"] == failed["status_text"].astype(str).value_counts().to_dict()
    assert set(failed["status_text"]) == {"iteration cap reached"}
    assert "(per rod in rods.parquet)" in capsys.readouterr().err


def test_optional_columns_hold_the_solution(tmp_path):
    """Tendon states, the error estimate and the stability verdict: a documented column each."""
    np.save(tmp_path / "tau.npy", TAU)
    text = from_file("tau.npy").replace("[solver]", '[solver]\nstability = "stable"\ntendon_states = true\n'
                                        "error_estimate = true")
    (tmp_path / "s.toml").write_text(text)
    assert main(["static", str(tmp_path / "s.toml"), "--out", str(tmp_path / "o"), "--no-figures"]) == 0
    rods = pd.read_parquet(tmp_path / "o" / "rods.parquet")
    assert not documented(rods.columns), documented(rods.columns)
    scene = load_scene(tmp_path / "s.toml")
    sol = tw.solve_static(scene.robot, scene.tensions, options=scene.options)
    for column, array in [("free_length[1]", sol.tendon_free_length[:, 1]), ("slack[0]", sol.slack[:, 0]),
                          ("tip_error_estimate", sol.tip_error_estimate), ("stable", sol.stable),
                          ("stability_index", sol.stability_index), ("branch", sol.branch),
                          ("lagrangian_error", sol.lagrangian_error), ("multiple_stable", sol.multiple_stable),
                          ("stability_margin", sol.stability_margin), ("success", sol.success)]:
        assert np.array_equal(rods[column].to_numpy(), array, equal_nan=array.dtype.kind == "f"), column
    assert rods["stability_text"].astype(str).tolist() == sol.stability_reasons()


def test_ik_large_batch_writes_its_table(large, tmp_path, capsys):
    """Targets the forward statics reached (and one out of reach): ik.parquet holds what ik.npz does."""
    _, _, sol = large
    targets = np.vstack([sol.tip_position, [[0.3, 0.0, 0.2]]])
    text = from_file("unused.npy").replace('tensions = "unused.npy"', "tensions = [[0.0, 0.0]]")
    (tmp_path / "s.toml").write_text(text + "[ik]\ntargets = " + repr(targets.tolist()) + "\ntension_max = 4.0\n")
    assert main(["ik", str(tmp_path / "s.toml"), "--out", str(tmp_path / "o")]) == 1
    assert "closest point found: ik.parquet" in capsys.readouterr().err
    res = json.loads((tmp_path / "o" / "ik.json").read_text())
    assert "rods" not in res and res["reached"] == B and res["reasons"] == {"reached": B, "unreachable": 1}
    rows = pd.read_parquet(tmp_path / "o" / "ik.parquet")
    assert not documented([*res, *rows.columns]), documented([*res, *rows.columns])
    assert set(res["files"]) == {"ik.npz", "ik.parquet"} and res["files"]["ik.parquet"]["rows"] == B + 1
    with np.load(tmp_path / "o" / "ik.npz") as z:
        assert {i.compress_type for i in z.zip.infolist()} == {0}
        assert np.array_equal(rows[["command[0]", "command[1]"]].to_numpy(), z["command"])
        assert np.array_equal(rows[[f"tip_position[{i}]" for i in range(3)]].to_numpy(), z["tip_position"])
        assert rows["reason"].astype(str).tolist() == z["reason"].tolist()
        for key in ("success", "position_error", "orientation_error", "iterations"):
            assert np.array_equal(rows[key].to_numpy(), z[key]), key
    assert np.array_equal(rows[[f"target[{i}]" for i in range(3)]].to_numpy(), targets)
    assert np.abs(rows["command[0]"][:B] - TAU[:, 0]).max() < 1e-6  # the tensions that made the tips


def test_simulate_large_batch_writes_its_table(tmp_path):
    (tmp_path / "s.toml").write_text(inline(TAU) + "[dynamics]\ndt = 0.005\nsteps = 3\n")
    assert main(["simulate", str(tmp_path / "s.toml"), "--out", str(tmp_path / "o"), "--quiet",
                 "--no-figures"]) == 0
    res = json.loads((tmp_path / "o" / "results.json").read_text())
    assert "completed" not in res and (res["completed_rods"], res["failed_rods"]) == (B, 0)
    rods = pd.read_parquet(tmp_path / "o" / "rods.parquet")
    assert not documented([*res, *rods.columns]), documented([*res, *rods.columns])
    with np.load(tmp_path / "o" / "trajectory.npz") as z:
        assert {i.compress_type for i in z.zip.infolist()} == {0}
        tip = z["tip_position"][-1]
        assert np.array_equal(rods[[f"final_tip_position[{i}]" for i in range(3)]].to_numpy(), tip)
        assert np.array_equal(rods["max_iterations"].to_numpy(), z["iterations"].max(axis=0))
    assert rods["completed"].all() and (rods["failed_step"] == 0).all()


def test_control_large_batch_writes_its_table(tmp_path):
    text = (ROOT / "examples" / "our_control.toml").read_text().replace(
        "tensions = [[0.0, 0.0, 0.0, 0.0]]", "tensions = " + repr([[0.0] * 4] * B)).replace("nodes = 50", "nodes = 8")
    (tmp_path / "s.toml").write_text(text)
    assert main(["control", str(tmp_path / "s.toml"), "--out", str(tmp_path / "o"), "--quiet", "--steps", "3"]) == 0
    res = json.loads((tmp_path / "o" / "metrics.json").read_text())
    assert "metrics" not in res and (res["completed_rods"], res["failed_rods"]) == (B, 0)
    table = pd.read_parquet(tmp_path / "o" / "metrics.parquet")
    assert not documented([*res, *table.columns]), documented([*res, *table.columns])
    assert set(res["units"]) | {"row", "completed", "target[0]", "target[1]", "target[2]"} == {
        c.split("[")[0] if c.startswith("mean_tension") else c for c in table.columns}
    with np.load(tmp_path / "o" / "control.npz") as z:
        assert {i.compress_type for i in z.zip.infolist()} == {0}
        assert np.array_equal(table[[f"target[{i}]" for i in range(3)]].to_numpy(), z["target"])
        assert np.array_equal(table["final_error"].to_numpy(), np.linalg.norm(z["error"][-1], axis=1))
