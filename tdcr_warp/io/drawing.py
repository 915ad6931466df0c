"""The robot as roboticists draw it: the backbone, its spacer disks, every tendon's path through
the disks with its tension, the base and tip frames. One geometry, used by the figures
(:mod:`tdcr_warp.io.plotting`), the animations and the HTML viewer (:mod:`tdcr_warp.io.viewer`).

Disks are drawn, not modelled: the rod's physics is continuous (the coupled model routes each
tendon along its path r(s) in the body frame). The ``[display]`` table of a scene sets how many
disks to draw and their radius:

    [display]
    disks = 20          # evenly spaced along the rod, the last at the tip (default 20)
    disk_radius = 0.012 # [m] (default 1.25 x the largest tendon offset, at least 2 x the rod radius)
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tdcr_warp.model.robot import InputError, Robot

__all__ = ["AXIS_COLOURS", "DISK_COLOUR", "DISPLAY_KEYS", "ROD_COLOURS", "TENSION_SCALE", "RobotGeometry",
           "display_options", "robot_geometry", "rod_colours"]

DISPLAY_KEYS = {"disks", "disk_radius"}
DEFAULT_DISKS = 20

# One palette for the figures, the animations and the viewer. Rods: blues, greens, purples (no reds
# or oranges: those are the tensions); one rod: near black.
ROD_COLOURS = ["#1f77b4", "#2ca02c", "#9467bd", "#17becf", "#393b79", "#637939", "#bcbd22", "#5254a3",
               "#8ca252", "#6b6ecf"]
SINGLE_ROD_COLOUR = "#202020"
DISK_COLOUR = "#8c8c8c"
# tension: light orange (slack, still visible on white) to dark red (the largest tension drawn)
TENSION_SCALE = [[0.0, "#fdae6b"], [0.4, "#f16913"], [0.75, "#d7301f"], [1.0, "#7f0000"]]
AXIS_COLOURS = ("#e41a1c", "#33a02c", "#1f4fff")  # the base and tip frames' x, y, z


def rod_colours(rods: int) -> list[str]:
    """A colour per rod: near black for one rod, else ROD_COLOURS in turn."""
    return [SINGLE_ROD_COLOUR] if rods == 1 else [ROD_COLOURS[b % len(ROD_COLOURS)] for b in range(rods)]


def display_options(table: dict | None) -> dict:
    """The checked ``[display]`` table: {"disks": int >= 0, "disk_radius": float > 0 or None}."""
    if table is not None and not isinstance(table, dict):
        raise InputError(f"[display] must be a table (disks, disk_radius), got {table!r}")
    t = dict(table or {})
    unknown = set(t) - DISPLAY_KEYS
    if unknown:
        raise InputError(f"unknown key {sorted(unknown)[0]!r} in [display] (known: {', '.join(sorted(DISPLAY_KEYS))})")
    disks = t.get("disks", DEFAULT_DISKS)
    if not isinstance(disks, int) or isinstance(disks, bool) or not 0 <= disks <= 1000:
        raise InputError(f"[display].disks must be an integer in [0, 1000], got {disks!r}")
    radius = t.get("disk_radius")
    if radius is not None and (isinstance(radius, bool) or not isinstance(radius, (int, float)) or not radius > 0
                               or not np.isfinite(radius)):
        raise InputError(f"[display].disk_radius must be a positive number [m], got {radius!r}")
    return {"disks": disks, "disk_radius": None if radius is None else float(radius)}


@dataclass
class RobotGeometry:
    """What to draw of B rods, in the world frame [m].

    s (B, N+1) and backbone (B, N+1, 3): the nodes; disk_s (B, D), disk_centres (B, D, 3),
    disk_frames (B, D, 3, 3) (columns: the body axes d1, d2, d3 = the backbone's tangent
    frame), disk_radius; tendon_s[k] (B, P_k) and tendon_points[k] (B, P_k, 3): tendon k from
    the base through every disk it passes to its end; tension (B, K) [N] at the base;
    tip_position (B, 3), tip_rotation (B, 3, 3); obstacles: each obstacle's outline as polylines
    (P, 3), NaN rows between them (rod 0's pose, ``obstacle_outlines``)."""

    s: np.ndarray
    backbone: np.ndarray
    disk_s: np.ndarray
    disk_centres: np.ndarray
    disk_frames: np.ndarray
    disk_radius: float
    tendon_s: list
    tendon_points: list
    tension: np.ndarray
    tip_position: np.ndarray
    tip_rotation: np.ndarray
    obstacles: list = field(default_factory=list)

    @property
    def rods(self) -> int:
        return self.backbone.shape[0]

    @property
    def axis_length(self) -> float:
        """The drawn length [m] of the base and tip frames' axes: 6 % of the longest rod, at least
        2.5 disk radii (clear of the disks)."""
        return max(2.5 * self.disk_radius, 0.06 * float(np.max(self.s[:, -1])))

    def disk_rims(self, points: int = 24) -> np.ndarray:
        """The disks' rims (B, D, points + 1, 3), closed."""
        a = np.linspace(0.0, 2 * np.pi, points + 1)
        ring = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=-1) * self.disk_radius  # body frame
        return self.disk_centres[:, :, None] + np.einsum("bdij,pj->bdpi", self.disk_frames, ring)


