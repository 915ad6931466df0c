"""Per-rod tables a scene names as files ([actuation].tensions = "tensions.npy", .csv, .parquet)
and the Parquet writer of the per-rod tables (tdcr_warp.io.store.write_table)."""

import io
import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from scenes import two_tendon_scene

from tdcr_warp.cli import main
from tdcr_warp.io.scene import load_scene
from tdcr_warp.io.store import write_table

TAU = np.random.default_rng(7).uniform(0.0, 2.0, (40, 2))


def inline(tau) -> str:
    return two_tendon_scene("[" + ", ".join(f"[{float(a)!r}, {float(b)!r}]" for a, b in tau) + "]", nodes=8)


def from_file(name: str) -> str:
    return two_tendon_scene(f'"{name}"', nodes=8)


@pytest.mark.parametrize("kind", ["npy", "csv", "csv_header", "parquet"])
def test_table_files_give_the_inline_tensions(tmp_path, monkeypatch, kind):
    folder = tmp_path / "scenes"
    folder.mkdir()
    name = {"csv_header": "t.csv"}.get(kind, f"t.{kind}")
    if kind == "npy":
        np.save(folder / name, TAU)
    elif kind == "parquet":  # every column, in order (no tensions[k] columns)
        pq.write_table(pa.table({"first": TAU[:, 0], "second": TAU[:, 1]}), folder / name)
    else:
        np.savetxt(folder / name, TAU, delimiter=",", fmt="%.17g",
                   header="left,right" if kind == "csv_header" else "", comments="")
    (folder / "s.toml").write_text(from_file(name))
    monkeypatch.chdir(tmp_path)  # the file is found beside the scene, not in the working directory
    scene = load_scene("scenes/s.toml")
    assert np.array_equal(scene.tensions, TAU)
    assert scene.source["actuation"]["tensions"] == str(folder / name)  # rebuildable from anywhere


@pytest.mark.parametrize("version", [(1, 0), (2, 0)])
@pytest.mark.parametrize("order", ["C", "F"])
def test_npy_files_of_either_format_and_order_are_read_as_saved(tmp_path, version, order):
    """The .npy reader reads the header itself (to check it before allocating): both formats numpy
    writes, Fortran order, integer tables."""
    for table in (np.asarray(TAU, order=order), np.asarray(np.round(TAU * 10), dtype=np.int32, order=order)):
        with open(tmp_path / "t.npy", "wb") as f:
            np.lib.format.write_array(f, table, version=version)
        (tmp_path / "s.toml").write_text(from_file("t.npy"))
        assert np.array_equal(load_scene(tmp_path / "s.toml").tensions, table)


def test_steps_and_displacements_read_files_too(tmp_path):
    np.save(tmp_path / "later.npy", TAU[:, ::-1])
    text = inline(TAU) + '[dynamics]\ndt = 0.01\nsteps = 4\n[[actuation.steps]]\nstart = 3\ntensions = "later.npy"\n'
    (tmp_path / "s.toml").write_text(text)
    schedule = load_scene(tmp_path / "s.toml").dynamics.schedule
    assert np.array_equal(schedule[:, 1], TAU) and np.array_equal(schedule[:, 3], TAU[:, ::-1])


def _npy_header(shape) -> bytes:
    """A .npy header of float64 of ``shape`` (the data to follow)."""
    f = io.BytesIO()
    np.lib.format.write_array_header_1_0(f, {"descr": "<f8", "fortran_order": False, "shape": shape})
    return f.getvalue()


@pytest.mark.parametrize("name, content, message", [
    ("nope.npy", None, "[actuation].tensions = '{path}': cannot read the file: No such file or directory"),
    ("t.txt", "1, 2\n", "[actuation].tensions = '{path}': a per-rod table file must end in .npy, .csv, .parquet"),
    ("t.csv", "1.0, 2.0\n1.0, x\n", "[actuation].tensions = '{path}': could not convert string ' x'"),
    ("t.csv", "1.0, 2.0\n-1.0, 1.0\n", "[actuation].tensions ('t.csv')[1][0] must be a finite number >= 0"),
    ("t.csv", "1.0, 2.0, 3.0\n", "[actuation].tensions ('t.csv'): expected shape (B, 2) for 2 tendons"),
    ("t.npy", np.array(["a", "b"]), "[actuation].tensions = '{path}': expected a (B, K) table of numbers, got "
     + "shape (2,) of <U1"),
    ("t.parquet", pa.table({"a": [1.0, 2.0], "b": ["x", "y"]}), "column 'b' holds string, not numbers"),
    ("t.parquet", pa.table({"a": [1.0, None], "b": [1.0, 2.0]}), "column 'a' has 1 missing values"),
    ("t.parquet", b"PAR1 not really", "[actuation].tensions = '{path}': not a readable Parquet file"),
    ("t.npy", np.array([1.0, None], dtype=object), "expected a (B, K) table of numbers, got shape (2,) of object"),
    ("t.npy", np.zeros((2, 2, 2)), "expected a (B, K) table of numbers, got shape (2, 2, 2) of float64"),
    ("t.npy", _npy_header((40, 2)) + bytes(8),
     "the header says shape (40, 2) of float64 (640 bytes), the file holds 8 bytes after it"),
    ("t.npy", b"not numpy", "[actuation].tensions = '{path}': the magic string is not correct"),
])
def test_a_bad_table_file_names_the_key_and_the_file(tmp_path, capsys, name, content, message):
    path = tmp_path / name
    if isinstance(content, str):
        path.write_text(content)
    elif isinstance(content, bytes):
        path.write_bytes(content)
    elif isinstance(content, np.ndarray):
        np.save(path, content)
    elif content is not None:
        pq.write_table(content, path)
    (tmp_path / "s.toml").write_text(from_file(name))
    assert main(["static", str(tmp_path / "s.toml"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert message.format(path=path) in err, err
    assert "Traceback" not in err and not (tmp_path / "o" / "results.json").exists()


def test_write_table_keeps_types_without_importing_pandas(tmp_path):
    """pa.array would import pandas (0.5-0.7 s) when installed; write_table builds from buffers."""
    code = f"""
import sys, numpy as np
from pathlib import Path
from tdcr_warp.io.store import write_table
cols = {{"f": np.array([1.5, -2.0, 3.25]), "i8": np.array([-1, 0, 1], np.int8), "b": np.array([True, False, True]),
        "col": np.arange(6.0).reshape(3, 2)[:, 1], "s": ["converged", "iteration cap reached", "converged"]}}
write_table(Path({str(tmp_path / "t.parquet")!r}), cols, {{"k": 1}})
print("pandas" in sys.modules)
"""
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert run.stdout.strip() == "False"
    df = pd.read_parquet(tmp_path / "t.parquet")
    assert df["f"].tolist() == [1.5, -2.0, 3.25] and df["i8"].dtype == np.int8 and df["i8"].tolist() == [-1, 0, 1]
    assert df["b"].tolist() == [True, False, True] and df["col"].tolist() == [1.0, 3.0, 5.0]
    assert df["s"].astype(str).tolist() == ["converged", "iteration cap reached", "converged"]
    assert json.loads(pq.read_schema(tmp_path / "t.parquet").metadata[b"tdcr_warp"]) == {"k": 1}
    write_table(tmp_path / "t.parquet", {"f": np.zeros(0)}, {})  # an empty table, replacing the file
    assert len(pd.read_parquet(tmp_path / "t.parquet")) == 0 and not list(tmp_path.glob(".*tmp"))
