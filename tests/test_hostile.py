"""A hostile or careless user (issue 39): every attack ends in exit 2 with one line naming the
field and the value, never a traceback, never silent acceptance. The attacks that could take
memory or time without bound run together in one subprocess under a 2 GiB address-space cap and a
timeout, so that a regression fails the test instead of the machine; the cheap refusals run
in-process."""

import copy
import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from tdcr_warp.apps.sweep import SweepSpec
from tdcr_warp.cli import main
from tdcr_warp.io.inputs import SCENE_LIMIT
from tdcr_warp.io.scene import scene_from_dict
from tdcr_warp.model.checks import InputError, is_number
from tdcr_warp.model.schema import SCHEMA

CAP = 2 * 2**30  # bytes of address space an attack may take (the CLI itself peaks near 0.6 GiB)
BASE = """[robot]
length = 0.5
youngs_modulus = 190e9
poisson_ratio = 0.3
radius = 1e-3
density = 7800.0
[[tendons]]
offset = [0.01, 0.0]
[actuation]
tensions = [[1.0]]
[solver]
nodes = 10
"""
GOOD = {"robot": {"length": 0.5, "youngs_modulus": 190e9, "poisson_ratio": 0.3, "radius": 1e-3, "density": 7800.0},
        "tendons": [{"offset": [0.01, 0.0]}], "actuation": {"tensions": [[1.0]]}}

# Runs the CLI on each argv in-process, under the cap; prints the argv it starts on stderr (which
# attack a killed process was on) and a JSON list of {argv, rc, err} at the end.
RUNNER = textwrap.dedent("""
    import contextlib, io, json, resource, sys
    resource.setrlimit(resource.RLIMIT_AS, ({cap}, {cap}))
    from tdcr_warp.cli import main
    out = []
    for argv in json.loads(sys.argv[1]):
        print("attack:", argv, file=sys.stderr, flush=True)
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            try:
                rc = main(argv)
            except SystemExit as e:
                rc = e.code
            except BaseException as e:  # MemoryError, RecursionError, ...: the failures looked for
                rc = repr(e)
        out.append({{"argv": argv, "rc": rc, "err": err.getvalue()}})
    print(json.dumps(out))
""")


def _write(path, text: str):
    path.write_text(text)
    return str(path)


def _npy_claiming(path, shape) -> None:
    """A .npy file whose header claims ``shape`` of float64 and holds 64 bytes."""
    with open(path, "wb") as f:
        np.lib.format.write_array_header_1_0(f, {"descr": "<f8", "fortran_order": False, "shape": shape})
        f.write(bytes(64))