def _at(s_nodes: np.ndarray, values: np.ndarray, s: np.ndarray) -> np.ndarray:
    """values (N+1, ...) at the nodes s_nodes (N+1,), linearly interpolated at s (P,)."""
    i = np.clip(np.searchsorted(s_nodes, s, side="right") - 1, 0, len(s_nodes) - 2)
    w = ((s - s_nodes[i]) / np.maximum(s_nodes[i + 1] - s_nodes[i], 1e-300)).reshape((-1,) + (1,) * (values.ndim - 1))
    return (1 - w) * values[i] + w * values[i + 1]


def _first(a: np.ndarray, B: int) -> np.ndarray:
    """Rows 0..B-1 of a per-rod table (1 or >= B rows)."""
    return np.broadcast_to(a, (B,) + a.shape[1:]) if a.shape[0] == 1 else a[:B]


def _orthonormal(R: np.ndarray) -> np.ndarray:
    """The nearest rotations of interpolated frames (..., 3, 3) (polar decomposition)."""
    u, _, vt = np.linalg.svd(R)
    return u @ vt


def _ring(centre: np.ndarray, u: np.ndarray, v: np.ndarray, radius: float, points: int = 36) -> np.ndarray:
    a = np.linspace(0.0, 2 * np.pi, points + 1)[:, None]
    return centre + radius * (np.cos(a) * u + np.sin(a) * v)


