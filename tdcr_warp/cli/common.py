"""What every command shares: files written atomically, strict JSON and neutralised CSV, the
output directory (locked, its files moved in as one set), the settings recorded beside the
results, the solver overrides, the per-rod lines printed and the arguments common to the
commands."""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import shutil
import tempfile
from dataclasses import asdict, fields, replace
from pathlib import Path
from typing import Self

import numpy as np

from tdcr_warp.io.files import FolderLock, printable, write_atomic
from tdcr_warp.kernels.variants import INTEGRATORS, MODELS
from tdcr_warp.model.checks import is_number
from tdcr_warp.model.options import check_model_support
from tdcr_warp.model.robot import InputError

# Batches up to this size are written per rod into the JSON results; larger ones into a Parquet
# table (per-rod JSON costs ~0.5 ms a rod: 8 s for 16,384 rods, twice their solve).
JSON_RODS = 100
# The [solver] fields that the command line overrides (--nodes, --integrator, --model, --precision).
OVERRIDES = ("nodes", "integrator", "model", "precision")
# A run's files are written into a private folder DIR/.run-XXXXXXXX, moved into DIR at its end.
STAGE = ".run-"
# The first characters that make a spreadsheet read a CSV cell as a formula (OWASP: CSV injection).
FORMULA_START = ("=", "+", "-", "@", "\t", "\r")


def write_npz(path: Path, save) -> None:
    """``save(file)`` writes an .npz into an open binary file (np.savez would rename a path)."""
    def write(tmp):
        with open(tmp, "wb") as f:
            save(f)
    write_atomic(path, write)


def write_arrays(path: Path, obj, **extra: np.ndarray) -> dict:
    """``path`` (.npz): the NumPy array fields of the dataclass ``obj`` and ``extra``, uncompressed
    (deflating the float64 shapes of 16,384 rods took 3.8 s and saved 15%). Returns {key: [shape,
    dtype]}."""
    arrays = {f.name: v for f in fields(obj) if isinstance(v := getattr(obj, f.name), np.ndarray)} | extra
    write_npz(path, lambda f: np.savez(f, **arrays))
    return {k: [list(v.shape), str(v.dtype)] for k, v in arrays.items()}


def write_rod_table(path: Path, command: str, first: dict, arrays: dict) -> dict:
    """``path`` (Parquet, one row per rod; docs/outputs.md): the column ``row`` (0..B-1), the
    columns ``first`` (arrays of one axis, lists of strings), then ``arrays``, a (B, n) array as n
    columns ``key[i]``; its schema metadata ``tdcr_warp`` holds command, rows and those widths.
    Returns {"rows": B, "columns": {name: type}} (the file list of the JSON results)."""
    from tdcr_warp.io.store import table_columns, write_table

    B = len(next(iter(first.values())))
    rest, widths, _ = table_columns(arrays, B)
    columns = {"row": np.arange(B, dtype=np.int64)} | first | rest
    write_table(path, columns, {"command": command, "rows": B, "widths": widths})
    return {"rows": B, "columns": {k: "string" if isinstance(v, list) else str(v.dtype) for k, v in columns.items()}}


def output_folder(args, default: Path) -> Path:
    """--out, or else ``default``: out/NAME with NAME made from the scene file's name, which must
    be one harmless path component (not empty, '.' or '..', no separator, no control character:
    a scene named '...toml' would otherwise write into the working directory); an InputError
    asks for --out."""
    if args.out:
        return Path(args.out)
    name = default.name
    if default.parent != Path("out") or name in ("", ".", "..") or "\\" in name or not name.isprintable():
        raise InputError(f"{args.scene}: the scene file's name gives no safe default output folder "
                         f"(out/{name!r}); choose one with --out")
    return default


def _make_folder(out: Path) -> Path:
    """``out``, created where missing; an unusable one is an InputError naming --out."""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"--out {str(out)!r}: cannot create the output directory: {e.strerror or e}") from None
    return out


