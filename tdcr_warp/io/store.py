"""Where a sweep's results live on disk, and the rules that keep them trustworthy.

An output folder holds one sweep:

    sweep.json              the manifest: fingerprint, job, rods, chunk size, state
    results/part-NNNNN.parquet   the per-rod table of chunk NNNNN (a Parquet dataset)
    arrays.zarr/            per-rod arrays of more than one axis (tip rotations, shapes,
                            Jacobians): one Zarr array each, (rows, ...), chunked like the sweep
                            (Zarr format 2 with xarray's dimension names, consolidated at the end)
    summary.json, *.png     the job's summary, written last
    .lock                   held (flock) by the one process writing the folder
                            (tdcr_warp.io.files.FolderLock; a link there is refused)

Every part carries in its Parquet metadata what identifies it: the sweep's fingerprint, the
chunk index, its row range and row count, and a SHA-256 of its columns and of its Zarr rows.
A part is read only through :meth:`ChunkStore.read`, which checks all of that, so a copied,
truncated, stale or foreign chunk is never merged. Parts are written to a temporary file and
renamed, after their Zarr rows: a part that exists is complete.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import shutil
from pathlib import Path

import numpy as np

from tdcr_warp.io.files import open_lock, write_atomic
from tdcr_warp.model.robot import InputError

__all__ = ["ChunkError", "ChunkStore", "check_no_links", "clear_outputs", "read_manifest", "table_columns", "write_manifest",
           "write_table"]

FORMAT = 1
MANIFEST = "sweep.json"
TABLE = "results"
ARRAYS = "arrays.zarr"
SUMMARY = "summary.json"
FIGURES = ("montecarlo.png", "workspace.png", "gain_grid.png")
LEGACY = ("manifest.json", "results.npz", "chunks")  # the npz layout of earlier versions
DIMS = {"positions": ("node", "xyz"), "tip_rotation": ("i", "j"), "tip_jacobian": ("pose", "command"),
        "tip_compliance": ("pose", "wrench")}


class ChunkError(InputError):
    """A chunk file that fails its checks (unreadable, foreign, incomplete or altered): bad
    input on disk, so the command line exits with status 2 naming the file."""


def read_manifest(out: Path) -> dict | None:
    """The manifest of the sweep in ``out``, {"legacy": True} for an output folder of the
    earlier npz layout, or None for a folder without a sweep."""
    path = out / MANIFEST
    if path.exists():
        try:
            return json.loads(path.read_text())
        except (OSError, ValueError) as e:
            raise InputError(f"{path}: unreadable sweep manifest ({e}); --overwrite replaces the sweep") from None
    if any((out / name).exists() for name in LEGACY) or (out / TABLE).exists():
        return {"legacy": True}
    return None


def write_manifest(out: Path, manifest: dict) -> None:
    write_atomic(out / MANIFEST, lambda tmp: Path(tmp).write_text(json.dumps(manifest, indent=1)))


def clear_outputs(out: Path, everything: bool) -> None:
    """Remove the summary and figures (nothing may look complete while a sweep runs); with
    ``everything`` also the manifest, the parts, the arrays and earlier layouts' files. Only
    names this module writes are touched."""
    names = [SUMMARY, *FIGURES] + ([MANIFEST, TABLE, ARRAYS, *LEGACY] if everything else [])
    for name in names:
        p = out / name
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        elif p.is_symlink() or p.exists():
            p.unlink()  # a link itself, never what it points to


def check_no_links(out: Path) -> None:
    """Neither the folders a sweep writes into (its parts, its arrays) nor anything in them is a
    symbolic link: Zarr and the parts would write through a linked folder, elsewhere. An
    InputError names the first link found."""
    for name in (TABLE, ARRAYS):
        top = out / name
        found = [top] if top.is_symlink() else (Path(d) / n for d, dirs, files in os.walk(top) for n in dirs + files)
        link = next((p for p in found if p.is_symlink()), None)
        if link is not None:
            raise InputError(f"{link} is a symbolic link: a sweep writes nothing through a link; remove it, or "
                             "--overwrite replaces the sweep")


@contextlib.contextmanager
def _file_lock(path: Path):
    with open_lock(path) as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def _digest(columns: dict[str, np.ndarray], arrays: dict[str, np.ndarray]) -> str:
    h = hashlib.sha256()
    for name in sorted(columns):
        h.update(name.encode())
        h.update(np.ascontiguousarray(columns[name]).tobytes())
    for name in sorted(arrays):
        h.update(name.encode())
        h.update(np.ascontiguousarray(arrays[name]).tobytes())
    return h.hexdigest()


def table_columns(res: dict, rows: int) -> tuple[dict[str, np.ndarray], dict[str, int], dict[str, np.ndarray]]:
    """A per-rod table's columns from ``res`` {key: array with ``rows`` rows}: an array of one
    axis is the column ``key``, of two axes one column per component (``key[i]``), of more a
    separate array. Returns (columns, {key: width} of the split ones, the other arrays); an
    array with another number of rows is a ValueError naming it."""
    columns: dict[str, np.ndarray] = {}
    widths, arrays = {}, {}
    for key, v in res.items():
        v = np.asarray(v)
        if v.shape[:1] != (rows,):
            raise ValueError(f"the job's {key!r} has {v.shape[:1]} rows, expected {rows}")
        if v.ndim == 1:
            columns[key] = v
        elif v.ndim == 2:
            widths[key] = v.shape[1]
            columns.update({f"{key}[{i}]": v[:, i] for i in range(v.shape[1])})
        else:
            arrays[key] = v
    return columns, widths, arrays


def _arrow(v):
    """A NumPy array of numbers or bools, or a list of strings (dictionary-encoded), as an Arrow
    array built from its buffers: pa.array would import pandas when it is installed (0.5-0.7 s)."""
    import pyarrow as pa

    if isinstance(v, list):
        words, index = np.unique(np.asarray(v, dtype=str), return_inverse=True)
        data = [w.encode() for w in words.tolist()]
        offsets = np.cumsum([0] + [len(d) for d in data], dtype=np.int32)
        dictionary = pa.Array.from_buffers(pa.string(), len(data), [None, pa.py_buffer(offsets),
                                                                     pa.py_buffer(b"".join(data))])
        return pa.DictionaryArray.from_arrays(_arrow(index.ravel().astype(np.int32)), dictionary)
    v = np.ascontiguousarray(v)
    if v.dtype == bool:
        return pa.Array.from_buffers(pa.bool_(), len(v), [None, pa.py_buffer(np.packbits(v, bitorder="little"))])
    return pa.Array.from_buffers(pa.from_numpy_dtype(v.dtype), len(v), [None, pa.py_buffer(v)])


def write_table(path: Path, columns: dict, meta: dict) -> None:
    """One Parquet file of ``columns`` (NumPy arrays of one axis, or lists of strings), with
    ``meta`` as JSON under the schema metadata key ``tdcr_warp``; written atomically
    (tdcr_warp.io.files.write_atomic)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.Table.from_arrays([_arrow(v) for v in columns.values()], names=list(columns))
    table = table.replace_schema_metadata({"tdcr_warp": json.dumps(meta)})
    # dictionary pages for the strings only: for numbers they cost 2.5x the time and save nothing
    strings = [k for k, v in columns.items() if isinstance(v, list)]
    write_atomic(path, lambda tmp: pq.write_table(table, tmp, use_dictionary=strings))