def _across(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors across the unit vector d."""
    u = np.cross(d, [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    return u, np.cross(d, u)


def obstacle_outlines(robot: Robot) -> list:
    """Each obstacle of rod 0 as polylines (P, 3) [m] joined by NaN rows: a plane as a square of
    the rod's length with a cross, a sphere as three great circles, a capsule or tube as its end
    rings and four lines along it, a bent tube as rings along its arc and four lines."""
    out, size = [], float(robot.length[0])
    gap = np.full((1, 3), np.nan)
    for ob in robot.obstacles:
        parts = []
        if ob.kind == "plane":
            c, n = ob.point[0], ob.normal[0]
            u, v = _across(n)
            corners = [c + size * (a * u + b * v) for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1), (-1, -1))]
            parts = [np.array(corners), np.array([c - size * u, c + size * u]), np.array([c - size * v, c + size * v])]
        elif ob.kind == "sphere":
            c, r, e = ob.center[0], float(ob.radius[0]), np.eye(3)
            parts = [_ring(c, e[i], e[(i + 1) % 3], r) for i in range(3)]
        elif ob.kind in ("capsule", "tube"):
            a, b, r = ob.start[0], ob.end[0], float(ob.radius[0])
            u, v = _across((b - a) / np.linalg.norm(b - a))
            parts = [_ring(a, u, v, r), _ring(b, u, v, r)] + [np.array([a + r * w, b + r * w]) for w in (u, -u, v, -v)]
        else:  # bent tube: its centre line turns from direction toward toward, about their normal
            a, d, t = ob.start[0], ob.direction[0], ob.toward[0]
            bend, r, angle = float(ob.bend_radius[0]), float(ob.radius[0]), float(ob.angle[0])
            z = np.cross(d, t)
            th = np.linspace(0.0, angle, 25)[:, None]
            centre = a + bend * t
            line = centre + bend * (np.sin(th) * d - np.cos(th) * t)  # the centre line
            normal = np.sin(th) * d - np.cos(th) * t
            parts = [line + r * w for w in (normal, -normal)] + [line + r * z, line - r * z]
            parts += [_ring(line[i], normal[i], z, r) for i in range(0, len(th), 6)]
        out.append(np.concatenate([np.concatenate([p, gap]) for p in parts])[:-1])
    return out


def robot_geometry(robot: Robot, positions: np.ndarray, rotations: np.ndarray, s: np.ndarray, tensions,
                   display: dict | None = None) -> RobotGeometry:
    """The drawing of B solved rods: ``positions`` (B, N+1, 3) [m], ``rotations`` (B, N+1, 3, 3)
    and arc lengths ``s`` (B, N+1) or (N+1,) of the nodes (a StaticSolution's, or one step of a
    trajectory), ``tensions`` (B, K) [N]; ``display``: the [display] options (display_options).
    ``robot`` may hold more rods than B (a batch's first B are drawn)."""
    opts = display_options(display)
    P, R = np.asarray(positions, dtype=np.float64), np.asarray(rotations, dtype=np.float64)
    B = P.shape[0]
    S = np.broadcast_to(np.asarray(s, dtype=np.float64), P.shape[:2])
    K = robot.n_tendons
    tau = np.broadcast_to(np.asarray(tensions, dtype=np.float64), (B, K))
    lengths = _first(robot.tendon_lengths(), B) if K else np.zeros((B, 0))
    per_rod = robot.routing_parameters()[0].shape[0]  # 1, or the robot's batch (>= B)

    def route(sv: np.ndarray) -> np.ndarray:
        """Body-frame routing (B, K, 3) of rods 0..B-1, tendon k at arc length sv[:, k] (B, K)."""
        full = np.zeros((max(per_rod, B), K))
        full[:B] = sv
        return robot.tendon_routing(full if per_rod > 1 else full[:B])[0][:B]
    offsets = [np.max(np.linalg.norm(t.offset, axis=-1)) for t in robot.tendons]
    radius = opts["disk_radius"] or max(1.25 * max(offsets, default=0.0), 2.0 * float(np.max(robot.radius)))
    D = opts["disks"]
    disk_s = S[:, -1:] * np.arange(1, D + 1)[None] / max(D, 1)
    centres = np.stack([_at(S[b], P[b], disk_s[b]) for b in range(B)]) if D else np.zeros((B, 0, 3))
    frames = _orthonormal(np.stack([_at(S[b], R[b], disk_s[b]) for b in range(B)])) if D else np.zeros((B, 0, 3, 3))
    # the candidate points of every tendon: the base, every disk, its end; the body-frame routing
    # of all tendons at them in D + 2 calls (each rod with its own routing parameters)
    cand = np.concatenate([np.zeros((B, 1)), disk_s], axis=1)  # (B, D + 1)
    r_all = np.stack([route(np.repeat(cand[:, j:j + 1], K, axis=1)) for j in range(D + 1)] + [route(lengths)],
                     axis=1) if K else None  # (B, D + 2, K, 3)
    tendon_s, tendon_points = [], []
    for k in range(K):
        sk = np.concatenate([cand, lengths[:, k:k + 1]], axis=1)  # (B, D + 2)
        keep = np.concatenate([sk[:, :-1] < lengths[:, k:k + 1] - 1e-12, np.ones((B, 1), dtype=bool)], axis=1)
        r = r_all[:, :, k]  # (B, D + 2, 3)
        pts_s, pts = [], []
        for b in range(B):
            sb = sk[b, keep[b]]
            pts_s.append(sb)
            pts.append(_at(S[b], P[b], sb) + np.einsum("pij,pj->pi", _orthonormal(_at(S[b], R[b], sb)), r[b, keep[b]]))
        width = max(len(x) for x in pts_s)  # rods of one batch may end a tendon at different disks
        tendon_s.append(np.stack([np.pad(x, (0, width - len(x)), mode="edge") for x in pts_s]))
        tendon_points.append(np.stack([np.pad(x, ((0, width - len(x)), (0, 0)), mode="edge") for x in pts]))
    return RobotGeometry(s=S, backbone=P, disk_s=disk_s, disk_centres=centres, disk_frames=frames,
                         disk_radius=radius, tendon_s=tendon_s, tendon_points=tendon_points, tension=tau.copy(),
                         tip_position=P[:, -1], tip_rotation=R[:, -1], obstacles=obstacle_outlines(robot))
