"""tdcr_warp.cli.common's output folder: a safe default name, one locked run at a time whose files
move in as one set, and CSV cells a spreadsheet does not run."""

import csv
import io
import json
import os
from argparse import Namespace
from pathlib import Path

import numpy as np
import pytest
from scenes import ROBOT

from tdcr_warp.cli import main
from tdcr_warp.cli.common import STAGE, CsvWriter, OutputRun, csv_cell, output_folder, write_json
from tdcr_warp.io.files import FolderLock
from tdcr_warp.model.robot import InputError

NAMES = ("results.json", "shapes.npz", "shapes.png")


def args(scene="scene.toml", out=None, command="static"):
    return Namespace(scene=scene, out=out, command=command)


@pytest.mark.parametrize("scene", ["...toml", "..toml", "dir/...toml", "\x1b[2J.toml", "a\nb.toml",
                                   "back\\slash.toml"])
def test_a_scene_name_that_is_no_safe_folder_name_needs_out(scene):
    """'...toml' would make out/.. (the working directory), '..toml' out itself, a control
    character a folder name that drives the terminal."""
    with pytest.raises(InputError) as e:
        output_folder(args(scene), Path("out") / Path(scene).stem)
    assert str(e.value).startswith(f"{scene}: the scene file's name gives no safe default output folder")
    assert str(e.value).endswith("; choose one with --out")
    assert output_folder(args(scene, out="elsewhere"), Path("out") / Path(scene).stem) == Path("elsewhere")


@pytest.mark.parametrize("scene,folder", [("my scene.toml", "my scene"), (".hidden.toml", ".hidden"),
                                          ("dir/ü.toml", "ü"), ("a..b.toml", "a..b"),
                                          (".toml", ".toml")])
def test_an_ordinary_scene_name_is_its_folder(scene, folder):
    assert output_folder(args(scene), Path("out") / Path(scene).stem) == Path("out") / folder


def test_dotted_scene_exits_2_and_writes_nothing_outside(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "...toml").write_text("\n" + ROBOT + "[[tendons]]\noffset = [0.01, 0.0]\n[actuation]\n"
                                      "tensions = [[1.0]]\n[solver]\nnodes = 8\n")
    before = sorted(os.listdir(tmp_path))
    assert main(["static", "...toml", "--no-figures"]) == 2
    err = capsys.readouterr().err
    assert err == ("tdcr-warp: error: ...toml: the scene file's name gives no safe default output folder "
                   "(out/'..'); choose one with --out\n")
    assert sorted(os.listdir(tmp_path)) == before


def staged(run, names, text="new"):
    for name in names:
        (run / name).write_text(text)


def test_a_run_moves_its_files_in_as_one_set(tmp_path):
    out = tmp_path / "o"
    out.mkdir()
    for name in NAMES:
        (out / name).write_text("old")
    (out / "other.txt").write_text("not ours")
    with OutputRun(args(out=out), Path("unused"), NAMES) as run:
        assert not (out / "results.json").exists()  # the earlier completion file goes first
        assert (out / "shapes.npz").read_text() == "old"  # the rest stays until the commit
        assert run.stage.parent == out and run.stage.name.startswith(STAGE) and (out / ".lock").exists()
        staged(run, ["shapes.npz", "results.json"])  # no shapes.png this time (--no-figures)
        run.commit()
    assert sorted(p.name for p in out.iterdir()) == ["other.txt", "results.json", "shapes.npz"]
    assert (out / "results.json").read_text() == (out / "shapes.npz").read_text() == "new"


def test_an_interrupted_run_leaves_nothing_of_its_own(tmp_path):
    out = tmp_path / "o"
    with pytest.raises(KeyboardInterrupt), OutputRun(args(out=out), Path("unused"), NAMES) as run:
        staged(run, ["shapes.npz"])
        raise KeyboardInterrupt
    assert list(out.iterdir()) == []  # no staging folder, no lock file
    killed = out / f"{STAGE}killed"  # a run killed with -9 leaves its staging folder: the next run removes it
    killed.mkdir()
    (killed / "shapes.npz").write_text("partial")
    with OutputRun(args(out=out), Path("unused"), NAMES) as run:
        assert not killed.exists()
        staged(run, ["results.json"])
        run.commit()
    assert [p.name for p in out.iterdir()] == ["results.json"]


def test_completion_files_go_first_and_come_back_last(tmp_path, monkeypatch):
    """fit's two completion files: removed on entry, moved in after the other files, fit.json last."""
    names = ("fit.json", "fitted.toml", "predictions.csv")
    for name in names:
        (tmp_path / name).write_text("old")
    moved = []
    replace = os.replace
    monkeypatch.setattr(os, "replace", lambda a, b: (moved.append(Path(b).name), replace(a, b)))
    with OutputRun(args(out=tmp_path, command="fit"), Path("unused"), names, complete=2) as run:
        assert sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith(".")) == ["predictions.csv"]
        staged(run, ["fit.json", "predictions.csv", "fitted.toml"])
        run.commit()
    assert moved == ["predictions.csv", "fitted.toml", "fit.json"]
    assert all((tmp_path / name).read_text() == "new" for name in names)