def _attacks(tmp) -> list[tuple[list[str], str]]:
    """(argv, the words its one-line error must hold) of every attack that could grow without bound."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    _npy_claiming(tmp / "huge.npy", (100_000, 100_000))
    os.symlink("/dev/zero", tmp / "zero.npy")
    os.mkfifo(tmp / "fifo.toml")
    os.mkfifo(tmp / "fifo.csv")
    pq.write_table(pa.table({"t": pa.array(np.zeros(40_000_000, dtype=np.int8))}), tmp / "rows.parquet")
    table = {name: _write(tmp / f"table_{name}.toml", BASE.replace("tensions = [[1.0]]", f'tensions = "{file}"'))
             for name, file in (("huge", "huge.npy"), ("zero", "zero.npy"), ("fifo", "fifo.csv"),
                                ("rows", "rows.parquet"))}
    big = _write(tmp / "big.toml", BASE + "#" * SCENE_LIMIT + "\n")
    deep = {kind: _write(tmp / f"deep_{kind}.toml", BASE + text) for kind, text in (
        ("header", "[" + ".".join(["a"] * 2000) + "]\nx = 1\n"),
        ("arrays", "[loads]\ngravity = " + "[" * 2000 + "]" * 2000 + "\n"),
        ("tables", "[loads]\ngravity = " + "{a = " * 2000 + "1" + "}" * 2000 + "\n"),
        ("keys", "[loads]\n" + ".".join(["a"] * 2000) + " = 1\n"))}
    disks = _write(tmp / "disks.toml", BASE.replace("density = 7800.0", "density = 7800.0\ndisks = 1000000000")
                   .replace("nodes = 10", 'nodes = 10\nmodel = "disks"'))
    static = ["static", "--out", str(tmp / "o"), "--no-figures", "--quiet"]
    return [
        (static + [table["huge"]], "the header says shape (100000, 100000) of float64"),
        (static + [table["zero"]], "not a regular file (a character device)"),
        (static + [table["fifo"]], "not a regular file (a named pipe)"),
        (static + [table["rows"]], "the file declares 40,000,000 rows"),
        (static + ["/dev/zero"], "cannot read scene '/dev/zero': not a regular file (a character device)"),
        (static + [str(tmp / "fifo.toml")], "not a regular file (a named pipe)"),
        (static + [str(tmp)], "not a regular file (a directory)"),
        (static + [big], "more than the 8.0 MiB this input takes"),
        (static + [deep["header"]], "a.a.a: nested more than 16 levels deep"),
        (static + [deep["arrays"]], "nested too deeply to parse"),
        (static + [deep["tables"]], "nested too deeply to parse"),
        (static + [deep["keys"]], "loads.a.a: nested more than 16 levels deep"),
        (static + [disks], "disks = 1000000000 per section in 1 section(s) is more than 100,000 disks"),
    ]


def test_unbounded_attacks_exit_2_under_a_memory_cap(tmp_path):
    """Each attack used to end in a traceback, a 74.5 GiB allocation, a read of /dev/zero until the
    OOM killer, a wait on a FIFO for ever or a RecursionError; now one line each, in one process
    capped at 2 GiB of address space and 120 s."""
    attacks = _attacks(tmp_path)
    argv = [a for a, _ in attacks]
    proc = subprocess.run([sys.executable, "-c", RUNNER.format(cap=CAP), json.dumps(argv)], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    results = json.loads(proc.stdout.splitlines()[-1])
    for (args, words), res in zip(attacks, results, strict=True):
        err = res["err"]
        assert res["rc"] == 2, (args, res)
        assert err.startswith("tdcr-warp: error: ") and err.count("\n") == 1 and "Traceback" not in err, (args, err)
        assert words in err, (args, err)


def _context(table: str) -> tuple[dict, dict]:
    """A valid scene holding table ``table`` (and what it needs), and that table's dict in it."""
    d = copy.deepcopy(GOOD) | {"dynamics": {"dt": 0.01, "steps": 3}}
    if table in ("control", "search"):
        d["control"] = {"target": [0.0, 0.0, 0.5], "epsilon": 0.005}
    if table == "search":
        d["search"] = {"ranges": {"control.epsilon": [0.001, 0.1]}, "budget": 4}
    if table == "ik":
        d["ik"] = {"targets": [0.0, 0.0, 0.5]}
    if table == "sweep":
        d["sweep"] = {"grid": {"actuation.tensions[0]": [0.0, 1.0, 2]}}
    if table == "actuation.steps":
        d["actuation"]["steps"] = [{"start": 1, "tensions": [[1.0]]}]
        return d, d["actuation"]["steps"][0]
    return d, d.setdefault(table, {})


def _parse(d: dict) -> None:
    scene_from_dict(d)
    if "sweep" in d:
        SweepSpec(d)


INTEGER_KEYS = [(t.name, k) for t in SCHEMA.values() for k in t.keys if k.type == "integer"]


@pytest.mark.parametrize("table,key", INTEGER_KEYS, ids=[f"{t}.{k.name}" for t, k in INTEGER_KEYS])
def test_every_integer_key_is_held_to_its_bounds(table, key):
    """The class of shapes_every = -1: every integer key of the schema has bounds, its least (and
    most) value is read, one beyond either is refused naming the key and the value."""
    least, most = key.bounds
    for value, ok in [(least, True), (least - 1, False)] + ([(most, True), (most + 1, False)] if most else []):
        d, where = _context(table)
        where[key.name] = value
        if key.name == "shapes_every":
            d["dynamics"]["steps"] = max(value, 1)
        if ok:
            _parse(d)
            continue
        with pytest.raises(InputError) as e:
            _parse(d)
        assert key.name in str(e.value) and str(value) in str(e.value), str(e.value)


def test_shapes_every_beyond_the_steps_is_refused():
    d, dyn = _context("dynamics")
    dyn["shapes_every"] = 4
    with pytest.raises(InputError, match=r"\[dynamics\].shapes_every = 4 is more than steps = 3"):
        scene_from_dict(d)


@pytest.mark.parametrize("dist,params,words", [
    ("uniform", [5.0, 1.0], "uniform [low, high] needs low <= high, got [5.0, 1.0]"),
    ("uniform", [0.0, float("inf")], "two finite numbers, got [0.0, inf]"),
    ("normal", [1.0, float("nan")], "two finite numbers, got [1.0, nan]"),
    ("normal", [1.0, -0.1], "normal [mean, std] needs std >= 0"),
    ("lognormal", [True, 0.1], "two finite numbers, got [True, 0.1]"),
])
def test_distribution_parameters_are_checked(dist, params, words):
    d = copy.deepcopy(GOOD) | {"sweep": {"samples": 4},
                               "uncertainty": [{"field": "robot.length", "distribution": dist, "params": params}]}
    with pytest.raises(InputError) as e:
        SweepSpec(d)
    assert str(e.value).startswith("[[uncertainty]] #1.params: ") and words in str(e.value), str(e.value)


