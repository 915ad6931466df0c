"""Measured robots: read keypoint CSVs, predict the measured tips, calibrate a scene on them.

A measurement CSV (e.g. the opencr-mujoco data of the Franka TDCRs) has one quasi-static
keypoint per row: ``timestamp`` [s], ``pattern_label``, one column per servo with the motor's
tendon displacement relative to the pretensioned zero [mm, positive = pull], and the measured
tip ``tip_x``, ``tip_y``, ``tip_z`` [mm]. The scene's ``[hardware]`` table says which column
drives which tendon (``servo_columns``, in tendon order; every tendon under displacement
control) and where the measured point is: the tip p(L) plus ``marker_offset`` plus
``base_offset`` (world frame, m; a marker above the tip, and the mocap frame's offset from the
clamp). Every row is one rod: a whole file is one batched solve.

``predict`` writes per row the predicted point and its error; ``metrics`` the Euclidean tip RMSE
without re-alignment (``rmse_mm``), after removing the mean offset (``rmse_aligned_mm``, the
convention of opencr-mujoco), median and 95th percentile. ``fit`` calibrates a lab's
parameters by Levenberg-Marquardt on batched solves (``FIT_PARAMETERS``).
"""

from __future__ import annotations

import copy
import csv
import io
import math
import re
import time
from array import array
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tdcr_warp.io.inputs import TABLE_LIMIT, read_limited
from tdcr_warp.io.scene import Scene, scene_from_dict
from tdcr_warp.model.robot import InputError
from tdcr_warp.physics.statics import StaticSolution, reference_lengths, solve_static

__all__ = ["FIT_PARAMETERS", "Measurements", "fit", "metrics", "pattern_folds", "predict", "predict_in_chunks",
           "predict_recorded", "read_measurements", "unidentifiable"]

GRID_ANGLES, GRID_ROWS = 12, 120  # the fit's start: a whole-robot rotation tried every 30 degrees on ~120 rows
FIT_RTOL = 3e-5  # Levenberg-Marquardt stops when an accepted step lowers the cost by less than this
LM_LAMBDA0 = 1.0  # its first damping (times the diagonal of J^T J): the nominal scene is far from the fit
REFERENCE_TOL = 1e-12  # the reference solves of the fit's Jacobian: their lengths differ by ~1e-7 m a step
COARSE_EVERY, COARSE_RTOL = 8, 1e-2  # the fit's first phase: every 8th row, until the cost falls by < 1%
MAX_SERVO_MM = 100.0  # a displacement beyond this is not a tendon's (the rods are ~0.2 m long)
MAX_TIP_MM = 1e4  # a measured point beyond 10 m of the mocap origin is a corrupt cell, not a tip
TIP_COLUMNS = ("tip_x", "tip_y", "tip_z")
RANK_RTOL = 1e-6  # a direction of the fit's scaled Jacobian this much weaker than the strongest: not identified
NULL_SHARE = 0.1  # a parameter with more of its unit vector than this in those directions: flagged by name
MAX_FIT_ROWS = 50_000  # the fit holds every row's solutions at once: ~76 kB a row at 15 nodes (v4), ~4 GB here


@dataclass(frozen=True)
class Measurements:
    """Rows of one or more CSV files: labels (M,), servo_mm (M, K) in the scene's tendon order,
    tip_mm (M, 3), source (M,) the file of each row."""

    labels: np.ndarray
    servo_mm: np.ndarray
    tip_mm: np.ndarray
    source: np.ndarray

    def __len__(self) -> int:
        return len(self.labels)

    def subset(self, rows: np.ndarray) -> "Measurements":
        return Measurements(self.labels[rows], self.servo_mm[rows], self.tip_mm[rows], self.source[rows])


def read_measurements(paths, servo_columns: list[str]) -> Measurements:
    """Read keypoint CSVs row by row (no list of every cell is held); an InputError names the file,
    and the row and column of anything missing, non-numeric, non-finite or out of range (|servo| >
    MAX_SERVO_MM, |tip| > MAX_TIP_MM), a duplicated column name and an empty file."""
    labels, source = [], []
    servo, tips = array("d"), array("d")
    for path in [paths] if isinstance(paths, (str, Path)) else paths:
        path, before = Path(path), len(labels)
        name = str(path)
        rows = csv.reader(io.StringIO(_read_text(path), newline=""))
        try:
            header = [h.strip() for h in next(rows, [])]
            need = ["pattern_label", *servo_columns, *TIP_COLUMNS]
            idx = _column_index(path, header, need)
            for n, r in enumerate(rows, start=2):
                if not any(cell.strip() for cell in r):
                    continue
                if len(r) < len(header):
                    raise InputError(f"{path}, row {n}: {len(r)} cells, the header has {len(header)}")
                labels.append(r[idx[0]].strip())
                source.append(name)
                vals = [_cell(path, n, c, r[i]) for c, i in zip(need[1:], idx[1:])]
                servo.extend(vals[:len(servo_columns)])
                tips.extend(vals[len(servo_columns):])
        except csv.Error as e:
            raise InputError(f"{path}: not a CSV ({e})") from None
        if len(labels) == before:
            raise InputError(f"{path}: no keypoint rows after the header")
    return Measurements(np.array(labels), np.frombuffer(servo).reshape(len(labels), len(servo_columns)),
                        np.frombuffer(tips).reshape(len(labels), 3), np.array(source, dtype=object))


