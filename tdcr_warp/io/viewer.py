"""The interactive 3D viewer: one self-contained HTML file (plotly, its JavaScript embedded) that
opens offline in any browser. Rotate, zoom and pan the robot(s); hover on a backbone for its arc
length s [m] and position [mm], on a tendon for its index, tension [N] and s;
a trajectory gets a time slider and play/pause buttons (at most MAX_FRAMES = 200 frames, and
ROD_FRAMES = 1000 rods x frames: a longer run is drawn at evenly spaced stored shapes).

Drawn from :func:`tdcr_warp.io.drawing.robot_geometry`, in millimetres, with equal scales on the
three axes (fixed over a trajectory's frames):

- per rod: its backbone (a thick line; one legend entry per rod when there are several, which
  also hides that rod's disks and tendons), its disks' rims (one trace, the rims separated by
  gaps), every tendon (one trace each) coloured by its tension on one colour scale shared by
  every tendon, rod and frame, with a colour bar in N;
- the base frames and the tip frames as short axes, x red, y green, z blue (three traces, one
  per axis direction, holding every rod's base and tip).

Traces per figure: B x (1 backbone + 1 disks [if disks > 0] + K tendons) + 3 frame axes.

``tdcr-warp static|simulate|control SCENE.toml --html`` writes ``robot.html``.
"""

from __future__ import annotations

import base64
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from tdcr_warp.io.drawing import AXIS_COLOURS, TENSION_SCALE, RobotGeometry, robot_geometry, rod_colours
from tdcr_warp.model.robot import InputError, Robot

__all__ = ["MAX_FRAMES", "MAX_RODS", "find_browser", "frame_indices", "robot_figure", "screenshot", "shape_tensions",
           "viewer_spec", "write_run_viewer", "write_viewer"]

MAX_RODS = 10  # rods the CLI draws (the first ones)
MAX_FRAMES = 200  # animation frames kept of a longer trajectory (evenly spaced, first and last kept)
ROD_FRAMES = 1000  # and at most this many rods x frames (10 rods: 100 frames), to keep the file small
RIM_POINTS = 16  # segments of a disk's rim
EYE = 2.1  # the camera's distance, in the largest of the scene box's half sizes (plotly's aspect ratios)
MM = 1e3
RIM_COLOUR = "rgba(110, 110, 110, 0.75)"  # the disks' rims (the palette's rods, tensions and axes: drawing)