class OutputRun:
    """A command's run into its output folder, a context manager (docs/outputs.md, "Output
    safety"). ``names``: the command's output files, its ``complete`` completion files first
    (the main one, ``names[0]``, first of all). On entry the folder (output_folder) is created
    and locked for the run (tdcr_warp.io.files.FolderLock: a second run or sweep into it is
    refused), the staging folders a killed run left are removed, and so are the completion files
    an earlier run left. The command writes its files to ``run / name``, in a private staging
    folder inside the output folder; :meth:`commit` moves them in, the completion files last
    (``names[0]`` the very last), and removes the files of ``names`` that this run did not write,
    so the folder never holds two runs' files beside a completion file. Leaving without commit
    (an error, Ctrl-C) discards the staged files. ``str(run)`` is the output folder, printable."""

    def __init__(self, args, default: Path, names: tuple[str, ...], complete: int = 1):
        self.path, self.names, self.command = output_folder(args, default), names, args.command
        self.complete = names[:complete]
        self.stage: Path | None = None
        self._lock = None

    def __enter__(self) -> Self:
        self._lock = FolderLock(_make_folder(self.path), self.command).__enter__()
        try:
            for old in self.path.glob(STAGE + "*"):  # a killed run's: no live run holds it (we hold the lock)
                if old.is_dir() and not old.is_symlink():
                    shutil.rmtree(old)
                else:
                    old.unlink()
            for name in self.complete:
                (self.path / name).unlink(missing_ok=True)
            self.stage = Path(tempfile.mkdtemp(prefix=STAGE, dir=self.path))
        except BaseException:
            self._lock.__exit__()
            raise
        return self

    def __truediv__(self, name: str) -> Path:
        return self.stage / name

    def __str__(self) -> str:
        return printable(self.path)

    def commit(self) -> None:
        """Move the staged files into the output folder (the completion file last) and remove
        the command's files that this run did not write."""
        staged = sorted(p.name for p in self.stage.iterdir())
        unknown = set(staged) - set(self.names)
        if unknown or self.names[0] not in staged:
            raise RuntimeError(f"{self.command} staged {staged}: not its outputs {self.names}, completion file first")
        for name in set(self.names) - set(staged):
            (self.path / name).unlink(missing_ok=True)
        last = [n for n in reversed(self.complete) if n in staged]
        for name in [n for n in staged if n not in last] + last:
            os.replace(self.stage / name, self.path / name)
        self.stage.rmdir()
        self.stage = None

    def __exit__(self, *exc) -> None:
        try:
            if self.stage is not None:
                shutil.rmtree(self.stage, ignore_errors=True)
        finally:
            self._lock.__exit__()


def _strict(obj):
    """obj with every non-finite float as None (null): strict JSON has no NaN or Infinity."""
    if isinstance(obj, float):
        return obj if np.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _strict(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_strict(v) for v in obj]
    return obj


def write_json(path: Path, obj) -> None:
    """Strict JSON (a non-finite number is null), written atomically."""
    def write(tmp):
        with open(tmp, "w") as f:
            json.dump(_strict(obj), f, indent=1, allow_nan=False)
    write_atomic(path, write)


def csv_cell(value):
    """A CSV cell that a spreadsheet shows rather than runs: text beginning with = + - @, a tab
    or a carriage return gets a leading single quote (OWASP); numbers stay numbers."""
    return "'" + value if isinstance(value, str) and value.startswith(FORMULA_START) else value


class CsvWriter:
    """csv.writer over the open text file ``f`` whose every cell goes through csv_cell: the
    package's CSV writer (labels and file names copied from the input are neutralised)."""

    def __init__(self, f):
        self._w = csv.writer(f)

    def writerow(self, row) -> None:
        self._w.writerow([csv_cell(v) for v in row])


def settings(scene, device) -> dict:
    """The StaticOptions fields (``tol`` as the tolerance used, ``tolerance_m``), the device
    actually used, the tdcr-warp and Warp versions and the scene file's text (docs/outputs.md)."""
    import warp as wp

    from tdcr_warp import __version__
    out = asdict(scene.options)
    out.pop("tol", None)  # None means the precision's default: tolerance_m is the value used
    try:
        dev = str(wp.get_device(None if device in (None, "default") else device))
    except (RuntimeError, ValueError):
        dev = str(device)
    out.update(device=dev, tolerance_m=scene.options.tolerance, tdcr_warp=__version__, warp=wp.__version__,
               scene_text=scene.text)
    return out


def apply_overrides(scene, args, dynamic: bool = False):
    """The scene with the [solver] fields given on the command line (OVERRIDES) replaced, its
    model checked against the robot (and, with ``dynamic``, against time stepping)."""
    over = {k: getattr(args, k) for k in OVERRIDES if getattr(args, k) is not None}
    scene = replace(scene, options=replace(scene.options, **over)) if over else scene
    check_model_support(scene.robot, scene.options.model, dynamic)
    return scene