def _read_text(path: Path) -> str:
    """The text of a keypoint CSV; an InputError if it cannot be read, is not a regular file of at
    most TABLE_LIMIT bytes (tdcr_warp/io/inputs.py), is not UTF-8, has a NUL byte."""
    try:
        text = read_limited(path, TABLE_LIMIT, f"{path}: cannot read it").decode("utf-8")
    except UnicodeDecodeError as e:
        raise InputError(f"{path}: not a UTF-8 text file (byte 0x{e.object[e.start]:02x} at offset {e.start}); "
                         "expected a CSV of keypoints") from None
    if "\x00" in text:
        raise InputError(f"{path}: not a text file (NUL byte at offset {text.index(chr(0))}); "
                         "expected a CSV of keypoints")
    if not text.strip():
        raise InputError(f"{path}: empty file (expected a header and keypoint rows)")
    return text


def _column_index(path: Path, header: list[str], need: list[str]) -> list[int]:
    """The position of every needed column in the header; an InputError names a missing or a
    duplicated one (which copy would be meant is unknowable)."""
    twice = sorted({h for h in header if h and header.count(h) > 1})
    if twice:
        raise InputError(f"{path}: column(s) {twice} appear more than once in the header")
    missing = [c for c in need if c not in header]
    if missing:
        raise InputError(f"{path}: missing column(s) {missing} (the header has {header})")
    return [header.index(c) for c in need]


def _cell(path: Path, row: int, column: str, text: str) -> float:
    """One numeric cell [mm]: a finite number within MAX_SERVO_MM (servo columns) or MAX_TIP_MM (tips)."""
    cell = text.strip()
    try:
        v = float(cell)
    except ValueError:
        raise InputError(f"{path}, row {row}, column {column}: not a number: {cell!r}") from None
    if not math.isfinite(v):
        raise InputError(f"{path}, row {row}, column {column}: not finite: {cell!r}")
    limit = MAX_TIP_MM if column in TIP_COLUMNS else MAX_SERVO_MM
    if abs(v) > limit:
        raise InputError(f"{path}, row {row}, column {column}: {v!r} mm is beyond +-{limit:g} mm")
    return v