class ChunkStore:
    """The parts of one sweep in ``out``: writes (from the driver or a Ray worker) and checked
    reads. Picklable: a Ray task gets it and writes its own chunk."""

    def __init__(self, out, fingerprint: str, rows: int, chunk: int):
        self.out, self.fingerprint, self.rows, self.chunk = Path(out), fingerprint, rows, chunk
        self.n_chunks = (rows + chunk - 1) // chunk

    def bounds(self, c: int) -> tuple[int, int]:
        return c * self.chunk, min(self.rows, (c + 1) * self.chunk)

    def part(self, c: int) -> Path:
        return self.out / TABLE / f"part-{c:05d}.parquet"

    def exists(self, c: int) -> bool:
        return self.part(c).exists()

    def write(self, c: int, res: dict[str, np.ndarray], samples: dict[str, np.ndarray]) -> int:
        """Write chunk c: ``res`` the job's per-rod arrays, ``samples`` its sample rows. Arrays
        of one or two axes become columns (``key`` or ``key[i]``), the others Zarr rows.
        Returns the number of rods that failed (``ok`` false)."""
        lo, hi = self.bounds(c)
        try:
            columns, widths, arrays = table_columns(res, hi - lo)
        except ValueError as e:
            raise ChunkError(f"chunk {c}: {e}") from None
        columns = {"row": np.arange(lo, hi, dtype=np.int64)} | columns
        columns.update({f"sample:{k}": np.asarray(v, dtype=np.float64) for k, v in samples.items()})
        if arrays:
            self._write_arrays(lo, hi, arrays)
        meta = {"format": FORMAT, "fingerprint": self.fingerprint, "chunk": c, "lo": lo, "hi": hi, "rows": hi - lo,
                "widths": widths, "arrays": sorted(arrays), "sha256": _digest(columns, arrays)}
        path = self.part(c)
        path.parent.mkdir(exist_ok=True)
        write_table(path, columns, meta)
        return int((~np.asarray(res["ok"]).astype(bool)).sum()) if "ok" in res else 0

    def _write_arrays(self, lo: int, hi: int, arrays: dict[str, np.ndarray]) -> None:
        import zarr

        root = self.out / ARRAYS
        with _file_lock(self.out / ".arrays.lock"):  # Ray workers may create the arrays at once
            group = zarr.open_group(root, mode="a", zarr_format=2)
            targets = {}
            for key, v in arrays.items():
                if key in group:
                    targets[key] = group[key]
                else:
                    dims = DIMS.get(key, tuple(f"{key}_{i}" for i in range(1, v.ndim)))
                    targets[key] = group.create_array(key, shape=(self.rows,) + v.shape[1:], dtype=v.dtype,
                                                      chunks=(self.chunk,) + v.shape[1:],
                                                      attributes={"_ARRAY_DIMENSIONS": ["row", *dims]})
        for key, v in arrays.items():
            targets[key][lo:hi] = v

    def finish(self) -> None:
        """After the last chunk: consolidate the Zarr metadata (one read opens the arrays)."""
        if (self.out / ARRAYS).exists():
            import zarr
            zarr.consolidate_metadata(self.out / ARRAYS, zarr_format=2)

    def read(self, c: int, *, check_only: bool = False) -> dict[str, np.ndarray] | None:
        """Chunk c's results (``row``, the job's keys with 2-axis columns regrouped, Zarr rows,
        and the ``sample:`` columns), after every check; raises ChunkError naming the file and what is
        wrong. ``check_only``: return None once the checks pass."""
        import pyarrow.parquet as pq

        path, (lo, hi) = self.part(c), self.bounds(c)
        try:
            table = pq.read_table(path)
            meta = json.loads((table.schema.metadata or {})[b"tdcr_warp"])
        except KeyError:
            raise ChunkError(f"{path}: not a tdcr-warp chunk (no tdcr_warp metadata)") from None
        except Exception as e:  # noqa: BLE001 (pyarrow raises many kinds on a damaged file)
            raise ChunkError(f"{path}: unreadable ({type(e).__name__}: {e})") from None
        expect = {"format": FORMAT, "fingerprint": self.fingerprint, "chunk": c, "lo": lo, "hi": hi, "rows": hi - lo}
        for k, v in expect.items():
            if meta.get(k) != v:
                what = "from another sweep" if k == "fingerprint" else f"{k} {meta.get(k)!r}, expected {v!r}"
                raise ChunkError(f"{path}: {what}")
        if table.num_rows != hi - lo:
            raise ChunkError(f"{path}: {table.num_rows} rows, expected {hi - lo}")
        columns = {name: table.column(name).to_numpy() for name in table.column_names}
        if not np.array_equal(columns.get("row"), np.arange(lo, hi)):
            raise ChunkError(f"{path}: its rows are not {lo}..{hi - 1}")
        arrays = {}
        if meta["arrays"]:
            import zarr
            try:
                group = zarr.open_group(self.out / ARRAYS, mode="r")
                arrays = {k: np.asarray(group[k][lo:hi]) for k in meta["arrays"]}
            except Exception as e:  # noqa: BLE001
                raise ChunkError(f"{self.out / ARRAYS}: rows {lo}..{hi - 1} unreadable ({type(e).__name__}: {e})") \
                    from None
        if _digest(columns, arrays) != meta["sha256"]:
            raise ChunkError(f"{path}: checksum mismatch (the file or its rows in {ARRAYS} were altered)")
        if check_only:
            return None
        out = {}
        for name, v in columns.items():
            key = name.rsplit("[", 1)[0]
            if key in meta["widths"] and not name.startswith("sample:"):
                if key not in out:
                    out[key] = np.stack([columns[f"{key}[{i}]"] for i in range(meta["widths"][key])], axis=1)
            else:
                out[name] = v
        return out | arrays