def overridden_source(scene, args) -> dict:
    """A copy of the scene's TOML table, its [solver] table the options used when the command
    line overrides any (OVERRIDES): the scene a sweep or search rebuilds per chunk."""
    data = dict(scene.source)
    if any(getattr(args, k) is not None for k in OVERRIDES):
        data["solver"] = {k: v for k, v in vars(scene.options).items() if v is not None}
    return data


def print_rods(tips, ok, iters, resid, reasons, limit: int = 10) -> None:
    """One line per rod (the first ``limit``): tip [m], iterations, residual [m], verdict."""
    for b in range(min(len(tips), limit)):
        t = tips[b]
        state = "ok" if ok[b] else f"FAILED ({reasons[b]})"
        print(f"  rod {b}: tip [{t[0]: .6f} {t[1]: .6f} {t[2]: .6f}] m  iterations {iters[b]:3d}  "
              f"residual {resid[b]:.1e} m  {state}")
    if len(tips) > limit:
        print(f"  ... {len(tips) - limit} more rods")


def load_kernels(scene, args, dynamic: bool = False) -> float:
    """Load (or compile, on first use) the scene's kernels before the timed run, so that its rate
    excludes them; a compile says so on stderr (tdcr_warp.core.solver.set_compile_notice)."""
    from tdcr_warp.core.solver import load_kernels

    return load_kernels(scene.robot, scene.options, args.device, dynamic=dynamic)


def number_type(least=None, integer: bool = False):
    """An argparse type: a number (an int with ``integer``) written as
    tdcr_warp.model.checks.is_number takes it (no underscores, spaces or non-ASCII digits, which
    Python's int() and float() accept), finite unless ``least`` is None, and >= ``least``."""
    def parse(text: str):
        value = (int(text) if integer else float(text)) if is_number(text, integer) else None
        if value is None or (least is not None and not (math.isfinite(value) and value >= least)):
            what = ("a positive integer" if integer and least == 1 else ("an integer" if integer else "a number")
                    + ("" if least is None else f" >= {least}"))
            raise argparse.ArgumentTypeError(f"must be {what}, got {text!r} (ASCII digits, no underscores)")
        return value
    return parse


positive_int = number_type(1, integer=True)  # the counts (--steps, --nodes, --max-iter, --budget): an integer >= 1


def add_command(subparsers, name: str, helptext: str, run) -> argparse.ArgumentParser:
    """The subcommand ``name`` with its scene argument; ``run(args) -> int`` carries it out."""
    p = subparsers.add_parser(name, help=helptext)
    p.set_defaults(run=run)
    p.add_argument("scene", help="scene file (TOML)")
    return p


def add_solver_arguments(p: argparse.ArgumentParser) -> None:
    """--out, --device and the [solver] overrides."""
    p.add_argument("--out", help="output directory (default: out/<scene name>)")
    p.add_argument("--device", default=None, help="cpu or cuda:0 (default: Warp's default device)")
    p.add_argument("--nodes", type=positive_int, help="override [solver].nodes")
    p.add_argument("--integrator", choices=list(INTEGRATORS), help="override [solver].integrator")
    p.add_argument("--model", choices=[*MODELS, "constant_curvature"], help="override [solver].model")
    p.add_argument("--precision", choices=["float64", "float32"], help="override [solver].precision")


def add_html_argument(p: argparse.ArgumentParser, animated: bool) -> None:
    """--html: robot.html, of the solved rods or (animated) of a run's stored shapes."""
    p.add_argument("--html", action="store_true",
                   help="write robot.html, an interactive 3D viewer (one file, opens offline): the first "
                        "10 rods" + (", animated from the shapes stored every [dynamics].shapes_every steps"
                                     if animated else ""))


def add_no_figures_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures (matplotlib costs ~0.7 s)")


def add_log_arguments(p: argparse.ArgumentParser) -> None:
    """--quiet and --verbose."""
    p.add_argument("--quiet", action="store_true", help="no progress bar, no compile notice")
    p.add_argument("-v", "--verbose", action="store_true",
                   help="also Warp's line per kernel module loaded or compiled, with its time")