def test_commit_refuses_files_the_command_does_not_declare(tmp_path):
    with OutputRun(args(out=tmp_path), Path("unused"), NAMES) as run:
        staged(run, ["results.json", "undocumented.txt"])
        with pytest.raises(RuntimeError, match="undocumented.txt"):
            run.commit()
    assert list(tmp_path.iterdir()) == []


def test_a_concurrent_run_is_refused_and_writes_nothing(tmp_path, capsys):
    """A second static run into a folder being written exits 2 naming the folder and the
    holder; the first run's files are its own alone."""
    scene = tmp_path / "s.toml"
    scene.write_text("\n" + ROBOT + "[[tendons]]\noffset = [0.01, 0.0]\n[actuation]\ntensions = [[1.0]]\n"
                     "[solver]\nnodes = 8\n")
    out = tmp_path / "o"
    with OutputRun(args(out=out), Path("unused"), NAMES) as first:
        assert main(["static", str(scene), "--out", str(out), "--no-figures"]) == 2
        staged(first, ["results.json"], "first")
        first.commit()
    err = capsys.readouterr().err
    assert err.startswith(f"tdcr-warp: error: {out} is being written by another tdcr-warp static (pid {os.getpid()} on ")
    assert err.count("\n") == 1
    assert [p.name for p in out.iterdir()] == ["results.json"] and (out / "results.json").read_text() == "first"


def test_a_sweep_and_a_run_exclude_each_other(tmp_path):
    with FolderLock(tmp_path, "montecarlo"), pytest.raises(InputError, match="another tdcr-warp montecarlo"):
        OutputRun(args(out=tmp_path), Path("unused"), NAMES).__enter__()


def test_every_file_of_a_run_gets_one_mode(tmp_path, monkeypatch):
    """JSON, npz, PNG and HTML alike: 0666 less the umask (here 027: 0640)."""
    scene = tmp_path / "s.toml"
    scene.write_text("\n" + ROBOT + "[[tendons]]\noffset = [0.01, 0.0]\n[actuation]\ntensions = [[1.0]]\n"
                     "[solver]\nnodes = 8\n")
    old = os.umask(0o027)
    try:
        assert main(["static", str(scene), "--out", str(tmp_path / "o"), "--html"]) == 0
    finally:
        os.umask(old)
    modes = {p.name: oct(p.stat().st_mode & 0o777) for p in (tmp_path / "o").iterdir()}
    assert modes == dict.fromkeys(["results.json", "shapes.npz", "shapes.png", "robot.html"], "0o640")


@pytest.mark.parametrize("cell,shown", [("=2+3", "'=2+3"), ("+1", "'+1"), ("-x", "'-x"), ("@SUM(A1)", "'@SUM(A1)"),
                                        ("\t=1", "'\t=1"), ("\r=1", "'\r=1"), ("a=1", "a=1"), ("", ""),
                                        (-2.5, -2.5), (3, 3), (np.str_("=1"), "'=1")])
def test_csv_cells_starting_a_formula_are_quoted(cell, shown):
    out = csv_cell(cell)
    assert out == shown and type(out) is type(shown)


def test_csv_writer_keeps_numbers_as_numbers():
    f = io.StringIO()
    CsvWriter(f).writerow(["=HYPERLINK(\"x\")", -1.5, 0, "-2"])
    assert next(csv.reader(io.StringIO(f.getvalue()))) == ["'=HYPERLINK(\"x\")", "-1.5", "0", "'-2"]


def test_predictions_csv_neutralises_labels_from_the_data(tmp_path, monkeypatch):
    """predict copies each row's label and its file's name into predictions.csv: neither reaches
    a spreadsheet as a formula; the numbers stay numbers."""
    hardware = ROBOT + ("[[tendons]]\noffset = [0.01, 0.0]\ncontrol = \"displacement\"\ncompliance = 2e-4\n"
                        "pretension = 0.5\n") * 1 + ("[[tendons]]\noffset = [0.0, 0.01]\ncontrol = \"displacement\"\n"
                                                     "compliance = 2e-4\npretension = 0.5\n") + \
        "[actuation]\ntensions = [[0.0, 0.0]]\n[solver]\nnodes = 10\n[hardware]\nservo_columns = [\"a\", \"b\"]\n"
    (tmp_path / "scene.toml").write_text(hardware)
    (tmp_path / "@data.csv").write_text("timestamp,pattern_label,a,b,tip_x,tip_y,tip_z\n"
                                        "0,=2+3,0.5,0,-1,0,500\n1,-cmd|' /C calc'!A0,0,0.5,0,-1,500\n")
    monkeypatch.chdir(tmp_path)
    assert main(["predict", "scene.toml", "@data.csv", "--out", "o"]) in (0, 1)
    rows = list(csv.reader(open(tmp_path / "o" / "predictions.csv", newline="")))
    assert [r[1:3] for r in rows[1:]] == [["'@data.csv", "'=2+3"], ["'@data.csv", "'-cmd|' /C calc'!A0"]]
    assert all(float(v) == float(v) for r in rows[1:] for v in r[3:10])  # plain numbers, negative ones included
    assert rows[1][6] == "-1.0"
    assert json.loads((tmp_path / "o" / "metrics.json").read_text())["rows"] == 2


def test_write_json_is_strict(tmp_path):
    write_json(tmp_path / "a.json", {"x": float("nan"), "y": [1.0, float("inf")]})
    assert json.loads((tmp_path / "a.json").read_text()) == {"x": None, "y": [1.0, None]}