DISKS = BASE.replace("density = 7800.0", "density = 7800.0\ndisks = 4")
WALL = '[[obstacles]]\nkind = "plane"\npoint = [0.05, 0.0, 0.0]\nnormal = [-1.0, 0.0, 0.0]\n'


@pytest.mark.parametrize("command,scene,extra,words", [
    ("static", DISKS.replace("nodes = 10", 'nodes = 10\nmodel = "disks"') + WALL, [], "obstacles (1 [[obstacles]])"),
    ("static", DISKS.replace("nodes = 10", 'nodes = 10\nmodel = "disks"').replace(
        "offset = [0.01, 0.0]", "offset = [0.01, 0.0]\nfriction = 0.1"), [], "friction (tendons[0].friction = 0.1)"),
    ("simulate", DISKS.replace("nodes = 10", 'nodes = 10\nmodel = "disks"') + "[dynamics]\ndt = 0.01\nsteps = 2\n",
     [], "dynamics (time stepping"),
    ("static", DISKS + WALL, ["--model", "disks"], "obstacles (1 [[obstacles]])"),
    ("control", DISKS + "[dynamics]\ndt = 0.01\nsteps = 2\n[control]\ntarget = [0.0, 0.0, 0.5]\n",
     ["--model", "disks"], "dynamics (time stepping"),
    ("static", BASE + WALL, ["--model", "constant_curvature"], "obstacles (1 [[obstacles]])"),
], ids=["disks+obstacle", "disks+friction", "disks+dynamics", "--model disks+obstacle", "--model disks+control",
        "--model constant_curvature+obstacle"])
def test_models_refuse_what_they_do_not_solve(tmp_path, capsys, command, scene, extra, words):
    """These ended in a kernel factory's ValueError traceback; refused before any kernel now."""
    path = _write(tmp_path / "s.toml", scene)
    assert main([command, path, "--out", str(tmp_path / "o"), "--quiet", *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith("tdcr-warp: error: ") and "does not support" in err and words in err, err
    assert "Traceback" not in err and not (tmp_path / "o" / "results.json").exists()


@pytest.mark.parametrize("argv,option", [
    (["static", "--nodes", "1_0"], "--nodes"), (["static", "--nodes", "\u0663"], "--nodes"),
    (["static", "--nodes", " 7"], "--nodes"), (["montecarlo", "--chunk", "1_6"], "--chunk"),
    (["montecarlo", "--workers", "0"], "--workers"), (["montecarlo", "--gpus-per-task", "nan"], "--gpus-per-task"),
    (["montecarlo", "--gpus-per-task", "-1"], "--gpus-per-task"), (["simulate", "--steps", "1e3"], "--steps"),
])
def test_numbers_on_the_command_line_are_read_strictly(tmp_path, capsys, argv, option):
    """Python's int() and float() take "1_0", " 7" and non-ASCII digits; the CLI refuses them."""
    command, *rest = argv
    with pytest.raises(SystemExit) as e:
        main([command, _write(tmp_path / "s.toml", BASE), *rest])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {option}: must be" in err and repr(rest[-1]) in err and "Traceback" not in err, err


@pytest.mark.parametrize("text,number,integer", [
    ("10", True, True), ("-3", True, True), ("1_0", False, True), ("1.5", False, True), ("\u0663", False, True),
    ("1.5e-3", True, False), (".5", True, False), ("inf", True, False), ("1_0.5", False, False), (" 1", False, False),
    ("", False, False), ("0x10", False, False),
])
def test_is_number_takes_ascii_numbers_only(text, number, integer):
    assert is_number(text, integer) is number


def test_an_error_is_one_bounded_line_however_long_the_input(tmp_path, capsys):
    """A megabyte key name was echoed whole (1,000,130 characters on stderr)."""
    path = _write(tmp_path / "s.toml", BASE + "[loads]\n" + "k" * 1_000_000 + " = 1\n")
    assert main(["static", path, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("tdcr-warp: error: ") and "unknown key 'kkk" in err and "Traceback" not in err
    assert err.count("\n") == 1 and len(err) < 2100 and err.endswith(" characters)\n"), err[-200:]


@pytest.mark.parametrize("name,words", [
    ("a\\u0000.npy", "cannot read the file: embedded null byte"),
    ("~no_such_user_here/t.npy", "[actuation].tensions = '~no_such_user_here/t.npy': Could not determine home"),
], ids=["NUL in the name", "~user of no user"])
def test_odd_table_file_names_exit_2(tmp_path, capsys, name, words):
    """A ValueError and a RuntimeError traceback before."""
    path = _write(tmp_path / "s.toml", BASE.replace("tensions = [[1.0]]", f'tensions = "{name}"'))
    assert main(["static", path, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("tdcr-warp: error: ") and words in err and "Traceback" not in err, err