def pattern_folds(labels: np.ndarray, k: int) -> np.ndarray:
    """(M,) the fold (0 .. k-1) of every row for a cross-validation that cannot leak: whole recorded
    patterns (a label and its ``_hold`` rows, which repeat the pattern's last pose), in blocks of
    consecutive patterns in recording order (neighbouring patterns, such as one bending direction and
    the next, share a fold), the blocks of about equal rows."""
    pattern = np.array([str(v).removesuffix("_hold") for v in labels])
    names, first, inverse = np.unique(pattern, return_index=True, return_inverse=True)
    order = np.argsort(first)  # the patterns in recording order
    rank = np.empty(len(names), dtype=int)
    rank[order] = np.arange(len(names))
    rows = np.bincount(rank[inverse], minlength=len(names))  # rows of each pattern, in recording order
    if k < 2 or k > len(names):
        raise InputError(f"folds: need 2 <= k <= {len(names)} (the recorded patterns), got {k}")
    start = np.cumsum(rows) - rows  # rows before each pattern
    fold_of_rank = np.minimum(start * k // len(labels), k - 1)
    return fold_of_rank[rank[inverse]]


FAMILIES = {"seg": "segment", "pair": "pair", "tendon": "pull"}  # a label's first word (after rep<n>_) -> family
# Validation by kind of motion (family_out_splits): the fit sees only the other families, simpler
# motions than those it predicts, as a user's new commands are.
HELD_FAMILIES = {"pairs out": "pair", "pulls out": "pull"}


def motion_families(labels: np.ndarray) -> np.ndarray:
    """(M,) each row's kind of motion from its recorded label: "segment" (one segment bent, in a
    direction or around a circle: seg<s>_...), "pair" (two segments bent together: pair<ij>_...),
    "pull" (a single tendon pulled: tendon<k>_..._pull); any other label is "other"."""
    words = [re.sub(r"^rep\d+_", "", str(v)) for v in labels]
    return np.array([next((f for w, f in FAMILIES.items() if re.match(w + r"\d", v)), "other") for v in words])


def family_out_splits(labels: np.ndarray) -> dict[str, np.ndarray]:
    """Validation that mimics use: for each HELD_FAMILIES entry with rows on both sides, a (M,)
    bool mask of the rows held out (that family); the fit sees every other row."""
    fam = motion_families(labels)
    out = {name: fam == f for name, f in HELD_FAMILIES.items()}
    return {name: m for name, m in out.items() if m.any() and not m.all()}


def _hardware(scene: Scene) -> dict:
    if scene.hardware is None:
        raise InputError("this needs a [hardware] table (servo_columns, marker_offset, base_offset)")
    bad = [k for k, t in enumerate(scene.robot.tendons) if t.control != "displacement"]
    if bad:
        raise InputError(f"[hardware]: tendon(s) {bad} are not under displacement control (the servos set lengths)")
    return scene.hardware


RETRY_ROUNDS = 4
PROGRESS_ROWS = 200
PREDICT_CHUNK = 2048  # rows a batched solve of predict_in_chunks (its solution: ~6 kB a row at 15 nodes)


def predict(scene: Scene, meas: Measurements, device=None, initial=None, before=None, **overrides) -> dict:
    """One batched solve of every row, then (up to RETRY_ROUNDS batched solves of the rows that
    did not converge) each such row again from the solution of the row before it in the same
    file, the way the robot was recorded: every keypoint settled from the last (``before``: the
    one-row solution of the row before the first, in the same file, e.g. the last of the previous
    chunk); with a warm start (``initial``: a solution of as many rows), what is still unconverged
    once more from the straight rod. Returns
    ``point_mm`` (M, 3) the predicted measured point, ``error_mm`` (M, 3) predicted less
    measured, ``converged`` (M,), ``unstable`` (M,) bool (converged to an equilibrium the stability
    verdict found unstable: not a trustworthy prediction), ``slack`` (M, K), ``retried`` (M,) bool, the
    ``solution`` and the solve time ``wall_s``."""
    hw = _hardware(scene)
    t0 = time.perf_counter()
    q = meas.servo_mm * 1e-3
    tau = np.zeros((len(meas), scene.robot.n_tendons))
    sol = solve_static(scene.robot, tau, displacements=q, options=scene.options, device=device, initial=initial,
                       **overrides)
    retried = np.zeros(len(meas), dtype=bool)
    prev = np.r_[-1, np.arange(len(meas) - 1)]
    prev[1:][meas.source[1:] != meas.source[:-1]] = -1
    if before is not None:
        prev[0] = len(meas)  # ``before``, appended to the rows a retry can start from
    for _ in range(RETRY_ROUNDS):
        known = sol if before is None else StaticSolution.joined([sol, before])
        rows = np.flatnonzero(~sol.converged & (prev >= 0))
        rows = rows[known.converged[prev[rows]]]
        if not len(rows):
            break
        part = solve_static(scene.robot, tau[rows], displacements=q[rows], options=scene.options, device=device,
                            initial=known.rows(prev[rows]), **overrides)
        retried[rows] = True
        if not part.converged.any():
            break
        sol = sol.replaced(rows[part.converged], part.rows(part.converged))
    rows = np.flatnonzero(~sol.converged)
    if initial is not None and len(rows):  # what a warm start lost, solved again from the straight rod
        part = solve_static(scene.robot, tau[rows], displacements=q[rows], options=scene.options, device=device,
                            **overrides)
        retried[rows] = True
        sol = sol.replaced(rows[part.converged], part.rows(part.converged))
    return _predicted(hw, meas, sol, retried, time.perf_counter() - t0)


def marker(hw: dict, sol) -> np.ndarray:
    """(B, 3) [m] the marker's offset from each tip in the world frame: ``marker_offset`` as given
    (marker_frame "world") or turned with the tip (marker_frame "tip")."""
    m = np.array(hw.get("marker_offset", [0.0, 0.0, 0.0]), dtype=float)
    if hw.get("marker_frame", "world") == "tip":
        return np.einsum("bij,j->bi", sol.tip_rotation, m)
    return np.broadcast_to(m, sol.tip_position.shape)


def _predicted(hw: dict, meas: Measurements, sol, retried: np.ndarray, wall: float) -> dict:
    point = 1e3 * (sol.tip_position + marker(hw, sol) + np.array(hw.get("base_offset", [0, 0, 0])))
    return {"point_mm": point, "error_mm": point - meas.tip_mm, "converged": sol.converged,
            "unstable": sol.converged & ~sol.success, "slack": sol.slack, "retried": retried, "solution": sol,
            "wall_s": wall}


def predict_recorded(scene: Scene, meas: Measurements, device=None, progress=None, **overrides) -> dict:
    """The rows solved one by one in the order they were recorded, each as a quasi-static step from
    the row before it in the same file (solve_static ``history``): with friction, each tendon keeps
    the tension profile friction holds (stick) and slips where it cannot, the slip directions from
    each motor's motion since the last row, so a pull and a release to the same displacement can
    end in different shapes (hysteresis). A row whose step does not converge is solved again without
    the memory (``retried``), and the next row starts from it. Without friction the rows are what
    ``predict`` gives (to Newton's tolerance), at one solve per row. ``progress(done, failed)`` (rows)
    every PROGRESS_ROWS rows; of each block of PROGRESS_ROWS only the per-row results are kept (bounded
    memory). Returns what ``predict_in_chunks`` does."""
    hw = _hardware(scene)
    t0 = time.perf_counter()
    q = meas.servo_mm * 1e-3
    tau = np.zeros((1, scene.robot.n_tendons))
    sols, parts, retried, prev, failed = [], [], np.zeros(len(meas), dtype=bool), None, 0
    for i in range(len(meas)):
        if i and meas.source[i] != meas.source[i - 1]:
            prev = None
        sol = solve_static(scene.robot, tau, displacements=q[i:i + 1], options=scene.options, device=device,
                           history=prev, **overrides)
        if not sol.converged[0] and prev is not None:
            retried[i] = True
            sol = solve_static(scene.robot, tau, displacements=q[i:i + 1], options=scene.options, device=device,
                               **overrides)
        prev = sol if sol.converged[0] else None
        failed += int(not sol.converged[0])
        sols.append(sol)
        if len(sols) == PROGRESS_ROWS or i == len(meas) - 1:
            rows = np.arange(i + 1 - len(sols), i + 1)
            parts.append(_predicted(hw, meas.subset(rows), StaticSolution.joined(sols), retried[rows], 0.0))
            sols = []
            if progress:
                progress(i + 1, failed)
    return _joined(parts, time.perf_counter() - t0)


def predict_in_chunks(scene: Scene, meas: Measurements, device=None, chunk: int = PREDICT_CHUNK, progress=None,
                      **overrides) -> dict:
    """``predict`` on consecutive chunks of ``chunk`` rows, keeping of each only the per-row
    results: the memory is one chunk's solve plus the measurements and results (~0.2 kB a row),
    however many rows. A row that does not converge is retried from the row before it as in ``predict``,
    across a chunk's start too (that row's solution is carried over), so the rows are the one
    batch's (but for a chain of more than RETRY_ROUNDS failed rows across a chunk's start).
    ``progress(done, failed)`` after every chunk (rows). Returns what ``predict`` does but
    ``solution``."""
    parts, failed, last = [], 0, None
    for a in range(0, len(meas), chunk):
        before = last if a and meas.source[a] == meas.source[a - 1] else None
        part = predict(scene, meas.subset(np.arange(a, min(a + chunk, len(meas)))), device=device, before=before,
                       **overrides)
        last = part.pop("solution").rows([-1])
        parts.append(part)
        failed += int((~part["converged"]).sum())
        if progress:
            progress(min(a + chunk, len(meas)), failed)
    return _joined(parts, sum(p["wall_s"] for p in parts))


def _joined(parts: list[dict], wall: float) -> dict:
    """The per-row results of consecutive parts (``_predicted``, their ``solution`` dropped) as one."""
    rows = ("point_mm", "error_mm", "converged", "unstable", "slack", "retried")
    return {k: None if parts[0][k] is None else np.concatenate([p[k] for p in parts]) for k in rows} | {"wall_s": wall}


def metrics(error_mm: np.ndarray, converged: np.ndarray, length_m: float) -> dict:
    """Tip errors [mm] over the converged rows: RMSE as is and after removing the mean offset,
    median and 95th percentile, and the RMSE in % of the robot's length."""
    e = error_mm[converged]
    d = np.linalg.norm(e, axis=1)
    da = np.linalg.norm(e - e.mean(axis=0), axis=1) if len(e) else d
    rmse = float(np.sqrt(np.mean(d**2))) if len(d) else float("nan")
    return {"rows": int(len(error_mm)), "converged": int(converged.sum()), "rmse_mm": rmse,
            "rmse_aligned_mm": float(np.sqrt(np.mean(da**2))) if len(d) else float("nan"),
            "median_mm": float(np.median(d)) if len(d) else float("nan"),
            "p95_mm": float(np.percentile(d, 95)) if len(d) else float("nan"),
            "mean_offset_mm": e.mean(axis=0).tolist() if len(e) else None,
            "rmse_percent_of_length": 100 * rmse / (1e3 * length_m)}


# The parameters ``fit`` calibrates (``_parameter_spec``): compliance (log-scaled, positive);
# pretension[s] (>= 0) per segment (the tendons of one termination length); angle[j], a
# rotation about the backbone [rad] of segment j's tendons (detail "tendon": of tendon j, and a
# compliance per segment); base_offset[i] [m]. The Young's modulus stays as measured: the
# statics of a displacement-controlled rod do not change when every stiffness and force scales
# by the same factor (E, 1 / compliance, pretension), so tip data alone cannot fix all three.
FIT_PARAMETERS = ("compliance", "pretension", "angle", "base_offset")
# More physics, each fitted on request (``fit(physics=...)``): "weight", the robot's weight per
# length as gravity[0..2] on the scene's (known) density: its direction is the robot's mounting,
# its size fixes the scale the tip data cannot (weight_report: the Young's modulus it implies for
# g = 9.81); "hole_radius[s]", the distance of segment s's tendons from the backbone [m].
# "marker": the marker's offset carried by the tip (marker_frame "tip", its body-frame offset
# fitted) instead of fixed in the world.
PHYSICS = ("weight", "hole_radius", "marker")


def _segments(data: dict) -> list[list[int]]:
    """Tendon indices grouped by termination length (a segment), base to tip."""
    L = data["robot"]["length"]
    lengths = [t.get("length", L) for t in data["tendons"]]
    return [[k for k, v in enumerate(lengths) if v == u] for u in sorted(set(lengths))]


DETAILS = ("segment", "tendon")


def _parameter_spec(data: dict, detail: str, physics=()) -> list[dict]:
    """The fitted parameters: name, kind, the tendons (or axis) each acts on, start value,
    bounds and the difference step of its reference lengths (_reference_rates). detail "segment":
    one compliance, a pretension and a rotation per segment; "tendon": a compliance and a
    pretension per segment and a rotation per tendon; then the ``physics`` asked for (PHYSICS)."""
    if detail not in DETAILS:
        raise InputError(f"fit detail must be one of {DETAILS}, got {detail!r}")
    unknown = [v for v in physics if v not in PHYSICS]
    if unknown:
        raise InputError(f"fit physics: {unknown} not among {PHYSICS}")
    segs = _segments(data)
    t = data["tendons"]
    everyone = [k for g in segs for k in g]
    spec = []
    for s, g in enumerate(segs if detail == "tendon" else [everyone]):
        spec.append({"name": "compliance" if detail == "segment" else f"compliance[{s}]", "kind": "compliance",
                     "on": g, "value": math.log(np.mean([t[k]["compliance"] for k in g])),
                     "lo": math.log(1e-7), "hi": math.log(1e-1), "step": 1e-3})
    for s, g in enumerate(segs):
        spec.append({"name": f"pretension[{s}]", "kind": "pretension", "on": g,
                     "value": float(np.mean([t[k]["pretension"] for k in g])), "lo": 0.0, "hi": 50.0, "step": 1e-2})
    for a, g in enumerate([[k] for k in everyone] if detail == "tendon" else segs):
        spec.append({"name": f"angle[{a}]", "kind": "angle", "on": g, "value": 0.0, "lo": -0.6, "hi": 0.6,
                     "step": 1e-4})
    for i in range(3):
        spec.append({"name": f"base_offset[{i}]", "kind": "offset", "on": i,
                     "value": float(data["hardware"].get("base_offset", [0.0, 0.0, 0.0])[i]), "lo": -0.05,
                     "hi": 0.05, "step": 0.0})
    return spec + _physics_spec(data, segs, physics)


def _physics_spec(data: dict, segs: list[list[int]], physics) -> list[dict]:
    """The PHYSICS parameters asked for: "weight" needs the scene's density (> 0)."""
    spec = []
    if "weight" in physics:
        if not data["robot"].get("density", 0.0) > 0:
            raise InputError("fit physics \"weight\" needs [robot] density > 0 (the backbone's and its disks' mass "
                             "per volume of the backbone): the weight's size is fitted as gravity against it")
        g = data.get("loads", {}).get("gravity", [0.0, 0.0, 0.0])
        spec += [{"name": f"gravity[{i}]", "kind": "gravity", "on": i, "value": float(g[i]), "lo": -100.0,
                  "hi": 100.0, "step": 1e-2} for i in range(3)]
    if "marker" in physics:
        m = data["hardware"].get("marker_offset", [0.0, 0.0, 0.0])
        spec += [{"name": f"marker_offset[{i}]", "kind": "marker", "on": i, "value": float(m[i]), "lo": -0.1,
                  "hi": 0.1, "step": 0.0} for i in range(3)]
    if "hole_radius" in physics:
        t = data["tendons"]
        spec += [{"name": f"hole_radius[{s}]", "kind": "radius", "on": g,
                  "value": float(np.mean([np.hypot(*t[k]["offset"]) for k in g])), "lo": 1e-4, "hi": 0.1,
                  "step": 1e-6} for s, g in enumerate(segs)]
    return spec


def _apply(data0: dict, spec: list[dict], p: np.ndarray) -> dict:
    """The scene dict with parameter vector p (angles relative to data0's tendon offsets)."""
    data = copy.deepcopy(data0)
    t = data["tendons"]
    for sp, v in zip(spec, p):
        if sp["kind"] == "compliance":
            for k in sp["on"]:
                t[k]["compliance"] = float(math.exp(v))
        elif sp["kind"] == "pretension":
            for k in sp["on"]:
                t[k]["pretension"] = float(max(v, 0.0))
        elif sp["kind"] == "angle":
            c, sn = math.cos(v), math.sin(v)
            for k in sp["on"]:
                x, y = t[k]["offset"]
                t[k]["offset"] = [c * x - sn * y, sn * x + c * y]
        elif sp["kind"] == "gravity":
            loads = data.setdefault("loads", {})
            loads["gravity"] = list(loads.get("gravity", [0.0, 0.0, 0.0]))
            loads["gravity"][sp["on"]] = float(v)
        elif sp["kind"] == "marker":
            data["hardware"]["marker_frame"] = "tip"
            data["hardware"]["marker_offset"] = list(data["hardware"].get("marker_offset", [0.0, 0.0, 0.0]))
            data["hardware"]["marker_offset"][sp["on"]] = float(v)
        elif sp["kind"] == "radius":
            for k in sp["on"]:
                x, y = t[k]["offset"]
                t[k]["offset"] = [v * x / math.hypot(x, y), v * y / math.hypot(x, y)]
        else:
            data["hardware"].setdefault("base_offset", [0.0, 0.0, 0.0])
            data["hardware"]["base_offset"] = list(data["hardware"]["base_offset"])
            data["hardware"]["base_offset"][sp["on"]] = float(v)
    return data


def _grid_angle(data: dict, spec: list[dict], p: np.ndarray, angles: np.ndarray, meas: Measurements,
                device) -> tuple[float, float]:
    """(aligned RMSE [mm], angle [rad]) of the best of GRID_ANGLES whole-robot rotations of the
    tendons (the parameters ``angles`` of ``p`` set to it) on about GRID_ROWS of the rows: the
    tendons' angular position as a whole is searched on a grid first, as an angle can be off by
    a half turn, far outside the basin of Gauss-Newton (opencr-mujoco's v6 description is)."""
    probe = meas.subset(np.arange(0, len(meas), max(1, len(meas) // GRID_ROWS)))
    best = None
    for a in np.arange(GRID_ANGLES) * 2 * math.pi / GRID_ANGLES:
        q = np.where(angles, a, p)
        out = predict(scene_from_dict(_apply(data, spec, q)), probe, device=device)
        e = metrics(out["error_mm"], out["converged"], 1.0)["rmse_aligned_mm"]
        if out["converged"].mean() > 0.5 and (best is None or e < best[0]):
            best = (e, a)
    if best is None:
        raise InputError("fit: the start converges on fewer than half of the rows at every angle tried")
    return best


def _jacobian_names(data: dict, spec: list[dict]) -> list[str]:
    """The robot parameters whose tip Jacobians (solve_static ``parameters``) the fit's columns are
    made of: every tendon's compliance and angle (a pretension moves only the reference state),
    and with the PHYSICS the gravity's components and the tendons' offsets."""
    K = range(len(data["tendons"]))
    kinds = {sp["kind"] for sp in spec}
    return ([f"tendons[{k}].{f}" for f in ("compliance", "angle") for k in K]
            + ([f"gravity[{i}]" for i in range(3)] if "gravity" in kinds else [])
            + ([f"tendons[{k}].offset[{c}]" for k in K for c in range(2)] if "radius" in kinds else []))


def _reference_rates(data: dict, spec: list[dict], p: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(K, P) d (reference length of each tendon) / d parameter: central differences (one-sided at
    a bound) of the one-rod reference solve of the scene at p (statics.reference_lengths); zero
    for the base offset."""
    K = len(data["tendons"])
    out = np.zeros((K, len(p)))
    for j, sp in enumerate(spec):
        if sp["kind"] == "offset":
            continue
        up, down = p.copy(), p.copy()
        up[j], down[j] = min(p[j] + sp["step"], hi[j]), max(p[j] - sp["step"], lo[j])
        scenes = [scene_from_dict(_apply(data, spec, q)) for q in (up, down)]
        ref = [reference_lengths(sc.robot, options=sc.options, tol=REFERENCE_TOL)[0] for sc in scenes]
        out[:, j] = (ref[0] - ref[1]) / (up[j] - down[j])
    return out


def _fit_jacobian(data: dict, spec: list[dict], p: np.ndarray, cur: dict, rows: np.ndarray, lo: np.ndarray,
                  hi: np.ndarray) -> np.ndarray:
    """(3 rows, P) d (predicted - measured point) [m] / d parameter over ``rows`` of the solution
    ``cur`` (solved with the ``_jacobian_names`` parameters), by the implicit-function theorem: a
    parameter moves the tip at the motors' given lengths (``parameter_jacobian``) and through the
    reference state, which sets those lengths (avail = reference - q: minus ``tip_jacobian`` times
    ``_reference_rates``); a marker carried by the tip moves with its rotation too (_point_rates);
    the base offset's columns are the identity, the marker's the tip's axes. No solve is repeated."""
    sol = cur["solution"]
    names = _jacobian_names(data, spec)
    now = _apply(data, spec, p)
    tendons = now["tendons"]
    arm = marker(now["hardware"], sol)[rows] * (now["hardware"].get("marker_frame", "world") == "tip")
    PJ, TJ = _point_rates(sol.parameter_jacobian[rows], arm), _point_rates(sol.tip_jacobian[rows], arm)
    J = np.zeros((len(rows), 3, len(p)))
    J -= np.einsum("bik,kj->bij", TJ, _reference_rates(data, spec, p, lo, hi))
    for j, sp in enumerate(spec):
        if sp["kind"] == "compliance":  # log-scaled: d/dv = compliance d/dc
            J[:, :, j] += math.exp(p[j]) * sum(PJ[:, :, names.index(f"tendons[{k}].compliance")] for k in sp["on"])
        elif sp["kind"] == "angle":
            J[:, :, j] += sum(PJ[:, :, names.index(f"tendons[{k}].angle")] for k in sp["on"])
        elif sp["kind"] == "gravity":
            J[:, :, j] += PJ[:, :, names.index(f"gravity[{sp['on']}]")]
        elif sp["kind"] == "radius":  # along each tendon's unit offset
            for k in sp["on"]:
                u = np.array(tendons[k]["offset"]) / np.hypot(*tendons[k]["offset"])
                J[:, :, j] += sum(u[c] * PJ[:, :, names.index(f"tendons[{k}].offset[{c}]")] for c in range(2))
        elif sp["kind"] == "offset":
            J[:, sp["on"], j] = 1.0
        elif sp["kind"] == "marker":  # the body-frame offset's column of the tip's rotation
            J[:, :, j] = sol.tip_rotation[rows][:, :, sp["on"]]
    return J.reshape(3 * len(rows), len(p))


def _point_rates(pose_rates: np.ndarray, arm: np.ndarray) -> np.ndarray:
    """(M, 3, P) the rates of the measured point from those of the tip's pose (M, 6, P) (position,
    then the world rotation vector): a marker at ``arm`` (M, 3) [m] from the tip, carried by it,
    moves by d theta x arm besides (zero arm: fixed in the world)."""
    return pose_rates[:, :3] - np.einsum("bij,bjp->bip", _skew(arm), pose_rates[:, 3:6])


def _skew(a: np.ndarray) -> np.ndarray:
    """(M, 3, 3) the cross-product matrices of (M, 3) vectors."""
    z = np.zeros(len(a))
    return np.stack([np.stack([z, -a[:, 2], a[:, 1]], -1), np.stack([a[:, 2], z, -a[:, 0]], -1),
                     np.stack([-a[:, 1], a[:, 0], z], -1)], axis=1)


def fit(data: dict, meas: Measurements, *, detail: str = "tendon", physics=(), max_iter: int = 30, device=None,
        progress=None) -> dict:
    """Calibrate the scene dict ``data`` (with [hardware]) on ``meas`` by Levenberg-Marquardt
    (``_levenberg_marquardt``): the residual is every row's predicted less measured point [m]; its
    Jacobian comes with each batched solve (``_fit_jacobian``: implicit-function theorem, no solve
    repeated), and each trial solve starts warm from the last accepted one. From the grid's start
    it runs first on every COARSE_EVERY-th row, then on all rows from there. Rows that do not
    converge are left out of that evaluation. Fewer coordinates (3 a row) than parameters + 1, or
    more than MAX_FIT_ROWS rows, are an InputError. Returns the fitted scene dict, the parameters
    with their standard deviations (sigma^2 (J^T J)^-1 at the fitted parameters, sigma^2 the
    residual variance per coordinate; ``_standard_deviations``), the names of those the data cannot
    determine (``unidentifiable``: their std NaN), the training metrics, iterations and time."""
    t0 = time.perf_counter()
    spec = _parameter_spec(data, detail, physics)
    if 3 * len(meas) <= len(spec):
        raise InputError(f"fit: {len(meas)} rows ({3 * len(meas)} coordinates) cannot determine the {len(spec)} "
                         f"parameters of detail {detail!r} and their uncertainty; need at least "
                         f"{len(spec) // 3 + 1} rows")
    if len(meas) > MAX_FIT_ROWS:
        raise InputError(f"fit: {len(meas)} rows, more than the {MAX_FIT_ROWS} it holds in memory at once (every "
                         "row's solution, trial and Jacobian); fit on a subset (e.g. every n-th row)")
    names = [sp["name"] for sp in spec]
    p = np.array([sp["value"] for sp in spec])
    lo, hi = (np.array([sp[k] for sp in spec]) for k in ("lo", "hi"))
    angles = np.array([sp["kind"] == "angle" for sp in spec])
    base_data = copy.deepcopy(data)
    best = _grid_angle(base_data, spec, p, angles, meas, device)
    base_data = _apply(base_data, spec, np.where(angles, best[1], p))
    p = np.where(angles, 0.0, p)  # the rotations are now relative to the grid's
    history = [{"grid_angle_rad": float(best[1]), "grid_rmse_aligned_mm": float(best[0])}]
    its, cur = 0, None
    general = {"specialize": False} if "weight" in physics else {}
    for part in (meas.subset(np.arange(0, len(meas), COARSE_EVERY)), meas):
        # all rows start from the coarse phase's solution of the row at or before them (a neighbour
        # in the recording)
        warm = None if cur is None else cur["solution"].rows(np.arange(len(meas)) // COARSE_EVERY)

        def evaluate(q, warm=None, part=part):  # a weight fitted from zero: kernels with gravity compiled in
            out = predict(scene_from_dict(_apply(base_data, spec, q)), part, device=device, initial=warm,
                          parameters=_jacobian_names(base_data, spec), **general)
            ok = out["converged"] & np.isfinite(out["solution"].parameter_jacobian).all(axis=(1, 2))
            out["rows"] = np.flatnonzero(ok)
            return out

        p, cur, n = _levenberg_marquardt(evaluate, lambda q, out: _fit_jacobian(base_data, spec, q, out, out["rows"],
                                                                                lo, hi),
                                         p, warm, lo, hi, max_iter - its, history, progress,
                                         COARSE_RTOL if part is not meas else FIT_RTOL)
        its += n
    J, r = cur["jacobian"], cur["error_mm"][cur["rows"]].ravel() * 1e-3
    lost = unidentifiable(J)
    std = _standard_deviations(J, r, lost)
    fitted = _apply(base_data, spec, p)
    L = fitted["robot"]["length"]
    report = {"parameters": {n: {"value": _natural(n, v), "std": _natural_std(n, v, s)} for n, v, s in zip(names, p, std)},
              "unidentifiable": [n for n, x in zip(names, lost) if x],
              "iterations": its, "history": history, "wall_s": time.perf_counter() - t0,
              "training": metrics(cur["error_mm"], cur["converged"], L), "rows": len(meas)}
    if "weight" in physics:
        report["weight"] = weight_report(fitted)
    return {"scene": fitted, "report": report, "prediction": cur}


def weight_report(data: dict) -> dict:
    """What a fitted weight says (scene dict with density and [loads] gravity): the weight per
    length [N/m] and in all [N], its direction in the base frame (the mounting), and the Young's
    modulus it implies if gravity is 9.81 m/s^2 and the density is right (a displacement-controlled
    robot's statics do not change when E, 1 / compliance, pretension and weight scale together)."""
    r = data["robot"]
    g = np.array(data.get("loads", {}).get("gravity", [0.0, 0.0, 0.0]), dtype=float)
    w = r["density"] * math.pi * r["radius"] ** 2 * float(np.linalg.norm(g))
    return {"per_length_N_per_m": w, "total_N": w * r["length"],
            "direction": (g / np.linalg.norm(g)).tolist() if w > 0 else None,
            "implied_youngs_modulus_Pa": r["youngs_modulus"] * 9.81 / float(np.linalg.norm(g)) if w > 0 else None}


def unidentifiable(J: np.ndarray) -> np.ndarray:
    """(P,) bool: the parameters the data cannot determine, from the Jacobian J (rows, P) of the
    residual: its columns scaled to unit length (a zero column: flagged), the directions the data
    see are the right singular vectors whose singular value is at least RANK_RTOL times the
    largest (at most one per row); a parameter is flagged when more than NULL_SHARE of its unit
    vector lies outside them (in the null space). Memory: J's size (the thin SVD)."""
    norm = np.linalg.norm(J, axis=0)
    lost = ~(norm > 0)
    live = np.flatnonzero(~lost)
    if not len(live):
        return lost
    _, sv, vt = np.linalg.svd(J[:, live] / norm[live], full_matrices=False)
    seen = vt[sv >= RANK_RTOL * sv[0]]
    lost[live] = np.sqrt(np.clip(1.0 - (seen ** 2).sum(axis=0), 0.0, None)) > NULL_SHARE
    return lost


def _standard_deviations(J: np.ndarray, r: np.ndarray, lost: np.ndarray) -> np.ndarray:
    """(P,) standard deviations sqrt(diag(sigma^2 (J^T J)^-1)) of the identifiable parameters
    (the ``lost`` ones held at their values, their entries NaN), sigma^2 = |r|^2 / (rows - those
    parameters) the residual variance per coordinate; all NaN without a residual degree of freedom."""
    std = np.full(J.shape[1], np.nan)
    keep = np.flatnonzero(~lost)
    if len(r) <= len(keep) or not len(keep):
        return std
    sigma2 = float(r @ r) / (len(r) - len(keep))
    std[keep] = np.sqrt(np.clip(np.diag(sigma2 * np.linalg.inv(J[:, keep].T @ J[:, keep])), 0, None))
    return std


def _levenberg_marquardt(evaluate, jacobian, p: np.ndarray, warm, lo: np.ndarray, hi: np.ndarray, max_iter: int,
                         history: list, progress, rtol: float) -> tuple[np.ndarray, dict, int]:
    """Levenberg-Marquardt (Marquardt's scaling, lambda from LM_LAMBDA0, /3 on success, x4 on
    failure) from p within [lo, hi] on ``evaluate(q, warm)``'s residual ``error_mm`` over its
    ``rows`` (the first evaluation warm-started from ``warm`` or None), with the Jacobian
    ``jacobian(q, evaluation)`` made at accepted points only (kept as the evaluation's
    ``jacobian``). A trial is accepted if it converges on as many rows and lowers the cost. Stops
    when a step fails 8 times, the cost falls by less than ``rtol``, or after max_iter iterations.
    Appends to ``history``; returns (p, its evaluation, iterations)."""
    cur = evaluate(p, warm)
    cur["jacobian"] = jacobian(p, cur)
    lam, it = LM_LAMBDA0, 0
    for it in range(1, max_iter + 1):
        rows, J = cur["rows"], cur["jacobian"]
        r = cur["error_mm"][rows].ravel() * 1e-3
        cost = float(r @ r)
        A, g = J.T @ J, -J.T @ r
        accepted = False
        for _ in range(8):
            dp = np.linalg.solve(A + lam * np.diag(np.diag(A) + 1e-30), g)
            q = np.clip(p + dp, lo, hi)
            trial = evaluate(q, cur["solution"])
            rt = trial["error_mm"][np.intersect1d(rows, trial["rows"])].ravel() * 1e-3
            if len(trial["rows"]) >= len(rows) and float(rt @ rt) < cost:
                p, cur, lam, accepted = q, trial, lam / 3, True
                break
            lam *= 4
        history.append({"iteration": len(history), "rows": len(cur["converged"]),
                        "rmse_mm": float(np.sqrt(cost / max(len(r) // 3, 1)) * 1e3), "lambda": lam,
                        "accepted": accepted})
        if progress:
            progress(history[-1])
        if not accepted:
            break
        cur["jacobian"] = jacobian(p, cur)
        new_cost = float(np.sum(cur["error_mm"][cur["rows"]] ** 2)) * 1e-6
        if np.abs(dp).max() < 1e-7 or cost - new_cost < rtol * cost:  # the cost has stopped falling
            break
    return p, cur, it


def _natural(name: str, v: float) -> float:
    return float(math.exp(v)) if name.startswith("compliance") else float(v)


def _natural_std(name: str, v: float, s: float) -> float:
    return float(math.exp(v) * s) if name.startswith("compliance") else float(s)