def frame_indices(count: int, max_frames: int = MAX_FRAMES, rods: int = 1) -> np.ndarray:
    """The frames drawn of ``count``: at most ``max_frames`` and ``ROD_FRAMES / rods`` indices,
    evenly spaced, the first and last kept."""
    max_frames = min(max_frames, max(2, ROD_FRAMES // max(rods, 1)))
    if count <= max_frames:
        return np.arange(count)
    return np.unique(np.round(np.linspace(0, count - 1, max(max_frames, 2))).astype(int))


def _gapped(parts) -> np.ndarray:
    """Polylines (each (P, C)) joined into one (sum P + gaps, C) array, NaN rows between them
    (plotly draws no line across a NaN)."""
    out = []
    for i, p in enumerate(parts):
        if i:
            out.append(np.full((1, p.shape[1]), np.nan))
        out.append(p)
    return np.concatenate(out) if out else np.zeros((0, 3))


def _f32(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float32)  # plotly embeds numpy arrays as typed arrays


def _axes_segments(origins, rotations, length: float) -> list[np.ndarray]:
    """Per axis j (x, y, z): the segments origin -> origin + length R[:, j], one per frame, NaN-gapped."""
    return [_gapped([np.stack([o, o + length * R[:, j]]) for o, R in zip(origins, rotations)]) for j in range(3)]


def _traces(g: RobotGeometry, colours, cmax: float, axis_length: float, base, base_R, names) -> list[dict]:
    """The traces of one frame (plotly trace dicts, positions in mm), in a fixed order."""
    B, K = g.rods, len(g.tendon_points)
    several = B > 1
    traces = []
    rims = g.disk_rims(RIM_POINTS) if g.disk_s.shape[1] else None
    for b in range(B):
        group = names[b]
        p = g.backbone[b] * MM
        traces.append(dict(
            type="scatter3d", mode="lines", name=names[b], legendgroup=group, showlegend=several,
            x=_f32(p[:, 0]), y=_f32(p[:, 1]), z=_f32(p[:, 2]), customdata=_f32(g.s[b]),
            line=dict(color=colours[b], width=9),
            hovertemplate=(f"{names[b]} backbone<br>s = %{{customdata:.4f}} m<br>"
                           "position = (%{x:.2f}, %{y:.2f}, %{z:.2f}) mm<extra></extra>")))
        if rims is not None:
            D = rims.shape[1]
            pts = _gapped([rims[b, d] * MM for d in range(D)])
            traces.append(dict(
                type="scatter3d", mode="lines", name=f"{names[b]} disks", legendgroup=group, showlegend=False,
                x=_f32(pts[:, 0]), y=_f32(pts[:, 1]), z=_f32(pts[:, 2]), line=dict(color=RIM_COLOUR, width=2),
                hovertemplate=f"{names[b]}: {D} disks<extra></extra>"))
        for k in range(K):
            q = g.tendon_points[k][b] * MM
            tau = float(g.tension[b, k])
            traces.append(dict(
                type="scatter3d", mode="lines", name=f"{names[b]} tendon {k}", legendgroup=group, showlegend=False,
                x=_f32(q[:, 0]), y=_f32(q[:, 1]), z=_f32(q[:, 2]),
                customdata=_f32(np.stack([g.tendon_s[k][b], np.full(len(q), tau)], axis=1)),
                line=dict(color=_f32(np.full(len(q), tau)), colorscale=TENSION_SCALE, cmin=0.0, cmax=cmax, width=5,
                          showscale=(b == 0 and k == 0),
                          colorbar=dict(title=dict(text="tension [N]"), thickness=14, len=0.6)),
                hovertemplate=(f"{names[b]} tendon {k}<br>tension = %{{customdata[1]:.3f}} N<br>"
                               "s = %{customdata[0]:.4f} m<extra></extra>")))
    for j, outline in enumerate(g.obstacles):
        q = outline * MM
        traces.append(dict(type="scatter3d", mode="lines", name=f"obstacle {j}", showlegend=False,
                           x=_f32(q[:, 0]), y=_f32(q[:, 1]), z=_f32(q[:, 2]), connectgaps=False,
                           line=dict(color="#888888", width=3), hovertemplate=f"obstacle {j}<extra></extra>"))
    origins = np.concatenate([base, g.tip_position]) * MM
    frames = np.concatenate([base_R, g.tip_rotation])
    for j, seg in enumerate(_axes_segments(origins, frames, axis_length * MM)):
        traces.append(dict(type="scatter3d", mode="lines", name=f"frame {'xyz'[j]}", showlegend=False,
                           x=_f32(seg[:, 0]), y=_f32(seg[:, 1]), z=_f32(seg[:, 2]),
                           line=dict(color=AXIS_COLOURS[j], width=6), hoverinfo="skip"))
    return traces


def _geometries(robot: Robot, P, R, s, tau, display) -> list[RobotGeometry]:
    """robot_geometry of each frame of P (F, B, N+1, 3). A robot shared by the batch (no per-rod
    field) draws all F x B rods in one call (its cost is per disk and tendon, not per rod)."""
    F, B = P.shape[:2]
    if robot.batch_size > 1 or F == 1:
        return [robot_geometry(robot, P[i], R[i], s, tau[i], display) for i in range(F)]
    S = np.broadcast_to(np.broadcast_to(np.asarray(s, dtype=np.float64), P.shape[1:3])[None], P.shape[:3])
    g = robot_geometry(robot, P.reshape((F * B,) + P.shape[2:]), R.reshape((F * B,) + R.shape[2:]),
                       S.reshape(F * B, -1), tau.reshape(F * B, -1), display)
    cut = lambda a, i: a[i * B:(i + 1) * B]  # noqa: E731
    return [RobotGeometry(s=cut(g.s, i), backbone=cut(g.backbone, i), disk_s=cut(g.disk_s, i),
                          disk_centres=cut(g.disk_centres, i), disk_frames=cut(g.disk_frames, i),
                          disk_radius=g.disk_radius, tendon_s=[cut(t, i) for t in g.tendon_s],
                          tendon_points=[cut(t, i) for t in g.tendon_points], tension=cut(g.tension, i),
                          tip_position=cut(g.tip_position, i), tip_rotation=cut(g.tip_rotation, i),
                          obstacles=g.obstacles)
            for i in range(F)]


def _camera(ranges, zoom: float = 1.0) -> dict:
    """A camera looking at the whole scene from the front right, a little above: plotly's
    aspectmode "data" sizes the box by span / (geometric mean of the spans), so the eye moves out
    with the largest of those (a tall, thin robot otherwise leaves the picture)."""
    spans = np.maximum([r[1] - r[0] for r in ranges], 1e-9)
    aspect = spans / np.exp(np.mean(np.log(spans)))
    eye = np.array([1.0, -1.0, 0.45]) / np.linalg.norm([1.0, -1.0, 0.45]) * EYE * float(np.max(aspect)) / zoom
    return dict(eye=dict(x=eye[0], y=eye[1], z=eye[2]), center=dict(x=0, y=0, z=0), up=dict(x=0, y=0, z=1))


def _bounds(traces) -> np.ndarray:
    pts = np.concatenate([np.stack([t["x"], t["y"], t["z"]], axis=1) for t in traces])
    return np.stack([np.nanmin(pts, axis=0), np.nanmax(pts, axis=0)])


def viewer_spec(robot: Robot, positions, rotations, s, tensions, *, times=None, display: dict | None = None,
                names=None, title: str | None = None, max_frames: int = MAX_FRAMES, zoom: float = 1.0) -> dict:
    """The viewer of B rods as a plotly figure dict {"data", "layout", "frames"} (numpy arrays in
    it; built without plotly's validation, which costs seconds on a long trajectory).

    One shape: ``positions`` (B, N+1, 3) [m], ``rotations`` (B, N+1, 3, 3), ``tensions`` (B, K) [N].
    A trajectory: ``positions`` (F, B, N+1, 3), ``rotations`` (F, B, N+1, 3, 3), ``tensions``
    (F, B, K) and ``times`` (F,) [s]: an animation frame per shape (at most ``max_frames``, and
    ROD_FRAMES / B, evenly spaced), a time slider and play/pause buttons. ``s``: the nodes' arc
    lengths (B, N+1) or (N+1,) [m]; ``display``: the scene's [display] options (disks,
    disk_radius); ``names``: a label per rod (default "rod b"); ``zoom`` > 1 moves the camera in."""
    import plotly.io as pio

    P = np.asarray(positions, dtype=np.float64)
    R = np.asarray(rotations, dtype=np.float64)
    animated = P.ndim == 4
    if not animated:
        if times is not None:
            raise InputError("times: given for one shape (a trajectory's positions are (F, B, N+1, 3))")
        P, R, tau = P[None], R[None], np.asarray(tensions, dtype=np.float64)[None]
    else:
        tau = np.asarray(tensions, dtype=np.float64)
        if times is None or len(times) != P.shape[0]:
            raise InputError(f"times: a trajectory of {P.shape[0]} shapes needs as many times, got "
                             f"{None if times is None else len(times)}")
    if P.ndim != 4 or P.shape[-1] != 3 or P.shape[0] == 0 or R.shape != P.shape + (3,):
        raise InputError(f"positions {np.shape(positions)} and rotations {np.shape(rotations)}: expected "
                         "(B, N+1, 3) and (B, N+1, 3, 3), or (F, B, N+1, 3) and (F, B, N+1, 3, 3)")
    F, B = P.shape[:2]
    K = robot.n_tendons
    tau = np.broadcast_to(tau, (F, B, K))
    keep = frame_indices(F, max_frames, B)
    times = None if times is None else np.asarray(times, dtype=np.float64)
    names = [f"rod {b}" for b in range(B)] if names is None else list(names)
    colours = rod_colours(B)
    finite = tau[keep][np.isfinite(tau[keep])]
    cmax = float(finite.max()) if finite.size and finite.max() > 0 else 1.0
    geoms = _geometries(robot, P[keep], R[keep], s, tau[keep], display)
    axis_length = geoms[0].axis_length
    base, base_R = P[keep[0], :, 0], R[keep[0], :, 0]
    data = [_traces(g, colours, cmax, axis_length, base, base_R, names) for g in geoms]
    lo, hi = np.min([_bounds(d)[0] for d in data], axis=0), np.max([_bounds(d)[1] for d in data], axis=0)
    pad = 0.04 * float(np.max(hi - lo)) + 1.0  # [mm]
    ranges = [[float(lo[i] - pad), float(hi[i] + pad)] for i in range(3)]
    spans = hi - lo + 2 * pad
    ticks = [int(np.clip(np.round(8 * spans[i] / spans.max()), 3, 8)) for i in range(3)]  # a short axis: few labels

    def head(i):
        return title or f"tdcr-warp: {B} rod{'s' * (B > 1)}" + (f", t = {times[i]:.4f} s" if animated else "")

    layout = dict(
        template=pio.templates["plotly_white"].to_plotly_json(),
        title=dict(text=head(keep[0]), x=0.02), margin=dict(l=0, r=0, t=40, b=0),
        legend=dict(x=0.01, y=0.95, bgcolor="rgba(255,255,255,0.7)"), hoverlabel=dict(namelength=-1),
        scene=dict(aspectmode="data", uirevision="keep",
                   xaxis=dict(title=dict(text="x [mm]"), range=ranges[0], nticks=ticks[0]),
                   yaxis=dict(title=dict(text="y [mm]"), range=ranges[1], nticks=ticks[1]),
                   zaxis=dict(title=dict(text="z [mm]"), range=ranges[2], nticks=ticks[2]),
                   camera=_camera(ranges, zoom)))
    spec = dict(data=data[0], layout=layout, frames=[])
    if animated:
        name = [f"{times[i]:.6g}" for i in keep]
        spec["frames"] = [dict(data=d, name=n, layout=dict(title=dict(text=head(i))))
                          for i, n, d in zip(keep, name, data)]
        play = dict(frame=dict(duration=60, redraw=True), fromcurrent=True, transition=dict(duration=0))
        pause = dict(frame=dict(duration=0, redraw=False), mode="immediate", transition=dict(duration=0))
        jump = dict(frame=dict(duration=0, redraw=True), mode="immediate", transition=dict(duration=0))
        layout["scene"]["domain"] = dict(y=[0.13, 1.0])  # room for the slider
        layout["updatemenus"] = [dict(
            type="buttons", direction="left", x=0.02, y=0.02, xanchor="left", yanchor="bottom", pad=dict(r=8, t=8),
            showactive=False, buttons=[dict(label="play", method="animate", args=[None, play]),
                                       dict(label="pause", method="animate", args=[[None], pause])])]
        layout["sliders"] = [dict(
            active=0, x=0.16, y=0.02, len=0.8, xanchor="left", yanchor="bottom", pad=dict(t=8, b=8),
            currentvalue=dict(prefix="t = ", suffix=" s", font=dict(size=13, color="#333")),
            # every step's label would overlap beyond a dozen: the current value says the time
            font=dict(size=10, color="#555" if len(keep) <= 12 else "rgba(0,0,0,0)"),
            steps=[dict(label=f"{times[i]:.4g}", method="animate", args=[[n], jump]) for i, n in zip(keep, name)])]
    return spec


def robot_figure(robot: Robot, positions, rotations, s, tensions, **kw):
    """The viewer as a plotly ``Figure`` (:func:`viewer_spec`'s arguments), e.g. to show in a
    notebook (``fig.show()``) or to change before writing it (validated by plotly: slow for
    hundreds of frames, where :func:`write_viewer` is not)."""
    import plotly.graph_objects as go

    return go.Figure(viewer_spec(robot, positions, rotations, s, tensions, **kw))


def _typed(obj):
    """The spec with its numpy arrays as plotly.js typed arrays (base64; plotly.js >= 2.28)."""
    if isinstance(obj, dict):
        return {k: _typed(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_typed(v) for v in obj]
    if isinstance(obj, np.ndarray):  # floats as float32, integers as int32 (plotly.js has no int64)
        a = np.ascontiguousarray(obj, dtype=np.float32 if obj.dtype.kind == "f" else np.int32)
        out = {"dtype": "f4" if a.dtype == np.float32 else "i4", "bdata": base64.b64encode(a.tobytes()).decode("ascii")}
        if a.ndim > 1:
            out["shape"] = ", ".join(str(n) for n in a.shape)
        return out
    return obj


def write_viewer(path, robot: Robot, positions, rotations, s, tensions, **kw) -> Path:
    """Write the viewer (:func:`viewer_spec`'s arguments) to ``path``: one HTML file with
    plotly's JavaScript embedded (no network needed to open it), filling the browser window.
    Returns the path."""
    import plotly.io as pio

    spec = _typed(viewer_spec(robot, positions, rotations, s, tensions, **kw))
    html = pio.to_html(spec, validate=False, include_plotlyjs=True, full_html=True, auto_play=False,
                       default_width="100%", default_height="100vh",
                       config={"displaylogo": False, "responsive": True})
    path = Path(path)
    path.write_text(html.replace("<body>", '<body style="margin: 0; overflow: hidden;">', 1), encoding="utf-8")
    return path


def shape_tensions(run, initial_tensions) -> np.ndarray:
    """The tensions (S, B, K) [N] of a run's stored shapes: at stored step i > 0 the command of
    step i (``run.tensions[i - 1]``), at step 0 the static start's ``initial_tensions`` (B, K)."""
    T, B, K = run.tensions.shape
    start = np.broadcast_to(np.asarray(initial_tensions, dtype=np.float64), (B, K))
    return np.stack([start if i == 0 else run.tensions[i - 1] for i in np.asarray(run.shape_steps)])


def write_run_viewer(path, robot: Robot, run, s, initial_tensions, *, display: dict | None = None,
                     rods: int = MAX_RODS, title: str | None = None, max_frames: int = MAX_FRAMES) -> int:
    """The viewer of a trajectory (:class:`tdcr_warp.Trajectory`) or closed-loop run
    (:class:`tdcr_warp.apps.control.ControlRun`) from its stored shapes (``shape_steps``,
    ``positions``, ``rotations``, the shapes kept every ``[dynamics].shapes_every`` steps), its
    first ``rods`` rods; ``s``: the nodes' arc lengths (the Simulator's ``grid``);
    ``initial_tensions``: the static start's (B, K). Returns the number of frames drawn."""
    steps = np.asarray(getattr(run, "shape_steps", np.zeros(0)))
    positions = getattr(run, "positions", None)
    if positions is None or len(steps) == 0 or positions.shape[0] == 0:
        raise InputError("--html: the run stored no shapes: set [dynamics].shapes_every (e.g. 5) in the scene")
    n = min(positions.shape[1], rods)
    s = np.asarray(s)
    times = np.asarray(run.time)[steps]
    write_viewer(path, robot, positions[:, :n], run.rotations[:, :n], s[:n] if s.ndim == 2 else s,
                 shape_tensions(run, initial_tensions)[:, :n], times=times, display=display, title=title,
                 max_frames=max_frames)
    return len(frame_indices(len(steps), max_frames, n))


BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable", "chrome")


def find_browser() -> str | None:
    """The first Chromium-family browser on PATH (for :func:`screenshot`), or None."""
    return next((b for b in BROWSERS if shutil.which(b)), None)


def screenshot(html, png, *, width: int = 800, height: int = 600, budget_ms: int = 5000, browser: str | None = None,
               timeout: float = 60.0) -> Path:
    """Render ``html`` (a viewer file) in a headless Chromium and save a ``width`` x ``height``
    PNG to ``png``; ``budget_ms``: the virtual time the page gets to draw (WebGL in software).
    Headless Chromium lays the page out about 90 px shorter than its window: the PNG's bottom
    rows stay blank. Raises RuntimeError when no browser is found or it writes no picture."""
    browser = browser or find_browser()
    if browser is None or shutil.which(browser) is None:
        raise RuntimeError(f"no Chromium-family browser on PATH (tried {', '.join(BROWSERS)})")
    png = Path(png).resolve()
    png.unlink(missing_ok=True)
    with tempfile.TemporaryDirectory(prefix="tdcr-viewer-") as profile:  # a fresh profile: no lock, no state
        # WebGL in software (SwiftShader: Chromium no longer falls back to it without the flag)
        cmd = [browser, "--headless", "--disable-gpu", "--enable-unsafe-swiftshader", "--no-sandbox",
               "--hide-scrollbars", "--no-first-run", "--disable-extensions", f"--user-data-dir={profile}",
               f"--window-size={width},{height}",
               f"--virtual-time-budget={budget_ms}", f"--screenshot={png}", Path(html).resolve().as_uri()]
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)
    if not png.exists():
        raise RuntimeError(f"{browser} wrote no screenshot (exit {proc.returncode}): {proc.stderr[-2000:]}")
    return png
